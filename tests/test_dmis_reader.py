"""The reader of real DMIS programs (algorithms/probing/dmis): the conformance corpus in
tests/data/dmis read, written back and read again; every error of the corpus refused with its
file and line; the twin's own programs read back identical; features, alignments and
tolerances evaluated to known values."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings

from algorithms.errors import AlgorithmError
from algorithms.probing.cmm_planning import StylusReach, program_moves
from algorithms.probing.dmis import geometry as geo
from algorithms.probing.dmis import write_dmis
from algorithms.probing.dmis.evaluation import evaluate
from algorithms.probing.dmis.flow import MAX_STATEMENTS
from algorithms.probing.dmis.lexer import decode, logical_lines, split_fields
from algorithms.probing.dmis.model import DmisModel, Feature, Touch, Where, lower
from algorithms.probing.dmis.output import write_output
from algorithms.probing.dmis.reader import parse_program, read_program
from algorithms.probing.dmis.writer import write_model
from tests.test_dmis import programs

DATA = Path(__file__).resolve().parent / "data" / "dmis"
ERRORS = DATA / "errors"

#: Positions written back to 1 nm agree to this [m]; directions to this.
SAME_M = 2e-9
SAME_DIR = 1e-9
#: A fit of exact points recovers its feature to this [m] / [rad].
FIT_M = 1e-9
FIT_RAD = 1e-9

HEAD = ("DMISMN/'T',05.3\nUNITS/MM,ANGDEC\nSNSET/APPRCH,2\nSNSET/RETRCT,2\nSNSET/SEARCH,5\nSNSET/CLRSRF,20\n"
        "SNSLCT/SA(S1)\n")


def program(body: str) -> DmisModel:
    return parse_program(HEAD + body + "ENDFIL\n", "t.dmi")


# --- the corpus: what each program holds ---------------------------------------------------------

CORPUS = {
    # file: (name, encoding, features, measured, touches, moves, skipped words that must be listed)
    "workshop_latin1.dmi": ("EQUERRE_RECEPTION", "latin-1", 16, 8, 30, 13,
                            {"FILNAM", "DMESWV", "DECPL", "VFORM", "DISPLY", "FLY", "TEXT", "PAUSE", "RECALL",
                             "CONST", "TOL", ""}),
    "modus_macros.dms": ("HOLE_PATTERN", "utf-8-sig", 6, 5, 20, 14, set()),
    "inch_radians.dmi": ("INCH_BLOCK", "utf-8", 1, 1, 3, 1, set()),
    "plate_bore.dmi": ("PLATE_BORE_CHECK", "utf-8", 5, 5, 23, 12, {"FILNAM", "DMESWV", "VFORM", "DISPLY", "MODE"}),
}


@pytest.mark.parametrize("name", sorted(CORPUS))
def test_the_corpus_is_read(name: str) -> None:
    """Each corpus program: its name, encoding, features, touches and moves, and the statements it
    skips listed with their lines (none of which moves the machine)."""
    m = read_program(DATA / name)
    prog, encoding, features, measured, touches, moves, skipped = CORPUS[name]
    assert (m.name, m.encoding) == (prog, encoding)
    assert (len(m.features), len(m.measurements), len(m.touches), len(m.moves)) == (features, measured, touches, moves)
    assert skipped <= {n.word for n in m.unsupported()}
    assert all(n.where.line > 0 for n in m.unsupported())


def test_latin1_program_keeps_its_text_and_follows_its_variables() -> None:
    """Latin-1 with CRLF, variables in coordinates, a $ continuation, a PTMEAS away from its nominal,
    a point measured at its nominal with no PTMEAS, a PTMEAS without i,j,k (the surface's normal)."""
    m = read_program(DATA / "workshop_latin1.dmi")
    plane_a = m.features["PLAN_A"]
    assert np.allclose(plane_a.point_m, [0.0, 0.0, 0.020])  # HAUT = 20
    t = {(x.feature, x.index): x for x in m.touches}
    assert np.allclose(t["PLAN_A", 1].point_m, [0.045, 0.005, 0.020])  # LARG - 5 = 2 * 20 + 10 - 5
    assert np.allclose(t["PLAN_B", 2].normal, [-1.0, 0.0, 0.0])  # the continued line's i,j,k
    assert np.allclose(t["PT_1", 0].point_m, [0.011, 0.009, 0.020])  # its own target, not the nominal
    assert np.allclose(t["PT_2", 0].point_m, m.features["PT_2"].point_m)  # no PTMEAS: the nominal
    assert np.allclose(t["ALESAGE", 0].normal, [-1.0, 0.0, 0.0])  # a bore's normal points to its axis
    assert np.allclose(m.moves[5].xyz_m, m.moves[4].xyz_m + [0, 0, 0.010])  # GOTO/INCR,10,0,0,1
    assert "Contrôle" not in str(m.notices)  # the text itself is not echoed; its line is
    assert {n.word for n in m.notices if n.message.startswith("not a DMIS statement")} == {""}


def test_macros_loops_conditions_jumps_and_called_files() -> None:
    """Four holes from one macro in a DO loop behind IF/ELSE, a JUMPTO over a move, a datum module
    from a CALL/EXTERN next to the program."""
    m = read_program(DATA / "modus_macros.dms")
    assert [Path(s).name for s in m.sources] == ["modus_macros.dms", "modus_datum.dmi"]
    for k in range(4):
        c = m.features[f"H{k}"]
        assert np.allclose(c.point_m, [0.040 * math.cos(k * math.pi / 2), 0.040 * math.sin(k * math.pi / 2), -0.005])
    assert not any(np.allclose(x.xyz_m, [0.999] * 3) for x in m.moves)  # jumped over
    assert m.datums == {"A": "TOPF"}
    auto = [t for t in m.touches if t.feature == "H1"]
    assert len(auto) == 4 and all(abs(np.linalg.norm(t.point_m - m.features["H1"].point_m) - 0.004) < 1e-12
                                  for t in auto)


def test_inches_radians_and_a_turned_frame() -> None:
    """UNITS/INCH,ANGRAD and ROTATE/ZAXIS by pi/2: the end face 4 in along +x of the base frame."""
    m = read_program(DATA / "inch_radians.dmi")
    end = m.features["END"]
    assert np.allclose(end.point_m, [4 * 0.0254, 0.0, 0.5 * 0.0254], atol=1e-12)
    assert np.allclose(end.direction, [1.0, 0.0, 0.0], atol=1e-12)
    assert m.settings.approach_m == pytest.approx(0.08 * 0.0254)


# --- written back and read again ----------------------------------------------------------------


def assert_same(a: DmisModel, b: DmisModel) -> None:
    """Two models do the same: features, touches, moves, stylus changes, constructions, datums,
    alignments (as frames), tolerances and outputs."""
    assert set(a.features) == set(b.features) and set(a.actuals) == set(b.actuals)
    for k in a.features:
        fa, fb = a.features[k], b.features[k]
        assert (fa.kind, fa.inner) == (fb.kind, fb.inner)
        assert np.allclose(fa.point_m, fb.point_m, atol=SAME_M)
        for va, vb in ((fa.direction, fb.direction), (fa.normal, fb.normal)):
            assert (va is None) == (vb is None) and (va is None or np.allclose(va, vb, atol=SAME_DIR))
        assert (fa.size_m is None) == (fb.size_m is None) and abs((fa.size_m or 0) - (fb.size_m or 0)) < SAME_M
    assert len(a.events) == len(b.events)
    for ea, eb in zip(a.events, b.events, strict=True):
        assert type(ea) is type(eb)
        if isinstance(ea, Touch):
            assert np.allclose(ea.point_m, eb.point_m, atol=SAME_M) and np.allclose(ea.normal, eb.normal, atol=SAME_DIR)
            assert ea.settings == eb.settings and ea.feature == eb.feature
        elif hasattr(ea, "xyz_m"):
            assert np.allclose(ea.xyz_m, eb.xyz_m, atol=SAME_M)
        else:
            assert ea.name == eb.name
    assert [(c.label, c.kind, c.method, c.inputs) for c in a.constructions] == \
        [(c.label, c.kind, c.method, c.inputs) for c in b.constructions]
    assert a.datums == b.datums
    assert [(t.label, t.kind) for t in a.tolerances.values()] == [(t.label, t.kind) for t in b.tolerances.values()]
    for ta, tb in zip(a.tolerances.values(), b.tolerances.values(), strict=True):
        for key, va in ta.params.items():
            vb = tb.params[key]
            assert va == pytest.approx(vb, abs=SAME_M) if isinstance(va, float) else va == vb
    assert [(o.features, o.tolerances) for o in a.outputs] == [(o.features, o.tolerances) for o in b.outputs]
    assert [m.alignment for m in a.measurements] == [m.alignment for m in b.measurements]
    ev_a = evaluate(a, [t.point_m for t in a.touches])
    ev_b = evaluate(b, [t.point_m for t in b.touches])
    assert [(t.label, t.in_tolerance) for t in ev_a.tolerances] == [(t.label, t.in_tolerance) for t in ev_b.tolerances]
    for ta, tb in zip(ev_a.tolerances, ev_b.tolerances, strict=True):
        assert (ta.actual_m is None and tb.actual_m is None) or abs(ta.actual_m - tb.actual_m) < 1e-8


@pytest.mark.parametrize("name", sorted(CORPUS))
def test_the_corpus_round_trips(name: str, tmp_path: Path) -> None:
    """Each corpus program written back as plain DMIS (flow unrolled) reads to the same program,
    and the plain text is a fixed point."""
    m = read_program(DATA / name)
    text = write_model(m)
    again = parse_program(text, str(tmp_path / "again.dmi"))
    assert_same(m, again)
    assert write_model(again) == text
    assert not again.unsupported()  # nothing left that the reader skips


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(programs())
def test_a_program_written_by_the_twin_reads_back_identical(prog) -> None:
    """Any program the twin writes (UNITS/MM,ANGDEC) is read by the real-program reader back to the
    same Program."""
    text = write_dmis(prog)
    assert "UNITS/MM,ANGDEC" in text and "ANGDEG" not in text
    m = parse_program(text)
    if prog.statements:
        assert lower(m).program == prog


def test_probing_distances_set_between_touches_are_each_touch_own() -> None:
    """SNSET/APPRCH set again between two touches: the second touch approaches from 5 mm, the
    first from 2 mm; written by the twin and read back, the same."""
    m = program("GOTO/CART,0,0,50\nF(P1)=FEAT/POINT,CART,0,0,0,0,0,1\nMEAS/POINT,F(P1),1\nENDMES\n"
                "SNSET/APPRCH,5\nF(P2)=FEAT/POINT,CART,10,0,0,0,0,1\nMEAS/POINT,F(P2),1\nENDMES\n")
    prog = lower(m).program
    p1, p2 = prog.measurements
    assert p1.settings is None and p2.settings is not None and p2.settings.approach_m == pytest.approx(0.005)
    moves = program_moves(prog, {"S1": StylusReach(np.array([0.0, 0.0, -1.0]), 0.05, 0.001)})
    approach = [mv for mv in moves if mv.kind == "approach"]
    assert approach[0].end_m[2] == pytest.approx(0.003) and approach[1].end_m[2] == pytest.approx(0.006)
    assert lower(parse_program(write_dmis(prog))).program == prog


# --- every error of the corpus ------------------------------------------------------------------

ERROR_CASES = {
    "unterminated_meas.dmi": (7, "ENDFIL inside the MEAS block of line 5"),
    "unterminated_meas_eof.dmi": (5, "the MEAS block is not closed by ENDMES"),
    "undefined_label.dmi": (4, r"MEAS of F\(NOPE\), which no FEAT defines"),
    "undefined_datum.dmi": (4, r"DAT\(A\) is not defined"),
    "undefined_alignment.dmi": (4, r"no alignment NEVER was saved"),
    "undefined_macro.dmi": (4, r"no macro M\(NOPE\)"),
    "undefined_jump.dmi": (4, r"no \(NOWHERE\) label"),
    "undeclared_variable.dmi": (4, "ZS is not a declared variable"),
    "missing_call.dmi": (4, "no such file next to missing_call.dmi"),
    "endless_loop.dmi": (None, f"more than {MAX_STATEMENTS} statements executed"),
    "recursive_macro.dmi": (5, "calls nested more than"),
    "moves_machine.dmi": (5, "GOHOME moves the machine to its home position"),
    "rotary_table.dmi": (4, "ROTAB turns a rotary table"),
    "polar_goto.dmi": (4, "GOTO/POL"),
    "unclosed_if.dmi": (5, "the IF block is not closed by ENDIF"),
    "unclosed_macro.dmi": (4, "MACRO 'A' is not closed by ENDMAC"),
    "else_without_if.dmi": (4, "ELSE without IF"),
    "auto_plane.dmi": (6, "without PTMEAS: the touches of a PLANE are not generated"),
    "wrong_kind.dmi": (5, r"MEAS/CIRCLE of F\(PL\), which is a PLANE"),
    "zero_normal.dmi": (4, "must be a nonzero vector"),
    "bad_units.dmi": (4, "UNITS 'FURLONG,ANGDEC' is not read"),
    "no_dmismn.dmi": (1, "UNITS before DMISMN"),
    "output_undefined_tolerance.dmi": (5, r"OUTPUT of T\(NOPE\)"),
    "division_by_zero.dmi": (5, "division by zero"),
    "empty.dmi": (None, "the file is empty"),
    "binary.dmi": (None, "the file is binary"),
}


def test_every_error_program_has_a_case() -> None:
    assert {p.name for p in ERRORS.iterdir()} == set(ERROR_CASES)


@pytest.mark.parametrize("name", sorted(ERROR_CASES))
def test_every_error_is_refused_with_its_file_and_line(name: str) -> None:
    line, message = ERROR_CASES[name]
    with pytest.raises(AlgorithmError) as caught:
        read_program(ERRORS / name)
    text = str(caught.value)
    assert "\n" not in text
    where = re.escape(f"{ERRORS / name}:{line}:") if line is not None else re.escape(f"{ERRORS / name}")
    assert re.match(where, text), text
    assert re.search(message, text), text


#: One malformed statement of each family the reader runs (the corpus's other errors are files).
FAMILY_ERRORS = [
    ("DECL", "DECL/COMMON,DOUBLE,2X\n", "DECL variable name"),
    ("ASSIGN", "ASSIGN/Q=1\n", "ASSIGN to Q, which no DECL declares"),
    ("IF", "IF/(1.EQ.)\nENDIF\n", "IF condition"),
    ("DO", "DECL/LOCAL,INTGR,I\nDO/I,1\nENDDO\n", "DO takes var,start,end"),
    ("CALL", "CALL/M(X),1\n", r"no macro M\(X\)"),
    ("SNSET", "SNSET/APPRCH,-1\n", "is not positive"),
    ("SNSLCT", "SNSLCT/T(S1)\n", r"SNSLCT's sensor must be S\(label\) or SA\(label\)"),
    ("GOTO", "GOTO/CART,1,2\n", "GOTO takes CART,x,y,z"),
    ("FEAT", "F(C)=FEAT/CIRCLE,CART,0,0,0,0,0,1,10\n", "FEAT/CIRCLE takes INNER or OUTER"),
    ("FEAT", "F(C)=FEAT/CIRCLE,INNER,CART,0,0,0,0,0,1\n", "FEAT/CIRCLE takes 7 numbers"),
    ("FEAT", "F(L)=FEAT/LINE,BND,CART,1,1,1,1,1,1,0,0,1\n", "its ends coincide"),
    ("FEAT", "F(C)=FEAT/CYLNDR,OUTER,CART,0,0,0,0,0,1,-3\n", "diameter -3 is not positive"),
    ("MEAS", "MEAS/POINT,P1,1\n", r"MEAS's feature must be F\(label\)"),
    ("PTMEAS", "PTMEAS/CART,0,0,0\n", "PTMEAS outside a MEAS block"),
    ("ENDMES", "ENDMES\n", "ENDMES outside a MEAS block"),
    ("CONST", "F(P)=FEAT/POINT,CART,0,0,0,0,0,1\nCONST/LINE,F(L),INTOF,F(P),F(P)\n",
     "takes 2 or more features of kinds"),
    ("DATDEF", "DATDEF/F(NONE),DAT(A)\n", "feature NONE is not defined"),
    ("DATSET", "F(P)=FEAT/PLANE,CART,0,0,0,0,0,1\nDATSET/F(P),WDIR\n", "DATSET takes datums each followed by"),
    ("DATSET", "F(P)=FEAT/PLANE,CART,0,0,0,0,0,1\nF(Q)=FEAT/PLANE,CART,0,0,0,0,0,1\nDATSET/F(P),ZDIR,F(Q),XDIR\n",
     "parallel to an axis already set"),
    ("TRANS", "TRANS/WORIG,1\n", "TRANS axis must be XORIG"),
    ("ROTATE", "ROTATE/ZAXIS\n", "ROTATE is read as"),
    ("RECALL", "RECALL/DA(X)\n", "no alignment X"),
    ("TOL", "T(F)=TOL/FLAT,0\n", "zone must be positive"),
    ("TOL", "T(P)=TOL/POS,0.1\n", "TOL/POS takes 2D|3D"),
    ("TOL", "T(D)=TOL/DISTWRT,NOMINL,5,-0.1,0.1,XAXIS\n", "TOL/DISTWRT takes its reference"),
    ("TOL", "TOL/FLAT,0.1\n", r"TOL defines a tolerance: T\(label\)"),
    ("OUTPUT", "OUTPUT/FA(NONE)\n", "feature NONE is not defined"),
    ("UNITS", "UNITS/MM,GRAD\n", "is not read"),
    ("DMISMN", "DMISMN/'again',05.3\n", "a second DMISMN"),
    ("JUMPTO", "JUMPTO/NOWHERE\n", r"JUMPTO takes a \(label\)"),
]


@pytest.mark.parametrize("family, body, message", FAMILY_ERRORS, ids=[f"{f}-{k}" for k, (f, *_) in
                                                                      enumerate(FAMILY_ERRORS)])
def test_each_statement_family_refuses_its_malformed_form(family: str, body: str, message: str) -> None:
    with pytest.raises(AlgorithmError) as caught:
        program(body)
    text = str(caught.value)
    assert re.match(r"t\.dmi:\d+: ", text) and re.search(message, text), text


# --- the lexer ---------------------------------------------------------------------------------


def test_lexer_comments_continuations_and_fields() -> None:
    """$$ comments anywhere outside strings, $ continuations joined, fields split outside quotes
    and parentheses, and the encodings read."""
    lines = logical_lines("GOTO/CART,1,$\r\n2,3 $$ a comment, with a comma\n$$ only\n\nTEXT/OPER,'a $$ b'\n")
    assert lines == [(1, "GOTO/CART,1,2,3"), (5, "TEXT/OPER,'a $$ b'")]
    assert split_fields("F(A),'x, y',(1+2)*3, DAT(B) ") == ("F(A)", "'x, y'", "(1+2)*3", "DAT(B)")
    assert decode("é".encode("latin-1"), "f") == ("é", "latin-1")
    assert decode(b"\xef\xbb\xbfA", "f") == ("A", "utf-8-sig")
    assert decode("é".encode(), "f") == ("é", "utf-8")


# --- fits and form ------------------------------------------------------------------------------


def _feature(kind: str, point, direction=None, size=None, inner=None, angle=None) -> Feature:
    d = None if direction is None else np.asarray(direction, float)
    return Feature("X", kind, inner, np.asarray(point, float), d, None, size, angle, Where("t", 1))


def _frame(seed: int) -> tuple[np.ndarray, np.ndarray]:
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    return Rotation.random(random_state=rng).as_matrix(), rng.uniform(-0.2, 0.2, 3)


def test_fits_recover_known_features_in_any_pose() -> None:
    """Exact points of a circle, cylinder, sphere and cone in a random pose give them back."""
    R, t = _frame(3)
    axis = R[:, 2]
    ang = np.linspace(0, 2 * np.pi, 9)[:-1]
    ring = np.column_stack([np.cos(ang), np.sin(ang), np.zeros_like(ang)])
    circle = (0.01 * ring) @ R.T + t
    f, res = geo.fitted(_feature("CIRCLE", t + [1e-4, 0, 0], axis, 0.0205, inner=True), circle)
    assert np.allclose(f.point_m, t, atol=FIT_M) and f.size_m == pytest.approx(0.02, abs=FIT_M)
    cyl = np.vstack([(0.01 * ring + [0, 0, z]) @ R.T + t for z in (0.0, 0.01, 0.02)])
    f, res = geo.fitted(_feature("CYLNDR", t + 3e-4 * R[:, 0], R @ [0.01, 0, 1] / np.linalg.norm([0.01, 0, 1]),
                                 0.021, inner=False), cyl)
    foot = t + ((f.point_m - t) @ axis) * axis
    assert np.allclose(f.point_m, foot, atol=FIT_M) and abs(abs(f.direction @ axis) - 1) < FIT_RAD
    assert f.size_m == pytest.approx(0.02, abs=FIT_M) and np.abs(res).max() < FIT_M
    sph = 0.0125 * np.vstack([ring, [[0, 0, 1]], [[0.6, 0, 0.8]]]) @ R.T + t
    f, _ = geo.fitted(_feature("SPHERE", t + 1e-4, None, 0.02), sph)
    assert np.allclose(f.point_m, t, atol=FIT_M) and f.size_m == pytest.approx(0.025, abs=FIT_M)
    half = math.radians(30)
    cone = np.vstack([(h * math.tan(half) * ring + [0, 0, h]) @ R.T + t for h in (0.005, 0.01, 0.015)])
    f, _ = geo.fitted(_feature("CONE", t - 2e-4 * axis, axis, angle=2 * half + 0.02, inner=True), cone)
    assert np.allclose(f.point_m, t, atol=1e-8) and f.angle_rad == pytest.approx(2 * half, abs=1e-8)


def test_minimum_zone_form_is_exact_on_known_cases() -> None:
    """Flatness of a twisted square (one corner up by d): d/2, where a plane through three corners
    gives d; roundness of a true circle about a centre 5 um off: 0, where the range about that
    centre is 10 um; of a circle with a one-point bump h: at most the least-squares range, at
    least 0.95 h (a bump cannot be tilted away)."""
    d = 1e-6
    square = np.array([[0, 0, 0], [0.05, 0, 0], [0.05, 0.05, d], [0, 0.05, 0]], float)
    assert geo.min_zone_flatness(square, np.array([0, 0, 1.0])) == pytest.approx(d / 2, rel=1e-6)
    ang = np.linspace(0, 2 * np.pi, 37)[:-1]
    ring = np.column_stack([np.cos(ang), np.sin(ang)])
    assert geo.min_zone_roundness(0.01 * ring, np.array([5e-6, 0.0])) == pytest.approx(0.0, abs=1e-8)
    r = np.full_like(ang, 0.01)
    r[0] += 4e-6
    uv = r[:, None] * ring
    c, _ = geo.fit_circle_2d(uv)
    mz = geo.min_zone_roundness(uv, c)
    assert 0.95 * 4e-6 <= mz <= np.ptp(np.linalg.norm(uv - c, axis=1)) + 1e-12


# --- alignments and tolerances -------------------------------------------------------------------

BLOCK = """F(TOP)=FEAT/PLANE,CART,0,0,20,0,0,1
MEAS/PLANE,F(TOP),4
PTMEAS/CART,-30,-20,20
PTMEAS/CART,30,-20,20
PTMEAS/CART,30,20,20
PTMEAS/CART,-30,20,20
ENDMES
F(LEFT)=FEAT/PLANE,CART,-40,0,10,-1,0,0
MEAS/PLANE,F(LEFT),3
PTMEAS/CART,-40,-20,15
PTMEAS/CART,-40,20,15
PTMEAS/CART,-40,0,5
ENDMES
F(FRONT)=FEAT/PLANE,CART,0,-30,10,0,-1,0
MEAS/PLANE,F(FRONT),3
PTMEAS/CART,-20,-30,15
PTMEAS/CART,20,-30,15
PTMEAS/CART,0,-30,5
ENDMES
DATDEF/FA(TOP),DAT(A)
DATDEF/FA(LEFT),DAT(B)
DATDEF/FA(FRONT),DAT(C)
D(PART)=DATSET/DAT(A),ZDIR,ZORIG,DAT(B),-XDIR,XORIG,DAT(C),-YDIR,YORIG
F(HOLE)=FEAT/CIRCLE,INNER,CART,50,40,-5,0,0,1,10
MEAS/CIRCLE,F(HOLE),6
ENDMES
F(BOTTOM)=FEAT/PLANE,CART,40,30,-20,0,0,-1
MEAS/PLANE,F(BOTTOM),4
PTMEAS/CART,20,10,-20
PTMEAS/CART,60,10,-20
PTMEAS/CART,60,50,-20
PTMEAS/CART,20,50,-20
ENDMES
T(DIA)=TOL/DIAM,-0.01,0.01
T(POS)=TOL/POS,2D,0.02
T(XPOS)=TOL/CORTOL,XAXIS,-0.006,0.006
T(DX)=TOL/DISTWRT,NOMINL,50,-0.01,0.01,DAT(B),XAXIS,AVG
T(THICK)=TOL/DISTB,NOMINL,20,-0.01,0.01,ZAXIS,AVG
T(PAR)=TOL/PARLEL,0.003,DAT(A)
T(PERP)=TOL/PERP,0.003,DAT(A)
T(FLAT)=TOL/FLAT,0.001
OUTPUT/FA(HOLE),TA(DIA),TA(POS),TA(XPOS),TA(DX)
OUTPUT/FA(TOP),FA(BOTTOM),TA(THICK)
OUTPUT/FA(BOTTOM),TA(PAR),TA(FLAT)
OUTPUT/FA(LEFT),TA(PERP)
"""


def _measured(m: DmisModel, R: np.ndarray, t: np.ndarray, edits=None) -> list[np.ndarray]:
    """Each touch's target on the part moved by (R, t), edited per feature by ``edits``."""
    out = []
    for touch in m.touches:
        p = touch.point_m
        if edits and touch.feature in edits:
            p = edits[touch.feature](touch)
        out.append(R @ p + t)
    return out


def test_a_part_off_its_alignment_is_judged_in_the_frame_of_its_measured_datums() -> None:
    """The part turned 0.2 deg and shifted 0.3 mm: every tolerance in the datum frame is exact
    (the position is 0), as it is with the part where the program expects it."""
    m = program(BLOCK)
    from scipy.spatial.transform import Rotation

    R = Rotation.from_euler("xyz", [0.05, -0.03, 0.2], degrees=True).as_matrix()
    ev = evaluate(m, _measured(m, R, np.array([3e-4, -2e-4, 1e-4])))
    assert ev.verdict == "PASS", [(t.label, t.actual_m, t.note) for t in ev.tolerances]
    pos = next(t for t in ev.tolerances if t.label == "POS")
    assert pos.actual_m == pytest.approx(0.0, abs=1e-9)


def test_tolerances_measure_known_deviations() -> None:
    """A bore 6 um larger and 4 um off in x, a bottom face 8 um lower and tilted 2 um over its
    40 mm, the left face leaning 1.5 um: each tolerance sees exactly that, in or out of its limits."""
    m = program(BLOCK)
    hole = m.features["HOLE"]

    def bore(t: Touch) -> np.ndarray:
        radial = t.point_m - hole.point_m
        return hole.point_m + radial * (0.005 + 3e-6) / 0.005 + [4e-6, 0, 0]

    def bottom(t: Touch) -> np.ndarray:  # 8 um lower, and 2 um more at the far x end
        return t.point_m + [0, 0, -8e-6 - 2e-6 * (t.point_m[0] + 0.020) / 0.040]

    def left(t: Touch) -> np.ndarray:  # leaning out by 1.5 um over the 10 mm from z = 5 to 15 mm
        return t.point_m + [-1.5e-6 * (t.point_m[2] - 0.005) / 0.010, 0, 0]

    ev = evaluate(m, _measured(m, np.eye(3), np.zeros(3), {"HOLE": bore, "BOTTOM": bottom, "LEFT": left}))
    r = {t.label: t for t in ev.tolerances}
    # LEFT's lean moves datum B's origin (its points' centroid) by their mean shift: the bore's x
    # from B is 50 mm + 4 um less that shift
    shift_b = -1.5e-6 * (np.mean([15, 15, 5]) - 5) / 10
    assert r["DIA"].actual_m == pytest.approx(0.010006, abs=1e-9) and r["DIA"].in_tolerance
    assert r["DX"].actual_m == pytest.approx(0.050 + 4e-6 - shift_b, abs=1e-8) and r["DX"].in_tolerance
    assert r["XPOS"].deviation_m == pytest.approx(4e-6 - shift_b, abs=1e-8) and r["XPOS"].in_tolerance
    assert r["THICK"].actual_m == pytest.approx(0.020 + 9e-6, abs=1e-8) and r["THICK"].in_tolerance
    assert r["PAR"].actual_m == pytest.approx(2e-6, abs=1e-9) and r["PAR"].in_tolerance
    assert r["FLAT"].actual_m == pytest.approx(0.0, abs=1e-9)
    assert r["PERP"].actual_m == pytest.approx(1.5e-6, abs=1e-9) and r["PERP"].in_tolerance
    assert ev.verdict == "PASS"
    # 12 um more on the bore's diameter takes it out: the verdict says FAIL and the output OUTOL
    ev = evaluate(m, _measured(m, np.eye(3), np.zeros(3), {
        "HOLE": lambda t: hole.point_m + (t.point_m - hole.point_m) * (0.005 + 9e-6) / 0.005}))
    assert ev.verdict == "FAIL" and "TA(DIA)=TOL/DIAM,0.0180,OUTOL" in write_output(m, ev)


def test_a_missed_datum_leaves_its_tolerances_unevaluated() -> None:
    """Datum B's touches missed: every result in its alignment is 'not evaluated', never judged
    in a frame the part did not give."""
    m = program(BLOCK)
    measured = [None if t.feature == "LEFT" else t.point_m for t in m.touches]
    ev = evaluate(m, measured)
    assert ev.verdict == "INCOMPLETE"
    dia = next(t for t in ev.tolerances if t.label == "DIA")
    assert dia.in_tolerance is None and "LEFT" in dia.note


def test_the_dmis_output_reads_back_as_the_actuals() -> None:
    """output.dmo's FA() features are the actuals in each OUTPUT's frame, to its 0.1 um."""
    m = program(BLOCK)
    ev = evaluate(m, [t.point_m for t in m.touches])
    back = parse_program(write_output(m, ev), "out.dmo")
    for out in ev.outputs:
        for label, _, actual in out.features:
            assert actual is not None
            assert np.allclose(back.actuals[label.upper()].point_m, actual.point_m, atol=1e-7)


# --- twin cmm check -----------------------------------------------------------------------------

CMM = Path(__file__).resolve().parents[1] / "scenarios" / "cmm"


@pytest.mark.slow
def test_twin_cmm_check_runs_a_program_and_writes_its_results(tmp_path: Path) -> None:
    """The plate program on the bore_and_face cell: every touch hit, no contact, all 8 tolerances
    in (the part lies 0.1 mm and 0.01 deg off; its datums give its frame); the DMIS output reads
    back, results.csv has a row per tolerance, the page shows the verdict."""
    import json

    from tests.helpers import run_cli

    out = tmp_path / "chk"
    r = run_cli("cmm", "check", str(DATA / "plate_bore.dmi"), str(CMM / "bore_and_face.toml"), "--out", str(out),
                "--stylus", "T1A0B0=S1", "--json", "--quiet")
    assert r.returncode == 0, r.stderr + r.stdout
    report = json.loads(r.stdout)
    assert report["verdict"] == "PASS" and len(report["results"]["tolerances"]) == 8
    pos = next(t for t in report["results"]["tolerances"] if t["tolerance"] == "POS_BORE")
    assert pos["actual_m"] < 0.1e-3  # in the datum frame; about 0.2 mm in the machine's nominal one
    back = parse_program((out / "output.dmo").read_text(), "output.dmo")
    assert {"TOP", "BORE", "SIDE", "FLOOR"} <= set(back.actuals)
    assert (out / "results.csv").read_text().count("\n") == 9
    assert "PASS" in (out / "report.html").read_text() and (out / "hits.csv").exists()


@pytest.mark.slow
def test_twin_cmm_check_without_a_datum_fails_the_position_and_says_so(tmp_path: Path) -> None:
    """Without datum C the bore's y is the machine's: its position is 0.2 mm off, exit 3, FAIL."""
    import json

    from tests.helpers import run_cli

    text = (DATA / "plate_bore.dmi").read_text().replace(",DAT(C),YORIG", "").replace("CART,62,46,", "CART,62,6,")
    text = text.replace("62,46,-", "62,6,-").replace(",46,-15", ",6,-15").replace(",54,-15", ",14,-15").replace(
        ",38,-15", ",-2,-15")
    prog = tmp_path / "two_datums.dmi"
    prog.write_text(text)
    r = run_cli("cmm", "check", str(prog), str(CMM / "bore_and_face.toml"), "--out", str(tmp_path / "o"),
                "--stylus", "T1A0B0=S1", "--json", "--quiet")
    assert r.returncode == 3, r.stderr
    report = json.loads(r.stdout)
    assert report["verdict"] == "FAIL"
    out = [t["tolerance"] for t in report["results"]["tolerances"] if t["in_tolerance"] is False]
    assert out == ["POS_BORE"]


@pytest.mark.slow
def test_twin_cmm_check_on_a_part_file_at_a_fixture_pose(tmp_path: Path) -> None:
    """--part: the plate's mesh file on the twin's CMM where the program expects it: PASS."""
    from tests.helpers import run_cli

    assert run_cli("export-mesh", str(CMM / "bore_and_face.toml"), str(tmp_path / "plate.stl")).returncode == 0
    r = run_cli("cmm", "check", str(DATA / "plate_bore.dmi"), "--part", str(tmp_path / "plate.stl"), "--units", "m",
                "--out", str(tmp_path / "o"), "--stylus", "T1A0B0=S1", "--quiet")
    assert r.returncode == 0, r.stderr + r.stdout
    assert "every tolerance in         pass" in r.stdout


def test_twin_cmm_check_reads_without_a_machine_and_refuses_in_one_line(tmp_path: Path) -> None:
    """Without a scenario: the summary (and check.json with --out); a statement that moves the
    machine, a stylus the machine lacks, a run without --out: exit 2, one line, nothing written."""
    import json

    from tests.helpers import run_cli

    r = run_cli("cmm", "check", str(DATA / "workshop_latin1.dmi"), "--json")
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout)
    assert summary["encoding"] == "latin-1" and summary["touches"] == 30
    assert any(n["word"] == "PAUSE" for n in summary["notices"])
    r = run_cli("cmm", "check", str(DATA / "modus_macros.dms"), "--out", str(tmp_path / "c"))
    assert r.returncode == 0 and json.loads((tmp_path / "c" / "check.json").read_text())["touches"] == 20
    for args, message in [
        ((str(ERRORS / "moves_machine.dmi"), str(CMM / "bore_and_face.toml"), "--out", str(tmp_path / "x")),
         "moves_machine.dmi:5: GOHOME"),
        ((str(DATA / "plate_bore.dmi"), str(CMM / "bore_and_face.toml"), "--out", str(tmp_path / "x")),
         "--stylus T1A0B0=NAME"),
        ((str(DATA / "plate_bore.dmi"), str(CMM / "bore_and_face.toml")), "give --out DIR"),
        ((str(DATA / "plate_bore.dmi"), "--stylus", "T1A0B0=S1"), "need a SCENARIO or --part"),
        ((str(DATA / "plate_bore.dmi"), "--part", "x.stl", "--fixture", "1,2", "--out", str(tmp_path / "x")),
         "--fixture '1,2' is not X,Y,Z,RX,RY,RZ"),
        ((str(DATA / "plate_bore.dmi"), "--stylus", "T1A0B0"), "is not PROGRAM=MACHINE"),
    ]:
        r = run_cli("cmm", "check", *args)
        assert r.returncode == 2 and message in r.stderr and "Traceback" not in r.stderr, r.stderr
        assert len(r.stderr.strip().splitlines()) == 1 and not (tmp_path / "x").exists()
