"""Touch probing: pre-travel model, qualification and compensation, planned probe points."""

import itertools

import numpy as np
import pytest
import trimesh

from algorithms.errors import AlgorithmError
from algorithms.geometry.mesh_index import MeshIndex
from algorithms.probing import (
    REASONS,
    PretravelModel,
    compensate,
    cosine_error_m,
    d_optimal,
    feasible_candidates,
    fit_sphere,
    log_det_information,
    predicted_pose_std,
    qualification_directions,
    qualify_ball,
    random_points,
    sample_candidates,
    spread_points,
)

# Named tolerances of this file.
EXACT_M = 1e-12            # a fit to exact points, a hand-computed length [m]
PRETRAVEL_EXACT_M = 1e-18  # a pre-travel (micrometres) against its closed form [m]
STD_ERRORS = 3.0           # a Monte Carlo mean or standard deviation within this many standard errors
LOGDET_TIE = 1e-9          # log-determinants compared (the exchange's own threshold)
REL = 1e-12                # relative agreement of closed forms

MM = 1e-3


# ----------------------------------------------------------------------------- pre-travel
def _lateral(phi):
    return np.column_stack([np.cos(phi), np.sin(phi), np.zeros_like(phi)])


def test_lateral_pretravel_follows_three_lobes():
    phase = np.deg2rad(10.0)
    model = PretravelModel(lobe_phase_rad=phase)
    phi = np.deg2rad(np.arange(360.0))
    values = model.pretravel_m(_lateral(phi))
    expected = model.lateral_m + model.lobe_m * np.cos(3.0 * (phi - phase))
    assert np.max(np.abs(values - expected)) < PRETRAVEL_EXACT_M
    top = np.flatnonzero(values >= values.max() - PRETRAVEL_EXACT_M)
    bottom = np.flatnonzero(values <= values.min() + PRETRAVEL_EXACT_M)
    assert top.tolist() == [10, 130, 250]
    assert bottom.tolist() == [70, 190, 310]
    assert values.max() == pytest.approx(model.lateral_m + model.lobe_m, abs=PRETRAVEL_EXACT_M)
    assert values.min() == pytest.approx(model.lateral_m - model.lobe_m, abs=PRETRAVEL_EXACT_M)
    assert model.mean_m(_lateral(phi)) == pytest.approx(model.lateral_m, abs=PRETRAVEL_EXACT_M)


def test_axial_pretravel_exceeds_lateral_and_scales_with_stylus():
    model = PretravelModel()
    assert model.pretravel_m(np.array([0.0, 0.0, 1.0])) == pytest.approx(model.axial_m, abs=PRETRAVEL_EXACT_M)
    assert model.axial_m > model.lateral_m + model.lobe_m
    rng = np.random.default_rng(3)
    u = rng.normal(size=(50, 3))
    u[:, 2] = np.abs(u[:, 2])
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    longer = PretravelModel(stylus_m=2 * model.stylus_m)
    np.testing.assert_allclose(longer.pretravel_m(u), 2.0 * model.pretravel_m(u), rtol=REL)
    # between the lateral and axial values everywhere in the upper hemisphere
    values = model.pretravel_m(u)
    assert np.all(values >= model.lateral_m - model.lobe_m) and np.all(values <= model.axial_m)


def test_pretravel_refuses_pulls_and_bad_directions():
    model = PretravelModel()
    with pytest.raises(AlgorithmError, match="pull"):
        model.pretravel_m(np.array([0.0, 0.0, -1.0]))
    u = np.vstack([_lateral(np.arange(3.0)), [[0, 0, -1.0], [0.6, 0.0, -0.8]]])
    with pytest.raises(AlgorithmError, match="2 of 5 rows pull"):
        model.pretravel_m(u)
    with pytest.raises(AlgorithmError, match="unit"):
        model.pretravel_m(np.array([[1.0, 1.0, 0.0]]))
    with pytest.raises(AlgorithmError, match="finite"):
        model.pretravel_m(np.array([[np.nan, 0.0, 1.0]]))
    with pytest.raises(AlgorithmError, match=r"\(N, 3\)"):
        model.pretravel_m(np.ones((2, 2)))


def test_draws_match_pretravel_and_repeatability():
    model = PretravelModel()
    u = np.array([0.6, 0.0, 0.8])
    n = 20_000
    draws = model.draw_m(np.tile(u, (n, 1)), np.random.default_rng(7))
    sigma = model.repeatability_sigma_m
    assert abs(draws.mean() - model.pretravel_m(u)) < STD_ERRORS * sigma / np.sqrt(n)
    assert abs(draws.std(ddof=1) - sigma) < STD_ERRORS * sigma / np.sqrt(2 * (n - 1))
    # same stream, same draws
    again = model.draw_m(np.tile(u, (n, 1)), np.random.default_rng(7))
    assert np.array_equal(draws, again)
    assert isinstance(model.draw_m(u, np.random.default_rng(1)), float)


def test_draws_are_clipped_at_zero():
    model = PretravelModel(lateral_m=0.2e-6, lobe_m=0.0, repeatability_sigma_m=1e-6)
    draws = model.draw_m(_lateral(np.zeros(5000)), np.random.default_rng(0))
    assert draws.min() == 0.0 and np.mean(draws == 0.0) > 0.3


@pytest.mark.parametrize("fields, word", [
    ({"lobe_m": 4.0e-6}, "lobe_m"),
    ({"lobe_m": -1e-7}, "lobe_m"),
    ({"stylus_m": -0.01}, "stylus_m"),
    ({"reference_stylus_m": 0.0}, "reference_stylus_m"),
    ({"axial_m": 0.0}, "axial_m"),
    ({"repeatability_sigma_m": -1e-9}, "repeatability_sigma_m"),
    ({"lateral_m": np.nan}, "lateral_m"),
])
def test_pretravel_refuses_bad_fields(fields, word):
    with pytest.raises(AlgorithmError, match=word):
        PretravelModel(**fields)


# -------------------------------------------------------------------------- qualification
def _unit_vectors(n, rng):
    u = rng.normal(size=(n, 3))
    return u / np.linalg.norm(u, axis=1, keepdims=True)


def test_fit_sphere_recovers_exact_sphere():
    centre = np.array([0.35, -0.2, 0.61])
    radius = 0.0135
    points = centre + radius * _unit_vectors(40, np.random.default_rng(0))
    fit = fit_sphere(points)
    assert np.linalg.norm(fit.centre - centre) < EXACT_M
    assert abs(fit.radius_m - radius) < EXACT_M
    assert fit.rms_m < EXACT_M and fit.converged


def test_fit_sphere_noisy_within_expected_spread():
    rng = np.random.default_rng(1)
    centre = np.array([0.1, 0.2, 0.3])
    radius, sigma, n = 0.0125, 1e-6, 2000
    d = _unit_vectors(n, rng)
    fit = fit_sphere(centre + (radius + rng.normal(0.0, sigma, n))[:, None] * d)
    # whole-sphere sampling: radius std sigma / sqrt(N), each centre coordinate sqrt(3 / N) sigma
    assert abs(fit.radius_m - radius) < STD_ERRORS * sigma / np.sqrt(n)
    assert np.all(np.abs(fit.centre - centre) < STD_ERRORS * sigma * np.sqrt(3.0 / n))
    assert fit.rms_m == pytest.approx(sigma, rel=0.05)
    assert np.sqrt(np.mean(fit.residuals_m**2)) == pytest.approx(fit.rms_m, rel=REL)


def test_qualify_ball_gives_effective_radius():
    centre = np.array([0.5, 0.0, 0.2])
    R, r, delta = 0.0125, 0.001, 4e-6
    d = qualification_directions(25)
    q = qualify_ball(centre + (R + r - delta) * d, R)
    assert abs(q.effective_radius_m - (r - delta)) < EXACT_M
    assert np.linalg.norm(q.sphere_centre - centre) < EXACT_M
    assert q.n_points == 25
    with pytest.raises(AlgorithmError, match="not larger than the reference sphere"):
        qualify_ball(centre + (R + r - delta) * d, R + 2 * r)
    with pytest.raises(AlgorithmError, match="sphere_radius_m"):
        qualify_ball(centre + R * d, -R)


def test_qualification_with_pretravel_absorbs_it():
    """Touches with the modelled pre-travel: r_eff lies between r - max and r - min pre-travel."""
    model = PretravelModel()
    R, r = 0.0125, 0.001
    d = qualification_directions(25)
    # vertical stylus (probe z = world -z); probe x = world x, probe y = world -y (right-handed)
    u_world = -d
    u_probe = u_world * np.array([1.0, -1.0, -1.0])
    travel = model.pretravel_m(u_probe)
    q = qualify_ball((R + r - travel)[:, None] * d, R)
    assert r - travel.max() < q.effective_radius_m < r - travel.min()
    assert q.rms_m < travel.max() - travel.min()


def test_fit_sphere_refuses_coplanar_and_too_few():
    circle = np.column_stack([np.cos(np.arange(8.0)), np.sin(np.arange(8.0)), np.zeros(8)])
    with pytest.raises(AlgorithmError, match="coplanar"):
        fit_sphere(circle)
    with pytest.raises(AlgorithmError, match="N >= 4"):
        fit_sphere(circle[:3] + [0, 0, 1.0])
    with pytest.raises(AlgorithmError, match="finite"):
        fit_sphere(np.vstack([circle, [[np.inf, 0, 0]]]))


def test_compensate_and_cosine_error_by_hand():
    centres = np.array([[1.0, 2.0, 3.0], [0.0, 0.0, 0.0]])
    s = np.sqrt(0.5)
    normals = np.array([[0.0, 0.0, 1.0], [s, s, 0.0]])
    out = compensate(centres, normals, 0.002)
    np.testing.assert_allclose(out, [[1.0, 2.0, 2.998], [-0.002 * s, -0.002 * s, 0.0]], rtol=0, atol=EXACT_M)
    with pytest.raises(AlgorithmError, match="unit"):
        compensate(centres, 2 * normals, 0.002)
    with pytest.raises(AlgorithmError, match="effective_radius_m"):
        compensate(centres, normals, 0.0)

    r = 0.002
    theta = np.array([0.0, 0.1, np.pi / 2, np.pi])
    np.testing.assert_allclose(cosine_error_m(r, theta), [0.0, r * (1 - np.cos(0.1)), r, 2 * r], rtol=REL)
    # small angles: r theta^2 / 2, where 1 - cos(theta) would round to 0
    assert cosine_error_m(r, 1e-9) == pytest.approx(r * 0.5e-18, rel=REL)
    assert isinstance(cosine_error_m(r, 0.1), float)


@pytest.mark.parametrize("n_points, min_elevation_deg", [(25, 0.0), (4, 0.0), (10, 20.0), (40, 15.0)])
def test_qualification_directions(n_points, min_elevation_deg):
    d = qualification_directions(n_points, min_elevation_deg)
    assert d.shape == (n_points, 3)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, rtol=0, atol=1e-15)
    assert np.all(d[:, 2] >= np.sin(np.deg2rad(min_elevation_deg)) - 1e-15)
    np.testing.assert_array_equal(d[0], [0.0, 0.0, 1.0])
    gaps = np.linalg.norm(d[:, None] - d[None], axis=2) + 10 * np.eye(n_points)
    assert gaps.min() > 0.1
    assert np.array_equal(d, qualification_directions(n_points, min_elevation_deg))
    fit_sphere(d)  # they fix a sphere


def test_qualification_directions_refuses_bad_input():
    with pytest.raises(AlgorithmError, match="n_points"):
        qualification_directions(3)
    with pytest.raises(AlgorithmError, match="min_elevation_deg"):
        qualification_directions(25, 90.0)


# ------------------------------------------------------------------------- point planning
def _cube_candidates(seed=0):
    cube = trimesh.creation.box((0.05, 0.05, 0.05))
    return cube, sample_candidates(cube, 4 * MM, np.random.default_rng(seed))


def test_sample_candidates_on_surface_and_spaced():
    cube, cand = _cube_candidates()
    index = MeshIndex(cube)
    assert np.max(index.query(cand.points).distance) < EXACT_M
    np.testing.assert_array_equal(cand.normals, cube.face_normals[cand.faces])
    gaps = np.linalg.norm(cand.points[:, None] - cand.points[None], axis=2) + np.eye(len(cand.points))
    assert gaps.min() >= 4 * MM
    expected = cube.area / (4 * MM) ** 2
    assert 0.4 * expected < len(cand.points) < 0.7 * expected
    again = sample_candidates(cube, 4 * MM, np.random.default_rng(0))
    assert np.array_equal(cand.points, again.points)


def test_d_optimal_beats_baselines_on_a_cube():
    _, cand = _cube_candidates()
    m = 12
    chosen = d_optimal(cand.points, cand.normals, m)
    assert len(np.unique(chosen)) == m
    assert np.linalg.matrix_rank(cand.normals[chosen]) == 3
    assert len(np.unique(np.round(cand.normals[chosen], 6), axis=0)) >= 3
    best = log_det_information(cand.points[chosen], cand.normals[chosen])
    spread = spread_points(cand.points, m)
    assert best >= log_det_information(cand.points[spread], cand.normals[spread])
    for seed in range(5):
        pick = random_points(len(cand.points), m, np.random.default_rng(seed))
        assert len(np.unique(pick)) == m
        assert best > log_det_information(cand.points[pick], cand.normals[pick])
    greedy = d_optimal(cand.points, cand.normals, m, max_passes=0)
    assert best >= log_det_information(cand.points[greedy], cand.normals[greedy]) - LOGDET_TIE
    assert np.array_equal(chosen, d_optimal(cand.points, cand.normals, m))


def test_d_optimal_ends_where_no_single_swap_helps():
    _, cand = _cube_candidates(seed=2)
    m = 8
    chosen = d_optimal(cand.points, cand.normals, m)
    best = log_det_information(cand.points[chosen], cand.normals[chosen])
    others = np.setdiff1d(np.arange(len(cand.points)), chosen)
    for slot, j in itertools.product(range(m), others):
        trial = chosen.copy()
        trial[slot] = j
        assert log_det_information(cand.points[trial], cand.normals[trial]) <= best + LOGDET_TIE


def test_d_optimal_respects_mask_and_refuses_bad_input():
    _, cand = _cube_candidates()
    not_top = cand.normals[:, 2] < 0.5
    chosen = d_optimal(cand.points, cand.normals, 10, candidates_mask=not_top)
    assert np.all(not_top[chosen])
    assert np.all(not_top[spread_points(cand.points, 10, candidates_mask=not_top)])
    assert np.all(not_top[random_points(len(not_top), 10, np.random.default_rng(0), candidates_mask=not_top)])
    with pytest.raises(AlgorithmError, match="m must be an integer >= 6"):
        d_optimal(cand.points, cand.normals, 5)
    with pytest.raises(AlgorithmError, match="only 3 candidates are allowed"):
        d_optimal(cand.points, cand.normals, 6, candidates_mask=np.arange(len(not_top)) < 3)
    top = cand.normals[:, 2] > 0.5
    with pytest.raises(AlgorithmError, match="cannot fix all six pose directions"):
        d_optimal(cand.points, cand.normals, 8, candidates_mask=top)


def test_predicted_pose_std_by_hand():
    """Four points on each face pair of a cube: the information is diagonal.

    Points ``s a e_k + t b e_(k+1)`` (s, t = +-1) with normals ``s e_k`` have rows
    ``[-t b s e_(k+2), s e_k]``; summed over k, s, t: ``4 b^2 I`` (rotation) and ``4 I``
    (translation), no coupling. So the standard deviations are ``sigma / (2 b)`` and ``sigma / 2``.
    """
    a, b, sigma = 0.02, 0.01, 1e-6
    e = np.eye(3)
    points, normals = [], []
    for k, s, t in itertools.product(range(3), (1.0, -1.0), (1.0, -1.0)):
        points.append(s * a * e[k] + t * b * e[(k + 1) % 3])
        normals.append(s * e[k])
    P, N = np.array(points), np.array(normals)
    expected = np.r_[np.full(3, sigma / (2 * b)), np.full(3, sigma / 2)]
    np.testing.assert_allclose(predicted_pose_std(P, N, sigma), expected, rtol=REL)
    # about the centroid: the same numbers wherever the cube is
    np.testing.assert_allclose(predicted_pose_std(P + [0.3, -0.1, 0.5], N, sigma), expected, rtol=1e-9)
    assert log_det_information(P + [0.3, -0.1, 0.5], N) == pytest.approx(log_det_information(P, N), rel=1e-9)
    assert log_det_information(P, N) == pytest.approx(np.log(4**6 * b**6), rel=REL)
    with pytest.raises(AlgorithmError, match="six pose directions"):
        predicted_pose_std(P[:4].repeat(2, axis=0), N[:4].repeat(2, axis=0), sigma)


# ---------------------------------------------------------------------------- feasibility
def _box(lo_mm, hi_mm):
    lo, hi = np.asarray(lo_mm) * MM, np.asarray(hi_mm) * MM
    return trimesh.creation.box(extents=hi - lo, transform=trimesh.transformations.translation_matrix((lo + hi) / 2))


# A low block (40 x 40 x 10 mm), a 60 mm tall block 6 mm to its +x side, a slab floating
# 1.5 mm above part of its top, and a block with a 1.5 mm groove (too narrow for the ball).
SCENE = trimesh.util.concatenate([
    _box((-20, -20, 0), (20, 20, 10)),
    _box((26, -20, 0), (46, 20, 60)),
    _box((-15, -20, 11.5), (15, -8, 14.5)),
    _box((-20, 40, 0), (-0.75, 60, 10)),
    _box((0.75, 40, 0), (20, 60, 10)),
    _box((-20, 40, -10), (20, 60, 0)),
])
PROBE = {
    "stylus_axis": np.array([0.0, 0.0, -1.0]),
    "ball_radius_m": 1.0 * MM,
    "stylus_radius_m": 0.5 * MM,
    "stylus_length_m": 20 * MM,
    "body_radius_m": 6.6 * MM,
    "body_length_m": 30 * MM,
    "approach_m": 1.0 * MM,
    "search_m": 1.0 * MM,
    "edge_margin_m": 1.0 * MM,
    "clearance_m": 0.2 * MM,
}


@pytest.fixture(scope="module")
def scene_index():
    return MeshIndex(SCENE)


def _feasibility(index, points_mm, normals, **override):
    return feasible_candidates(index, np.asarray(points_mm) * MM, np.asarray(normals, dtype=np.float64),
                               **{**PROBE, **override})


def _grid(xs, ys, z):
    x, y = np.meshgrid(xs, ys)
    return np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z)])


def test_feasibility_top_bottom_and_edges(scene_index):
    top = _grid(np.linspace(-18, 18, 7), np.linspace(-6, 18, 5), 10.0)  # clear of the slab (y < -8 + margin)
    up = np.tile([0.0, 0.0, 1.0], (len(top), 1))
    f = _feasibility(scene_index, top, up)
    assert f.mask.all(), f.counts

    bottom = _grid(np.linspace(-19.9, 19.9, 5), np.linspace(-19.9, 19.9, 5), 0.0)
    f = _feasibility(scene_index, bottom, -up[: len(bottom)])
    assert np.all(f.reason == REASONS.index("faces_away")), "bottom face (even at its edges) faces away"

    # top face 0.5, 0.9 and 0.1 mm from an edge, 0.8 mm from two at a corner; side face 0.5 mm below the top
    near = np.array([[-19.5, 0, 10], [19.1, 5, 10], [0, 19.9, 10], [-19.2, -19.2, 10], [0, 20, 9.5]])
    normals = np.array([[0, 0, 1]] * 4 + [[0, 1, 0]], dtype=np.float64)
    f = _feasibility(scene_index, near, normals)
    assert np.all(f.reason == REASONS.index("near_edge")), f.reason


def test_feasibility_edge_found_in_any_direction():
    """An edge at 22.5 deg to the test's tangent directions is still found within the margin."""
    turn = trimesh.transformations.rotation_matrix(np.deg2rad(22.5), [0, 0, 1])
    block = _box((-20, -20, 0), (20, 20, 10))
    block.apply_transform(turn)
    index = MeshIndex(block)
    inward = np.array([0.95, 1.2, 3.0])  # distances from the +x edge, in units of the margin
    local = np.column_stack([20 - inward, np.zeros(3), np.full(3, 10.0)])
    points = local @ turn[:3, :3].T
    f = _feasibility(index, points, np.tile([0.0, 0.0, 1.0], (3, 1)))
    assert [REASONS[k] for k in f.reason] == ["near_edge", "ok", "ok"]


def test_feasibility_ball_blocked(scene_index):
    under_slab = _grid(np.linspace(-10, 10, 5), [-15.0, -12.0], 10.0)
    f = _feasibility(scene_index, under_slab, np.tile([0.0, 0.0, 1.0], (len(under_slab), 1)))
    assert np.all(f.reason == REASONS.index("ball_blocked")), f.counts
    groove_floor = np.array([[0.0, 45.0, 0.0], [0.0, 50.0, 0.0]])
    f = _feasibility(scene_index, groove_floor, [[0, 0, 1.0]] * 2, edge_margin_m=0.2 * MM)
    assert np.all(f.reason == REASONS.index("ball_blocked")), f.counts


def test_feasibility_stylus_hits_the_tall_neighbour(scene_index):
    side = np.column_stack([np.zeros(5), np.linspace(-15, 15, 5), np.full(5, 5.0)])
    plus_x = side + [20.0, 0, 0]   # faces the tall block 6 mm away: the 13.2 mm body hits it
    minus_x = side - [20.0, 0, 0]  # nothing beside it
    points = np.vstack([plus_x, minus_x])
    normals = np.vstack([np.tile([1.0, 0, 0], (5, 1)), np.tile([-1.0, 0, 0], (5, 1))])
    f = _feasibility(scene_index, points, normals)
    assert [REASONS[k] for k in f.reason] == ["stylus_collision"] * 5 + ["ok"] * 5
    # a probe body that keeps 0.2 mm from the neighbour (ball 3 mm off the face at most) passes
    f = _feasibility(scene_index, plus_x, normals[:5], body_radius_m=2.5 * MM)
    assert f.mask.all(), f.counts


def test_feasibility_counts_and_smooth_curved_patch(scene_index):
    cand = sample_candidates(SCENE, 2 * MM, np.random.default_rng(4))
    f = _feasibility(scene_index, cand.points / MM, cand.normals)
    assert sum(f.counts.values()) == len(cand.points)
    assert list(f.counts) == list(REASONS)
    for code, name in enumerate(REASONS):
        assert f.counts[name] == int(np.sum(f.reason == code)) > 0
    np.testing.assert_array_equal(f.mask, f.reason == 0)

    # a faceted cylinder (128 sections) is one smooth patch around its mid-height points
    cylinder = trimesh.creation.cylinder(radius=0.02, height=0.01, sections=128)
    phi = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    normals = np.column_stack([np.cos(phi), np.sin(phi), np.zeros(12)])
    cp = MeshIndex(cylinder).query(0.02 * normals)
    f = _feasibility(MeshIndex(cylinder), cp.foot / MM, cp.normal)
    assert f.mask.all(), f.counts


def test_feasibility_refuses_bad_input(scene_index):
    with pytest.raises(AlgorithmError, match="stylus_axis"):
        _feasibility(scene_index, [[0, 0, 10.0]], [[0, 0, 1.0]], stylus_axis=np.array([0, 0, -2.0]))
    with pytest.raises(AlgorithmError, match="normals must be unit"):
        _feasibility(scene_index, [[0, 0, 10.0]], [[0, 0, 2.0]])
    with pytest.raises(AlgorithmError, match="stylus_length_m"):
        _feasibility(scene_index, [[0, 0, 10.0]], [[0, 0, 1.0]], stylus_length_m=0.5 * MM)
    with pytest.raises(AlgorithmError, match="clearance_m"):
        _feasibility(scene_index, [[0, 0, 10.0]], [[0, 0, 1.0]], clearance_m=-1.0)
