"""A command line that is still starting ends cleanly on SIGINT or SIGTERM.

Until :func:`twin.cli.main` installs its own handlers, Python's would print a traceback (or a
compiled module's import would swallow the signal). :func:`guard` installs a handler that ends
the process at once with the one line and the exit status of an interruption: nothing has
been written yet. It acts only when this process is the ``twin`` command (``twin ...`` or
``python -m twin ...``), so importing the package as a library changes no signal handler.
"""

from __future__ import annotations

import os
import signal
import sys
from types import FrameType

COMMAND_MODULES = ("twin", "twin.cli", "twin.__main__")


def while_starting(signum: int, frame: FrameType | None) -> None:
    word = "terminated (SIGTERM)" if signum == signal.SIGTERM else "interrupted (SIGINT)"
    sys.stderr.write(f"twin: {word}; nothing written\n")
    sys.stderr.flush()
    os._exit(143 if signum == signal.SIGTERM else 130)


def started_as_command() -> bool:
    """Whether this process was started as the ``twin`` command: ``python -m twin[.cli]`` (the
    interpreter's own arguments) or the installed ``twin`` script."""
    argv = list(getattr(sys, "orig_argv", []))
    if "-m" in argv[:-1] and argv[argv.index("-m") + 1] in COMMAND_MODULES:
        return True
    return os.path.basename(sys.argv[0] if sys.argv else "") == "twin"


def guard() -> None:
    """Install :func:`while_starting` for SIGINT and SIGTERM when this process is the command,
    in place of Python's default handlers only (a signal the parent made this process ignore
    stays ignored)."""
    if started_as_command():
        for s, default in ((signal.SIGINT, signal.default_int_handler), (signal.SIGTERM, signal.SIG_DFL)):
            if signal.getsignal(s) is default:
                signal.signal(s, while_starting)
