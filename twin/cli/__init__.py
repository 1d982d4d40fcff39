"""The ``twin`` command line.

Each subcommand lives in its own module ``twin/cli/<name>.py`` exposing
``add_parser(subparsers)`` and ``run(args) -> int``. stdout carries the result only (a short
summary, or one JSON object with ``--json``); progress and errors go to stderr (``--quiet``
keeps the errors only). Whatever goes wrong ends in one line on stderr and a documented exit
status, never a traceback (docs/concepts/verdicts.md, "Exit status"):

- 0: done, and the result can be trusted;
- 2: bad input (a file, an option, an output location, a file system error): nothing written;
- 3: finished, but the result cannot be trusted (printed and written all the same, saying so);
- 4: a stage failed (``twin run``, ``twin locate``): what the finished stages made is written,
  the report says ``complete: false`` and why;
- 130 / 143: interrupted by SIGINT / SIGTERM: temporary files removed, nothing written (a
  study keeps its finished batches for ``--resume``);
- 141: the reader of stdout went away (``twin ... | head``): ends quietly.
"""

from __future__ import annotations

import argparse
import importlib
import os
import signal
import sys
from collections.abc import Sequence
from types import FrameType, ModuleType

from algorithms.errors import AlgorithmError
from twin.cli.common import EXIT_BAD_INPUT, EXIT_BROKEN_PIPE, EXIT_SIGINT, EXIT_SIGTERM, OneLineParser
from twin.errors import TwinError
from twin.io import output

#: Subcommands and their one-line help; each is the module of its name with "-" as "_"
#: (``export-mesh``: ``export_mesh.py``). Only the module of the command being run is imported:
#: ``twin --help`` lists this table without loading MuJoCo, SciPy or the kernels.
COMMANDS = {
    "scan": "simulate a scan of a scenario and write samples, points and metadata",
    "demo": "run the whole loop on the S-surface part and write a report and a recording",
    "localize": "find T_world_workpiece from measured points and the CAD mesh",
    "run": "scan, localize, plan the process paths, solve IK, replay and verify",
    "locate": "document 001: coarse laser pass, planned touch probing, T = T_fine T_coarse",
    "view": "open a .rrd recording in the Rerun viewer",
    "export-mesh": "write the scenario's workpiece mesh (metres, workpiece frame) to STL, PLY or OBJ",
    "warmup": "compile the closest-point kernels now (once per installation)",
    "study": "run a Monte Carlo / benchmark study (a grid of factors, trials per cell), resumable",
    "cmm": "document 002: plan, write and run CMM measurement programs (GOTO planning, DMIS)",
}


class Terminated(BaseException):
    """SIGTERM, raised where the program is, so that every staged output is cleaned up."""


def command_module(name: str) -> ModuleType:
    """The module of subcommand ``name`` (imported on first use)."""
    return importlib.import_module(f"twin.cli.{name.replace('-', '_')}")


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The ``twin`` parser, with the full parser of the command ``argv`` names (all of them when
    ``argv`` is None) and a one-line entry for every other command."""
    parser = OneLineParser(
        prog="twin",
        description="Digital twin for robotic laser scanning and CAD-based workpiece localization.",
    )
    parser.add_argument("--version", action="version", version=f"twin {_version()}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND", parser_class=OneLineParser)
    wanted = set(COMMANDS) if argv is None else set(argv[:1]) & set(COMMANDS)
    for name, help_text in COMMANDS.items():
        if name in wanted:
            command_module(name).add_parser(sub)
        else:
            sub.add_parser(name, help=help_text)
    return parser


def _version() -> str:
    """The installed package's version (``pyproject.toml``), without importing the package."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("scan-twin")
    except PackageNotFoundError:
        return "unknown (not installed)"


def _on_signal(signum: int, frame: FrameType | None) -> None:
    """Note the signal (:func:`twin.io.output.note_signal`) and raise it where the program is.

    A library can swallow the raised exception: a signal landing while a compiled module is
    imported, or inside a foreign callback (numba writing its cache through ctypes). The note
    stays, so nothing is committed or printed afterwards (the library may also fail later with
    an error of its own, which is then the interruption, not a fault), and a later signal
    raises again. Only while the clean-up of the first interruption runs is a later one
    ignored: that clean-up must not be interrupted in turn.
    """
    cleaning_up = output.signal_received() is not None and isinstance(
        sys.exc_info()[1], (KeyboardInterrupt, Terminated, output.Interrupted))
    output.note_signal(signum)
    if cleaning_up:
        return
    raise Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()


def _quiet_unraisable(unraisable: sys.UnraisableHookArgs) -> None:
    """Python prints an exception it cannot raise (one from a callback) with its traceback:
    our own interruption is reported once, by ``main``, and the rest as Python would."""
    if isinstance(unraisable.exc_value, (Terminated, KeyboardInterrupt)):
        return
    sys.__unraisablehook__(unraisable)


def _interrupted(command: str) -> int:
    if output.signal_received() == signal.SIGTERM:
        print(f"{command}: terminated (SIGTERM); {_left_behind(command)}", file=sys.stderr)
        return EXIT_SIGTERM
    print(f"{command}: interrupted (SIGINT); {_left_behind(command)}", file=sys.stderr)
    return EXIT_SIGINT


def _left_behind(command: str) -> str:
    """What an interrupted command leaves: a study keeps its finished batches for --resume; a
    command whose output was already in place when the signal came leaves it whole."""
    if command == "twin study":
        return "the finished batches are kept (run again with --resume to finish the study)"
    done = output.committed()
    if done:
        return f"{', '.join(str(p) for p in done)} had been written whole before it"
    return "nothing written"


def _quiet_stdout() -> None:
    """After a broken pipe, send what is left to /dev/null so that the exit does not fail again."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass


def _os_error_line(exc: OSError) -> str:
    where = f": {exc.filename}" if getattr(exc, "filename", None) else ""
    return f"{exc.strerror or type(exc).__name__}{where}"


def _failed(command: str, exc: Exception) -> int:
    """The one line and exit status of an error; an error of no known kind is a bug: raised."""
    if isinstance(exc, (TwinError, AlgorithmError)):
        print(f"{command}: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return EXIT_BAD_INPUT
    if isinstance(exc, BrokenPipeError):
        _quiet_stdout()
        return EXIT_BROKEN_PIPE
    if isinstance(exc, OSError):
        print(f"{command}: error: {_os_error_line(exc)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    raise exc


def _plain_logs_unless_terminal() -> None:
    """Log lines of the compiled libraries and the viewer (Rust's ``env_logger``) without colour
    codes where stderr is not a terminal (a file, a pipe, a CI log); a user's own setting wins."""
    try:
        terminal = sys.stderr.isatty()
    except (AttributeError, ValueError):
        terminal = False
    if not terminal:
        os.environ.setdefault("RUST_LOG_STYLE", "never")


def main(argv: list[str] | None = None) -> int:
    _plain_logs_unless_terminal()
    output.clear_signal()
    output.clear_committed()
    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    unraisable_hook = sys.unraisablehook
    in_main_thread = True
    try:
        for s in handlers:
            signal.signal(s, _on_signal)
        sys.unraisablehook = _quiet_unraisable
    except ValueError:  # not the main thread (an embedding program): leave signals alone
        in_main_thread = False
    command = "twin"
    try:
        args_in = sys.argv[1:] if argv is None else list(argv)
        parser = build_parser(args_in)
        try:
            args = parser.parse_args(args_in)
        except SystemExit as exc:  # --help (0) or a one-line argument error (2)
            return exc.code if isinstance(exc.code, int) else EXIT_BAD_INPUT
        command = f"twin {args.command}"
        code = int(args.run(args) or 0)
        sys.stdout.flush()
        output.raise_if_interrupted()  # a swallowed signal and a command that wrote nothing
        return code
    except (KeyboardInterrupt, Terminated):
        return _interrupted(command)
    except Exception as exc:
        if output.signal_received() is not None:  # a library failing on the interruption it swallowed
            return _interrupted(command)
        return _failed(command, exc)
    finally:
        if in_main_thread:
            _restore(handlers)
            sys.unraisablehook = unraisable_hook


def _restore(handlers: dict) -> None:
    """Put the caller's signal handlers back. A signal arriving meanwhile is not raised again:
    the command has already ended and said how."""
    for s, h in handlers.items():
        for _ in range(3):
            try:
                signal.signal(s, h)
                break
            except (KeyboardInterrupt, Terminated):
                continue


if __name__ == "__main__":
    sys.exit(main())
