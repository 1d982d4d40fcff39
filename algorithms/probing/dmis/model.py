"""What a DMIS program means, once read: its nominal features, the touches and moves it makes in
order, its constructions, datums, alignments, tolerances and outputs, and what was skipped.

Frame and units: every position and direction is in the program's *base* frame (the part
coordinate system the program starts in, before any ``DATSET``/``TRANS``/``ROTATE``), in metres
and unit vectors; angles in radians. The reader converts each statement from the coordinate system
then active and from the file's units. A machine runs the motion in the base frame
(:func:`lower` gives the :class:`~algorithms.probing.program.Program` it runs); the alignments
are kept as recipes so that the evaluation can rebuild them from the measured datums.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from algorithms.arraytypes import FloatArray
from algorithms.errors import AlgorithmError
from algorithms.probing.program import (
    LABEL_PATTERN,
    Goto,
    MeasurePoint,
    ProbeSettings,
    Program,
    SelectStylus,
    Statement,
)

#: The nominal feature types read (DMIS ``FEAT`` minor words).
FEATURE_KINDS = ("POINT", "PLANE", "LINE", "CIRCLE", "CYLNDR", "SPHERE", "CONE")


@dataclass(frozen=True)
class Where:
    """A statement's file and first line."""

    source: str
    line: int

    def __str__(self) -> str:
        return f"{self.source}:{self.line}"


@dataclass(frozen=True)
class Notice:
    """A statement read but not acted on (``skipped``) or acted on with a caveat (``warning``)."""

    where: Where
    word: str
    kind: str
    message: str


@dataclass(frozen=True)
class Feature:
    """A nominal (``F``) or given actual (``FA``) feature, base frame.

    Attributes:
        label: its label; kind: one of :data:`FEATURE_KINDS`; inner: True for a bore (INNER),
            False for a boss (OUTER), None where it does not apply.
        point_m: (3,) the point, the plane's point, the line's start, the centre [m].
        direction: (3,) the point's or plane's outward normal, the line's direction, the axis; or None.
        normal: (3,) a line's surface normal (the ``i,j,k`` of ``FEAT/LINE``), else None.
        size_m: the diameter of a circle, cylinder or sphere, the length of a bounded line [m], or None.
        angle_rad: a cone's full apex angle [rad], or None.
        where: where it was defined.
    """

    label: str
    kind: str
    inner: bool | None
    point_m: FloatArray
    direction: FloatArray | None
    normal: FloatArray | None
    size_m: float | None
    angle_rad: float | None
    where: Where


@dataclass(frozen=True)
class Touch:
    """One probing point of a ``MEAS`` block: the target surface point and its outward normal
    (base frame), the probing distances in force and the stylus."""

    feature: str
    index: int
    point_m: FloatArray
    normal: FloatArray
    settings: ProbeSettings
    stylus: str | None
    where: Where


@dataclass(frozen=True)
class Move:
    """A ``GOTO``: the ball centre to ``xyz_m`` (base frame)."""

    xyz_m: FloatArray
    where: Where


@dataclass(frozen=True)
class StylusChange:
    """A ``SNSLCT``: the probe indexes to stylus ``name``."""

    name: str
    where: Where


Event = Move | StylusChange | Touch


@dataclass(frozen=True)
class Measurement:
    """A ``MEAS`` block: the feature, the number of points asked for, the touches made."""

    feature: str
    requested: int
    touches: tuple[Touch, ...]
    where: Where
    alignment: int | None
    events: tuple[Event, ...] = ()  # the block's GOTOs and touches, in order


@dataclass(frozen=True)
class Construction:
    """A ``CONST``: feature ``label`` of ``kind`` built by ``method`` (``BF``, ``INTOF``, ``PROJCT``,
    ``MIDPT``) from ``inputs`` (feature labels)."""

    label: str
    kind: str
    method: str
    inputs: tuple[str, ...]
    where: Where
    alignment: int | None


@dataclass(frozen=True)
class AlignmentStep:
    """One step from a parent alignment (``None``: the base frame).

    ``op`` is ``"datset"`` (``args``: a tuple of (feature label, roles) pairs), ``"trans"`` (``args``:
    (axis, value in metres or a feature label) pairs), ``"rotate"`` (``args``: (axis, angle [rad]))
    or ``"recall"`` (``args``: (), the step only names its parent).
    """

    parent: int | None
    op: str
    args: tuple
    where: Where


@dataclass(frozen=True)
class Tolerance:
    """A ``T(label)=TOL/...``: its type and its parsed parameters (lengths in metres, angles in radians)."""

    label: str
    kind: str
    params: dict
    where: Where


@dataclass(frozen=True)
class OutputRequest:
    """An ``OUTPUT``: the features and tolerances it reports, and the alignment then active."""

    features: tuple[str, ...]
    tolerances: tuple[str, ...]
    where: Where
    alignment: int | None


@dataclass
class DmisModel:
    """A DMIS program, read (see the module docstring).

    Attributes:
        name: the ``DMISMN`` name; version: its version; encoding: the file's encoding.
        sources: every file read (the program and what it calls), in order.
        features: nominal features by upper-case label; actuals: features given as ``FA(...)=FEAT``.
        events: the moves, stylus changes and touches, in the order the machine makes them.
        measurements: the ``MEAS`` blocks, in order.
        constructions, tolerances (by upper-case label), outputs, datums (letter -> feature label).
        alignments: the alignment steps; each ``Measurement``, ``Construction`` and ``OutputRequest``
            names the one active (None: the base frame).
        settings: the probing distances in force at the program's first move, stylus change or touch.
        notices: what was skipped or warned about, with its line.
        statements_executed: how many statements the reader executed (loops and calls counted).
        items: everything above in program order, as (kind, item) pairs: ``feature``, ``actual``,
            ``stylus``, ``move``, ``meas``, ``const``, ``datdef`` ((letter, label)), ``align``
            ((index, name or None)), ``save`` (name), ``tol``, ``output``; what
            :func:`~algorithms.probing.dmis.writer.write_model` writes back.
    """

    name: str
    version: str
    encoding: str
    sources: list[str] = field(default_factory=list)
    features: dict[str, Feature] = field(default_factory=dict)
    actuals: dict[str, Feature] = field(default_factory=dict)
    events: list[Event] = field(default_factory=list)
    measurements: list[Measurement] = field(default_factory=list)
    constructions: list[Construction] = field(default_factory=list)
    tolerances: dict[str, Tolerance] = field(default_factory=dict)
    outputs: list[OutputRequest] = field(default_factory=list)
    datums: dict[str, str] = field(default_factory=dict)
    alignments: list[AlignmentStep] = field(default_factory=list)
    notices: list[Notice] = field(default_factory=list)
    statements_executed: int = 0
    items: list[tuple[str, Any]] = field(default_factory=list)
    settings: ProbeSettings = field(default_factory=ProbeSettings)

    @property
    def touches(self) -> list[Touch]:
        return [e for e in self.events if isinstance(e, Touch)]

    @property
    def moves(self) -> list[Move]:
        return [e for e in self.events if isinstance(e, Move)]

    @property
    def styli(self) -> list[str]:
        """The styli the program selects, in first-use order."""
        seen: dict[str, None] = {}
        for e in self.events:
            if isinstance(e, StylusChange):
                seen.setdefault(e.name, None)
        return list(seen)

    def unsupported(self) -> list[Notice]:
        return [n for n in self.notices if n.kind == "skipped"]


@dataclass(frozen=True)
class Lowered:
    """A program model as the :class:`Program` a machine runs, and each touch's label in it."""

    program: Program
    touch_labels: tuple[str, ...]  # in the order of DmisModel.touches


def _touch_labels(model: DmisModel) -> list[str]:
    """A label per touch: the feature's own for a point measured by one touch, else a generated one."""
    per_feature: dict[str, int] = {}
    for t in model.touches:
        per_feature[t.feature.upper()] = per_feature.get(t.feature.upper(), 0) + 1
    taken = {t.feature.upper() for t in model.touches if per_feature[t.feature.upper()] == 1
             and LABEL_PATTERN.fullmatch(t.feature)}
    labels: list[str] = []
    n = 0
    for t in model.touches:
        if per_feature[t.feature.upper()] == 1 and LABEL_PATTERN.fullmatch(t.feature):
            labels.append(t.feature)
            continue
        while True:
            n += 1
            candidate = f"PT{n:05d}"
            if candidate.upper() not in taken:
                break
        taken.add(candidate.upper())
        labels.append(candidate)
    return labels


def lower(model: DmisModel, stylus_names: dict[str, str] | None = None, default_stylus: str | None = None) -> Lowered:
    """The :class:`Program` that makes ``model``'s moves, stylus changes and touches in order.

    Args:
        stylus_names: the machine's stylus for a program's stylus label (upper case keys); a label
            not in it keeps its name.
        default_stylus: the stylus to select first when the program selects none before its
            first move (None: none is selected, and a machine refuses the program).

    Raises:
        AlgorithmError: no move, stylus change or touch.
    """
    names = {k.upper(): v for k, v in (stylus_names or {}).items()}
    if not model.events:
        raise AlgorithmError(f"program {model.name!r} makes no move, stylus change or touch: nothing to run")
    labels = _touch_labels(model)
    first = model.settings
    statements: list[Statement] = []
    k = 0
    if not isinstance(model.events[0], StylusChange) and default_stylus is not None:
        statements.append(SelectStylus(default_stylus))
    for e in model.events:
        if isinstance(e, StylusChange):
            statements.append(SelectStylus(names.get(e.name.upper(), e.name)))
        elif isinstance(e, Move):
            statements.append(Goto(tuple(e.xyz_m)))  # type: ignore[arg-type]
        else:
            statements.append(MeasurePoint(labels[k], tuple(e.point_m), tuple(e.normal),  # type: ignore[arg-type]
                                           settings=None if e.settings == first else e.settings))
            k += 1
    return Lowered(Program(model.name, first, tuple(statements)), tuple(labels))


def unit(v: FloatArray, what: str) -> FloatArray:
    """``v`` normalised; an AlgorithmError naming ``what`` for a zero vector."""
    n = float(np.linalg.norm(v))
    if not np.isfinite(n) or n == 0.0:
        raise AlgorithmError(f"{what} must be a nonzero vector, got {tuple(float(x) for x in v)}")
    return np.asarray(v, dtype=np.float64) / n
