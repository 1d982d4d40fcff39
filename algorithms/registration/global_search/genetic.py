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

* The search space: every orientation by default (our reading: nothing in the document says
  where the part lies); ``rotation_range_rad`` and a centre orientation constrain each Euler
  angle to that range about it (the document's "under specific constraints": a part clamped
  roughly as planned; a study states the range it reads from the document's experiment).
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
  points the fitness reaches 0.95 only when ``sum D_err <= 0.053 mm`` (a mean distance of
  0.35 um over 150 points): the early stop is practically unreachable and the GA runs its
  100 generations.
* ``Pm = 0.1`` per bit (the classical meaning of a binary GA's mutation rate, Goldberg 1989;
  ``mutation="per_chromosome"`` flips one random bit of a chromosome with probability 0.1
  instead). Selection is fitness-proportional (roulette wheel), crossover single-point on
  consecutive pairs, and the best individual is kept (elitism, 1): the document names none
  of these.
* D_err is read from the coarse nearest-surface field (:mod:`.fields`) for the whole
  population at once; the fine stage uses exact closest points.
* Restarts: from random orientations one GA run often ends in a wrong basin (a
  near-symmetric pose; rates in ``benchmarks/results_localization.md``). So, when
  ``noise_sigma_m`` is known, a run is checked the way Algorithm 5 checks a start (a short
  exact descent from the GA's pose; RMS residual within 2 sigma_eff) and the GA is run again
  with fresh random genes, at most ``ga_restarts`` times. ``ga_restarts=1`` is the
  document's single run.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from algorithms.arraytypes import FloatArray, Pose
from algorithms.geometry.se3 import inv_pose
from algorithms.registration.global_search.fields import NearestSurface, sq_dist
from algorithms.registration.global_search.multistart import NOISE_ACCEPT_FACTOR, CoarseProblem, descend
from algorithms.registration.global_search.poses import make_poses, to_model
from algorithms.registration.local import localize_checked
from algorithms.registration.robust import OutlierConfig

__all__ = [
    "FINE_001_D",
    "FINE_001_MAX_ITERATIONS",
    "GA_BITS",
    "GA_CROSSOVER_PROB",
    "GA_FITNESS_STOP",
    "GA_GENERATIONS",
    "GA_MUTATION_PROB",
    "GA_POPULATION",
    "GASettings",
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
#: The restart check: a short exact descent of at most this many steps from a run's pose.
RUN_CHECK_ITERATIONS = 30


@dataclass(frozen=True)
class GASettings:
    """The genetic algorithm's settings: bits per parameter, ``"per_bit"`` or
    ``"per_chromosome"`` mutation, population, generations, the most runs (restarts), and the
    search's constraint: None (every orientation), or the rotations within
    ``rotation_range_rad`` of ``R_center`` (3, 3) on each Euler angle (document 001's GA
    "under specific constraints")."""

    bits: int = GA_BITS
    mutation: str = "per_bit"
    population: int = GA_POPULATION
    generations: int = GA_GENERATIONS
    restarts: int = 10
    rotation_range_rad: float | None = None
    R_center: FloatArray | None = None


def decode(bits: np.ndarray, lo: FloatArray, hi: FloatArray, nbits: int) -> FloatArray:
    """(P, 6*nbits) 0/1 plain binary code -> (P, 6) parameters, each linear in [lo, hi]."""
    P = len(bits)
    b = bits.reshape(P, 6, nbits).astype(np.int64)
    w = (1 << np.arange(nbits - 1, -1, -1)).astype(np.int64)
    ints = b @ w
    return lo + (hi - lo) * ints / float((1 << nbits) - 1)


def ga_poses(params: FloatArray, y_mean: FloatArray, c_model: FloatArray,
             R_center: FloatArray | None = None) -> FloatArray:
    """(P, 4, 4) poses of chromosomes' parameters (P, 6): ``R = Rz(gamma) Ry(beta) Rx(alpha)``
    (``R_center`` times it for a constrained search), and ``[X_T, Y_T, Z_T]`` the model-frame
    position of the points' centroid relative to the model centroid, so that
    ``T^-1 y = R^T (y - mean(y)) + c_model + [X_T, Y_T, Z_T]`` (the best translation genes do
    not depend on the rotation genes)."""
    R = Rotation.from_euler("ZYX", params[:, [5, 4, 3]]).as_matrix()
    if R_center is not None:
        R = np.einsum("ij,kjl->kil", R_center, R)
    p = y_mean[None, :] - np.einsum("kij,kj->ki", R, c_model[None, :] + params[:, :3])
    return make_poses(R, p)


def ga_fitness(field: NearestSurface, y: FloatArray, T: FloatArray) -> FloatArray:
    """(P,) ``1 / (1 + sum_i D_err,i [mm])`` of the poses T (P, 4, 4) on the points y (N, 3) [m]."""
    x = to_model(T, y)
    foot, normal, _ = field.closest(x.reshape(-1, 3))
    d2, _ = sq_dist(x.reshape(-1, 3), foot, normal, field.tangent_tol)
    dist_mm = 1e3 * np.sqrt(d2).reshape(len(T), len(y))
    return 1.0 / (1.0 + dist_mm.sum(axis=1))


@dataclass(frozen=True)
class _GeneSpace:
    """Where chromosomes live: parameter bounds, bits, and the centroids their poses match."""

    lo: FloatArray  # (6,) [m, m, m, rad, rad, rad]
    hi: FloatArray
    nbits: int
    y_mean: FloatArray  # (3,) [m] the points' centroid, world frame
    c_model: FloatArray  # (3,) [m] the model's area centroid, workpiece frame
    R_center: FloatArray | None = None  # (3, 3) the constrained search's centre orientation

    @classmethod
    def around(cls, half_size: FloatArray, settings: GASettings, y: FloatArray, c_model: FloatArray) -> _GeneSpace:
        r = settings.rotation_range_rad
        angles = np.array([np.pi, np.pi / 2, np.pi]) if r is None else np.full(3, r)
        lo = np.concatenate([-half_size, -angles])
        hi = np.concatenate([half_size, angles])
        return cls(lo, hi, int(settings.bits), y.mean(axis=0), c_model, None if r is None else settings.R_center)

    @property
    def n_genes(self) -> int:
        return 6 * self.nbits

    def poses(self, pop: np.ndarray) -> FloatArray:
        return ga_poses(decode(pop, self.lo, self.hi, self.nbits), self.y_mean, self.c_model, self.R_center)


@dataclass(frozen=True)
class _GARun:
    """One GA run: its best chromosome's pose and fitness, generations, best fitness per
    generation, and the RMS residual [m] of the short exact descent from its pose."""

    T: Pose
    fitness: float
    generations: int
    history: FloatArray
    check_rms_m: float = math.nan


def genetic(field: NearestSurface, y_g: FloatArray, c_model: FloatArray, half_size: FloatArray,
            rng: np.random.Generator, settings: GASettings) -> _GARun:
    """One run of document 001's GA on the points y_g (n, 3) [m] (world frame)."""
    space = _GeneSpace.around(half_size, settings, y_g, c_model)
    population = int(settings.population)
    generations = int(settings.generations)
    pop = rng.integers(0, 2, size=(population, space.n_genes), dtype=np.int8)
    best_bits, best_fit = pop[0], -1.0
    history = []
    gen = 0
    for gen in range(1, generations + 1):
        fit = ga_fitness(field, y_g, space.poses(pop))
        i = int(np.argmax(fit))
        if fit[i] > best_fit:
            best_fit, best_bits = float(fit[i]), pop[i].copy()
        history.append(float(fit.max()))
        if best_fit >= GA_FITNESS_STOP or gen == generations:
            break
        pop = _next_generation(pop, fit, best_bits, rng, settings.mutation)
    return _GARun(space.poses(best_bits[None])[0], best_fit, gen, np.asarray(history))


def _next_generation(pop: np.ndarray, fit: FloatArray, best_bits: np.ndarray, rng: np.random.Generator,
                     mutation: str) -> np.ndarray:
    """Roulette-wheel selection, single-point crossover on consecutive pairs (Pc), mutation
    (Pm), and the best chromosome so far in place of one child (elitism)."""
    population, nb = len(pop), int(pop.shape[1])
    parents = pop[rng.choice(population, size=population, p=fit / fit.sum())]
    children = parents.copy()
    for k in range(0, population - 1, 2):
        if rng.random() < GA_CROSSOVER_PROB:
            cut = int(rng.integers(1, nb))
            children[k, cut:] = parents[k + 1, cut:]
            children[k + 1, cut:] = parents[k, cut:]
    if mutation == "per_bit":
        flip = rng.random(children.shape) < GA_MUTATION_PROB
        children ^= flip.astype(np.int8)
    else:
        who = np.nonzero(rng.random(population) < GA_MUTATION_PROB)[0]
        bit = rng.integers(0, nb, size=len(who))
        children[who, bit] ^= 1
    children[int(rng.integers(0, population))] = best_bits
    return children


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
    fitness_history: FloatArray
    runs: int
    run_check_rms_m: tuple[float, ...]
    T_coarse: Pose
    T_fine: Pose
    bits: int
    mutation: str
    fine_001_rmse_m: float
    fine_001_iterations: int


def genetic_stage(problem: CoarseProblem, exact: NearestSurface, index: Any, mesh: Any, rng: np.random.Generator,
                  *, sigma: float | None, sig_eff: float | None, outlier_cfg: OutlierConfig,
                  settings: GASettings) -> tuple[Pose, GeneticDiagnostics, dict[str, float]]:
    """Document 001's coarse (GA, with restarts) and fine (``fine_001``) stages.

    Args:
        problem: the coarse field and points (``problem.delta2`` unused).
        exact: the exact oracle; index: the model's mesh index; mesh: the model.
        rng: random generator.
        sigma: the given noise sigma [m] (or None); sig_eff: the effective sigma (or None:
            unknown, one run).
        outlier_cfg: the checked outlier rule of the fine stage.
        settings: the GA's settings.

    Returns:
        (the fine stage's pose (4, 4), diagnostics, timings [s]).
    """
    t = time.perf_counter()
    runs = _runs_with_restarts(problem, exact, mesh, rng, sig_eff, settings)
    best = min(runs, key=lambda run: run.check_rms_m)
    timings = {"ga_s": time.perf_counter() - t}
    t = time.perf_counter()
    # document 001's fine stage works on a few probe points (m >= 6): the coarse subset.
    # FINE_001_D stops it at steps below about 1e-8 rad / 1e-8 m; the polish converges
    # quadratically from there
    fine = localize_checked(problem.y, index, "fine_001", best.T, sigma=sigma, outlier_cfg=outlier_cfg,
                            tolerance=FINE_001_D, max_iterations=FINE_001_MAX_ITERATIONS)
    timings["fine_001_s"] = time.perf_counter() - t
    T_after = fine.T_world_workpiece
    diag = GeneticDiagnostics(
        best_fitness=best.fitness,
        generations=best.generations,
        fitness_history=best.history,
        runs=len(runs),
        run_check_rms_m=tuple(run.check_rms_m for run in runs),
        T_coarse=best.T,
        T_fine=T_after @ inv_pose(best.T),
        bits=int(settings.bits),
        mutation=settings.mutation,
        fine_001_rmse_m=fine.rmse_m,
        fine_001_iterations=fine.iterations,
    )
    return T_after, diag, timings


def _runs_with_restarts(problem: CoarseProblem, exact: NearestSurface, mesh: Any, rng: np.random.Generator,
                        sig_eff: float | None, settings: GASettings) -> list[_GARun]:
    """GA runs until one passes Algorithm 5's acceptance (a short exact descent from its pose
    leaves an RMS residual within NOISE_ACCEPT_FACTOR sigma_eff; a larger one means a wrong
    basin), at most ``settings.restarts``; one run when sigma_eff is unknown."""
    half_size = 0.5 * np.ptp(np.asarray(mesh.vertices, dtype=np.float64), axis=0)
    runs: list[_GARun] = []
    for _ in range(int(settings.restarts)):
        run = genetic(problem.field, problem.y, problem.c_model, half_size, rng, settings)
        chk = descend(exact, problem.y, run.T[None], L=problem.L, delta1=1e-9, delta2=np.inf, delta3=1e-9,
                      max_iter_per_descent=RUN_CHECK_ITERATIONS, rng=None)
        rms_chk = math.sqrt(float(chk.eps[0]) / len(problem.y))
        runs.append(_GARun(run.T, run.fitness, run.generations, run.history, rms_chk))
        if sig_eff is None or rms_chk <= NOISE_ACCEPT_FACTOR * sig_eff:
            break
    return runs
