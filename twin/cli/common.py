"""What every command shares: the one-line argument parser, option types, output and print
options, the progress reporter on stderr and the result on stdout."""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import re
import sys
import threading
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any, NoReturn, TextIO

from twin.errors import TwinError
from twin.io.output import check_output_file, check_output_folder, raise_if_interrupted

#: Exit statuses of every command (docs/concepts/verdicts.md, "Exit status").
EXIT_OK, EXIT_BAD_INPUT, EXIT_UNTRUSTED, EXIT_STAGE_FAILED = 0, 2, 3, 4
EXIT_BROKEN_PIPE, EXIT_SIGINT, EXIT_SIGTERM = 141, 130, 143


class OneLineParser(argparse.ArgumentParser):
    """argparse with errors as one line naming the option and what is allowed (exit 2)."""

    def error(self, message: str) -> NoReturn:
        text = " ".join(message.split())
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {text} (see {self.prog} --help)\n")


def _number(text: str, parse, ok, wanted: str):
    """``parse(text)`` if it parses and ``ok`` holds, else argparse's one-line type error."""
    try:
        value = parse(text)
    except ValueError:
        value = None
    if value is None or not ok(value):
        raise argparse.ArgumentTypeError(f"must be {wanted}, got {text!r}")
    return value


def non_negative_int(text: str) -> int:
    """An argparse type: an integer >= 0 (seeds)."""
    return _number(text, int, lambda v: v >= 0, "a non-negative integer")


def positive_int(text: str) -> int:
    """An argparse type: an integer >= 1."""
    return _number(text, int, lambda v: v >= 1, "a positive integer")


def positive_float(text: str) -> float:
    """An argparse type: a finite number > 0."""
    return _number(text, float, lambda v: math.isfinite(v) and v > 0, "a positive finite number")


def add_print_options(p: argparse.ArgumentParser, quiet: bool = True) -> None:
    """``--json`` (stdout carries the machine-readable result only) and ``--quiet`` (no progress)."""
    p.add_argument("--json", action="store_true",
                   help="print the result as one JSON object on stdout and nothing else there "
                        "(default: a short summary for a reader)")
    if quiet:
        p.add_argument("--quiet", action="store_true",
                       help="no progress lines or bars on stderr (errors are still printed)")


def add_output_options(p: argparse.ArgumentParser, out_help: str, default_out: str | None = None,
                       rrd_help: str = "also write a rerun recording to this .rrd file") -> None:
    """``--out`` (a folder), ``--rrd`` (a recording), ``--force`` (replace them whole), and the
    print options (:func:`add_print_options`) of every command that writes a folder."""
    if default_out is None:
        p.add_argument("--out", required=True, help=out_help)
    else:
        p.add_argument("--out", default=default_out, help=out_help)
    p.add_argument("--rrd", help=rrd_help)
    p.add_argument("--force", action="store_true",
                   help="replace an existing output folder (and recording) whole; without it they are refused")
    add_print_options(p)


#: A Rerun viewer's or server's gRPC address, as ``rerun`` prints it.
LIVE_URL = re.compile(r"^rerun\+https?://(?P<host>[^/:]+):(?P<port>\d{1,5})/proxy$")


def add_live_options(p: argparse.ArgumentParser) -> None:
    """``--spawn`` / ``--connect URL``: stream the run to a live viewer while it goes."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--spawn", action="store_true",
                   help="start a Rerun viewer on this machine and stream each stage to it as it finishes "
                        "(the --rrd file, if any, is still written at the end)")
    g.add_argument("--connect", metavar="URL",
                   help="stream each stage as it finishes to a Rerun viewer or server already running, "
                        "at rerun+http://HOST:PORT/proxy (what `rerun` prints when it starts)")


def live_sink(args: argparse.Namespace) -> str | None:
    """None, ``"spawn"`` or a checked viewer address: refused in one line, before any work,
    when it is malformed or nothing listens there."""
    if getattr(args, "spawn", False):
        if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
            raise TwinError("--spawn needs a display for the viewer's window (neither DISPLAY nor WAYLAND_DISPLAY "
                            "is set); write the recording with --rrd FILE and open it with `twin view FILE --web`, "
                            "or stream to a viewer elsewhere with --connect")
        return "spawn"
    url = getattr(args, "connect", None)
    if url is None:
        return None
    m = LIVE_URL.match(url)
    if m is None or not 0 < int(m["port"]) < 65536:
        raise TwinError(f"--connect {url!r} is not a Rerun viewer address; give rerun+http://HOST:PORT/proxy "
                        "(PORT 1-65535)")
    import socket

    try:
        socket.create_connection((m["host"], int(m["port"])), timeout=2.0).close()
    except OSError as exc:
        raise TwinError(f"--connect {url}: no Rerun viewer listens there ({exc.strerror or exc}); "
                        "start one with `rerun`, or use --spawn") from None
    return url


def checked_outputs(args: argparse.Namespace, default_rrd_name: str | None = None) -> tuple[Path, Path | None]:
    """The checked output folder and recording path (None: no recording), refused before any work."""
    out = check_output_folder(args.out, args.force)
    rrd_arg = getattr(args, "rrd", None)
    if rrd_arg is None and default_rrd_name is not None and not getattr(args, "no_rrd", False):
        return out, out / default_rrd_name
    if rrd_arg is None:
        return out, None
    return out, check_output_file(rrd_arg, ".rrd", args.force, "--rrd")


def progress(command: str, msg: str) -> None:
    """A line on stderr that ``--quiet`` does not silence (a stage that failed); stage lines go
    through :class:`Progress`."""
    print(f"[{command}] {msg}", file=sys.stderr, flush=True)


# ------------------------------------------------------------------ progress on stderr
#: "i/n" in a stage line ("probe point 3/12 (p3): hit"): step i of n of one series.
_COUNT = re.compile(r"(?<![\w./])(\d+)/(\d+)(?![\w./])")
#: Seconds a stage runs before a terminal shows it ticking (shorter stages print their line only).
TICK_AFTER_S = 1.0
_REFRESH_S = 0.25


class Progress:
    """A ``say`` callback (``loop.run(realized, say=...)``) that reports stages on stderr.

    Each call is one stage line, ``[command] msg``. On a terminal, a line with a count ``i/n``
    drives a tqdm bar of n steps (rate and time left; a new series starts a new bar), and a
    stage that runs longer than :data:`TICK_AFTER_S` without a line shows its elapsed time.
    Elsewhere (a pipe, a file, a test) every call is one plain line and nothing is animated,
    so a captured stderr reads as a log. ``quiet`` prints nothing. ``defer`` holds the stage
    lines until :meth:`release` or the block's end without an error (a command whose first
    stages can still refuse its input, as ``twin scan``: a refusal leaves its one error line
    only). Calls may come from several threads (the pipeline replays one path in the background).
    """

    def __init__(self, command: str, quiet: bool = False, stream: TextIO | None = None,
                 animate: bool | None = None, defer: bool = False):
        self.command = command
        self.quiet = quiet
        self.defer = defer
        self._held: list[str] = []
        self.stream = sys.stderr if stream is None else stream
        if animate is None:
            try:
                animate = self.stream.isatty()
            except (AttributeError, ValueError):
                animate = False
        self.animate = bool(animate) and not quiet
        self._lock = threading.RLock()
        self._bar: Any = None       # the counted bar of the current series
        self._series: tuple[str, int] | None = None
        self._ticker: Any = None    # elapsed time of a stage with no count
        # wall-clock seconds, the clock of tqdm's start_t, which is set back to this moment
        self._t_line = time.time()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        if self.animate:
            # tqdm redraws only when a bar moves; between stage lines nothing would move
            self._thread = threading.Thread(target=self._tick, name="twin-progress", daemon=True)
            self._thread.start()

    def __call__(self, msg: str) -> None:
        raise_if_interrupted()  # a signal a library swallowed ends the command at its next step
        if self.quiet:
            return
        text = " ".join(str(msg).split())
        with self._lock:
            m = _COUNT.search(text)
            if self.animate and m and 1 <= int(m[1]) <= int(m[2]):
                self._step(text, m)
            else:
                self._line(text)

    def release(self) -> None:
        """Print the held lines and show every later one as it comes (the input can no longer
        be refused)."""
        with self._lock:
            self.defer = False
            self._flush_held()

    def close(self) -> None:
        """Stop the ticking and leave the terminal on a fresh line."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=1.0)
        # bounded: an interrupt inside tqdm's drawing can leave the refresh thread blocked
        # while it holds this lock, and ending the command matters more than the last redraw
        if self._lock.acquire(timeout=1.0):
            try:
                self._close_ticker()
                self._close_bar()
            finally:
                self._lock.release()

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *exc: object) -> None:
        self.close()
        if exc_type is None:
            self._flush_held()
        self._held.clear()

    def _flush_held(self) -> None:
        if self._held:
            self.stream.write("".join(f"{line}\n" for line in self._held))
            self.stream.flush()
            self._held.clear()

    # ------------------------------------------------------------------ internals
    def _line(self, text: str) -> None:
        self._close_ticker()
        self._close_bar()
        if self.defer:
            self._held.append(f"[{self.command}] {text}")
        else:
            self.stream.write(f"[{self.command}] {text}\n")
            self.stream.flush()
        self._t_line = time.time()

    def _step(self, text: str, m: re.Match) -> None:
        i, n = int(m[1]), int(m[2])
        series = (text[:m.start()].strip(), n)
        if self._bar is None or series != self._series or i <= self._bar.n:
            self._close_ticker()
            self._close_bar()
            # the first step ran since the previous line: its time counts in the rate
            self._bar = self._new_bar(f"[{self.command}] {series[0]}".rstrip(), n, self._t_line)
            self._series = series
        self._bar.set_postfix_str(text[m.end():].strip(" :"), refresh=False)
        self._bar.update(i - self._bar.n)
        self._t_line = time.time()
        if i == n:
            self._close_bar()

    def _new_bar(self, desc: str, total: int | None, started: float, bar_format: str | None = None):
        """A bar whose clock started at ``started`` (the stage's start, before the bar existed)."""
        # imported here: a command whose stderr is not a terminal never needs it
        from tqdm import tqdm

        # The ticker is not drawn at once (delay), with its clock at zero, but by the refresh that
        # follows; a counted bar is, since a fast series may end before any refresh. The rate
        # over the whole series (smoothing 0) suits a few slow steps better than a moving average.
        bar = tqdm(total=total, desc=desc, file=self.stream, leave=total is not None, dynamic_ncols=True,
                   mininterval=0.1, bar_format=bar_format, unit="step", smoothing=0.0,
                   delay=0.0 if total is not None else _REFRESH_S)
        bar.start_t = min(bar.start_t, started)
        return bar

    def _close_bar(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar, self._series = None, None

    def _close_ticker(self) -> None:
        if self._ticker is not None:
            self._ticker.close()
            self._ticker = None

    def _tick(self) -> None:
        while not self._stop.wait(_REFRESH_S):
            with self._lock:
                if self._stop.is_set():
                    return
                if self._bar is not None:
                    self._bar.refresh()
                elif self._ticker is not None:
                    self._ticker.refresh()
                elif time.time() - self._t_line >= TICK_AFTER_S:
                    self._ticker = self._new_bar(f"[{self.command}] working", None, self._t_line, "{desc} {elapsed}")
                    self._ticker.refresh()


@contextlib.contextmanager
def reporting(args: argparse.Namespace, command: str, defer: bool = False) -> Iterator[Progress]:
    """The command's :class:`Progress` for the length of its work (``defer``: see there). With
    ``--quiet`` the library's own notes on stderr (numba compiling its kernels on a first run)
    are dropped too; an error still reaches stderr, since ``twin.cli.main`` prints it after
    this block."""
    quiet = bool(getattr(args, "quiet", False))
    with contextlib.ExitStack() as stack:
        if quiet:
            stack.enter_context(contextlib.redirect_stderr(stack.enter_context(open(os.devnull, "w"))))
        say = stack.enter_context(Progress(command, quiet=quiet, defer=defer))
        yield say


# ------------------------------------------------------------------ the result on stdout
def print_result(args: argparse.Namespace, data: dict, rows: Sequence[tuple[str, str]],
                 indent: int | None = None) -> None:
    """``data`` as JSON with ``--json`` (and nothing else on stdout), else ``rows``
    (label, text) as aligned lines for a reader; refused once a signal has been received."""
    raise_if_interrupted()
    if getattr(args, "json", False):
        print(json.dumps(data, indent=indent))
        return
    width = max((len(label) for label, _ in rows), default=0)
    for label, text in rows:
        print(f"{label:<{width}}  {text}".rstrip())


def number(value: Any, unit: str = "", digits: int = 4) -> str:
    """A report value for a reader: a number to ``digits`` significant digits with its unit; a
    word (``"free"``) or a missing value as it is."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return "n/a" if value is None else str(value)
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    text = f"{value:.{digits}g}" if isinstance(value, float) else str(value)
    return f"{text} {unit}".rstrip()


def yes_no(flag: Any) -> str:
    return "yes" if flag else "no"
