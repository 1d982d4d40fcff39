"""Property-based fuzzing of the file readers (hypothesis): scenario, study and teach files and
DMIS programs, each a valid shipped file changed the ways files go bad (``tests.test_fuzz``'s
mutations: cut, bytes changed, lines dropped or repeated, numbers made non-finite or huge,
random bytes). Every case is read or refused with the reader's one-line error
(:class:`twin.errors.TwinError`, :class:`algorithms.errors.AlgorithmError`): any other
exception is a bug.

CI runs a fixed, derandomized budget (a few seconds); ``TWIN_FUZZ=slow pytest -m long
tests/test_fuzz_parsers.py`` runs 2,000 random cases per reader.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from algorithms.errors import AlgorithmError
from algorithms.probing.dmis import parse_dmis
from algorithms.probing.dmis.lexer import decode
from algorithms.probing.dmis.reader import parse_program
from tests.helpers import ROOT, SCENARIOS
from tests.test_dmis import EXAMPLE
from tests.test_fuzz import mutated, slow_or_ci
from twin.errors import TwinError
from twin.formats.teach import load_teach
from twin.scenario import load_scenario
from twin.studies import load_study

SLOW = os.environ.get("TWIN_FUZZ") == "slow"
CASES = (2000, 40)  # (slow, CI) per reader


def budget():
    return settings(max_examples=CASES[0] if SLOW else CASES[1], deadline=None, derandomize=not SLOW,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                           HealthCheck.function_scoped_fixture], database=None)


def _read_or_refuse(read, raw: bytes, name: str, folder: Path) -> None:
    path = folder / name
    path.write_bytes(raw)
    try:
        read(path)
    except (TwinError, AlgorithmError) as exc:
        message = str(exc)
        assert message.strip() and "Traceback" not in message


_FOLDER = Path(tempfile.mkdtemp(prefix="twin-fuzz-parsers-"))
(_FOLDER / "meshes").symlink_to(SCENARIOS / "meshes")
_SCENARIO = (SCENARIOS / "bracket.toml").read_bytes()
_STUDY = (ROOT / "studies" / "robot_errors.toml").read_text().replace(
    '"../scenarios/s_surface.toml"', f'"{SCENARIOS / "s_surface.toml"}"').encode()
_TEACH = (SCENARIOS / "cmm" / "teach" / "through_hole.toml").read_bytes()


#: Each TOML reader, the shipped file it starts from and the name it is read under.
TOML_READERS = {"scenario": (load_scenario, _SCENARIO, "scenario.toml"),
                "study": (load_study, _STUDY, "study.toml"),
                "teach": (load_teach, _TEACH, "teach.toml")}


@slow_or_ci
@pytest.mark.parametrize("reader", list(TOML_READERS))
@budget()
@given(data=st.data())
def test_fuzz_toml_readers(reader, data):
    read, valid, name = TOML_READERS[reader]
    _read_or_refuse(read, data.draw(mutated(valid)), name, _FOLDER)


@slow_or_ci
@budget()
@given(raw=mutated(EXAMPLE.encode()))
def test_fuzz_dmis_reader(raw):
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        return  # the file reader refuses it before parsing (tests/test_dmis.py)
    try:
        parse_dmis(text, "fuzz.dmi")
    except AlgorithmError as exc:
        assert str(exc).strip()


WORKSHOP = (ROOT / "tests" / "data" / "dmis" / "workshop_latin1.dmi").read_bytes()


@slow_or_ci
@budget()
@given(raw=mutated(WORKSHOP))
def test_fuzz_real_program_reader(raw):
    """Any bytes near a real program: read, or refused in one line naming the file; nothing else."""
    try:
        text, encoding = decode(raw, "fuzz.dmi")
        parse_program(text, str(ROOT / "tests" / "data" / "dmis" / "fuzz.dmi"), encoding)
    except AlgorithmError as exc:
        assert str(exc).strip() and "\n" not in str(exc)
