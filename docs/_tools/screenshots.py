"""Regenerate the documentation's screenshots of each command's recording and report page.

    python docs/_tools/screenshots.py [--out docs/images] [--only run,locate,cmm]

Runs ``twin demo``, ``twin locate`` and ``twin cmm compare`` into a temporary folder, serves each
recording with ``rerun --serve-web``, opens it in the system's headless Chromium (driven by
Playwright: ``pip install -e ".[screenshots]"``; no browser is downloaded), waits until the
recording is shown, moves the time cursor to the end (typed into the time field: clicks on the
time ruler do not register, the ``#when=`` URL fragment is ignored) and saves a PNG; then a
full-page PNG of each ``report.html``, and ``screenshots.json`` naming each file, the command that
made it and the commit.

Slow: minutes. With SwiftShader a frame of the viewer can take 10-25 s on a loaded machine and a
recording of tens of MB a minute or more to show; the viewer counts as shown when the recording has
finished streaming in (no "latency" in the top bar, a time field in the time panel), two
screenshots in a row are identical and the page drew frames between them. Every process it starts
(the commands, the rerun server and the native viewer it starts) is ended on the way out, also on
Ctrl-C and SIGTERM.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
VIEWPORT = {"width": 1600, "height": 1000}  # the positions below are for this window size
REPORT_VIEWPORT = {"width": 1200, "height": 800}  # the report pages are at most 1100 px wide
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]
TIME_FIELD = (392, 864)  # the time field of the time panel, right of the timeline's name and speed
IDLE_MOUSE = (1250, 15)  # an empty part of the top bar: no hover highlight in a view
TIME_FIELD_BOX = (300, 856, 490, 873)  # its text; blank while the recording has no data on the timeline
LATENCY_BOX = (215, 4, 520, 32)  # where the top bar says "N s latency" while data streams in
END_TIME = "+1000000s"  # typed into the time field; the viewer clamps it to the recording's end
POLL_S = 5.0
NAMES = ("run", "locate", "cmm")
FRAME_COUNTER = "window.__frames = 0; (function tick() { window.__frames++; requestAnimationFrame(tick); })();"


class Failure(Exception):
    """An error said in one line."""


@dataclass(frozen=True)
class Job:
    name: str  # run, locate, cmm: the PNG names
    folder: str  # under the work folder
    args: tuple[str, ...]  # twin's arguments; {out} is the output folder
    report: bool  # writes report.html

    def argv(self, work: Path) -> list[str]:
        return [a.format(out=work / self.folder) for a in self.args]

    def shown(self) -> str:
        return "twin " + " ".join(a.format(out=f"DIR/{self.folder}") for a in self.args)


JOBS = {
    "run": Job("run", "demo", ("demo", "--out", "{out}", "--quiet"), True),
    "locate": Job("locate", "locate", ("locate", "scenarios/locate_s_surface.toml", "--out", "{out}",
                                       "--rrd", "{out}/locate.rrd", "--quiet"), True),
    "cmm": Job("cmm", "cmm", ("cmm", "compare", "scenarios/cmm/teach/through_hole.toml",
                              "scenarios/cmm/through_hole.toml", "--out", "{out}", "--quiet"), False),
}


def say(text: str) -> None:
    print(f"screenshots: {text}", file=sys.stderr, flush=True)


# --- processes --------------------------------------------------------------------------------


class Processes:
    """The processes this script started, each in its own process group, ended on the way out."""

    def __init__(self) -> None:
        self.started: list[subprocess.Popen[bytes]] = []

    def start(self, argv: list[str], log: Path) -> subprocess.Popen[bytes]:
        with open(log, "wb") as out:
            proc = subprocess.Popen(argv, cwd=ROOT, stdout=out, stderr=subprocess.STDOUT, start_new_session=True)
        self.started.append(proc)
        return proc

    def stop(self, proc: subprocess.Popen[bytes]) -> None:
        """End the process's group (the rerun wrapper and the native viewer it started) and reap it."""
        for sig, grace in ((signal.SIGTERM, 10.0), (signal.SIGKILL, 5.0)):
            try:
                os.killpg(proc.pid, sig)
            except ProcessLookupError:
                break
            deadline = time.monotonic() + grace
            while time.monotonic() < deadline and _group_alive(proc.pid):
                with contextlib.suppress(subprocess.TimeoutExpired):
                    proc.wait(timeout=0.2)
            if not _group_alive(proc.pid):
                break
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(timeout=5)
        if proc in self.started:
            self.started.remove(proc)

    def stop_all(self) -> None:
        for proc in list(reversed(self.started)):
            self.stop(proc)


def _group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    # a group of zombies only (the wrapper not reaped yet) counts as ended
    return any(_state(pid) not in ("Z", "") for pid in _members(pgid))


def _members(pgid: int) -> list[int]:
    pids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            with contextlib.suppress(OSError, ValueError, IndexError):
                if int((entry / "stat").read_text().rsplit(")", 1)[1].split()[2]) == pgid:
                    pids.append(int(entry.name))
    return pids


def _state(pid: int) -> str:
    try:
        return (Path("/proc") / str(pid) / "stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return ""


def run_twin(procs: Processes, job: Job, work: Path, force: bool = False) -> float:
    """Run the job's command (exit 0, or 3: finished with a failed check, files written); its seconds."""
    log = work / f"{job.folder}.log"
    start = time.monotonic()
    proc = procs.start([sys.executable, "-m", "twin", *job.argv(work), *(["--force"] if force else [])], log)
    code = proc.wait()
    procs.started.remove(proc)
    seconds = time.monotonic() - start
    if code not in (0, 3):
        lines = log.read_text(errors="replace").strip().splitlines()
        raise Failure(f"{job.shown()} exited {code}: {lines[-1] if lines else 'no output'}")
    if code == 3:
        say(f"{job.shown()}: a check failed (exit 3); the screenshots show it as it is")
    return seconds


def find_recording(folder: Path) -> Path:
    found = sorted(folder.glob("*.rrd"), key=lambda p: p.stat().st_size, reverse=True)
    if not found:
        raise Failure(f"no .rrd recording in {folder}")
    return found[0]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def serve(procs: Processes, rrd: Path, log: Path) -> tuple[subprocess.Popen[bytes], str]:
    """Serve the recording to a web viewer; the process and the viewer's URL once it answers."""
    rerun = shutil.which("rerun", path=str(Path(sys.executable).parent)) or shutil.which("rerun")
    if rerun is None:
        raise Failure("no rerun command (pip install rerun-sdk)")
    web, grpc = free_port(), free_port()
    while grpc == web:
        grpc = free_port()
    argv = [rerun, "--serve-web", str(rrd), "--web-viewer-port", str(web), "--port", str(grpc), "--bind", "127.0.0.1"]
    proc = procs.start(argv, log)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            lines = log.read_text(errors="replace").strip().splitlines()
            raise Failure(f"rerun --serve-web exited {proc.returncode}: {lines[-1] if lines else 'no output'}")
        with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", web), timeout=1):
            return proc, f"http://127.0.0.1:{web}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{grpc}%2Fproxy"
        time.sleep(0.5)
    raise Failure(f"rerun --serve-web did not answer on port {web} within a minute")


# --- the viewer -------------------------------------------------------------------------------


def looks_shown(png: bytes) -> bool:
    """The time panel has its time field (the recording has data on a timeline) and the top bar says no
    "latency" (the recording has streamed in whole)."""
    from PIL import Image

    image = Image.open(io.BytesIO(png)).convert("RGB")
    latency = image.crop(LATENCY_BOX).getcolors(maxcolors=4)
    field = image.crop(TIME_FIELD_BOX).getcolors(maxcolors=4)
    return latency is not None and len(latency) == 1 and (field is None or len(field) > 1)


def frames(page: Any) -> int:
    return int(page.evaluate("window.__frames || 0"))


def wait_frames(page: Any, count: int, timeout: float) -> None:
    """Until the page has drawn `count` more frames (so that the viewer has handled the input)."""
    start, deadline = frames(page), time.monotonic() + timeout
    while frames(page) < start + count and time.monotonic() < deadline:
        time.sleep(0.5)


def wait_shown(page: Any, timeout: float, what: str) -> tuple[bytes, bool]:
    """Screenshots until two in a row are identical, shown, with frames drawn between; (last, settled)."""
    deadline = time.monotonic() + timeout
    previous, previous_frames = b"", 0
    while True:
        time.sleep(POLL_S)
        shot = page.screenshot()
        drawn = frames(page)
        if shot == previous and drawn >= previous_frames + 2 and looks_shown(shot):
            return shot, True
        if time.monotonic() > deadline:
            say(f"{what}: timed out after {timeout:.0f} s waiting for the viewer to settle; kept the last screenshot")
            return shot, False
        previous, previous_frames = shot, drawn


def move_time_to_end(page: Any, before: bytes, timeout: float, what: str) -> tuple[bytes, bool]:
    """Type a time past the end into the time field (the viewer clamps it); the settled screenshot."""
    page.mouse.click(*TIME_FIELD)
    wait_frames(page, 3, 60)
    page.keyboard.press("Control+a")
    page.keyboard.type(END_TIME)
    page.keyboard.press("Enter")
    wait_frames(page, 3, 60)
    page.mouse.move(*IDLE_MOUSE)
    shot, settled = wait_shown(page, timeout, what)
    if shot == before:
        say(f"{what}: the time cursor did not move (the time field not where expected?); kept the first time")
    return shot, settled


def shoot_recording(browser: Any, url: str, png: Path, timeout: float) -> bool:
    """Open the viewer, wait until the recording is shown, move to its end, save the PNG; settled or not."""
    page = browser.new_page(viewport=VIEWPORT)
    try:
        page.set_default_timeout(180_000)
        page.add_init_script(FRAME_COUNTER)
        page.goto(url, wait_until="load")
        page.mouse.move(*IDLE_MOUSE)
        first, loaded = wait_shown(page, timeout, png.name)
        shot, settled = move_time_to_end(page, first, timeout, png.name)
        png.write_bytes(shot)
        shrink(png)
        return loaded and settled
    finally:
        page.close()


def shoot_report(browser: Any, html: Path, png: Path) -> None:
    page = browser.new_page(viewport=REPORT_VIEWPORT)
    try:
        page.goto(html.as_uri(), wait_until="load")
        page.screenshot(path=str(png), full_page=True)
        shrink(png)
    finally:
        page.close()


def shrink(png: Path, colours: int = 256) -> None:
    """The PNG reduced to a palette of ``colours`` by an octree (every colour within 14 levels of
    8 bits on the legend's colour bar, where a median cut merged the bar's hues; a third of
    the bytes: the documentation's pages load faster)."""
    from PIL import Image

    with Image.open(png) as im:
        small = im.convert("RGB").quantize(colors=colours, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE)
    small.save(png, optimize=True)


# --- the whole ---------------------------------------------------------------------------------


def git_commit() -> str:
    def git(*args: str) -> str:
        done = subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, check=False, timeout=60)
        return done.stdout.strip() if done.returncode == 0 else ""

    commit = git("rev-parse", "--short", "HEAD") or "unknown"
    # the images this script writes are not what they show: only the code counts
    changed = git("status", "--porcelain", "--", ".", ":(exclude)docs/images")
    return commit + (" with uncommitted changes" if changed else "")


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="python docs/_tools/screenshots.py",
        description="Screenshots of twin demo's, twin locate's and twin cmm compare's recordings in Rerun's "
        "web viewer and of their report pages, for the documentation. Needs playwright (pip install -e "
        '".[screenshots]") and Chromium at /usr/bin/chromium. Takes minutes.',
    )
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "images", help="folder for the PNGs and "
                        "screenshots.json (default: docs/images)")
    parser.add_argument("--only", default=",".join(NAMES), help="comma-separated subset of run,locate,cmm")
    parser.add_argument("--timeout", type=float, default=600.0, help="seconds to wait for the viewer to settle, "
                        "each time (default 600); past it the last screenshot is kept and stderr says so")
    parser.add_argument("--work", type=Path, help="run the commands into this folder and keep it (default: a "
                        "temporary folder, removed); outputs already there are used, not made again")
    args = parser.parse_args(argv)
    only = [n.strip() for n in args.only.split(",") if n.strip()]
    unknown = [n for n in only if n not in NAMES]
    if unknown or not only:
        parser.error(f"--only: {', '.join(unknown) or 'nothing'} not among {','.join(NAMES)}")
    if args.timeout <= 0:
        parser.error("--timeout must be positive")
    args.only = [n for n in NAMES if n in only]
    return args


def make_recordings(procs: Processes, jobs: list[Job], work: Path) -> dict[str, float]:
    seconds = {}
    for job in jobs:
        if (work / job.folder).is_dir() and list((work / job.folder).glob("*.rrd")):
            say(f"{job.shown()}: using what {work / job.folder} holds")
            continue
        say(f"running {job.shown()}")
        seconds[job.name] = run_twin(procs, job, work, force=(work / job.folder).exists())
        say(f"{job.shown()}: {seconds[job.name]:.0f} s")
    return seconds


def shoot_all(procs: Processes, jobs: list[Job], work: Path, out: Path, timeout: float) -> list[dict[str, Any]]:
    """The PNGs of every job into `out`; an entry of screenshots.json for each."""
    from playwright.sync_api import sync_playwright

    entries = []
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        for job in jobs:
            rrd = find_recording(work / job.folder)
            png = out / f"screenshot_{job.name}_recording.png"
            start = time.monotonic()
            server, url = serve(procs, rrd, work / f"{job.folder}_rerun.log")
            try:
                settled = shoot_recording(browser, url, png, timeout)
            finally:
                procs.stop(server)
            took = time.monotonic() - start
            say(f"{png.name}: {took:.0f} s" + ("" if settled else " (timed out)"))
            entries.append({"file": png.name, "command": job.shown(), "seconds": round(took),
                            "shot": f"rerun --serve-web DIR/{job.folder}/{rrd.name} --web-viewer-port PORT --bind "
                            f"127.0.0.1 in headless Chromium ({VIEWPORT['width']}x{VIEWPORT['height']}, "
                            f"SwiftShader), the time cursor at the recording's end", "settled": settled})
            if job.report:
                png = out / f"screenshot_{job.name}_report.png"
                start = time.monotonic()
                shoot_report(browser, work / job.folder / "report.html", png)
                took = time.monotonic() - start
                say(f"{png.name}: {took:.0f} s")
                entries.append({"file": png.name, "command": job.shown(), "seconds": round(took),
                                "shot": f"DIR/{job.folder}/report.html in headless Chromium, full page"})
        browser.close()
    return entries


def write_index(out: Path, entries: list[dict[str, Any]]) -> None:
    """screenshots.json: the entries made now, and those of files made before and not made again."""
    path = out / "screenshots.json"
    commit = git_commit()
    made = {e["file"] for e in entries}
    old: list[dict[str, Any]] = []
    with contextlib.suppress(OSError, ValueError, TypeError, KeyError):
        before = json.loads(path.read_text())["files"]
        old = [e for e in before if e["file"] not in made and (out / e["file"]).is_file()]
    for entry in entries:
        entry["commit"] = commit
    files = sorted(old + entries, key=lambda e: e["file"])
    index = {"made_by": "python docs/_tools/screenshots.py", "files": files}
    path.write_text(json.dumps(index, indent=2) + "\n")


def _on_signal(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    signal.signal(signal.SIGTERM, _on_signal)
    signal.signal(signal.SIGINT, _on_signal)  # also where the caller ignored it (a background job)
    procs = Processes()
    jobs = [JOBS[n] for n in args.only]
    try:
        if not Path(CHROMIUM).is_file():
            raise Failure(f"no Chromium at {CHROMIUM}")
        try:
            import playwright.sync_api  # noqa: F401
        except ImportError as exc:
            raise Failure(f'{exc} (playwright: pip install -e ".[screenshots]")') from None
        out = args.out.resolve()
        out.mkdir(parents=True, exist_ok=True)
        with _work_folder(args.work) as work:
            make_recordings(procs, jobs, work)
            entries = shoot_all(procs, jobs, work, out, args.timeout)
        write_index(out, entries)
        say(f"wrote {', '.join(e['file'] for e in entries)} and screenshots.json to {out}")
        return 0
    except KeyboardInterrupt:
        say("interrupted; the processes it started are ended")
        return 130
    except Failure as exc:
        say(f"error: {exc}")
        return 1
    except Exception as exc:  # one line, not a traceback: Playwright's and OS errors
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
        say(f"error: {type(exc).__name__}: {first}")
        return 1
    finally:
        procs.stop_all()


@contextlib.contextmanager
def _work_folder(work: Path | None) -> Iterator[Path]:
    if work is not None:
        work = work.resolve()
        work.mkdir(parents=True, exist_ok=True)
        yield work
        return
    with tempfile.TemporaryDirectory(prefix="twin_screenshots_") as tmp:
        yield Path(tmp)


if __name__ == "__main__":
    sys.exit(main())
