"""Reading the project's TOML files (scenarios, studies, teach files): one line on any problem."""

from __future__ import annotations

import tomllib
from pathlib import Path

from twin.errors import TwinError


def read_toml(path: str | Path, what: str) -> dict:
    """The table of the TOML file ``path``; ``what`` names the kind of file in the error
    ("scenario", "study", "teach file"): missing, unreadable or not TOML is a TwinError."""
    path = Path(path)
    if not path.is_file():
        raise TwinError(f"{what} file not found: {path}")
    try:
        return tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise TwinError(f"{what} {path} is not valid TOML: {' '.join(str(exc).split())}") from None
