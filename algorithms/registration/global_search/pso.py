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
with the library's local method so results reach 1e-6 m / 1e-6 rad (the swarm alone stops at
its own resolution, recorded in ``PSODiagnostics.T_pso``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from algorithms.registration.global_search.fields import sq_dist
from algorithms.registration.global_search.poses import make_poses, rotvec_to_matrix, to_model

__all__ = [
    "PSO_C1_FINAL",
    "PSO_C1_INITIAL",
    "PSO_C2_FINAL",
    "PSO_C2_INITIAL",
    "PSO_ITERATIONS",
    "PSO_PARTICLES",
    "PSO_W_MAX",
    "PSO_W_MIN",
    "PSODiagnostics",
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


def pso(oracle, y_p, T_init, L, rng, *, rot_range, trans_range, particles, iterations):
    z = (y_p - T_init[:3, 3]) @ T_init[:3, :3]  # points in the initial model frame
    c = z.mean(axis=0)
    x_max = np.array([rot_range] * 3 + [trans_range] * 3)
    x_min = -x_max
    v_max = x_max - x_min

    def poses(X):
        R = rotvec_to_matrix(X[:, :3])
        t = c[None, :] - np.einsum("kij,j->ki", R, c) + X[:, 3:]
        return make_poses(R, t)

    hints = [None]

    def fitness(X):
        D = poses(X)
        x = to_model(D, z)  # Delta^-1 z
        h = hints[0]
        foot, normal, face = oracle.closest(x.reshape(-1, 3), hint=h)
        if face is not None:
            hints[0] = np.asarray(face)
        d2, _ = sq_dist(x.reshape(-1, 3), foot, normal, oracle.tangent_tol)
        return d2.reshape(len(X), len(z)).sum(axis=1)

    X = rng.uniform(x_min, x_max, size=(particles, 6))
    V = rng.uniform(-v_max / 2, v_max / 2, size=(particles, 6))
    f = fitness(X)
    pbest, pbest_f = X.copy(), f.copy()
    g = int(np.argmin(f))
    gbest, gbest_f = X[g].copy(), float(f[g])
    history = [gbest_f]
    N = iterations
    for k in range(1, N + 1):
        w = PSO_W_MAX - (PSO_W_MAX - PSO_W_MIN) * k / N
        c1 = PSO_C1_INITIAL + (PSO_C1_FINAL - PSO_C1_INITIAL) * k / N
        c2 = PSO_C2_INITIAL + (PSO_C2_FINAL - PSO_C2_INITIAL) * k / N
        r1 = rng.random((particles, 6))
        r2 = rng.random((particles, 6))
        V = w * V + c1 * r1 * (pbest - X) + c2 * r2 * (gbest[None, :] - X)
        V = np.clip(V, -v_max, v_max)
        X = np.clip(X + V, x_min, x_max)
        f = fitness(X)
        imp = f < pbest_f
        pbest[imp] = X[imp]
        pbest_f[imp] = f[imp]
        g = int(np.argmin(pbest_f))
        if pbest_f[g] < gbest_f:
            gbest, gbest_f = pbest[g].copy(), float(pbest_f[g])
        history.append(gbest_f)
    D = poses(gbest[None])[0]
    return T_init @ D, gbest, gbest_f, np.asarray(history), T_init @ poses(pbest)



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

    T_initial: np.ndarray
    T_pso: np.ndarray
    best_vector: np.ndarray
    best_fitness_m2: float
    fitness_history: np.ndarray
    rotation_range_rad: float
    translation_range_m: float
    fitness: str


def pso_stage(oracle, y_c, T_init, L, rng, *, rotation_range_rad, translation_range_m, particles, iterations,
              fitness) -> tuple[np.ndarray, PSODiagnostics, dict]:
    """Document 003's swarm from the pre-registration ``T_init``.

    Returns:
        (the swarm's pose (4, 4), diagnostics, timings [s]).
    """
    t = time.perf_counter()
    T_pso, gbest, gbest_f, hist, _pbest_T = pso(
        oracle,
        y_c,
        T_init,
        L,
        rng,
        rot_range=float(rotation_range_rad),
        trans_range=translation_range_m,
        particles=int(particles),
        iterations=int(iterations),
    )
    timings = {"pso_s": time.perf_counter() - t}
    diag = PSODiagnostics(
        T_initial=T_init,
        T_pso=T_pso,
        best_vector=gbest,
        best_fitness_m2=gbest_f,
        fitness_history=hist,
        rotation_range_rad=float(rotation_range_rad),
        translation_range_m=translation_range_m,
        fitness=fitness,
    )
    return T_pso, diag, timings
