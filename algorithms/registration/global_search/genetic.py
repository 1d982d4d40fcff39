"""Document 001 (hierarchical macro/micro localization): the genetic coarse stage and the fine
stage after it.

A binary chromosome ``{X_T | Y_T | Z_T | alpha | beta | gamma}``, fitness
``1 / (1 + sum_i D_err,i)``, crossover probability ``Pc = 0.9``, mutation ``Pm = 0.1``, 100
individuals, random initial genes, stop at generation 100 or best fitness >= 0.95. Then the
fine stage (document 001's variable-iteration-centre linearised least squares,
``localize(..., method="fine_001", init=T_coarse)``, on the coarse subset of at most
``n_coarse`` points: the document's fine stage uses a few probe points) and
``T = T_fine @ T_coarse``; then the polish with all points (:mod:`.search`).

Readings and choices (the original does not state them):

* Bits: 10 per parameter (60 per chromosome), plain binary code as the document says.
  Angles ``R = Rz(gamma) Ry(beta) Rx(alpha)``: alpha, gamma in [-180, 180) degrees, beta in
  [-90, 90] degrees (resolution 0.35 and 0.18 degrees, below the document's "a few tenths of
  a degree"). ``[X_T, Y_T, Z_T]`` is where the points' centroid lies in the model frame,
  relative to the model's (area) centroid:
  ``T^-1 y = R^T (y - mean(y)) + c_model + [X_T, Y_T, Z_T]``, each within half the model's
  bounding box. Document 001 first moves the part by its moment of inertia; centring on the
  centroids plays that role, and makes the best translation genes independent of the
  rotation genes (a translation of the world origin would couple them).
* ``D_err`` in millimetres, the document's unit (its matrices are in mm). Summed over N
  points the fitness reaches 0.95 only when ``sum D_err <= 0.053 mm``, e.g. a mean distance
  of 0.35 um over 150 points: the early stop is practically unreachable and the GA runs its
  100 generations.
* ``Pm = 0.1`` per bit (the classical meaning of a binary GA's mutation rate, Goldberg 1989;
  ``mutation="per_chromosome"`` flips one random bit of a chromosome with probability 0.1
  instead). Selection is fitness-proportional (roulette wheel), crossover single-point on
  consecutive pairs, and the best individual is kept (elitism, 1): the document names none
  of these.
* D_err is read from the coarse nearest-surface field (:mod:`.fields`, resolution about a
  millimetre) for all 100 chromosomes at once; the fine stage uses exact closest points.
* Restarts: from random orientations one GA run (100 x 100) often ends in a wrong basin (it
  settles on a near-symmetric pose, e.g. the hemisphere's points matched and the part turned
  90 or 180 degrees; measured rates in ``benchmarks/results_localization.md``). So, when
  ``noise_sigma_m`` is known, a run is checked the way Algorithm 5 checks a start (a short
  exact descent from the GA's pose; RMS residual within 2 sigma_eff) and the GA is run again
  with fresh random genes, at most ``ga_restarts`` times. ``ga_restarts=1`` is the
  document's single run.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from algorithms.geometry.se3 import inv_pose
from algorithms.registration.global_search.fields import sq_dist
from algorithms.registration.global_search.multistart import NOISE_ACCEPT_FACTOR, descend
from algorithms.registration.global_search.poses import make_poses, to_model
from algorithms.registration.local import localize_checked

__all__ = [
    "FINE_001_D",
    "FINE_001_MAX_ITERATIONS",
    "GA_BITS",
    "GA_CROSSOVER_PROB",
    "GA_FITNESS_STOP",
    "GA_GENERATIONS",
    "GA_MUTATION_PROB",
    "GA_POPULATION",
    "GeneticDiagnostics",
    "genetic_stage",
]

GA_POPULATION = 100
GA_GENERATIONS = 100
GA_CROSSOVER_PROB = 0.9
GA_MUTATION_PROB = 0.1
GA_FITNESS_STOP = 0.95
#: Our choice (the document does not give it): bits per parameter.
GA_BITS = 10
#: Fine stage stop value d [rad^2 + m^2] and iteration cap (our choices; the polish follows).
FINE_001_D = 1e-16
FINE_001_MAX_ITERATIONS = 300


def decode(bits: np.ndarray, lo: np.ndarray, hi: np.ndarray, nbits: int) -> np.ndarray:
    """(P, 6*nbits) 0/1 plain binary code -> (P, 6) parameters, each linear in [lo, hi]."""
    P = len(bits)
    b = bits.reshape(P, 6, nbits).astype(np.int64)
    w = (1 << np.arange(nbits - 1, -1, -1)).astype(np.int64)
    ints = b @ w
    return lo + (hi - lo) * ints / float((1 << nbits) - 1)


def ga_poses(params: np.ndarray, y_mean: np.ndarray, c_model: np.ndarray) -> np.ndarray:
    """Poses of chromosomes: ``R = Rz(gamma) Ry(beta) Rx(alpha)``, and ``[X_T, Y_T, Z_T]`` the
    model-frame position of the points' centroid relative to the model centroid, so that
    ``T^-1 y = R^T (y - mean(y)) + c_model + [X_T, Y_T, Z_T]`` (the best translation genes do
    not depend on the rotation genes)."""
    R = Rotation.from_euler("ZYX", params[:, [5, 4, 3]]).as_matrix()
    p = y_mean[None, :] - np.einsum("kij,kj->ki", R, c_model[None, :] + params[:, :3])
    return make_poses(R, p)


def ga_fitness(field, y, T) -> np.ndarray:
    x = to_model(T, y)
    foot, normal, _ = field.closest(x.reshape(-1, 3))
    d2, _ = sq_dist(x.reshape(-1, 3), foot, normal, field.tangent_tol)
    dist_mm = 1e3 * np.sqrt(d2).reshape(len(T), len(y))
    return 1.0 / (1.0 + dist_mm.sum(axis=1))


def genetic(field, y_g, c_model, half_size, rng, *, nbits, mutation, population, generations):
    lo = np.concatenate([-half_size, [-np.pi, -np.pi / 2, -np.pi]])
    hi = np.concatenate([half_size, [np.pi, np.pi / 2, np.pi]])
    nb = 6 * nbits
    y_mean = y_g.mean(axis=0)
    pop = rng.integers(0, 2, size=(population, nb), dtype=np.int8)
    best_bits, best_fit = None, -1.0
    history = []
    hall: list[tuple[float, np.ndarray]] = []
    gen = 0
    for gen in range(1, generations + 1):
        params = decode(pop, lo, hi, nbits)
        T = ga_poses(params, y_mean, c_model)
        fit = ga_fitness(field, y_g, T)
        i = int(np.argmax(fit))
        if fit[i] > best_fit:
            best_fit, best_bits = float(fit[i]), pop[i].copy()
        history.append(float(fit.max()))
        # the distinct good chromosomes of every generation, for hypothesis verification
        top = np.argsort(-fit)[:5]
        hall.extend((float(fit[t]), T[t]) for t in top)
        if best_fit >= GA_FITNESS_STOP or gen == generations:
            break
        # roulette-wheel selection
        prob = fit / fit.sum()
        parents = pop[rng.choice(population, size=population, p=prob)]
        # single-point crossover on consecutive pairs with probability Pc
        children = parents.copy()
        for k in range(0, population - 1, 2):
            if rng.random() < GA_CROSSOVER_PROB:
                cut = int(rng.integers(1, nb))
                children[k, cut:] = parents[k + 1, cut:]
                children[k + 1, cut:] = parents[k, cut:]
        # mutation with probability Pm
        if mutation == "per_bit":
            flip = rng.random(children.shape) < GA_MUTATION_PROB
            children ^= flip.astype(np.int8)
        else:
            who = np.nonzero(rng.random(population) < GA_MUTATION_PROB)[0]
            bit = rng.integers(0, nb, size=len(who))
            children[who, bit] ^= 1
        # elitism: the best so far replaces one child
        children[int(rng.integers(0, population))] = best_bits
        pop = children
    T_best = ga_poses(decode(best_bits[None], lo, hi, nbits), y_mean, c_model)[0]
    return T_best, best_fit, gen, np.asarray(history), hall



@dataclass(frozen=True, kw_only=True, eq=False)
class GeneticDiagnostics:
    """What the genetic stage did (``GlobalDiagnostics.genetic``).

    Attributes:
        best_fitness: the best chromosome's fitness ``1 / (1 + sum D_err [mm])``.
        generations: generations run in the kept run.
        fitness_history: (generations,) best fitness per generation of the kept run.
        runs: GA runs made (restarts included).
        run_check_rms_m: RMS residual [m] of the short exact descent from each run's pose.
        T_coarse: (4, 4) the GA's pose (the coarse stage).
        T_fine: (4, 4) the fine stage's correction: its result is ``T_fine @ T_coarse``.
        bits: bits per parameter.
        mutation: ``"per_bit"`` or ``"per_chromosome"``.
        fine_001_rmse_m: RMS residual of the fine stage [m] (on the coarse subset).
        fine_001_iterations: its iterations.
    """

    best_fitness: float
    generations: int
    fitness_history: np.ndarray
    runs: int
    run_check_rms_m: tuple
    T_coarse: np.ndarray
    T_fine: np.ndarray
    bits: int
    mutation: str
    fine_001_rmse_m: float
    fine_001_iterations: int


def genetic_stage(field, exact, index, mesh, y_c, c_model, L, rng, *, sigma, sig_eff, outlier_cfg, bits,
                  mutation, population, generations, restarts) -> tuple[np.ndarray, GeneticDiagnostics, dict]:
    """Document 001's coarse (GA, with restarts) and fine (``fine_001``) stages.

    Args:
        field: the coarse nearest-surface field; exact: the exact oracle; index: the mesh
            index; mesh: the model.
        y_c: (n, 3) [m] the coarse subset of the points, world frame.
        c_model: (3,) the model's area centroid; L: the points' characteristic length [m].
        rng: random generator.
        sigma: the given noise sigma [m] (or None); sig_eff: the effective sigma (or None:
            unknown, one run).
        outlier_cfg: the checked outlier rule of the fine stage.
        bits, mutation, population, generations, restarts: GA settings.

    Returns:
        (the fine stage's pose (4, 4), diagnostics, timings [s]).
    """
    timings = {}
    t = time.perf_counter()
    half_size = 0.5 * np.ptp(np.asarray(mesh.vertices, dtype=np.float64), axis=0)
    runs = []
    for _ in range(int(restarts)):
        T_ga, fit, gens, hist, _hall = genetic(
            field,
            y_c,
            c_model,
            half_size,
            rng,
            nbits=int(bits),
            mutation=mutation,
            population=int(population),
            generations=int(generations),
        )
        # Algorithm 5's acceptance applied to the GA: a short exact descent from the
        # coarse pose; a residual above the noise means the GA found a wrong basin
        chk = descend(exact, y_c, T_ga[None], L=L, delta1=1e-9, delta2=np.inf, delta3=1e-9,
                      max_iter_per_descent=30, rng=None)
        rms_chk = math.sqrt(float(chk.eps[0]) / len(y_c))
        runs.append((rms_chk, T_ga, fit, gens, hist))
        if sig_eff is None or rms_chk <= NOISE_ACCEPT_FACTOR * sig_eff:
            break
    rms_chk, T_ga, fit, gens, hist = min(runs, key=lambda z: z[0])
    timings["ga_s"] = time.perf_counter() - t
    t = time.perf_counter()
    # document 001's fine stage works on a few probe points (m >= 6): the coarse subset
    # d of document 001's stop test: sum dtheta^2 + sum dDelta^2 < FINE_001_D (steps below
    # 1e-8 rad / 1e-8 m; the polish that follows converges quadratically from there)
    fine = localize_checked(y_c, index, "fine_001", T_ga, sigma=sigma, outlier_cfg=outlier_cfg,
                            tolerance=FINE_001_D, max_iterations=FINE_001_MAX_ITERATIONS)
    timings["fine_001_s"] = time.perf_counter() - t
    T_after = fine.T_world_workpiece
    diag = GeneticDiagnostics(
        best_fitness=fit,
        generations=gens,
        fitness_history=hist,
        runs=len(runs),
        run_check_rms_m=tuple(r[0] for r in runs),
        T_coarse=T_ga,
        T_fine=T_after @ inv_pose(T_ga),
        bits=int(bits),
        mutation=mutation,
        fine_001_rmse_m=fine.rmse_m,
        fine_001_iterations=fine.iterations,
    )
    return T_after, diag, timings
