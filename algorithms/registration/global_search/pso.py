"""Document 003 (patent CN103438844B): particle swarm fine registration after a coarse
pre-registration.

40 particles, 100 iterations, linearly decreasing inertia ``w = w_max - (w_max - w_min) k / N``
from 0.9 to 0.4, time-varying acceleration ``c1 = 2.5 + (0.5 - 2.5) k / N``,
``c2 = 0.5 + (2.5 - 0.5) k / N`` (k = 1..N),
``v <- w v + c1 r1 (p_best - x) + c2 r2 (g_best - x)`` with r1, r2 uniform in [0, 1] per
dimension, ``|v| <= v_max = x_max - x_min``, fitness ``sum ||g Q_i - P_i||^2`` with P_i the
nearest model point (exact closest points by default), final matrix = initial @ PSO.

Readings and choices: the coarse pre-registration ("any rough method") is the first, coarse
phase of the multistart (:mod:`.multistart`, its best minimum). A particle is
``x = [omega (3), t (3)]``: a rotation vector about the points' centroid (model frame) and a
translation, ``Delta(x) = [R(omega), c - R(omega) c + t]``, in the ranges
``+-pso_rotation_range_rad`` and ``+-pso_translation_range_m``; positions are clipped to the
range, initial velocities uniform in ``[-v_max/2, v_max/2]``. The PSO result is then polished
with the library's local method (the swarm alone stops at its own resolution, recorded in
``PSODiagnostics.T_pso``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from algorithms.arraytypes import FloatArray, IntArray, Pose
from algorithms.registration.global_search.fields import NearestSurface, sq_dist
from algorithms.registration.global_search.poses import make_poses, rotvec_to_matrix, to_model

__all__ = [
    "PSO_C1_FINAL",
    "PSO_C1_INITIAL",
    "PSO_C2_FINAL",
    "PSO_C2_INITIAL",
    "PSO_ITERATIONS",
    "PSO_PARTICLES",
    "PSO_TRANSLATION_RANGE_FRAC",
    "PSO_W_MAX",
    "PSO_W_MIN",
    "PSODiagnostics",
    "PSOSettings",
    "pso_stage",
]

PSO_PARTICLES = 40
PSO_ITERATIONS = 100
PSO_W_MAX = 0.9
PSO_W_MIN = 0.4
PSO_C1_INITIAL = 2.5
PSO_C1_FINAL = 0.5
PSO_C2_INITIAL = 0.5
PSO_C2_FINAL = 2.5
#: Default translation range: this fraction of the model's size.
PSO_TRANSLATION_RANGE_FRAC = 0.02


@dataclass(frozen=True)
class PSOSettings:
    """The swarm's settings: search ranges about the pre-registration (rotation [rad],
    translation [m]; None: PSO_TRANSLATION_RANGE_FRAC of the model's size), particles,
    iterations, and the fitness (``"exact"`` or ``"field"``)."""

    rotation_range_rad: float
    translation_range_m: float | None
    particles: int = PSO_PARTICLES
    iterations: int = PSO_ITERATIONS
    fitness: str = "exact"

    def translation_range_for(self, extent: float) -> float:
        """The translation range [m] for a model of size ``extent`` [m]."""
        if self.translation_range_m is None:
            return PSO_TRANSLATION_RANGE_FRAC * extent
        return float(self.translation_range_m)


class _SwarmFitness:
    """Particles ``[omega, t]`` (P, 6) to motions ``Delta`` about the points' centroid ``c``
    (initial model frame) and their fitness ``sum ||Delta^-1 z_i - P_i||^2`` [m^2]."""

    def __init__(self, oracle: NearestSurface, z: FloatArray) -> None:
        self.oracle = oracle
        self.z = z  # (n, 3) [m] the points in the initial model frame
        self.c = z.mean(axis=0)
        self.hints: IntArray | None = None  # the previous query's faces (exact oracle)

    def poses(self, X: FloatArray) -> FloatArray:
        """(P, 4, 4) the motions ``Delta(x) = [R(omega), c - R(omega) c + t]``."""
        R = rotvec_to_matrix(X[:, :3])
        t = self.c[None, :] - np.einsum("kij,j->ki", R, self.c) + X[:, 3:]
        return make_poses(R, t)

    def __call__(self, X: FloatArray) -> FloatArray:
        x = to_model(self.poses(X), self.z)  # Delta^-1 z
        foot, normal, face = self.oracle.closest(x.reshape(-1, 3), hint=self.hints)
        if face is not None:
            self.hints = np.asarray(face)
        d2, _ = sq_dist(x.reshape(-1, 3), foot, normal, self.oracle.tangent_tol)
        return d2.reshape(len(X), len(self.z)).sum(axis=1)


@dataclass
class _Swarm:
    """Positions, velocities, personal and global bests of the particles."""

    X: FloatArray  # (P, 6)
    V: FloatArray  # (P, 6)
    pbest: FloatArray  # (P, 6)
    pbest_f: FloatArray  # (P,) [m^2]
    gbest: FloatArray  # (6,)
    gbest_f: float  # [m^2]


@dataclass(frozen=True)
class _SwarmResult:
    T: Pose  # T_init @ Delta(g_best)
    gbest: FloatArray
    gbest_f: float
    history: FloatArray  # (iterations + 1,) [m^2]


def pso(oracle: NearestSurface, y_p: FloatArray, T_init: Pose, rng: np.random.Generator, *, rot_range: float,
        trans_range: float, particles: int, iterations: int) -> _SwarmResult:
    """Document 003's swarm about ``T_init`` on the points y_p (n, 3) [m] (world frame)."""
    fitness = _SwarmFitness(oracle, (y_p - T_init[:3, 3]) @ T_init[:3, :3])
    x_max = np.array([rot_range] * 3 + [trans_range] * 3)
    x_min = -x_max
    v_max = x_max - x_min
    X = rng.uniform(x_min, x_max, size=(particles, 6))
    V = rng.uniform(-v_max / 2, v_max / 2, size=(particles, 6))
    f = fitness(X)
    g = int(np.argmin(f))
    swarm = _Swarm(X, V, X.copy(), f.copy(), X[g].copy(), float(f[g]))
    history = [swarm.gbest_f]
    for k in range(1, iterations + 1):
        _fly(swarm, fitness, rng, k, iterations, x_min, x_max, v_max)
        history.append(swarm.gbest_f)
    D = fitness.poses(swarm.gbest[None])[0]
    return _SwarmResult(T_init @ D, swarm.gbest, swarm.gbest_f, np.asarray(history))


def _fly(swarm: _Swarm, fitness: _SwarmFitness, rng: np.random.Generator, k: int, N: int, x_min: FloatArray,
         x_max: FloatArray, v_max: FloatArray) -> None:
    """Iteration k of N: the patent's inertia and accelerations, the velocity and position
    updates (clipped), then the personal and global bests."""
    P = len(swarm.X)
    w = PSO_W_MAX - (PSO_W_MAX - PSO_W_MIN) * k / N
    c1 = PSO_C1_INITIAL + (PSO_C1_FINAL - PSO_C1_INITIAL) * k / N
    c2 = PSO_C2_INITIAL + (PSO_C2_FINAL - PSO_C2_INITIAL) * k / N
    r1 = rng.random((P, 6))
    r2 = rng.random((P, 6))
    V = w * swarm.V + c1 * r1 * (swarm.pbest - swarm.X) + c2 * r2 * (swarm.gbest[None, :] - swarm.X)
    swarm.V = np.clip(V, -v_max, v_max)
    swarm.X = np.clip(swarm.X + swarm.V, x_min, x_max)
    f = fitness(swarm.X)
    imp = f < swarm.pbest_f
    swarm.pbest[imp] = swarm.X[imp]
    swarm.pbest_f[imp] = f[imp]
    g = int(np.argmin(swarm.pbest_f))
    if swarm.pbest_f[g] < swarm.gbest_f:
        swarm.gbest, swarm.gbest_f = swarm.pbest[g].copy(), float(swarm.pbest_f[g])


@dataclass(frozen=True, kw_only=True, eq=False)
class PSODiagnostics:
    """What the particle swarm stage did (``GlobalDiagnostics.pso``).

    Attributes:
        T_initial: (4, 4) the coarse pre-registration (the multistart's best minimum).
        T_pso: (4, 4) the swarm's pose before the polish (``T_initial @ Delta(g_best)``).
        best_vector: (6,) the best particle ``[omega, t]``.
        best_fitness_m2: its fitness, ``sum ||g Q_i - P_i||^2`` [m^2].
        fitness_history: (iterations + 1,) the best fitness after each iteration [m^2].
        rotation_range_rad, translation_range_m: the search ranges.
        fitness: ``"exact"`` or ``"field"``.
    """

    T_initial: Pose
    T_pso: Pose
    best_vector: FloatArray
    best_fitness_m2: float
    fitness_history: FloatArray
    rotation_range_rad: float
    translation_range_m: float
    fitness: str


def pso_stage(oracle: NearestSurface, y_c: FloatArray, T_init: Pose, rng: np.random.Generator,
              settings: PSOSettings, extent: float) -> tuple[Pose, PSODiagnostics, dict[str, float]]:
    """Document 003's swarm from the pre-registration ``T_init`` (4, 4) on the points y_c (n, 3)
    [m], world frame; ``extent`` [m]: the model's size (for the default translation range).

    Returns:
        (the swarm's pose (4, 4), diagnostics, timings [s]).
    """
    trans_range = settings.translation_range_for(extent)
    t = time.perf_counter()
    run = pso(oracle, y_c, T_init, rng, rot_range=float(settings.rotation_range_rad), trans_range=trans_range,
              particles=int(settings.particles), iterations=int(settings.iterations))
    timings = {"pso_s": time.perf_counter() - t}
    diag = PSODiagnostics(
        T_initial=T_init,
        T_pso=run.T,
        best_vector=run.gbest,
        best_fitness_m2=run.gbest_f,
        fitness_history=run.history,
        rotation_range_rad=float(settings.rotation_range_rad),
        translation_range_m=trans_range,
        fitness=settings.fitness,
    )
    return run.T, diag, timings
