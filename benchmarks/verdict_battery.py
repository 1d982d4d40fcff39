"""The adversarial battery of localization verdicts: seeded trials that try to make
:func:`algorithms.registration.localize` call a wrong answer good, and sound trials that must be
called good.

Every trial is a pure function of ``(kind, part, seed)``: model points drawn uniformly by area on
the part's faces (all faces, or those seen from a random direction: a partial view), mapped by a
known pose, isotropic Gaussian noise, then the trial's corruption; the fit starts from the
trial's initial pose with the noise sigma given. Kinds:

Sound (must be ``ok`` within 0.5 deg / 0.5 mm; anything else is a false alarm, unless the points
themselves leave a direction weak, which is then not counted):

* ``sound``: 150-2,000 points, sigma 1-20 um, a start within 5 deg / 2 mm.
* ``sound_partial``: the same, seen from one side (faces facing a random direction).
* ``sound_outliers``: the same plus 2-10 % real-like gross errors (spurious returns displaced
  0.2-5 mm along a near-vertical beam, and a few anywhere in the part's box).

Adversarial (an ``ok`` farther than 0.5 deg / 0.5 mm from the truth is a false ``ok``; a refusal,
or any other verdict, is not):

* ``far_start``: starts 30-180 deg about a random axis, the model's centroid on the points' mean.
* ``dome_45``: document 000's workpiece A as its section 8 samples it (100 points on the dome,
  25 on each of two side faces, sigma 5 um), started 45 deg off about the centroid.
* ``gross``: 10-30 % gross errors (as above, half spurious returns, half anywhere in the box),
  a start within 10 deg.
* ``partial_weak``: a view from one side of a part and a start within 10 deg.
* ``wrong_part``: the points of another part (every answer is wrong: any ``ok`` is false).
* ``mirrored``: the points mirrored in the part's x = centre plane.
* ``scaled``: the part scaled by 1-5 % about its centre.
* ``units_mm``: the points in millimetres against a model in metres, and ``units_model_mm`` the
  reverse (a correct fit is a refusal).

Run the large version with ``python -m benchmarks.bench_verdicts``; ``tests/test_verdicts.py``
runs a small one.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from functools import cache

import numpy as np

from algorithms.errors import AlgorithmError
from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import (
    exp_se3,
    inv_pose,
    make_pose,
    rotation_error_rad,
    transform_points,
    translation_error_m,
)
from algorithms.registration import localize
from algorithms.registration.global_search.multistart import model_centroid
from algorithms.registration.global_search.verify import symmetries_of
from algorithms.registration.uncertainty import observability
from twin.parts import make_workpiece

#: Parts without symmetry (a symmetric part's poses are equivalent; its verdicts belong to
#: ``localize_symmetric``).
PARTS = ("s_surface", "hemisphere_punch", "bottle_punch", "inner_sphere", "through_hole", "bore_and_face",
         "cast_blank")
SOUND_KINDS = ("sound", "sound_partial", "sound_outliers")
ADVERSARIAL_KINDS = ("far_start", "dome_45", "gross", "partial_weak", "wrong_part", "mirrored", "scaled", "units_mm",
                     "units_model_mm")
#: Kinds without a true pose: an answer is right only where the model at it explains the points.
NO_TRUTH_KINDS = ("wrong_part", "mirrored", "scaled")
#: A result farther than this from the truth (or an equivalent pose of a symmetric part) is wrong.
ANGLE_TOL_DEG = 0.5
DISTANCE_TOL_M = 5e-4


@dataclass(frozen=True)
class Outcome:
    """One trial: what was asked and what came back.

    Attributes:
        kind, part, seed: the trial.
        status: the verdict's value, or ``"refused"`` (an ``AlgorithmError``).
        correct: the pose within ``ANGLE_TOL_DEG`` / ``DISTANCE_TOL_M`` of the truth.
        weak: the trial's own points leave a direction weak (a sound trial's non-``ok`` is then
            no false alarm).
        angle_deg, distance_mm: the error (NaN when refused or no truth).
        review: the result's ``rejection_review`` (None when none ran).
        time_s: the call's wall time.
    """

    kind: str
    part: str
    seed: int
    status: str
    correct: bool
    weak: bool
    angle_deg: float
    distance_mm: float
    review: str | None
    time_s: float

    @property
    def false_ok(self) -> bool:
        return self.status == "ok" and not self.correct

    @property
    def false_alarm(self) -> bool:
        return self.kind in SOUND_KINDS and not self.weak and not (self.status == "ok" and self.correct)


@cache
def _model(part: str, scale: float = 1.0):
    mesh = make_workpiece(part)
    if scale != 1.0:
        mesh.apply_scale(scale)
    return mesh, MeshIndex(mesh)


def _sample(mesh, faces: np.ndarray, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """n points uniform by area on ``faces``, and their face normals."""
    area = np.asarray(mesh.area_faces)[faces]
    f = faces[rng.choice(len(faces), size=n, p=area / area.sum())]
    u = rng.uniform(size=(n, 2))
    flip = u.sum(axis=1) > 1.0
    u[flip] = 1.0 - u[flip]
    t = np.asarray(mesh.triangles)[f]
    return t[:, 0] + u[:, :1] * (t[:, 1] - t[:, 0]) + u[:, 1:] * (t[:, 2] - t[:, 0]), np.asarray(mesh.face_normals)[f]


def _faces(mesh, partial: bool, rng: np.random.Generator) -> np.ndarray:
    if not partial:
        return np.arange(len(mesh.faces))
    view = rng.standard_normal(3)
    view[2] = abs(view[2]) + 0.5  # from above, as a cell sees a clamped part
    view /= np.linalg.norm(view)
    return np.flatnonzero(np.asarray(mesh.face_normals) @ view > 0.3)


def _dome_points(mesh, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    normals = np.asarray(mesh.face_normals)
    centres = np.asarray(mesh.triangles_center)
    dome = np.flatnonzero(np.all((centres >= [-0.026, -0.036, 0.0201]) & (centres <= [0.046, 0.036, 0.06]), axis=1))
    side_x = np.flatnonzero(normals @ [1.0, 0.0, 0.0] > math.cos(math.radians(1.0)))
    side_y = np.flatnonzero(normals @ [0.0, -1.0, 0.0] > math.cos(math.radians(1.0)))
    parts = [_sample(mesh, f, n, rng) for f, n in ((dome, 100), (side_x, 25), (side_y, 25))]
    return np.concatenate([p for p, _ in parts]), np.concatenate([n for _, n in parts])


def _gross(Y: np.ndarray, fraction: float, rng: np.random.Generator, box_fraction: float) -> np.ndarray:
    """``fraction`` of the points replaced by gross errors: spurious returns displaced 0.2-5 mm
    along a near-vertical beam, and ``box_fraction`` of them anywhere in the points' box + 10 mm."""
    Y = Y.copy()
    k = max(1, int(round(fraction * len(Y))))
    idx = rng.choice(len(Y), size=k, replace=False)
    n_box = int(round(box_fraction * k))
    beam = np.array([0.0, 0.0, 1.0]) + 0.3 * rng.standard_normal((k - n_box, 3))
    beam /= np.linalg.norm(beam, axis=1)[:, None]
    Y[idx[n_box:]] += beam * rng.uniform(2e-4, 5e-3, (k - n_box, 1)) * rng.choice([-1.0, 1.0], (k - n_box, 1))
    Y[idx[:n_box]] = rng.uniform(Y.min(axis=0) - 0.01, Y.max(axis=0) + 0.01, (n_box, 3))
    return Y


def _start(T_true: np.ndarray, angle_deg: float, distance_m: float, rng: np.random.Generator) -> np.ndarray:
    axis = rng.standard_normal(3)
    axis /= np.linalg.norm(axis)
    u = rng.standard_normal(3)
    u /= np.linalg.norm(u)
    return T_true @ exp_se3(np.concatenate([math.radians(angle_deg) * axis, distance_m * u]))


def _error_modulo_symmetry(T: np.ndarray, T_true: np.ndarray, index: MeshIndex) -> tuple[float, float]:
    """The pose error [deg], [m] to the nearest pose of ``T_true`` the part's symmetries make
    equivalent (an inner sphere's block turned 90 deg is the same part)."""
    best = (math.inf, math.inf)
    for S in symmetries_of(index):
        Ts = T_true @ S
        e = (math.degrees(rotation_error_rad(T, Ts)), translation_error_m(T, Ts))
        if e[0] / ANGLE_TOL_DEG + e[1] / DISTANCE_TOL_M < best[0] / ANGLE_TOL_DEG + best[1] / DISTANCE_TOL_M:
            best = e
    return best


def trial(kind: str, part: str, seed: int) -> Outcome:
    """Run one trial (module docstring)."""
    rng = np.random.default_rng([seed, ADVERSARIAL_KINDS.index(kind) + 10 if kind in ADVERSARIAL_KINDS
                                 else SOUND_KINDS.index(kind), PARTS.index(part)])
    mesh, index = _model(part)
    T_true = make_pose(exp_se3(np.r_[0, 0, rng.uniform(-0.2, 0.2), 0, 0, 0])[:3, :3],
                       [0.45 + rng.uniform(-0.02, 0.02), 0.1, 0.0])
    sigma = float(np.exp(rng.uniform(math.log(1e-6), math.log(2e-5))))
    n = int(np.exp(rng.uniform(math.log(150), math.log(2000))))
    partial = kind in ("sound_partial", "partial_weak")
    if kind == "dome_45":
        mesh, index = _model("hemisphere_punch")
        x, normals = _dome_points(mesh, rng)
        sigma = 5e-6
    elif kind == "wrong_part":
        other = PARTS[(PARTS.index(part) + 1 + int(rng.integers(len(PARTS) - 1))) % len(PARTS)]
        x, normals = _sample(_model(other)[0], np.arange(len(_model(other)[0].faces)), n, rng)
    else:
        x, normals = _sample(mesh, _faces(mesh, partial, rng), n, rng)
    weak = not observability(x, normals).observable
    centre = np.asarray(mesh.bounds).mean(axis=0)
    if kind == "mirrored":
        x = x.copy()
        x[:, 0] = 2.0 * centre[0] - x[:, 0]
    if kind == "scaled":
        x = centre + (1.0 + rng.uniform(0.01, 0.05) * rng.choice([-1.0, 1.0])) * (x - centre)
    Y = transform_points(T_true, x) + sigma * rng.standard_normal(x.shape)
    if kind == "sound_outliers":
        Y = _gross(Y, rng.uniform(0.02, 0.10), rng, box_fraction=0.2)
    elif kind == "gross":
        Y = _gross(Y, rng.uniform(0.10, 0.30), rng, box_fraction=0.5)
    if kind in SOUND_KINDS:
        T0 = _start(T_true, rng.uniform(0.0, 5.0), rng.uniform(0.0, 2e-3), rng)
    elif kind in ("far_start", "dome_45"):
        T0 = _start(T_true, 45.0 if kind == "dome_45" else rng.uniform(30.0, 180.0), 0.0, rng)
        T0[:3, 3] = Y.mean(axis=0) - T0[:3, :3] @ model_centroid(mesh)
    else:
        T0 = _start(T_true, rng.uniform(0.0, 10.0), rng.uniform(0.0, 2e-3), rng)
    if kind == "units_mm":
        Y = 1e3 * Y
    if kind == "units_model_mm":
        index = _model(part, 1e3)[1]
    t0 = time.perf_counter()
    try:
        r = localize(Y, index=index, init=T0, sigma=sigma)
    except AlgorithmError:
        return Outcome(kind, part, seed, "refused", False, weak, math.nan, math.nan, None, time.perf_counter() - t0)
    dt = time.perf_counter() - t0
    angle, dist = _error_modulo_symmetry(r.T_world_workpiece, T_true, index)
    if kind in NO_TRUTH_KINDS:  # right only where the model explains the (noise-free) points
        d = index.query(transform_points(inv_pose(r.T_world_workpiece) @ T_true, x)).distance
        correct = float(np.sqrt(np.mean(d**2))) <= max(2.0 * sigma, 1e-6)
    else:
        correct = angle <= ANGLE_TOL_DEG and dist <= DISTANCE_TOL_M
    return Outcome(kind, part, seed, r.status.value, correct, weak, angle, 1e3 * dist, r.rejection_review, dt)


def battery(n_per_cell: int, kinds: tuple[str, ...] = SOUND_KINDS + ADVERSARIAL_KINDS,
            parts: tuple[str, ...] = PARTS, first_seed: int = 0) -> list[Outcome]:
    """``n_per_cell`` trials of every (kind, part) (``dome_45`` on its own part only)."""
    out = []
    for kind in kinds:
        for part in (("hemisphere_punch",) if kind == "dome_45" else parts):
            out.extend(trial(kind, part, first_seed + s) for s in range(n_per_cell))
    return out
