"""Global localization (document 000 Algorithm 5, document 001 GA, document 003 PSO)."""

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

import algorithms.registration.global_search as gs
from algorithms.errors import AlgorithmError
from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.se3 import inv_pose, transform_points
from algorithms.registration import RegistrationResult, Status, local, localize
from algorithms.registration.global_search import global_localize, orientation_table
from tests.helpers import assert_pose_close
from tests.tolerances import (
    EQUAL_FIT_M,
    EXACT_FIT_M,
    GLOBAL_CLOSE_M,
    GLOBAL_CLOSE_RAD,
    GLOBAL_NOISY_M,
    GLOBAL_NOISY_RAD,
    ORTHONORMAL_TOL,
    RECOVER_M,
    RECOVER_RAD,
)


def _block(nx=31, ny=21, lx=0.12, ly=0.08, h=0.025):
    """A closed block whose top is a non-symmetric height field (no rigid self-symmetry)."""

    def top(x, y):
        return (
            h
            + 0.006 * np.sin(2 * np.pi * x / 0.1 + 0.3)
            + 0.004 * np.cos(2 * np.pi * y / 0.07)
            + 0.08 * x * (y + 0.01)
            + 0.05 * x
        )

    xs = np.linspace(-lx / 2, lx / 2, nx)
    ys = np.linspace(-ly / 2, ly / 2, ny)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    topv = np.stack([X, Y, top(X, Y)], -1).reshape(-1, 3)
    botv = np.stack([X, Y, np.zeros_like(X)], -1).reshape(-1, 3)
    V = np.vstack([topv, botv])
    off = nx * ny

    def idx(i, j):
        return i * ny + j

    F = []
    for i in range(nx - 1):
        for j in range(ny - 1):
            a, b, c, d = idx(i, j), idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1)
            F += [[a, b, c], [a, c, d], [a + off, c + off, b + off], [a + off, d + off, c + off]]

    def side(seq):
        for k in range(len(seq) - 1):
            p, q = seq[k], seq[k + 1]
            F.extend([[p, q + off, q], [p, p + off, q + off]])

    side([idx(i, 0) for i in range(nx)])
    side([idx(nx - 1, j) for j in range(ny)])
    side([idx(i, ny - 1) for i in range(nx - 1, -1, -1)])
    side([idx(0, j) for j in range(ny - 1, -1, -1)])
    m = trimesh.Trimesh(V, np.array(F), process=True)
    m.fix_normals()
    return m


def _scan(mesh, n, keep, seed):
    """n points on the faces selected by keep(points, normals)."""
    pts, fi = trimesh.sample.sample_surface(mesh, 60 * n, seed=seed)
    sel = keep(pts, mesh.face_normals[fi])
    pts = pts[sel]
    rng = np.random.default_rng(seed)
    return pts[rng.choice(len(pts), n, replace=False)]


def _top_and_two_sides(p, n):
    return (n[:, 2] > 0.3) | (n[:, 0] > 0.99) | (n[:, 1] < -0.99)


def _pose(rotvec, t=(0.4, -0.2, 0.1)):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    T[:3, 3] = t
    return T


@pytest.fixture(scope="module")
def part():
    m = _block()
    idx = MeshIndex(m)
    pts = _scan(m, 150, _top_and_two_sides, seed=3)
    return m, idx, pts


# orientations of the true pose: random ones and ~180 degrees about several axes
TRUE_ROTVECS = [
    Rotation.random(random_state=11).as_rotvec(),
    np.array([0.0, 0.0, np.pi * 0.995]),
    np.array([np.pi * 0.99, 0.0, 0.0]) / 1.0,
    Rotation.random(random_state=12).as_rotvec(),
]


def _check_recovered(r, T_true, tol_m=RECOVER_M, tol_rad=RECOVER_RAD):
    assert r.trusted and r.status is Status.OK, r.message
    assert not r.ambiguous and len(r.solutions) == 1
    assert_pose_close(r.T_world_workpiece, T_true, tol_m, tol_rad, what=r.message)
    R = r.T_world_workpiece[:3, :3]
    assert np.allclose(R.T @ R, np.eye(3), atol=ORTHONORMAL_TOL) and np.linalg.det(R) > 0


# ------------------------------------------------------------------ document constants
def test_document_constants():
    # document 001, section 6: Pc 0.9, Pm 0.1, 100 individuals, 100 generations, fitness 0.95
    assert gs.GA_CROSSOVER_PROB == 0.9
    assert gs.GA_MUTATION_PROB == 0.1
    assert gs.GA_POPULATION == 100
    assert gs.GA_GENERATIONS == 100
    assert gs.GA_FITNESS_STOP == 0.95
    # document 003, claim 4.1-4.2
    assert gs.PSO_PARTICLES == 40
    assert gs.PSO_ITERATIONS == 100
    assert (gs.PSO_W_MAX, gs.PSO_W_MIN) == (0.9, 0.4)
    assert (gs.PSO_C1_INITIAL, gs.PSO_C1_FINAL) == (2.5, 0.5)
    assert (gs.PSO_C2_INITIAL, gs.PSO_C2_FINAL) == (0.5, 2.5)
    # document 000, section 8
    assert sorted(gs.LIU2001_START_ANGLES_DEG) == [-150, -90, -30, 30, 90, 150]
    assert gs.CONVERGENCE_RADIUS_DEG == 45.0


def test_orientation_tables():
    liu = orientation_table("liu2001")
    ico = orientation_table("icosahedral")
    assert liu.shape == (36, 3, 3) and ico.shape == (60, 3, 3)
    for R in (liu, ico):
        assert np.allclose(np.einsum("kji,kjl->kil", R, R), np.eye(3), atol=ORTHONORMAL_TOL)
        assert np.allclose(np.linalg.det(R), 1.0)
    # the icosahedral table covers SO(3) within the document's 45 degree convergence radius;
    # the printed 36-start table does not
    q = Rotation.random(3000, random_state=0)

    def gap(table):
        best = np.full(len(q), np.inf)
        for R in table:
            best = np.minimum(best, (Rotation.from_matrix(R).inv() * q).magnitude())
        return np.degrees(best.max())

    assert gap(ico) < 45.0
    assert gap(liu) > 60.0
    with pytest.raises(AlgorithmError):
        orientation_table("cube")
    with pytest.raises(AlgorithmError):
        orientation_table(np.zeros((2, 3, 3)))


# ------------------------------------------------------------------ recovery, noise-free
@pytest.mark.parametrize("k", range(len(TRUE_ROTVECS)))
def test_multistart_recovers_any_orientation(part, k):
    m, idx, pts = part
    T = _pose(TRUE_ROTVECS[k])
    y = pts @ T[:3, :3].T + T[:3, 3]
    r = global_localize(y, m, "multistart", index=idx, noise_sigma_m=0.0, rng=np.random.default_rng(k))
    assert isinstance(r, RegistrationResult)
    _check_recovered(r, T)
    assert r.message.startswith("ok")
    assert r.diagnostics.n_starts == 60


@pytest.mark.parametrize("k", [1, 3])
def test_genetic_recovers_any_orientation(part, k):
    m, idx, pts = part
    T = _pose(TRUE_ROTVECS[k])
    y = pts @ T[:3, :3].T + T[:3, 3]
    r = global_localize(y, m, "genetic", index=idx, noise_sigma_m=0.0, rng=np.random.default_rng(k))
    _check_recovered(r, T)
    # T = T_fine @ T_coarse (document 001): the fine stage's result composes back
    ga = r.diagnostics.genetic
    assert r.diagnostics.pso is None
    assert_pose_close(ga.T_fine @ ga.T_coarse, T, RECOVER_M, RECOVER_RAD)
    # the fitness is 1 / (1 + sum D [mm]) over the points: far below the 0.95 stop
    assert 0 < ga.best_fitness < gs.GA_FITNESS_STOP
    assert ga.generations == gs.GA_GENERATIONS


@pytest.mark.parametrize("k", [0, 2])
def test_pso_recovers_any_orientation(part, k):
    m, idx, pts = part
    T = _pose(TRUE_ROTVECS[k])
    y = pts @ T[:3, :3].T + T[:3, 3]
    r = global_localize(y, m, "pso", index=idx, noise_sigma_m=0.0, rng=np.random.default_rng(k))
    _check_recovered(r, T)
    # the swarm alone improves on its pre-registration; the polish takes it to 1e-6
    pso = r.diagnostics.pso
    h = pso.fitness_history
    assert len(h) == gs.PSO_ITERATIONS + 1 and h[-1] <= h[0]
    assert_pose_close(pso.T_pso, T, GLOBAL_CLOSE_M, GLOBAL_CLOSE_RAD)


def test_multistart_with_noise(part):
    m, idx, pts = part
    rng = np.random.default_rng(5)
    T = _pose(TRUE_ROTVECS[1])
    y = pts @ T[:3, :3].T + T[:3, 3] + rng.normal(0.0, 20e-6, pts.shape)
    r = global_localize(y, m, "multistart", index=idx, noise_sigma_m=20e-6, rng=rng)
    _check_recovered(r, T, GLOBAL_NOISY_M, GLOBAL_NOISY_RAD)
    # wrong noise level: the residual check refuses the pose instead of claiming success
    bad = global_localize(y, m, "multistart", index=idx, noise_sigma_m=2e-6, rng=np.random.default_rng(5))
    assert not bad.trusted and bad.status is Status.POOR_FIT and bad.message.startswith("poor fit")


def test_a_polish_that_did_not_converge_is_not_a_success(part, monkeypatch):
    m, idx, pts = part
    rng = np.random.default_rng(5)
    T = _pose(TRUE_ROTVECS[1])
    y = pts @ T[:3, :3].T + T[:3, 3] + rng.normal(0.0, 20e-6, pts.shape)
    monkeypatch.setitem(local.MAX_ITERATIONS, "hong_tan", 1)  # the polish stops after one update
    r = global_localize(y, m, "multistart", index=idx, noise_sigma_m=20e-6, rng=rng)
    assert not r.converged and not r.trusted and r.status is Status.NOT_CONVERGED
    assert r.message.startswith("polish not converged: reached max_iterations = 1")


def test_same_seed_same_result(part):
    m, idx, pts = part
    T = _pose(TRUE_ROTVECS[0])
    y = pts @ T[:3, :3].T + T[:3, 3]
    for method in ("multistart", "genetic"):
        a = global_localize(y, m, method, index=idx, noise_sigma_m=0.0, rng=np.random.default_rng(7), ga_restarts=1)
        b = global_localize(y, m, method, index=idx, noise_sigma_m=0.0, rng=np.random.default_rng(7), ga_restarts=1)
        assert np.array_equal(a.T_world_workpiece, b.T_world_workpiece)
        assert a.diagnostics.perturbations == b.diagnostics.perturbations
        if method == "genetic":
            assert np.array_equal(a.diagnostics.genetic.T_coarse, b.diagnostics.genetic.T_coarse)
            assert np.array_equal(a.diagnostics.genetic.fitness_history, b.diagnostics.genetic.fitness_history)


# ------------------------------------------------------------------ symmetric parts
def test_box_is_ambiguous_not_a_success():
    box = trimesh.creation.box(extents=(0.10, 0.06, 0.04))
    pts = _scan(box, 150, lambda p, n: np.ones(len(p), bool), seed=1)
    T = _pose(Rotation.random(random_state=4).as_rotvec())
    y = pts @ T[:3, :3].T + T[:3, 3]
    idx = MeshIndex(box)
    for method in ("multistart", "pso", "genetic"):
        r = global_localize(y, box, method, index=idx, noise_sigma_m=0.0, rng=np.random.default_rng(0),
                            ga_restarts=2)
        assert not r.trusted, (method, r.message)
        if r.status is Status.AMBIGUOUS:
            assert r.ambiguous and r.message.startswith("ambiguous")
            # the box's four symmetries: every equally good pose is listed, each fits as well
            assert len(r.solutions) == 4 and np.array_equal(r.solutions[0], r.T_world_workpiece)
            for Te in r.solutions:
                x = (y - Te[:3, 3]) @ Te[:3, :3]
                assert np.sqrt(np.mean(idx.query(x).distance ** 2)) < EQUAL_FIT_M
    # the multistart finds the box's symmetric poses
    r = global_localize(y, box, "multistart", index=idx, noise_sigma_m=0.0)
    assert r.ambiguous and r.status is Status.AMBIGUOUS and len(r.solutions) == 4


def test_cylinder_is_not_a_confident_success():
    cyl = trimesh.creation.cylinder(radius=0.03, height=0.08, sections=128)
    pts = _scan(cyl, 150, lambda p, n: np.ones(len(p), bool), seed=2)
    T = _pose(Rotation.random(random_state=6).as_rotvec())
    y = pts @ T[:3, :3].T + T[:3, 3]
    r = global_localize(y, cyl, "multistart", noise_sigma_m=0.0)
    assert not r.trusted
    assert r.status in (Status.AMBIGUOUS, Status.UNOBSERVABLE)


def test_outliers_are_rejected_and_verification_uses_the_inliers(part):
    m, idx, pts = part
    rng = np.random.default_rng(9)
    T = _pose(TRUE_ROTVECS[3])
    y = pts @ T[:3, :3].T + T[:3, 3] + rng.normal(0.0, 20e-6, pts.shape)
    # 10 % gross outliers: returns 5-20 mm off the part; and a row the sensor saw nothing on
    bad = rng.choice(len(y), 15, replace=False)
    y[bad] += rng.normal(size=(15, 3)) * rng.uniform(5e-3, 2e-2, (15, 1))
    y = np.vstack([y, np.full((1, 3), np.nan)])
    r = global_localize(y, m, index=idx, noise_sigma_m=20e-6, rng=np.random.default_rng(1))
    _check_recovered(r, T, GLOBAL_NOISY_M, GLOBAL_NOISY_RAD)
    assert r.n_dropped_nonfinite == 1 and not r.inliers[-1]
    # the displaced points that did leave the surface (by more than a millimetre) are outliers
    far = bad[idx.query(transform_points(inv_pose(T), y[bad])).distance > 1e-3]
    assert len(far) >= 10 and not r.inliers[far].any()
    assert r.diagnostics.n_verify == len(pts) - r.n_outliers  # the verification used the inliers
    # keeping every point, the outliers spoil the residual: no confident pose
    kept = global_localize(y, m, index=idx, noise_sigma_m=20e-6, rng=np.random.default_rng(1), outlier=None)
    assert kept.status is Status.POOR_FIT


# ------------------------------------------------------------------ inputs
def test_input_errors(part):
    m, idx, pts = part
    with pytest.raises(AlgorithmError, match="method"):
        global_localize(pts, m, "annealing")
    with pytest.raises(AlgorithmError, match=r"\(N, 3\)"):
        global_localize(pts[:4], m)
    with pytest.raises(AlgorithmError, match="rng"):
        global_localize(pts, m, rng=42)
    with pytest.raises(AlgorithmError, match="noise_sigma_m"):
        global_localize(pts, m, noise_sigma_m=-1.0)
    with pytest.raises(AlgorithmError, match=r"at least 6 finite"):
        global_localize(np.full((10, 3), np.nan), m)
    with pytest.raises(AlgorithmError, match="units look wrong"):
        global_localize(pts * 1000.0, m)
    with pytest.raises(AlgorithmError, match="outlier"):
        global_localize(pts, m, outlier="huber")
    with pytest.raises(AlgorithmError, match="polish"):
        global_localize(pts, m, polish="gicp")
    with pytest.raises(AlgorithmError, match="mesh"):
        global_localize(pts)


# ------------------------------------------------------------------ options and integration
def test_printed_start_table_and_stop_at_first(part):
    m, idx, pts = part
    T = _pose(TRUE_ROTVECS[0])
    y = pts @ T[:3, :3].T + T[:3, 3]
    r = global_localize(y, m, index=idx, noise_sigma_m=0.0, start_table="liu2001", stop_at_first=True)
    assert r.diagnostics.n_starts == 36
    assert r.diagnostics.starts_accepted >= 1
    _check_recovered(r, T)


def test_result_type_and_the_local_method_from_its_pose(part):
    m, idx, pts = part
    T = _pose(TRUE_ROTVECS[2])
    y = pts @ T[:3, :3].T + T[:3, 3]
    r = global_localize(y, m, index=idx, noise_sigma_m=0.0)
    assert isinstance(r, gs.GlobalLocalizationResult) and isinstance(r, RegistrationResult)
    assert r.method == "multistart" and r.rmse_m < EXACT_FIT_M
    assert r.diagnostics.polish == "hong_tan" and r.diagnostics.polish_status is Status.OK
    assert r.covariance.shape == (6, 6) and r.free_dofs == 0
    # an unknown pose goes through the global search; the local method refines from its pose
    local = localize(y, m, init=r.T_world_workpiece, index=idx)
    assert_pose_close(local.T_world_workpiece, T, RECOVER_M, RECOVER_RAD)
    with pytest.raises(AlgorithmError, match="global_localize"):
        localize(y, m, init="global", index=idx)
