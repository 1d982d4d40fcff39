"""Every ``twin`` command as Markdown, read from the parsers the commands run with.

The documentation's command reference is generated from here (``docs/_tools/hooks.py``),
so an option added to a command's ``add_parser`` appears there without editing a page.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from twin.cli import build_parser

_ROOT = str(Path(__file__).resolve().parents[2]) + "/"


def _subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """The parsers of ``parser``'s subcommands, in the order they were added."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _argument(action: argparse.Action) -> str:
    """How the argument is written: its flags and value (``--out DIR``), or its name."""
    if not action.option_strings:
        return f"`{action.metavar or action.dest}`"
    value = ""
    if action.nargs != 0:
        metavar = action.metavar or (
            "{" + ",".join(map(str, action.choices)) + "}" if action.choices else action.dest.upper())
        value = f" {metavar}" + (" ..." if action.nargs in ("+", "*") else "")
    return ", ".join(f"`{flag}{value}`" for flag in action.option_strings)


def _default(action: argparse.Action) -> str:
    if action.nargs == 0 or action.default in (None, argparse.SUPPRESS) or not action.option_strings:
        return ""
    return f"`{str(action.default).removeprefix(_ROOT)}`"


def _help(action: argparse.Action) -> str:
    text = (action.help or "").replace("%(default)s", str(action.default)).replace("%%", "%")
    return text.replace("|", "\\|").replace("\n", " ")


def _command_markdown(name: str, parser: argparse.ArgumentParser, level: int) -> list[str]:
    """One command: its usage, description and a table of its arguments, then its subcommands."""
    out = [f"{'#' * level} `{name}`", ""]
    if parser.description:
        out += [parser.description, ""]
    out += ["```text", parser.format_usage().strip().removeprefix("usage: "), "```", ""]
    actions = [a for a in parser._actions
               if a.help != argparse.SUPPRESS and not isinstance(a, (argparse._HelpAction, argparse._SubParsersAction))]
    if actions:
        out += ["| argument | default | what it does |", "|---|---|---|"]
        out += [f"| {_argument(a)} | {_default(a)} | {_help(a)} |" for a in actions]
        out.append("")
    for sub_name, sub in _subcommands(parser).items():
        out += _command_markdown(f"{name} {sub_name}", sub, level + 1)
    return out


def commands_markdown(parser: argparse.ArgumentParser | None = None) -> str:
    """Every command of ``parser`` (default: the full ``twin`` parser) as Markdown sections."""
    parser = parser or build_parser()
    out: list[str] = []
    for name, sub in _subcommands(parser).items():
        out += _command_markdown(f"twin {name}", sub, 2)
    return "\n".join(out)
