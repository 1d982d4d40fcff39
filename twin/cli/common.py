"""What every command shares: the one-line argument parser, option types, output options."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import NoReturn

from twin.io.output import check_output_file, check_output_folder

#: Exit statuses of every command (README, "Exit status").
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


def add_output_options(p: argparse.ArgumentParser, out_help: str, default_out: str | None = None,
                       rrd_help: str = "also write a rerun recording to this .rrd file") -> None:
    """``--out`` (a folder), ``--rrd`` (a recording) and ``--force`` (replace them whole)."""
    if default_out is None:
        p.add_argument("--out", required=True, help=out_help)
    else:
        p.add_argument("--out", default=default_out, help=out_help)
    p.add_argument("--rrd", help=rrd_help)
    p.add_argument("--force", action="store_true",
                   help="replace an existing output folder (and recording) whole; without it they are refused")


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
    """A progress line on stderr (stdout carries the JSON only)."""
    print(f"[{command}] {msg}", file=sys.stderr, flush=True)
