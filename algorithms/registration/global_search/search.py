"""Global workpiece localization: a pose from any initial orientation.

Three methods from the source documents, one entry point :func:`global_localize`:

* ``"multistart"``: document 000's Algorithm 5 (:mod:`.multistart`);
* ``"genetic"``: document 001's genetic coarse stage and its fine stage (:mod:`.genetic`),
  with a coarse multistart phase for verification;
* ``"pso"``: document 003's particle swarm (:mod:`.pso`) after the multistart's coarse phase
  as pre-registration.

The steps of a call: the points are checked once (non-finite rows dropped and counted, units),
a coarse subset (farthest-point sampling, ``n_coarse``) and a verification subset (random,
``n_verify``) are drawn; the method's search runs on the coarse nearest-surface field
(:mod:`.fields`); its result and the best distinct coarse minima are refined with exact
closest points; the best is polished with the library's local method
(:func:`algorithms.registration.local.localize`, with the robust outlier rule of
:mod:`algorithms.registration.robust`) on every point; then the hypotheses are verified
(:mod:`.verify`): the residual must match the noise, no distinct pose may fit better, and
every equally good pose (a symmetric part) is listed in ``solutions``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from algorithms.arraytypes import ArrayLike, FloatArray, IntArray, Pose
from algorithms.errors import AlgorithmError
from algorithms.geometry.se3 import as_pose
from algorithms.registration.global_search.fields import CoarseField, ExactOracle, coarse_field
from algorithms.registration.global_search.genetic import (
    GA_BITS,
    GA_GENERATIONS,
    GA_POPULATION,
    GASettings,
    GeneticDiagnostics,
    genetic_stage,
)
from algorithms.registration.global_search.multistart import (
    FIELD_FLOOR_FACTOR,
    NOISE_ACCEPT_FACTOR,
    CoarseProblem,
    MultistartOutcome,
    StartTable,
    farthest_point_subset,
    model_centroid,
    multistart_stage,
    orientation_table,
)
from algorithms.registration.global_search.pso import (
    PSO_ITERATIONS,
    PSO_PARTICLES,
    PSODiagnostics,
    PSOSettings,
    pso_stage,
)
from algorithms.registration.global_search.verify import Verdict, refine, refine_candidates, symmetries_of, verify
from algorithms.registration.inputs import check_units, finite_rows, mesh_index
from algorithms.registration.local import METHODS, localize_checked
from algorithms.registration.rejected import LOAD_BEARING_INFORMATION, rejected_information
from algorithms.registration.result import RegistrationResult, Status
from algorithms.registration.robust import OutlierConfig, outlier_config

__all__ = [
    "pso_refine",
    "DEFAULT_MODEL_ERROR_M",
    "DEFAULT_POLISH",
    "GLOBAL_METHODS",
    "GlobalDiagnostics",
    "GlobalLocalizationResult",
    "global_localize",
]

GLOBAL_METHODS = ("multistart", "genetic", "pso")
#: Default allowance for model (tessellation) error when checking residuals [m].
DEFAULT_MODEL_ERROR_M = 1e-6
#: The local method used to polish (document 000 finds Hong-Tan best).
DEFAULT_POLISH = "hong_tan"


@dataclass(frozen=True, kw_only=True, eq=False)
class GlobalDiagnostics:
    """What a global search did.

    Attributes:
        method: the global method.
        polish: the local method of the polish (None: none).
        polish_status, polish_message: the polish's own verdict.
        field_cell_m: the coarse field's cell size [m].
        n_starts: multistart starts run (both rounds).
        second_round: whether the offset start table was run too.
        starts_accepted: starts that passed all of Algorithm 5's tests.
        coarse_iterations: pose updates of the coarse phase, all starts together.
        perturbations: Algorithm 5's perturbations, all starts together.
        sigma_eff_m: effective noise sigma of the tests [m] (estimated when not given).
        sigma_known: whether ``noise_sigma_m`` was given.
        rms_verify_m: the result's RMS residual on the verification points [m].
        n_verify: verification points used (inliers of the polish).
        n_coarse: points of the coarse phases.
        timings_s: wall time per stage [s].
        genetic: the genetic stage's diagnostics (``method="genetic"``), else None.
        pso: the swarm's diagnostics (``method="pso"``), else None.
    """

    method: str
    polish: str | None
    polish_status: Status
    polish_message: str
    field_cell_m: float
    n_starts: int
    second_round: bool
    starts_accepted: int
    coarse_iterations: int
    perturbations: int
    sigma_eff_m: float
    sigma_known: bool
    rms_verify_m: float
    n_verify: int
    n_coarse: int
    timings_s: dict[str, float]
    genetic: GeneticDiagnostics | None = None
    pso: PSODiagnostics | None = None

    @property
    def selection(self) -> str:
        """How the answer was chosen, in words. Algorithm 5's tests on the coarse points decide
        only how long the starts run; the best candidates are refined on the verification
        points and the best of them polished and verified, so a search can be solved with no
        start accepted on the coarse points."""
        if self.n_starts == 0:
            passed = f"the {self.method} search gave its candidates"
        elif self.starts_accepted:
            passed = f"{self.starts_accepted} of {self.n_starts} starts passed Algorithm 5's tests on the coarse points"
        else:
            passed = (f"no start of {self.n_starts} passed Algorithm 5's tests on the coarse points (their sigma is "
                      "estimated from the coarse fit)")
        return (f"{passed}; the best candidates were refined on {self.n_verify} verification points, the best "
                "of them polished and verified")


@dataclass(frozen=True, kw_only=True, eq=False)
class GlobalLocalizationResult(RegistrationResult):
    """:class:`algorithms.registration.result.RegistrationResult` of a global search, plus:

    Attributes:
        candidates: ``(T_world_workpiece, rms_m)`` of the distinct minima (refined with exact
            closest points on the verification points) and of the model's symmetric poses,
            the result first.
        diagnostics: :class:`GlobalDiagnostics`.

    ``method`` is the global method's name; ``status`` is OK, AMBIGUOUS (``solutions`` lists
    every equally good pose), UNOBSERVABLE, POOR_FIT or FAILED; ``iterations``, ``converged``,
    ``history``, the covariance and the directions are those of the final polish.
    """

    candidates: tuple[tuple[Pose, float], ...] = ()
    diagnostics: GlobalDiagnostics

    @property
    def ambiguous(self) -> bool:
        """Several distinct poses fit equally well (``solutions``)."""
        return self.status is Status.AMBIGUOUS


@dataclass(frozen=True)
class _Options:
    """The checked options of a call."""

    method: str
    polish: str | None
    outlier_cfg: OutlierConfig
    model_error_m: float
    start_table: StartTable
    stop_at_first: bool
    n_coarse: int
    n_verify: int
    max_candidates: int
    ga: GASettings
    pso: PSOSettings


@dataclass(frozen=True)
class _Model:
    """The CAD model and its nearest-surface oracles."""

    index: Any  # MeshIndex
    mesh: Any  # trimesh.Trimesh, workpiece frame [m]
    extent: float  # [m]
    c_model: FloatArray  # (3,) [m] area centroid, workpiece frame
    field: CoarseField
    exact: ExactOracle


@dataclass(frozen=True)
class _Points:
    """The measured points and their subsets (world frame, metres)."""

    P: FloatArray  # (N_in, 3) the rows as given
    rows: IntArray  # indices of the finite rows
    y: FloatArray  # (N, 3) the finite points
    y_c: FloatArray  # (n_coarse, 3) farthest-point subset of the coarse phases
    idx_v: IntArray  # indices into y of the verification subset
    y_v: FloatArray  # (n_verify, 3) the verification subset
    L: float  # characteristic length [m]: RMS distance of y_c from its centroid


@dataclass(frozen=True)
class _Noise:
    """The noise model of the tests."""

    sigma_known: bool  # noise_sigma_m was given
    sigma_local: float | None  # sigma of the local fits (0, exact data, counts as none)
    sig_eff: float | None  # [m] sqrt(sigma^2 + model_error^2); None: estimated in the verification


@dataclass(frozen=True)
class _Search:
    """What the method's search found before the exact refinement."""

    coarse: MultistartOutcome  # Algorithm 5's coarse phase (every method runs it)
    primary: Pose | None  # the genetic or swarm result (None for the multistart)
    genetic: GeneticDiagnostics | None
    pso: PSODiagnostics | None


def global_localize(
    points: ArrayLike,
    mesh: Any = None,
    method: str = "multistart",
    *,
    rng: np.random.Generator | None = None,
    index: Any = None,
    noise_sigma_m: float | None = None,
    model_error_m: float = DEFAULT_MODEL_ERROR_M,
    polish: str | None = DEFAULT_POLISH,
    outlier: OutlierConfig = "mad",
    start_table: StartTable = "icosahedral",
    stop_at_first: bool = False,
    n_coarse: int = 150,
    n_verify: int = 400,
    max_candidates: int = 6,
    ga_bits: int = GA_BITS,
    ga_mutation: str = "per_bit",
    ga_population: int = GA_POPULATION,
    ga_generations: int = GA_GENERATIONS,
    ga_restarts: int = 10,
    pso_particles: int = PSO_PARTICLES,
    pso_iterations: int = PSO_ITERATIONS,
    pso_rotation_range_rad: float = math.radians(5.0),
    pso_translation_range_m: float | None = None,
    pso_fitness: str = "exact",
    variant: str = "ours",
    init: ArrayLike | None = None,
    ga_rotation_range_rad: float | None = None,
) -> GlobalLocalizationResult:
    """Localize a workpiece from any initial pose: document 000's multistart (Algorithm 5),
    document 001's genetic coarse + fine stages, or document 003's particle swarm.

    Args:
        points: (N, 3) [m] measured points, world frame; rows with NaN or infinite coordinates
            are dropped (at least 6 finite rows); outliers are left to the polish's ``outlier``.
        mesh: the CAD model (``trimesh.Trimesh``), workpiece frame [m]; None when ``index`` is given.
        method: ``"multistart"`` | ``"genetic"`` | ``"pso"``.
        rng: random generator (perturbations, GA, PSO, subsets); default ``default_rng(0)``.
        index: a prebuilt :class:`algorithms.geometry.mesh_index.MeshIndex` of ``mesh``.
        noise_sigma_m: noise sigma [m] along the normals (Algorithm 5's ``delta2``, perturbations,
            POOR_FIT check); None: estimated from the best fit (then only ambiguity is tested).
        model_error_m: model error (tessellation, form) [m], added in quadrature to sigma.
        polish: local method of :func:`algorithms.registration.local.localize` applied to the
            best pose with all points (None: no polish; the GA's fine stage still runs).
        outlier: the polish's and the GA fine stage's outlier rule (:mod:`..robust`).
        start_table: multistart start orientations (see :func:`orientation_table`).
        stop_at_first: document 000's literal rule: stop at the first start passing all tests.
        n_coarse: points used in the coarse phases (farthest-point subset).
        n_verify: points used to refine and compare candidate minima (random subset).
        max_candidates: distinct coarse minima refined with exact closest points.
        ga_bits: GA bits per pose coordinate (default: our 10).
        ga_mutation: what the document's Pm applies to: ``"per_bit"`` or ``"per_chromosome"``.
        ga_population: GA population (default: the document's 100).
        ga_generations: GA generations (default: the document's 100).
        ga_restarts: the most GA runs, until one passes Algorithm 5's test (one without a sigma).
        ga_rotation_range_rad: None (every orientation) or each GA Euler angle within this
            range [rad], in (0, pi], of ``init``'s orientation (a (4, 4) nominal pose).
        pso_particles: PSO swarm size (default: the patent's 40).
        pso_iterations: PSO iterations (default: the patent's 100).
        pso_rotation_range_rad: PSO rotation range around the pre-registration (default 5 deg).
        pso_translation_range_m: PSO translation range (default 2 % of the model's size).
        pso_fitness: ``"exact"`` (patent: nearest model points) or ``"field"`` (coarse field).
        variant: ``"ours"`` or ``"printed"``: Algorithm 5's start table and stop as printed
            (sets ``start_table="liu2001"``, ``stop_at_first=True``: leave both out); multistart only.

    Returns:
        GlobalLocalizationResult: ``status`` OK, AMBIGUOUS (``solutions``: every equally good
        pose), UNOBSERVABLE, POOR_FIT, NOT_CONVERGED (the polish) or FAILED.

    Raises:
        AlgorithmError: bad points, units, options or an unknown method.
    """
    t0 = time.perf_counter()
    if method not in GLOBAL_METHODS:
        raise AlgorithmError(f"method must be one of {', '.join(GLOBAL_METHODS)}; got {method!r}")
    start_table, stop_at_first = _variant_starts(variant, method, start_table, stop_at_first)
    P, rows = finite_rows(points)
    rng = _checked_rng(rng)
    index = mesh_index(mesh, index)
    opts = _checked_options(
        method, noise_sigma_m, model_error_m, polish, outlier, start_table, stop_at_first, n_coarse, n_verify,
        max_candidates, GASettings(ga_bits, ga_mutation, ga_population, ga_generations, ga_restarts,
                                   *_ga_constraint(method, ga_rotation_range_rad, init)),
        PSOSettings(pso_rotation_range_rad, pso_translation_range_m, pso_particles, pso_iterations, pso_fitness))
    R0, y = orientation_table(start_table), P[rows]
    check_units(y, index)
    model = _model(index, index.mesh if mesh is None else mesh)
    pts = _subsets(P, rows, y, opts, rng, model.extent)
    noise = _noise(noise_sigma_m, model_error_m)
    timings: dict[str, float] = {}
    search, res, T_final, verdict = _search_and_polish(opts, model, pts, noise, R0, rng, timings, t0)
    status, message, reason = _final_status(opts, res, verdict, _first_start_unconfirmed(res, T_final, y, rows, index)
                                            if opts.stop_at_first else None)
    base = {f.name: getattr(res, f.name) for f in fields(RegistrationResult)}
    base.update(T_world_workpiece=T_final, method=method, status=status, message=message,
                solutions=verdict.solutions, time_s=time.perf_counter() - t0,
                poor_fit_reason=reason)
    return GlobalLocalizationResult(**base, candidates=verdict.candidates,
                                    diagnostics=_diagnostics(opts, model, pts, noise, search, res, verdict, timings))


@contextmanager
def _stopwatch(timings: dict[str, float], key: str) -> Iterator[None]:
    """``timings[key]``: the wall time of the block [s]."""
    t = time.perf_counter()
    yield
    timings[key] = time.perf_counter() - t


def _checked_rng(rng: np.random.Generator | None) -> np.random.Generator:
    if rng is None:
        return np.random.default_rng(0)
    if not isinstance(rng, np.random.Generator):
        raise AlgorithmError(f"rng must be a numpy.random.Generator or None, got {type(rng).__name__}")
    return rng


def _ga_constraint(method: str, range_rad: float | None, init: ArrayLike | None) -> tuple[float | None, Any]:
    """The GA's (rotation range [rad], centre orientation (3, 3)), or (None, None): every orientation."""
    if range_rad is None:
        return None, None
    if method != "genetic":
        raise AlgorithmError(f"ga_rotation_range_rad constrains the genetic search; method {method!r} has none")
    if not (np.isfinite(range_rad) and 0.0 < range_rad <= math.pi):
        raise AlgorithmError(f"ga_rotation_range_rad must be in (0, pi], got {range_rad}")
    if init is None:
        raise AlgorithmError("ga_rotation_range_rad needs init: the nominal pose whose orientation the range is about")
    return float(range_rad), as_pose(init, name="init")[:3, :3]


def _variant_starts(variant: str, method: str, start_table: StartTable,
                    stop_at_first: bool) -> tuple[StartTable, bool]:
    """The start table and stopping rule of ``variant`` (see :func:`global_localize`)."""
    if variant == "ours":
        return start_table, stop_at_first
    if variant != "printed":
        raise AlgorithmError(f"variant must be 'ours' or 'printed', got {variant!r}")
    if method != "multistart":
        raise AlgorithmError(f"variant='printed' is Algorithm 5's multistart as printed; method {method!r} has none")
    if not (isinstance(start_table, str) and start_table == "icosahedral") or stop_at_first:
        raise AlgorithmError("variant='printed' sets start_table='liu2001' and stop_at_first=True: leave both out")
    return "liu2001", True


def _checked_options(method: str, noise_sigma_m: float | None, model_error_m: float, polish: str | None,
                     outlier: OutlierConfig, start_table: StartTable, stop_at_first: bool, n_coarse: int,
                     n_verify: int, max_candidates: int, ga: GASettings, pso: PSOSettings) -> _Options:
    """Refuse bad options (in this order), with what is allowed."""
    if noise_sigma_m is not None and not (np.isfinite(noise_sigma_m) and noise_sigma_m >= 0):
        raise AlgorithmError(f"noise_sigma_m must be a length >= 0 [m] or None, got {noise_sigma_m}")
    if not (np.isfinite(model_error_m) and model_error_m >= 0):
        raise AlgorithmError(f"model_error_m must be a length >= 0 [m], got {model_error_m}")
    if polish is not None and polish not in METHODS:
        raise AlgorithmError(f"polish must be one of {', '.join(METHODS)} or None; got {polish!r}")
    outlier_cfg = outlier_config(outlier)
    if ga.mutation not in ("per_bit", "per_chromosome"):
        raise AlgorithmError(f"ga_mutation must be 'per_bit' or 'per_chromosome', got {ga.mutation!r}")
    if pso.fitness not in ("exact", "field"):
        raise AlgorithmError(f"pso_fitness must be 'exact' or 'field', got {pso.fitness!r}")
    for name, v, lo in (
        ("n_coarse", n_coarse, 6),
        ("n_verify", n_verify, 6),
        ("max_candidates", max_candidates, 1),
        ("ga_bits", ga.bits, 2),
        ("ga_population", ga.population, 2),
        ("ga_generations", ga.generations, 1),
        ("ga_restarts", ga.restarts, 1),
        ("pso_particles", pso.particles, 1),
        ("pso_iterations", pso.iterations, 1),
    ):
        if int(v) < lo:
            raise AlgorithmError(f"{name} must be >= {lo}, got {v}")
    return _Options(method, polish, outlier_cfg, model_error_m, start_table, stop_at_first, int(n_coarse),
                    int(n_verify), int(max_candidates), ga, pso)


def _model(index: Any, mesh: Any) -> _Model:
    """The model's size, area centroid, coarse field (cached per mesh) and exact oracle."""
    extent = float(index.extent)
    c_model = model_centroid(mesh)
    return _Model(index, mesh, extent, c_model, coarse_field(mesh), ExactOracle(index))


def _subsets(P: FloatArray, rows: IntArray, y: FloatArray, opts: _Options, rng: np.random.Generator,
             extent: float) -> _Points:
    """The coarse subset (farthest points), the verification subset (random, drawn from
    ``rng``) and the characteristic length L [m] (the model's size for a degenerate subset)."""
    y_c = y[farthest_point_subset(y, opts.n_coarse)]
    if len(y) > opts.n_verify:
        idx_v = np.sort(rng.choice(len(y), size=opts.n_verify, replace=False))
    else:
        idx_v = np.arange(len(y))
    dc = y_c - y_c.mean(axis=0)
    L = float(np.sqrt(np.mean(np.einsum("ij,ij->i", dc, dc)))) or extent
    return _Points(P, rows, y, y_c, idx_v, y[idx_v], L)


def _noise(noise_sigma_m: float | None, model_error_m: float) -> _Noise:
    if noise_sigma_m is None:
        return _Noise(False, None, None)
    return _Noise(True, noise_sigma_m or None, math.hypot(float(noise_sigma_m), model_error_m))


def _coarse_problem(model: _Model, pts: _Points, noise: _Noise) -> CoarseProblem:
    """Algorithm 5's delta2 on the coarse field: the field's own error is heavy-tailed (exact
    for most points, up to a few cells near edges), so the noise allowance is widened by
    FIELD_FLOOR_FACTOR times the field's RMS floor; unknown noise: no delta2 (inf)."""
    delta2 = np.inf
    if noise.sig_eff is not None:
        delta2 = len(pts.y_c) * (NOISE_ACCEPT_FACTOR * noise.sig_eff + FIELD_FLOOR_FACTOR * model.field.floor_rms) ** 2
    return CoarseProblem(model.field, pts.y_c, model.c_model, pts.L, delta2)


def _search(opts: _Options, model: _Model, pts: _Points, noise: _Noise, R0: FloatArray, rng: np.random.Generator,
            timings: dict[str, float]) -> _Search:
    """Algorithm 5's coarse phase, then the genetic or swarm stage when asked (``timings`` [s]
    gets each stage's wall time)."""
    problem = _coarse_problem(model, pts, noise)
    with _stopwatch(timings, "coarse_multistart_s"):
        coarse = multistart_stage(problem, R0, opts.start_table, rng,
                                  stop_at_first=opts.stop_at_first and opts.method == "multistart",
                                  sigma_known=noise.sigma_known)
    if opts.method == "genetic":
        primary, ga_diag, more = genetic_stage(problem, model.exact, model.index, model.mesh, rng,
                                               sigma=noise.sigma_local, sig_eff=noise.sig_eff,
                                               outlier_cfg=opts.outlier_cfg, settings=opts.ga)
        timings.update(more)
        return _Search(coarse, primary, ga_diag, None)
    if opts.method == "pso":
        T_init = coarse.lanes.T[np.argsort(coarse.lanes.eps)[0]]
        oracle = model.exact if opts.pso.fitness == "exact" else model.field
        primary, pso_diag, more = pso_stage(oracle, pts.y_c, T_init, rng, opts.pso, model.extent)
        timings.update(more)
        return _Search(coarse, primary, None, pso_diag)
    return _Search(coarse, None, None, None)


def _polish(opts: _Options, model: _Model, pts: _Points, noise: _Noise, T_best: Pose,
            t0: float) -> tuple[RegistrationResult, Pose]:
    """The local method from ``T_best`` on every point (without ``polish``: one step, for the
    inliers and the directions; the pose stays ``T_best``). Returns (its result, the pose)."""
    res = localize_checked(pts.y, model.index, opts.polish or DEFAULT_POLISH, T_best, sigma=noise.sigma_local,
                           outlier_cfg=opts.outlier_cfg, max_iterations=None if opts.polish is not None else 1,
                           rows=pts.rows, n_input=len(pts.P), t_start=t0)
    return res, res.T_world_workpiece if opts.polish is not None else T_best


def _verify_on_inliers(opts: _Options, model: _Model, pts: _Points, noise: _Noise, res: RegistrationResult,
                       T_final: Pose, refined_T: FloatArray, refined_eps: FloatArray) -> Verdict:
    """:func:`.verify` on the polish's inliers among the verification points (the candidates
    refined again on them when some are outliers)."""
    y_v = pts.y_v
    inlier_v = res.inliers[pts.rows][pts.idx_v]
    if not inlier_v.all():
        y_v = y_v[inlier_v]
        refined_T, refined_eps = refine(model.exact, y_v, refined_T, pts.L)
    return verify(model.index, y_v, T_final, refined_T, refined_eps, extent=model.extent, sig_eff=noise.sig_eff,
                  model_error_m=opts.model_error_m, method=opts.method, observable=res.observable,
                  polish_message=res.message, symmetries=symmetries_of(model.index))


def _diagnostics(opts: _Options, model: _Model, pts: _Points, noise: _Noise, search: _Search,
                 res: RegistrationResult, verdict: Verdict, timings: dict[str, float]) -> GlobalDiagnostics:
    lanes = search.coarse.lanes
    return GlobalDiagnostics(
        method=opts.method,
        polish=opts.polish,
        polish_status=res.status,
        polish_message=res.message,
        field_cell_m=model.field.cell,
        n_starts=search.coarse.n_starts,
        second_round=search.coarse.second_round,
        starts_accepted=int(lanes.accepted.sum()),
        coarse_iterations=int(lanes.iterations.sum()),
        perturbations=int(lanes.perturbations.sum()),
        sigma_eff_m=verdict.sigma_eff_m,
        sigma_known=noise.sigma_known,
        rms_verify_m=verdict.rms_m,
        n_verify=verdict.n_points,
        n_coarse=len(pts.y_c),
        timings_s=timings,
        genetic=search.genetic,
        pso=search.pso,
    )


def _search_and_polish(opts: _Options, model: Any, pts: Any, noise: Any, R0: FloatArray, rng: np.random.Generator,
                       timings: dict[str, float], t0: float) -> tuple[Any, RegistrationResult, Pose, Verdict]:
    """The method's search, its candidates refined, the best polished and verified:
    (the search, the polish's result, the final pose, the verification's verdict)."""
    search = _search(opts, model, pts, noise, R0, rng, timings)
    with _stopwatch(timings, "refine_s"):
        refined_T, refined_eps = refine_candidates(model.exact, pts.y_v, search.primary, search.coarse.lanes,
                                                   model.extent, opts.max_candidates, pts.L)
    with _stopwatch(timings, "polish_s"):
        T_best = search.primary if search.primary is not None else refined_T[int(np.argmin(refined_eps))]
        res, T_final = _polish(opts, model, pts, noise, T_best, t0)
    return search, res, T_final, _verify_on_inliers(opts, model, pts, noise, res, T_final, refined_T, refined_eps)


def _first_start_unconfirmed(res: RegistrationResult, T: Pose, y: FloatArray, rows: np.ndarray,
                             index: Any) -> str | None:
    """A search that stopped at the first start that passed (``stop_at_first``, Algorithm 5 as
    printed) never compared its answer with the other starts': the review's rule for an
    unconfirmed fit (:mod:`algorithms.registration.review`, :mod:`..rejected`) applies. The reason it is a poor fit
    where the points the polish rejected would carry at least ``LOAD_BEARING_INFORMATION`` of the
    kept points' information (workpiece A turned 90 deg about its dome fits all but the few points
    that tell the turns apart), else None."""
    if res.n_outliers == 0:
        return None
    info = rejected_information(y, res.inliers[rows], T, index)
    if info.ratio < LOAD_BEARING_INFORMATION:
        return None
    return (f"the search stopped at the first start that passed (the other starts not run) and its polish rejected "
            f"{info.n_rejected} point(s) that would carry {info.ratio:.2g} x the kept points' information: "
            "unconfirmed")


def _final_status(opts: _Options, res: RegistrationResult, verdict: Verdict,
                  unconfirmed: str | None) -> tuple[Status, str, str | None]:
    """The verification's verdict, overruled by the polish: its fit check sees what a residual
    test against an estimated sigma cannot (POOR_FIT), and a polish that did not converge
    returns a pose not at its minimum (NOT_CONVERGED); an ``ok`` from a search stopped at its
    first start, by ``unconfirmed`` (:func:`_first_start_unconfirmed`). With the poor fit's reason."""
    status, message = verdict.status, verdict.message
    if status not in (Status.OK, Status.AMBIGUOUS, Status.UNOBSERVABLE):
        return status, message, res.poor_fit_reason
    if res.poor_fit_reason is not None:
        return Status.POOR_FIT, f"poor fit: {res.poor_fit_reason}; {verdict.message}", res.poor_fit_reason
    if opts.polish is not None and not res.converged:
        return Status.NOT_CONVERGED, f"polish {res.message}; {verdict.message}", None
    if status == Status.OK and unconfirmed is not None:
        return Status.POOR_FIT, f"poor fit: {unconfirmed}; {message}", unconfirmed
    return status, message, None


def pso_refine(points: ArrayLike, T_init: ArrayLike, *, index: Any = None, mesh: Any = None,
               rng: np.random.Generator | None = None, rotation_range_rad: float = math.radians(5.0),
               translation_range_m: float | None = None, particles: int = PSO_PARTICLES,
               iterations: int = PSO_ITERATIONS) -> tuple[Pose, PSODiagnostics]:
    """Document 003's step 4 alone: the particle swarm from a given pre-registration
    ``T_init`` (workpiece to world), exact nearest model points, no polish.

    Args:
        points: (N, 3) [m] measured points, world frame (all of them are the swarm's points).
        T_init: (4, 4) the pre-registration.
        index / mesh: the CAD model's :class:`MeshIndex` or its mesh.
        rng: the swarm's random generator (default ``np.random.default_rng(0)``).
        rotation_range_rad, translation_range_m: the search ranges around ``T_init`` (default
            5 degrees and 2 % of the model's size, as :func:`global_localize`).
        particles, iterations: the patent's 40 and 100 by default.

    Returns:
        (the swarm's pose ``T_init @ Delta(g_best)`` (4, 4), its diagnostics).
    """
    P, rows = finite_rows(points)
    y = P[rows]
    index = mesh_index(mesh, index)
    check_units(y, index)
    T0 = np.asarray(T_init, dtype=np.float64)
    if T0.shape != (4, 4) or not np.all(np.isfinite(T0)):
        raise AlgorithmError(f"T_init must be a finite (4, 4) pose, got shape {T0.shape}")
    rng = np.random.default_rng(0) if rng is None else rng
    settings = PSOSettings(rotation_range_rad=rotation_range_rad, translation_range_m=translation_range_m,
                           particles=particles, iterations=iterations, fitness="exact")
    T, diag, _ = pso_stage(ExactOracle(index), y, T0, rng, settings, float(index.extent))
    return T, diag
