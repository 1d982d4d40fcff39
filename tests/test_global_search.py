"""Global localization (document 000 Algorithm 5, document 001 GA, document 003 PSO)."""

import math

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from algorithms.registration.global_search import search as gs
from algorithms.geometry.mesh_index import MeshIndex
from algorithms.errors import AlgorithmError
from algorithms.registration.global_search import global_localize, orientation_table
from algorithms.registration.local import LocalizationResult
from algorithms.geometry.se3 import rotation_error_rad, translation_error_m

# Named tolerances (DESIGN.md rule 8).
POSE_TOL_M = 1e-6
POSE_TOL_RAD = 1e-6
NOISY_TOL_M = 5e-5  # 150 points, sigma 20 um: errors of a few um; 50 um is a gross failure
NOISY_TOL_RAD = 1e-3


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


def _check_recovered(r, T_true, tol_m=POSE_TOL_M, tol_rad=POSE_TOL_RAD):
    assert r.success, r.status
    assert not r.ambiguous
    assert rotation_error_rad(r.T_world_workpiece, T_true) < tol_rad
    assert translation_error_m(r.T_world_workpiece, T_true) < tol_m
    R = r.T_world_workpiece[:3, :3]
    assert np.allclose(R.T @ R, np.eye(3), atol=1e-12) and np.linalg.det(R) > 0


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
        assert np.allclose(np.einsum("kji,kjl->kil", R, R), np.eye(3), atol=1e-12)
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
    assert isinstance(r, LocalizationResult)
    _check_recovered(r, T)
    assert r.status.startswith("ok")
    assert r.extra["n_starts"] == 60
    assert len(r.equivalent_poses) == 1


@pytest.mark.parametrize("k", [1, 3])
def test_genetic_recovers_any_orientation(part, k):
    m, idx, pts = part
    T = _pose(TRUE_ROTVECS[k])
    y = pts @ T[:3, :3].T + T[:3, 3]
    r = global_localize(y, m, "genetic", index=idx, noise_sigma_m=0.0, rng=np.random.default_rng(k))
    _check_recovered(r, T)
    # T = T_fine @ T_coarse (document 001): the fine stage's result composes back
    fine = r.extra["T_fine"] @ r.extra["T_coarse"]
    assert rotation_error_rad(fine, T) < POSE_TOL_RAD and translation_error_m(fine, T) < POSE_TOL_M
    # the fitness is 1 / (1 + sum D [mm]) over the points: far below the 0.95 stop
    assert 0 < r.extra["ga_best_fitness"] < gs.GA_FITNESS_STOP
    assert r.extra["ga_generations"] == gs.GA_GENERATIONS


@pytest.mark.parametrize("k", [0, 2])
def test_pso_recovers_any_orientation(part, k):
    m, idx, pts = part
    T = _pose(TRUE_ROTVECS[k])
    y = pts @ T[:3, :3].T + T[:3, 3]
    r = global_localize(y, m, "pso", index=idx, noise_sigma_m=0.0, rng=np.random.default_rng(k))
    _check_recovered(r, T)
    # the swarm alone improves on its pre-registration; the polish takes it to 1e-6
    h = r.extra["pso_fitness_history"]
    assert len(h) == gs.PSO_ITERATIONS + 1 and h[-1] <= h[0]
    pso_only = r.extra["pso_only_T"]
    assert rotation_error_rad(pso_only, T) < math.radians(1.0)
    assert translation_error_m(pso_only, T) < 1e-3


def test_multistart_with_noise(part):
    m, idx, pts = part
    rng = np.random.default_rng(5)
    T = _pose(TRUE_ROTVECS[1])
    y = pts @ T[:3, :3].T + T[:3, 3] + rng.normal(0.0, 20e-6, pts.shape)
    r = global_localize(y, m, "multistart", index=idx, noise_sigma_m=20e-6, rng=rng)
    _check_recovered(r, T, NOISY_TOL_M, NOISY_TOL_RAD)
    # wrong noise level: the residual check refuses the pose instead of claiming success
    bad = global_localize(y, m, "multistart", index=idx, noise_sigma_m=2e-6, rng=np.random.default_rng(5))
    assert not bad.success and bad.status.startswith("failed")


def test_same_seed_same_result(part):
    m, idx, pts = part
    T = _pose(TRUE_ROTVECS[0])
    y = pts @ T[:3, :3].T + T[:3, 3]
    for method in ("multistart", "genetic"):
        a = global_localize(y, m, method, index=idx, noise_sigma_m=0.0, rng=np.random.default_rng(7), ga_restarts=1)
        b = global_localize(y, m, method, index=idx, noise_sigma_m=0.0, rng=np.random.default_rng(7), ga_restarts=1)
        assert np.array_equal(a.T_world_workpiece, b.T_world_workpiece)
        assert a.extra["perturbations"] == b.extra["perturbations"]
        if method == "genetic":
            assert np.array_equal(a.extra["T_coarse"], b.extra["T_coarse"])
            assert np.array_equal(a.extra["ga_fitness_history"], b.extra["ga_fitness_history"])


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
        assert not r.success, (method, r.status)
        if r.status.startswith("ambiguous"):
            assert r.ambiguous and len(r.equivalent_poses) >= 2
            # each equivalent pose fits the points as well as the result
            for Te in r.equivalent_poses:
                x = (y - Te[:3, 3]) @ Te[:3, :3]
                assert np.sqrt(np.mean(idx.query(x).distance ** 2)) < 1e-6
    # the multistart finds the box's symmetric poses
    r = global_localize(y, box, "multistart", index=idx, noise_sigma_m=0.0)
    assert r.ambiguous and r.status.startswith("ambiguous")


def test_cylinder_is_not_a_confident_success():
    cyl = trimesh.creation.cylinder(radius=0.03, height=0.08, sections=128)
    pts = _scan(cyl, 150, lambda p, n: np.ones(len(p), bool), seed=2)
    T = _pose(Rotation.random(random_state=6).as_rotvec())
    y = pts @ T[:3, :3].T + T[:3, 3]
    r = global_localize(y, cyl, "multistart", noise_sigma_m=0.0)
    assert not r.success
    assert r.status.split(":")[0] in ("ambiguous", "unobservable")


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
    bad = pts.copy()
    bad[0, 0] = np.nan
    with pytest.raises(AlgorithmError, match="NaN"):
        global_localize(bad, m)
    with pytest.raises(AlgorithmError, match="mesh"):
        global_localize(pts)


# ------------------------------------------------------------------ options and integration
def test_printed_start_table_and_stop_at_first(part):
    m, idx, pts = part
    T = _pose(TRUE_ROTVECS[0])
    y = pts @ T[:3, :3].T + T[:3, 3]
    r = global_localize(y, m, index=idx, noise_sigma_m=0.0, start_table="liu2001", stop_at_first=True)
    assert r.extra["n_starts"] == 36
    assert r.extra["starts_accepted"] >= 1
    _check_recovered(r, T)


def test_result_type_and_localize_global_init(part):
    from algorithms.registration.local import localize

    m, idx, pts = part
    T = _pose(TRUE_ROTVECS[2])
    y = pts @ T[:3, :3].T + T[:3, 3]
    r = global_localize(y, m, index=idx, noise_sigma_m=0.0)
    assert isinstance(r, gs.GlobalLocalizationResult) and isinstance(r, LocalizationResult)
    assert r.method == "multistart" and r.rmse_m < 1e-9
    local = localize(y, m, init="global", index=idx)
    assert rotation_error_rad(local.T_world_workpiece, T) < POSE_TOL_RAD
    assert translation_error_m(local.T_world_workpiece, T) < POSE_TOL_M
