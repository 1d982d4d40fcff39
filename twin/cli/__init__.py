"""The ``twin`` command line.

Each subcommand lives in its own module ``twin/cli/<name>.py`` exposing
``add_parser(subparsers)`` and ``run(args) -> int``. Domain errors become one line on
stderr and a non-zero exit, never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from algorithms.errors import AlgorithmError
from twin.errors import TwinError

COMMANDS = ["scan", "demo", "localize", "run", "warmup"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="twin",
        description="Digital twin for robotic laser scanning and CAD-based workpiece localization.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMANDS:
        module = importlib.import_module(f"twin.cli.{name}")
        module.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.run(args) or 0)
    except (TwinError, AlgorithmError) as exc:
        print(f"twin {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"twin {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
