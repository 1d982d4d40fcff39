"""GOTO planning for a taught CMM program: the safe-plane baseline, document 002's algorithm,
and a variant that checks every move.

All three read the same taught path (:func:`algorithms.probing.safety_plane.taught_path`) and
write a :class:`~algorithms.probing.program.Program`. The measured points and the stylus
changes are the operator's, in the operator's order; the planners differ in the GOTOs
(via points) they put between them.

* :func:`plan_baseline` (the clearance-plane rule of PC-DMIS and Rational DMIS): before each
  feature, GOTO the safe position of its first point; after it, GOTO the safe position of its
  last point; the points of a feature are joined by straight moves.
* :func:`plan_document` (document 002): every effective penetration recorded while teaching
  gets the safe position of its penetration point as a GOTO; if the straight move from that
  GOTO to the next measured point hits the part, find-safe-path bisects between the measured
  point's projection on the penetration line and the safe position for a point M from which
  the move is free, and M becomes a GOTO (:func:`find_safe_path`). Leaving the penetration is
  planned the same way, through the point where the taught path comes back above the plane
  (our reading: the document plans the way in and states the way out is symmetric). Moves
  below the plane are not checked: a detour the operator took below the plane is lost, which
  the document names as its limit.
* :func:`plan_full_check` (beyond the document): document 002's program, then every move is
  swept; a move that hits the part is replaced by a chain of stations of the taught path
  (which the operator drove, and which is checked) that keeps every move clear, found by
  greedy shortcutting: from each point, the farthest station it can reach straight. A move no
  chain clears is reported, never hidden.

Collision checks are a callable ``check(start, end, stylus) -> MoveCheck`` (a swept check of
the whole probe, :class:`algorithms.probing.sweep.ProbeSweep`), so the planners run on a real
CMM's CAD model as well as in the twin.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from algorithms.arraytypes import ArrayLike, FloatArray
from algorithms.errors import AlgorithmError
from algorithms.probing.program import Goto, ProbeSettings, Program, SelectStylus, Statement
from algorithms.probing.safety_plane import (
    Penetration,
    SafetyPlane,
    Station,
    Teach,
    penetrations,
    safe_position,
)
from algorithms.probing.sweep import MoveCheck

#: Planner names, in the order reports show them.
PLANNERS = ("baseline", "document", "full_check")
#: find-safe-path stops bisecting when the interval is this short [m].
BISECTION_TOL_M = 2e-4
#: Kinds of moves a program makes (:func:`program_moves`); the planners sweep the transits.
TRANSIT_KINDS = ("goto", "approach", "index")

Check = Callable[[FloatArray, FloatArray, str], MoveCheck]


@dataclass(frozen=True)
class Move:
    """One straight move of the ball centre in a program (part frame) [m].

    ``kind``: "goto" (to a via point), "approach" (to a measured point's approach centre),
    "probe" (from the approach centre to the touch, the ball centre at ``point + r n``),
    "retract" (back off by the retract distance), "index" (a stylus change: the head turns,
    the ball centre jumps from the old stylus's ball to the new one's). ``statement`` is the
    index of the program statement that makes it.
    """

    start_m: FloatArray
    end_m: FloatArray
    stylus: str
    kind: str
    statement: int

    @property
    def length_m(self) -> float:
        """Length of the move [m]."""
        return float(np.linalg.norm(self.end_m - self.start_m))


@dataclass(frozen=True)
class StylusReach:
    """Where a stylus's ball sits relative to the probe head (part frame)."""

    direction: FloatArray
    reach_m: float
    ball_radius_m: float


def program_moves(program: Program, styli: dict[str, StylusReach]) -> list[Move]:
    """The moves a program makes, in order (the probing moves end at the nominal touch).

    Raises:
        AlgorithmError: a stylus the machine lacks, or a motion before the first GOTO and stylus.
    """
    cur: FloatArray | None = None
    stylus: str | None = None
    s = program.settings
    out: list[Move] = []
    for k, st in enumerate(program.statements):
        if isinstance(st, SelectStylus):
            if st.name not in styli:
                raise AlgorithmError(f"statement {k + 1} selects stylus {st.name!r}; the machine has "
                                     f"{', '.join(sorted(styli))}")
            if cur is not None and stylus is not None:
                old, new = styli[stylus], styli[st.name]
                head = cur - old.reach_m * old.direction
                nxt = head + new.reach_m * new.direction
                out.append(Move(cur, nxt, st.name, "index", k))
                cur = nxt
            stylus = st.name
            continue
        if stylus is None:
            raise AlgorithmError(f"statement {k + 1} moves before any stylus is selected (SNSLCT)")
        if isinstance(st, Goto):
            p = np.asarray(st.xyz_m)
            if cur is not None:
                out.append(Move(cur, p, stylus, "goto", k))
            cur = p
            continue
        if cur is None:
            raise AlgorithmError(f"statement {k + 1} measures before the first GOTO: the program must say where "
                                 "the probe starts")
        r = styli[stylus].ball_radius_m
        here = st.settings or s
        a = st.approach_centre(r, here.approach_m)
        touch = np.asarray(st.point_m) + r * np.asarray(st.normal)
        back = st.approach_centre(r, here.retract_m)
        out += [Move(cur, a, stylus, "approach", k), Move(a, touch, stylus, "probe", k),
                Move(touch, back, stylus, "retract", k)]
        cur = back
    return out


@dataclass(frozen=True)
class Collision:
    """A planned move that does not keep the clearance (from a swept check)."""

    statement: int
    kind: str
    start_m: FloatArray
    end_m: FloatArray
    check: MoveCheck


@dataclass(frozen=True)
class Plan:
    """A planner's program, why each statement is there, and what the planner found.

    Attributes:
        method: "baseline", "document" or "full_check".
        program: the planned program.
        reasons: one line per statement: why it is there.
        penetrations: the taught path's penetrations of the safety plane.
        plane: the safety plane planned with.
        unresolved: moves the planner could not clear, one line each (empty when it could).
        collisions: transit moves of the program that do not keep the clearance (swept).
    """

    method: str
    program: Program
    reasons: tuple[str, ...]
    penetrations: tuple[Penetration, ...]
    plane: SafetyPlane
    unresolved: tuple[str, ...]
    collisions: tuple[Collision, ...]


def _goto(p) -> Goto:
    a = np.asarray(p, dtype=np.float64)
    return Goto((float(a[0]), float(a[1]), float(a[2])))


def _mm(p) -> str:
    return "(" + ", ".join(f"{1e3 * float(x):.1f}" for x in p) + ") mm"


def sweep_program(program: Program, styli: dict[str, StylusReach], check: Check) -> list[Collision]:
    """Every transit move (GOTO, approach, stylus change) of a program that is not clear."""
    out = []
    for mv in program_moves(program, styli):
        if mv.kind in TRANSIT_KINDS:
            # A stylus change turns the head where it stands: the planner checks the new stylus
            # there (the replay checks the whole swing at 1 ms).
            start = mv.end_m if mv.kind == "index" else mv.start_m
            res = check(start, mv.end_m, mv.stylus)
            if not res.clear:
                out.append(Collision(mv.statement, mv.kind, mv.start_m, mv.end_m, res))
    return out


def find_safe_path(target_m: FloatArray, line_point_m: FloatArray, safe_m: FloatArray, normal: FloatArray,
                   stylus: str, check: Check, tol_m: float = BISECTION_TOL_M) -> FloatArray | None:
    """Document 002's find-safe-path: a point M on the penetration line from which the straight
    move to ``target_m`` is clear.

    The measured point (its approach centre) is projected on the penetration line (through
    ``line_point_m`` along ``normal``); between that projection Q (clear) and the safe
    position ``safe_m`` (not clear) the interval is bisected, keeping its clear end, until it
    is shorter than ``tol_m``; M is the highest clear point found. None when even Q is not clear.
    """
    n = np.asarray(normal, dtype=np.float64)
    q = line_point_m + float((target_m - line_point_m) @ n) * n
    if not check(q, target_m, stylus).clear:
        return None
    lo, hi = q, np.asarray(safe_m, dtype=np.float64)
    while float(np.linalg.norm(hi - lo)) > tol_m:
        mid = 0.5 * (lo + hi)
        if check(mid, target_m, stylus).clear:
            lo = mid
        else:
            hi = mid
    return lo


@dataclass
class _Builder:
    """Statements with their reasons and their place on the taught path (a station index)."""

    statements: list[Statement]
    reasons: list[str]
    params: list[float]

    def add(self, st: Statement, param: float, reason: str) -> None:
        self.statements.append(st)
        self.params.append(float(param))
        self.reasons.append(reason)


def _start(teach: Teach, stations: list[Station]) -> _Builder:
    b = _Builder([], [], [])
    b.add(SelectStylus(teach.stylus), 0, "the stylus the operator started with")
    b.add(_goto(stations[0].position_m), 0, "where the operator started teaching")
    return b


def _program(teach: Teach, method: str, b: _Builder) -> Program:
    s = teach.settings
    settings = ProbeSettings(s.approach_m, s.retract_m, s.search_m, teach.safe_distance_m)
    return Program(f"{teach.name} {method}", settings, tuple(b.statements))


def _plane(teach: Teach, vertices: ArrayLike) -> SafetyPlane:
    return teach.plane if teach.plane is not None else SafetyPlane.through_highest_point(vertices)


def plan_baseline(teach: Teach, stations: list[Station], vertices: ArrayLike, styli: dict[str, StylusReach],
                  check: Check) -> Plan:
    """The clearance-plane rule: safe positions before and after each feature (consecutive
    touches of one feature), straight moves between its points."""
    plane = _plane(teach, vertices)
    b = _start(teach, stations)
    touch_idx = [i for i, st in enumerate(stations) if st.touch is not None]
    for i, st in enumerate(stations[1:], start=1):
        if st.touch is None:
            if st.stylus != stations[i - 1].stylus:
                b.add(SelectStylus(st.stylus), i, "the operator changed the stylus here")
            continue
        k = touch_idx.index(i)
        feature = st.touch.feature
        if k == 0 or stations[touch_idx[k - 1]].touch.feature != feature:  # type: ignore[union-attr]
            b.add(_goto(safe_position(st.position_m, plane, teach.safe_distance_m)), i - 0.5,
                  f"safe position of the first point of feature {feature}")
        b.add(st.touch.measure(), i, f"point {st.touch.label} of feature {feature}")
        if k == len(touch_idx) - 1 or stations[touch_idx[k + 1]].touch.feature != feature:  # type: ignore[union-attr]
            b.add(_goto(safe_position(st.position_m, plane, teach.safe_distance_m)), i + 0.5,
                  f"safe position of the last point of feature {feature}")
    return _finish("baseline", teach, b, stations, plane, styli, check, [])


def _document_builder(teach: Teach, stations: list[Station], plane: SafetyPlane, styli: dict[str, StylusReach],
                      check: Check, unresolved: list[str]) -> tuple[_Builder, list[Penetration]]:
    pens = penetrations(stations, plane)
    entering = {p.entry_after: (j, p) for j, p in enumerate(pens) if p.effective}
    leaving = {p.exit_after: (j, p) for j, p in enumerate(pens) if p.effective and p.exit_after is not None}
    b = _start(teach, stations)
    cur = stations[0].position_m
    pending: tuple[int, Penetration, FloatArray] | None = None
    settings = teach.settings
    for i, st in enumerate(stations[1:], start=1):
        if i - 1 in entering:
            j, pen = entering[i - 1]
            s = safe_position(pen.entry_m, plane, teach.safe_distance_m)
            b.add(_goto(s), i - 0.5, f"safe position of penetration point {j + 1} at {_mm(pen.entry_m)}")
            cur, pending = s, (j, pen, s)
        if st.touch is None:
            if st.stylus != stations[i - 1].stylus:
                b.add(SelectStylus(st.stylus), i, "the operator changed the stylus here")
                cur = st.position_m
        else:
            if pending is not None:
                j, pen, s = pending
                res = check(s, st.position_m, st.stylus)
                if not res.clear:
                    m = find_safe_path(st.position_m, pen.entry_m, s, plane.normal, st.stylus, check)
                    if m is None:
                        unresolved.append(f"find-safe-path found no clear point on penetration line {j + 1} "
                                          f"for point {st.touch.label}")
                    else:
                        b.add(_goto(m), i - 0.25, f"find-safe-path on penetration line {j + 1}: the move from its "
                                                 f"safe position to {st.touch.label} hits the part ({res.part})")
                pending = None
            m_pt = st.touch.measure()
            b.add(m_pt, i, f"point {st.touch.label} of feature {st.touch.feature}")
            cur = m_pt.approach_centre(styli[st.stylus].ball_radius_m, settings.retract_m)
        if i in leaving:
            j, pen = leaving[i]
            s = safe_position(pen.exit_m, plane, teach.safe_distance_m)  # type: ignore[arg-type]
            res = check(cur, s, st.stylus)
            if not res.clear:
                m = find_safe_path(cur, pen.exit_m, s, plane.normal, st.stylus, check)  # type: ignore[arg-type]
                if m is None:
                    unresolved.append(f"find-safe-path found no clear point on the way out of penetration {j + 1}")
                else:
                    b.add(_goto(m), i + 0.25, f"find-safe-path on the way out of penetration {j + 1}: the straight "
                                             f"move up hits the part ({res.part})")
            b.add(_goto(s), i + 0.5, f"safe position where the path leaves penetration {j + 1} at "
                                    f"{_mm(pen.exit_m)}")
            cur = s
    return b, pens


def plan_document(teach: Teach, stations: list[Station], vertices: ArrayLike, styli: dict[str, StylusReach],
                  check: Check) -> Plan:
    """Document 002's algorithm (see the module docstring)."""
    plane = _plane(teach, vertices)
    unresolved: list[str] = []
    b, pens = _document_builder(teach, stations, plane, styli, check, unresolved)
    return _finish("document", teach, b, stations, plane, styli, check, unresolved, pens)


def plan_full_check(teach: Teach, stations: list[Station], vertices: ArrayLike, styli: dict[str, StylusReach],
                    check: Check) -> Plan:
    """Document 002's program with every move swept and repaired through the taught path."""
    plane = _plane(teach, vertices)
    unresolved: list[str] = []
    doc, pens = _document_builder(teach, stations, plane, styli, check, unresolved)
    crossings = [(p.entry_after + 0.5, p.entry_m) for p in pens]
    crossings += [(p.exit_after + 0.5, p.exit_m) for p in pens if p.exit_m is not None and p.exit_after is not None]
    b = _Builder([], [], [])
    program = _program(teach, "full_check", doc)
    moves = program_moves(program, styli)
    by_statement: dict[int, list[Move]] = {}
    for mv in moves:
        by_statement.setdefault(mv.statement, []).append(mv)
    for k, st in enumerate(doc.statements):
        first = by_statement.get(k, [None])[0]
        if first is not None and first.kind in ("goto", "approach") and k > 0:
            res = check(first.start_m, first.end_m, first.stylus)
            if not res.clear:
                vias = _via_chain(first, doc.params[k - 1], doc.params[k], stations, crossings, check)
                if vias is None:
                    unresolved.append(f"statement {k + 1}: the {first.kind} move from {_mm(first.start_m)} to "
                                      f"{_mm(first.end_m)} hits the part ({res.part} at {_mm(res.ball_centre_m)}) "
                                      "and no chain of taught stations clears it")
                else:
                    for p, param in vias:
                        b.add(_goto(p), param, f"via point on the taught path: the straight {first.kind} move to "
                                              f"statement {k + 1} hits the part ({res.part})")
        elif first is not None and first.kind == "index":
            res = check(first.end_m, first.end_m, first.stylus)
            if not res.clear:
                unresolved.append(f"statement {k + 1}: stylus {first.stylus} hits the part where the head indexes")
        b.add(st, doc.params[k], doc.reasons[k])
    return _finish("full_check", teach, b, stations, plane, styli, check, unresolved, pens)


def _via_chain(move: Move, p0: float, p1: float, stations: list[Station], crossings: list[tuple[float, FloatArray]],
               check: Check) -> list[tuple[FloatArray, float]] | None:
    """Taught points between places ``p0`` and ``p1`` of the taught path that join
    the move's ends by clear straight moves (greedy: always the farthest reachable), or None."""
    lo, hi = min(p0, p1), max(p0, p1)
    cands = [(float(i), s.position_m) for i, s in enumerate(stations)
             if lo < i < hi and s.stylus == move.stylus]
    cands += [(p, c) for p, c in crossings if lo < p < hi]
    cands.sort(key=lambda c: c[0])
    if p0 > p1:
        cands.reverse()
    chain: list[tuple[FloatArray, float]] = []
    cur = move.start_m
    pts = cands + [(p1, move.end_m)]
    i = 0
    while True:
        for j in range(len(pts) - 1, i - 1, -1):
            if check(cur, pts[j][1], move.stylus).clear:
                if j == len(pts) - 1:
                    return chain
                chain.append((pts[j][1], pts[j][0]))
                cur, i = pts[j][1], j + 1
                break
        else:
            return None


def _finish(method: str, teach: Teach, b: _Builder, stations: list[Station], plane: SafetyPlane,
            styli: dict[str, StylusReach], check: Check, unresolved: list[str],
            pens: list[Penetration] | None = None) -> Plan:
    program = _program(teach, method, b)
    if pens is None:
        pens = penetrations(stations, plane)
    return Plan(method, program, tuple(b.reasons), tuple(pens), plane, tuple(unresolved),
                tuple(sweep_program(program, styli, check)))


def taught_path_collisions(stations: list[Station], check: Check) -> list[str]:
    """The moves of the taught path that do not keep the clearance, one line each (a teach
    the operator drove cannot pass through the part: such a teach is wrong)."""
    out = []
    for i in range(1, len(stations)):
        a, b = stations[i - 1], stations[i]
        if b.stylus != a.stylus and b.touch is None:
            res = check(b.position_m, b.position_m, b.stylus)
        else:
            res = check(a.position_m, b.position_m, b.stylus)
        if not res.clear:
            where = _mm(res.ball_centre_m) if res.ball_centre_m is not None else "?"
            out.append(f"teach step {b.step + 1}: the probe's {res.part} comes within "
                       f"{1e3 * (res.distance_m or 0.0):.2f} mm of the part with the ball at {where}")
    return out


def plan(method: str, teach: Teach, stations: list[Station], vertices: ArrayLike, styli: dict[str, StylusReach],
         check: Check) -> Plan:
    """Plan with the named method (one of :data:`PLANNERS`).

    Args:
        method: the planner's name.
        teach: the taught program (points, styli, the safety plane if the operator set one).
        stations: its taught path (:func:`algorithms.probing.safety_plane.taught_path`).
        vertices: (V, 3) [m] the part's vertices, part frame: the default safety plane runs
            through the highest one.
        styli: where each stylus's ball sits relative to the head.
        check: the swept collision check of a straight move.
    """
    planners = {"baseline": plan_baseline, "document": plan_document, "full_check": plan_full_check}
    if method not in planners:
        raise AlgorithmError(f"unknown planner {method!r}; allowed: {', '.join(PLANNERS)}")
    return planners[method](teach, stations, vertices, styli, check)
