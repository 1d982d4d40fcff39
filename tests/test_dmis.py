"""DMIS 5 text of measurement programs: the writer, the strict parser and the file helpers."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from algorithms.errors import AlgorithmError
from algorithms.probing.dmis import parse_dmis, read_dmis, write_dmis, write_dmis_file
from algorithms.probing.program import (
    LABEL_PATTERN,
    Goto,
    MeasurePoint,
    ProbeSettings,
    Program,
    SelectStylus,
    Statement,
)

INCH_M = 0.0254  # one inch [m]
EXACT_M = 1e-15  # a length converted from inches against its hand-computed value [m]

EXAMPLE = """\
DMISMN/'inner_sphere document',05.3
UNITS/MM,ANGDEC
MODE/PROG,MAN
SNSET/APPRCH,2.000000
SNSET/RETRCT,2.000000
SNSET/SEARCH,5.000000
SNSET/CLRSRF,30.000000
SNSLCT/SA(S1)
GOTO/CART,12.500000,0.000000,93.000000
F(SPH1_1)=FEAT/POINT,CART,38.729833,0.000000,50.000000,-0.968245837,0.000000000,-0.250000000
MEAS/POINT,F(SPH1_1),1
PTMEAS/CART,38.729833,0.000000,50.000000,-0.968245837,0.000000000,-0.250000000
ENDMES
ENDFIL
"""


#: EXAMPLE as the writer writes it: with the FILNAM line.
WRITTEN = EXAMPLE.replace("05.3\n", "05.3\nFILNAM/'inner_sphere document',05.3\n", 1)


def example_program() -> Program:
    """The program EXAMPLE holds."""
    return Program(
        "inner_sphere document",
        ProbeSettings(approach_m=0.002, retract_m=0.002, search_m=0.005, clearance_m=0.030),
        (
            SelectStylus("S1"),
            Goto((0.0125, 0.0, 0.093)),
            MeasurePoint("SPH1_1", (0.038729833, 0.0, 0.05), (-math.sqrt(15.0) / 4.0, 0.0, -0.25)),
        ),
    )


def edited(edits: dict[int, str]) -> str:
    """EXAMPLE with line N (1-based) replaced by ``edits[N]`` (several lines, or none: a blank line)."""
    lines = EXAMPLE.splitlines()
    for n, text in edits.items():
        lines[n - 1] = text
    return "\n".join(lines) + "\n"


# --- writing and the round trip ----------------------------------------------------------------


def test_writes_the_expected_text() -> None:
    """The hand-written program is written as the documented example, and reads back equal."""
    assert write_dmis(example_program()) == WRITTEN
    assert parse_dmis(WRITTEN) == example_program()
    assert parse_dmis(EXAMPLE) == example_program()


def _snap_m(x_m: float) -> float:
    return round(x_m * 1e3, 6) / 1e3


labels = st.from_regex(LABEL_PATTERN, fullmatch=True).filter(lambda s: not s.endswith("\n"))
coordinates = st.floats(min_value=-2.0, max_value=2.0, allow_nan=False)
points = st.tuples(coordinates, coordinates, coordinates)
components = st.floats(min_value=-1.0, max_value=1.0, allow_nan=False)
normals = st.tuples(components, components, components).filter(lambda v: math.hypot(*v) > 1e-3)
distances = st.floats(min_value=1e-9, max_value=0.1).map(_snap_m)
names = st.text(st.characters(exclude_characters="'\n", exclude_categories=["Cs"]), min_size=1, max_size=30)


@st.composite
def programs(draw: st.DrawFn) -> Program:
    """A random valid program: random statements, labels, positions within 2 m, unit normals."""
    kinds = draw(st.lists(st.sampled_from(["goto", "stylus", "point"]), max_size=12))
    feature_labels = iter(draw(st.lists(labels, min_size=kinds.count("point"), max_size=kinds.count("point"),
                                        unique_by=str.upper)))
    statements: list[Statement] = []
    for kind in kinds:
        if kind == "goto":
            statements.append(Goto(draw(points)))
        elif kind == "stylus":
            statements.append(SelectStylus(draw(labels)))
        else:
            statements.append(MeasurePoint(next(feature_labels), draw(points), draw(normals)))
    probe = ProbeSettings(draw(distances), draw(distances), draw(distances), draw(distances))
    return Program(draw(names), probe, tuple(statements))


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(programs())
def test_round_trip(program: Program) -> None:
    """Any valid program reads back equal from its text, and its text is a fixed point."""
    text = write_dmis(program)
    again = parse_dmis(text)
    assert again == program
    assert write_dmis(again) == text


def test_file_round_trip(tmp_path: Path) -> None:
    """write_dmis_file and read_dmis: the program back, the text on disk as write_dmis gives it."""
    path = tmp_path / "example.dmi"
    write_dmis_file(example_program(), path)
    assert path.read_bytes() == WRITTEN.encode("utf-8")
    assert read_dmis(path) == example_program()
    assert read_dmis(str(path)) == example_program()


def test_a_label_with_a_trailing_newline_is_refused() -> None:
    """A label must match whole: "S1\\n" would break the file."""
    with pytest.raises(AlgorithmError, match="stylus label"):
        Program("p", ProbeSettings(), (SelectStylus("S1\n"),))


def test_a_setting_below_the_grid_is_refused() -> None:
    """A setting that would be written as 0.000000 mm is refused, not written as a file the parser refuses."""
    with pytest.raises(AlgorithmError, match="approach_m"):
        write_dmis(Program("p", ProbeSettings(approach_m=1e-13), ()))


# --- reading ---------------------------------------------------------------------------------------


def test_inch_units_read_as_metres() -> None:
    """UNITS/INCH,ANGDEC: lengths are inches (25.4 mm); normals are unitless."""
    text = edited({2: "UNITS/INCH,ANGDEC", 4: "SNSET/APPRCH,0.1", 9: "GOTO/1,0,-2",
                   10: "F(P1)=FEAT/POINT,CART,0.5,0,0,0,0,1", 11: "MEAS/POINT,F(P1),1",
                   12: "PTMEAS/CART,0.5,0,0,0,0,1"})
    program = parse_dmis(text)
    assert program.settings.approach_m == pytest.approx(0.1 * INCH_M, abs=EXACT_M)
    assert program.settings.retract_m == pytest.approx(2.0 * INCH_M, abs=EXACT_M)
    goto, point = program.gotos[0], program.measurements[0]
    assert goto.xyz_m == pytest.approx((INCH_M, 0.0, -2.0 * INCH_M), abs=EXACT_M)
    assert point.point_m == pytest.approx((0.5 * INCH_M, 0.0, 0.0), abs=EXACT_M)
    assert point.normal == (0.0, 0.0, 1.0)


def test_case_and_spaces_are_accepted() -> None:
    """Lower case statements, spaces around commas and around the line: the same program."""
    text = """\
   dmismn/'inner_sphere document', 5.0
units/mm , angdeg
Mode/Auto, Prog, Man
snset/clrsrf , 30
snset/apprch,2.0
SnSet / Search ,  5.000000
snset/retrct,2
snslct/sa(S1)
goto/ 12.5 , 0 , 93
f(SPH1_1) = feat/point, cart, 38.729833, 0, 50, -0.968245837, 0, -0.25
meas/point, f(sph1_1), 1
ptmeas/cart, 38.729833, 0.0, 50.0, -0.968245837, 0.0, -0.25
endmes
  endfil  \r
"""
    assert parse_dmis(text) == example_program()


def test_comments_and_blank_lines_are_ignored() -> None:
    """$$ lines and blank lines anywhere (before DMISMN, inside a MEAS block, after ENDFIL) change nothing."""
    lines = EXAMPLE.splitlines()
    text = "$$ written by hand\n\n" + "\n".join(f"{line}\n$$ after {line}\n   \n" for line in lines) + "$$ the end\n"
    assert parse_dmis(text) == example_program()
    assert parse_dmis(EXAMPLE.replace("\n", "\r\n")) == example_program()


@pytest.mark.parametrize("version", ["05.0", "05.1", "05.2", "05.3", "5.0", "5.3"])
def test_versions_accepted(version: str) -> None:
    """DMIS 5.0 to 5.3, with or without the leading zero."""
    assert parse_dmis(edited({1: f"DMISMN/'inner_sphere document',{version}"})) == example_program()


@pytest.mark.parametrize("mode", ["MODE/PROG,MAN", "MODE/AUTO,PROG,MAN", "MODE/MAN"])
def test_modes_accepted(mode: str) -> None:
    """The three MODE statements a program may have."""
    assert parse_dmis(edited({3: mode})) == example_program()


def test_ptmeas_within_a_micrometre_is_accepted() -> None:
    """A PTMEAS 0.5 um off its FEAT, with a normal 1e-7 off: the program holds the FEAT's nominal."""
    text = edited({12: "PTMEAS/CART,38.730333,0.000000,50.000000,-0.968245837,0.0000001,-0.250000000"})
    assert parse_dmis(text) == example_program()


def test_normals_are_normalised() -> None:
    """A FEAT normal that is not a unit vector is scaled to one."""
    text = edited({10: "F(SPH1_1)=FEAT/POINT,CART,38.729833,0,50,0,0,-2", 12: "PTMEAS/CART,38.729833,0,50,0,0,-1"})
    assert parse_dmis(text).measurements[0].normal == (0.0, 0.0, -1.0)


# --- refusals: one per kind of bad statement ------------------------------------------------------

FEAT = "F(SPH1_1)=FEAT/POINT,CART,38.729833,0.000000,50.000000,-0.968245837,0.000000000,-0.250000000"
PTMEAS = "PTMEAS/CART,38.729833,0.000000,50.000000,-0.968245837,0.000000000,-0.250000000"
MEASURE = f"{FEAT}\nMEAS/POINT,F(SPH1_1),1\n{PTMEAS}\nENDMES"

REFUSALS: list[tuple[str, str, int, str]] = [
    # id, text, line, a piece of the message
    ("unknown word", edited({9: "FOO/1,2"}), 9, "FOO is not a statement this subset knows: .*DMISMN, FILNAM, UNITS"),
    ("DMIS word not run", edited({9: "CONST/POINT,F(X),MOVEPT,F(SPH1_1),1"}), 9, "CONST is a DMIS statement this "
     "subset does not run"),
    ("not a statement", edited({9: "12,3"}), 9, "not a statement"),
    ("missing slash", edited({9: "GOTO 12.5,0,93"}), 9, "missing '/'"),
    ("missing slash in SNSET", edited({4: "SNSET APPRCH,2"}), 4, "missing '/'"),
    ("ENDFIL with fields", edited({14: "ENDFIL/1"}), 14, "ENDFIL stands alone"),
    ("too few fields", edited({9: "GOTO/12.5,0"}), 9, "GOTO takes 3 coordinates"),
    ("too many fields", edited({9: "GOTO/12.5,0,93,4"}), 9, "GOTO takes 3 coordinates"),
    ("FEAT fields", edited({10: "F(SPH1_1)=FEAT/POINT,CART,38.729833,0,50"}), 10, "FEAT takes 8 fields"),
    ("non-number", edited({9: "GOTO/12.5,abc,93"}), 9, "GOTO coordinate y must be a number"),
    ("nan", edited({9: "GOTO/12.5,nan,93"}), 9, "must be a number"),
    ("empty field", edited({9: "GOTO/12.5,,93"}), 9, "must be a number"),
    ("non-number normal", edited({12: PTMEAS.replace("-0.250000000", "x")}), 12, "normal component k must be a number"),
    ("bad feature label", edited({10: FEAT.replace("SPH1_1", "1SPH")}), 10, "feature label '1SPH' is not a DMIS "
     "label"),
    ("long feature label", edited({10: FEAT.replace("SPH1_1", "A" * 21)}), 10, "is not a DMIS label"),
    ("bad stylus label", edited({8: "SNSLCT/SA(S-1)"}), 8, "stylus label 'S-1' is not a DMIS label"),
    ("stylus not SA", edited({8: "SNSLCT/S(S1)"}), 8, r"SNSLCT takes a stylus as SA\(label\)"),
    ("FEAT without label", edited({10: FEAT.replace("F(SPH1_1)=", "")}), 10, "FEAT must define a feature label"),
    ("label on GOTO", edited({9: "F(X)=GOTO/12.5,0,93"}), 9, "GOTO takes no label assignment"),
    ("not a point", edited({10: FEAT.replace("POINT", "CIRCLE")}), 10, "point features only"),
    ("not CART", edited({10: FEAT.replace("CART", "POL")}), 10, "CART"),
    ("units CM", edited({2: "UNITS/CM,ANGDEC"}), 2, "UNITS/MM or UNITS/INCH, with ANGDEC"),
    ("units degrees and minutes only", edited({2: "UNITS/MM"}), 2, "the units accepted are"),
    ("mode", edited({3: "MODE/AUTO"}), 3, "the modes accepted are MODE/PROG,MAN"),
    ("SNSET word", edited({4: "SNSET/DEPTH,2"}), 4, "the SNSET words accepted are APPRCH, RETRCT, SEARCH, CLRSRF"),
    ("SNSET zero", edited({5: "SNSET/RETRCT,0"}), 5, "SNSET/RETRCT distance 0 is not positive"),
    ("SNSET negative", edited({6: "SNSET/SEARCH,-5"}), 6, "is not positive"),
    ("SNSET below 1 nm", edited({7: "SNSET/CLRSRF,0.0000001"}), 7, "below the 1 nm"),
    ("SNSET twice", edited({7: "SNSET/CLRSRF,30\nSNSET/APPRCH,3"}), 8, "a second SNSET/APPRCH .the first on line 4."),
    ("SNSET missing", edited({6: ""}), 8, "SNSLCT before SNSET/SEARCH: all four"),
    ("SNSET missing, no motion", edited({i: "" for i in range(8, 14)} | {5: ""}), 14, "ENDFIL before "
     "SNSET/RETRCT"),
    ("SNSET after motion", edited({9: "GOTO/12.5,0,93\nSNSET/APPRCH,1"}), 10, "a second SNSET/APPRCH"),
    ("version 4", edited({1: "DMISMN/'inner_sphere document',04.0"}), 1, "version '04.0' is not read: .*05.0 to "
     "05.3"),
    ("version 5.4", edited({1: "DMISMN/'inner_sphere document',05.4"}), 1, "version '05.4' is not read"),
    ("DMISMN unquoted", edited({1: "DMISMN/inner,05.0"}), 1, "DMISMN takes 'name',version"),
    ("DMISMN empty name", edited({1: "DMISMN/'',05.0"}), 1, "empty name"),
    ("second DMISMN", edited({2: "DMISMN/'again',05.0"}), 2, "a second DMISMN"),
    ("before DMISMN", "$$ a comment\nGOTO/1,2,3\n" + EXAMPLE, 2, "GOTO before DMISMN"),
    ("no DMISMN", "$$ nothing\n\n", 2, "no DMISMN statement"),
    ("empty text", "", 1, "no DMISMN statement"),
    ("after ENDFIL", EXAMPLE + "$$ fine\nGOTO/1,2,3\n", 16, "GOTO after ENDFIL"),
    ("missing ENDFIL", edited({14: "$$ no end"}) + "\n", 15, "missing ENDFIL"),
    ("missing ENDFIL in MEAS", edited({13: "", 14: ""}), 14, "missing ENDFIL .*MEAS block of line 11"),
    ("MEAS undefined", edited({11: "MEAS/POINT,F(SPH1_2),1"}), 11, r"MEAS of F\(SPH1_2\), which no FEAT defines"),
    ("MEAS count", edited({11: "MEAS/POINT,F(SPH1_1),2"}), 11, "MEAS count 2: .*exactly 1 touch"),
    ("MEAS count not integer", edited({11: "MEAS/POINT,F(SPH1_1),1.0"}), 11, "count must be a whole number"),
    ("MEAS feature ref", edited({11: "MEAS/POINT,SPH1_1,1"}), 11, r"MEAS takes the feature as F\(label\)"),
    ("MEAS not POINT", edited({11: "MEAS/CIRCLE,F(SPH1_1),1"}), 11, "point features only"),
    ("MEAS twice", edited({13: "ENDMES\nMEAS/POINT,F(sph1_1),1\n" + PTMEAS + "\nENDMES"}), 14, "measured twice"),
    ("PTMEAS outside MEAS", edited({9: PTMEAS}), 9, "PTMEAS outside a MEAS block"),
    ("ENDMES outside MEAS", edited({9: "ENDMES"}), 9, "ENDMES outside a MEAS block"),
    ("MEAS without PTMEAS", edited({12: "$$ no touch"}), 13, "ends without a PTMEAS"),
    ("two PTMEAS", edited({12: PTMEAS + "\n" + PTMEAS}), 13, "a second PTMEAS .*exactly one PTMEAS"),
    ("PTMEAS point off", edited({12: PTMEAS.replace("38.729833", "38.731833")}), 12, "PTMEAS is 0.002000 mm from "
     "the nominal point"),
    ("PTMEAS normal off", edited({12: PTMEAS.replace("0.000000000", "0.01")}), 12, "PTMEAS normal differs"),
    ("PTMEAS not CART", edited({12: PTMEAS.replace("CART", "POL")}), 12, "CART"),
    ("GOTO inside MEAS", edited({12: "GOTO/1,2,3"}), 12, "GOTO inside the MEAS block of line 11"),
    ("SNSLCT inside MEAS", edited({12: PTMEAS + "\nSNSLCT/SA(S2)"}), 13, "SNSLCT inside the MEAS block"),
    ("MEAS inside MEAS", edited({12: "MEAS/POINT,F(SPH1_1),1"}), 12, "MEAS inside the MEAS block"),
    ("ENDFIL inside MEAS", edited({13: ""}), 14, "ENDFIL inside the MEAS block"),
    ("feature twice", edited({10: FEAT + "\n" + FEAT.replace("SPH1_1", "sph1_1")}), 11, r"feature F\(sph1_1\) is "
     "defined twice .first on line 10."),
    ("FEAT not measured", edited({9: FEAT.replace("SPH1_1", "P2")}), 9, r"F\(P2\) is defined but not measured "
     "before ENDFIL .line 14."),
    ("zero normal", edited({10: FEAT.replace("-0.968245837", "0").replace("-0.250000000", "0.0")}), 10,
     "FEAT has a zero normal"),
    ("zero PTMEAS normal", edited({12: PTMEAS.replace("-0.968245837", "0").replace("-0.250000000", "-0")}), 12,
     "PTMEAS has a zero normal"),
]


@pytest.mark.parametrize(("text", "line", "message"), [case[1:] for case in REFUSALS],
                         ids=[case[0] for case in REFUSALS])
def test_refusals(text: str, line: int, message: str) -> None:
    """Each bad statement is refused with the source, its line and what is allowed, on one line."""
    with pytest.raises(AlgorithmError, match=rf"^program:{line}: ") as caught:
        parse_dmis(text)
    assert "\n" not in str(caught.value)
    assert caught.match(message)


def test_refusals_name_the_source() -> None:
    """The source given to parse_dmis starts the message."""
    with pytest.raises(AlgorithmError, match=r"^cell/probe\.dmi:9: FOO is not a statement"):
        parse_dmis(edited({9: "FOO/1,2"}), source="cell/probe.dmi")


def test_read_refuses_a_missing_file(tmp_path: Path) -> None:
    """read_dmis of a path with no file."""
    with pytest.raises(AlgorithmError, match="no DMIS file at"):
        read_dmis(tmp_path / "absent.dmi")


def test_read_refuses_non_utf8(tmp_path: Path) -> None:
    """read_dmis of Latin-1 bytes."""
    path = tmp_path / "latin1.dmi"
    path.write_bytes(EXAMPLE.replace("inner_sphere", "pi\xe8ce").encode("latin-1"))
    with pytest.raises(AlgorithmError, match="is not UTF-8"):
        read_dmis(path)


def test_read_names_the_file_in_refusals(tmp_path: Path) -> None:
    """A refusal from a file starts with its path and the line."""
    path = tmp_path / "bad.dmi"
    path.write_text(edited({11: "MEAS/POINT,F(SPH1_1),3"}), encoding="utf-8")
    with pytest.raises(AlgorithmError) as caught:
        read_dmis(path)
    assert str(caught.value).startswith(f"{path}:11: MEAS count 3")


def test_parse_refuses_non_text() -> None:
    """parse_dmis takes a str, not bytes."""
    with pytest.raises(AlgorithmError, match="takes the DMIS text as a str"):
        parse_dmis(EXAMPLE.encode())  # type: ignore[arg-type]
