"""``twin view FILE.rrd [--web] [--port N]``: open a recording in the Rerun viewer.

The viewer is the ``rerun`` executable that the rerun-sdk package installs beside the Python
interpreter (``python -m rerun_cli`` where there is none); this command checks the file and
starts it, nothing more (only ``twin/viz/`` imports rerun). With ``--web`` it serves the
recording to a browser on 127.0.0.1 and prints the address to open.
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
from pathlib import Path
from urllib.parse import quote

from twin.cli import COMMANDS
from twin.errors import TwinError

#: The first four bytes of a Rerun recording (``RRF2`` now; ``RRF0`` and ``RRF1`` in older releases).
RRD_MAGICS = (b"RRF2", b"RRF1", b"RRF0")
DEFAULT_WEB_PORT = 9090
HOST = "127.0.0.1"


def port_number(text: str) -> int:
    """An argparse type: a TCP port, 0 (any free one) to 65535."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"must be a port number from 0 (any free port) to 65535, got {text!r}")
    return value


def add_parser(sub) -> None:
    p = sub.add_parser(
        "view", help=COMMANDS["view"],
        description="Open a recording written by twin scan, run, demo or locate (--rrd) in the Rerun viewer "
                    "(a window; with --web a viewer served to a browser on 127.0.0.1, whose address is printed). "
                    "Runs until the viewer is closed (--web: until Ctrl-C).",
    )
    p.add_argument("recording", metavar="FILE.rrd", help="a Rerun recording (.rrd)")
    p.add_argument("--web", action="store_true", help="serve the viewer to a web browser instead of opening a window")
    p.add_argument("--port", type=port_number, default=None,
                   help=f"with --web: the port of the web viewer on {HOST} (default {DEFAULT_WEB_PORT}; "
                        "0: any free port)")
    p.set_defaults(run=run)


def check_recording(path: str) -> Path:
    """The recording's path, refused in one line if it is missing, not .rrd or not a Rerun recording."""
    p = Path(path)
    if p.suffix.lower() != ".rrd":
        raise TwinError(f"{path!r} is not a .rrd file; give a Rerun recording (FILE.rrd, written with --rrd)")
    if not p.exists():
        raise TwinError(f"recording not found: {path}")
    if not p.is_file():
        raise TwinError(f"{path} is not a file; give a Rerun recording (FILE.rrd)")
    with p.open("rb") as fh:
        head = fh.read(4)
    if head not in RRD_MAGICS:
        raise TwinError(f"{path} is not a Rerun recording (it does not begin with "
                        f"{' or '.join(m.decode() for m in RRD_MAGICS)})")
    return p


def rerun_command() -> list[str]:
    """The Rerun viewer's command: the ``rerun`` script beside this interpreter, else its module."""
    exe = Path(sys.executable).parent / ("rerun.exe" if sys.platform.startswith("win") else "rerun")
    return [str(exe)] if exe.is_file() else [sys.executable, "-m", "rerun_cli"]


def free_port(port: int = 0) -> int:
    """``port`` if it can be bound on 127.0.0.1 now (0: a free one the system picks), else a one-line error."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        try:
            s.bind((HOST, port))
        except OSError:
            raise TwinError(f"port {port} on {HOST} is in use; give another with --port (0: any free port)") from None
        return s.getsockname()[1]


def web_url(web_port: int, grpc_port: int) -> str:
    """The address that opens the served web viewer on the served recording."""
    return f"http://{HOST}:{web_port}/?url=" + quote(f"rerun+http://{HOST}:{grpc_port}/proxy", safe="")


def launch(argv: list[str]) -> tuple[int, str]:
    """Run the viewer in the foreground: (its exit status, the last line of its log).

    It runs in a process group of its own, which is ended with this command however it ends
    (Ctrl-C, SIGTERM, an error): the ``rerun`` script starts the viewer binary as a child, and
    ending the script alone would leave the viewer serving (the next ``--web`` finds its port
    busy). Its log is kept aside, so that a viewer that cannot start is reported in one line.
    """
    # a file, not a pipe: a child of the viewer holding the pipe open would hold the command
    with tempfile.TemporaryFile("w+", errors="replace") as log:
        proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=log, start_new_session=True)
        try:
            proc.wait()
        finally:
            _end_group(proc)
        log.seek(0)
        lines = [ln.strip() for ln in _ANSI.sub("", log.read()).splitlines() if ln.strip()]
    return proc.returncode, (lines[-1] if lines else "")


_ANSI = re.compile(r"\x1b\[[0-9;]*m")


def _end_group(proc: subprocess.Popen) -> None:
    """SIGTERM to the viewer's process group, then SIGKILL to what is left after 2 s."""
    for sig, wait_s in ((signal.SIGTERM, 2.0), (signal.SIGKILL, 2.0)):
        try:
            os.killpg(proc.pid, sig)
        except (ProcessLookupError, PermissionError):
            return
        try:
            proc.wait(wait_s)
        except subprocess.TimeoutExpired:
            continue
        # the script is gone; a child of it may still hold the group
        try:
            os.killpg(proc.pid, 0)
        except (ProcessLookupError, PermissionError):
            return


def run(args: argparse.Namespace) -> int:
    if args.port is not None and not args.web:
        raise TwinError("--port applies with --web only (the port of the web viewer)")
    rrd = check_recording(args.recording)
    cmd = rerun_command()
    if args.web:
        web_port = free_port(DEFAULT_WEB_PORT if args.port is None else args.port)
        # the viewer's data server gets a free port of its own: its default (9876) may be held by
        # another viewer, and the printed address names the one chosen
        grpc_port = free_port(0)
        cmd += ["--serve-web", str(rrd), "--web-viewer-port", str(web_port), "--port", str(grpc_port),
                "--bind", HOST]
        print(f"serving {rrd} at {web_url(web_port, grpc_port)} (Ctrl-C stops)", flush=True)
    else:
        cmd += [str(rrd)]
    code, last = launch(cmd)
    if code != 0:
        said = f": {last[:160]}" if last else ""
        raise TwinError(f"the Rerun viewer ({cmd[0]}) ended with exit status {code}{said}"
                        + ("" if args.web else " (no display? try --web)"))
    return 0
