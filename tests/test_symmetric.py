"""Symmetric localization: Algorithm 2, symmetry detection, discrete symmetries
(algorithms/registration/symmetric/), and the symmetric scenarios through the scan cell."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from algorithms.errors import AlgorithmError
from algorithms.geometry.se3 import exp_se3, inv_pose, rotation_error_rad, transform_points
from algorithms.registration import Status
from algorithms.registration.local import localize
from algorithms.registration.symmetric import (
    DETECTION_TOL,
    FEATURE_TABLE,
    FEATURE_TYPES,
    SymmetricResult,
    algorithm2,
    detect_symmetry,
    localize_symmetric,
    model_symmetries,
)
from algorithms.registration.symmetric.pipeline import _move_group
from tests.helpers import scenario
from tests.test_features import bumpy_mesh, example_features, sample_feature
from tests.tolerances import (
    AXIS_TOL,
    DETECTED_M,
    DETECTED_RAD,
    EXACT_AXIS_TOL,
    EXACT_M,
    FIXED_TOL,
    RECOVER_RAD,
    SAME_RMS_REL,
    SCAN_FIXED_M,
    SCAN_FIXED_RAD,
)
from twin.cli.localize import EXIT_UNTRUSTED

DEFAULT_NOISE_M = 2e-6  # the scenarios' default sensor sigma (Keyence IL-065 repeatability)
DETECTION_TRIALS = 8  # seeded trials per feature for the automatic detection


def _random_pose(rng, planar=False):
    if planar:
        return exp_se3([0.0, 0.0, rng.uniform(-np.pi, np.pi), *rng.normal(0, 0.1, 2), 0.0])
    return exp_se3(np.concatenate([rng.normal(0, 0.8, 3), rng.normal(0, 0.2, 3)]))


def _span_equal(A, B, tol=1e-9):
    return (np.linalg.matrix_rank(np.vstack([A, B]), tol=tol) == len(A) == len(B)
            == np.linalg.matrix_rank(A, tol=tol))


# ------------------------------------------------------------------ Algorithm 2, the bar
@pytest.mark.parametrize("kind", FEATURE_TYPES)
def test_algorithm2_recovers_the_fixed_directions_on_every_feature(kind):
    rng = np.random.default_rng(FEATURE_TYPES.index(kind) + 100)
    f = example_features()[kind]
    planar = f.planar
    X = sample_feature(f, 200, rng)
    T_true = _random_pose(rng, planar)
    Y = transform_points(T_true, X)
    # initial error along every direction, the free ones included
    if planar:
        xi0 = np.array([0.0, 0.0, 0.05, 0.004, -0.003, 0.0])
    else:
        xi0 = np.concatenate([rng.normal(0, 0.04, 3), rng.normal(0, 0.004, 3)])
    init = T_true @ exp_se3(xi0)
    res = algorithm2(Y, f, init=init)
    assert isinstance(res, SymmetricResult) and res.method == "algorithm2"
    assert res.converged, res.message
    assert res.status is (Status.UNOBSERVABLE if f.group.dim else Status.OK), res.message
    ang, dist = f.group.distance(inv_pose(T_true) @ res.T_world_workpiece)
    assert ang < FIXED_TOL and dist < FIXED_TOL
    info = FEATURE_TABLE[kind]
    assert res.feature == kind
    assert res.free_dofs == info.group_dim
    assert len(res.determined_directions) == info.quotient_dim
    assert res.covariance.shape == (info.quotient_dim, info.quotient_dim)
    # exactly the table's free directions (the feature's g_0, workpiece frame)
    if res.free_dofs:
        assert _span_equal(res.free_directions, f.group.g0)
    # Tangent / Hong-Tan face a singular system on the same data: reported, not raised
    ambient = 3 if planar else 6
    assert res.general_system_rank == ambient - info.group_dim
    if info.group_dim:
        assert res.general_system_condition == float("inf")
        assert res.relative_eigenvalues[info.group_dim - 1] < DETECTION_TOL
    else:
        assert np.isfinite(res.general_system_condition)


SYMMETRIC_MESHES = {
    "plane": (lambda: trimesh.creation.box([0.08, 0.06, 0.02]), lambda m: m.face_normals[:, 2] > 0.99, 3),
    "cylinder": (lambda: trimesh.creation.cylinder(0.02, 0.08, sections=256),
                 lambda m: np.abs(m.face_normals[:, 2]) < 0.01, 2),
    "sphere": (lambda: trimesh.creation.icosphere(5, 0.03), lambda m: m.triangles_center[:, 2] > 0.01, 3),
    "cone": (lambda: trimesh.creation.cone(0.03, 0.05, sections=256), lambda m: m.face_normals[:, 2] > 0.01, 1),
    "freeform": (bumpy_mesh, lambda m: np.ones(len(m.faces), dtype=bool), 0),
}


def _scan_like(mesh, faces, n, rng, sigma):
    sub = mesh.submesh([faces], append=True)
    tri = sub.triangles
    fi = rng.choice(len(tri), n, p=sub.area_faces / sub.area)
    u, v = rng.random(n), rng.random(n)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    p = tri[fi, 0] + u[:, None] * (tri[fi, 1] - tri[fi, 0]) + v[:, None] * (tri[fi, 2] - tri[fi, 0])
    return p + rng.normal(0, sigma, (n, 1)) * sub.face_normals[fi]


@pytest.mark.parametrize("kind", list(SYMMETRIC_MESHES))
def test_tangent_and_hong_tan_report_singularity_without_crashing(kind):
    make, select, r = SYMMETRIC_MESHES[kind]
    mesh = make()
    rng = np.random.default_rng(7)
    X = _scan_like(mesh, np.nonzero(select(mesh))[0], 300, rng, 0.0)
    T = _random_pose(rng)
    for method in ("tangent", "hong_tan"):
        res = localize(transform_points(T, X), mesh, method=method, init=T @ exp_se3([0.01, 0, 0, 0, 0.001, 0]))
        assert res.observable == (r == 0)
        if r:
            assert res.status is Status.UNOBSERVABLE and res.message.startswith("unobservable")
            # the directions the points fix keep their covariance; the free ones have none
            q = 6 - res.free_dofs
            assert 1 <= res.free_dofs <= r and res.covariance.shape == (q, q)


@pytest.mark.parametrize("kind", list(SYMMETRIC_MESHES))
def test_detection_picks_the_right_subgroup_in_every_seeded_trial(kind):
    make, select, r = SYMMETRIC_MESHES[kind]
    mesh = make()
    faces = np.nonzero(select(mesh))[0]
    picked = []
    for seed in range(DETECTION_TRIALS):
        rng = np.random.default_rng(seed)
        X = _scan_like(mesh, faces, 300, rng, DEFAULT_NOISE_M)
        T = _random_pose(rng)
        init = T @ exp_se3(np.concatenate([rng.normal(0, 0.03, 3), rng.normal(0, 0.002, 3)]))
        res = localize_symmetric(transform_points(T, X), mesh, init=init)
        picked.append((res.feature, res.free_dofs))
        ang, dist = res.group.distance(inv_pose(T) @ res.T_world_workpiece)
        if len(res.solutions) == 1:
            assert ang < DETECTED_RAD and dist < DETECTED_M
    assert picked == [(kind, r)] * DETECTION_TRIALS


def test_detection_on_exact_features_names_the_group_and_its_geometry():
    feats = example_features()
    rng = np.random.default_rng(3)
    for kind in ("plane", "sphere", "cylinder", "cone"):
        f = feats[kind]
        p = f.closest(sample_feature(f, 300, rng))
        det = detect_symmetry(p.foot, p.normals[:, 0, :])
        assert det.group.kind == kind
        assert _span_equal(det.group.g0, f.group.g0, tol=1e-6)
    assert detect_symmetry(*(lambda p: (p.foot, p.normals[:, 0, :]))(
        feats["sphere"].closest(sample_feature(feats["sphere"], 100, rng)))).group.origin == pytest.approx(
        feats["sphere"].origin, abs=EXACT_M)


# -------------------------------------------------------------------- discrete symmetries
def test_model_symmetries_of_a_cube_and_a_box():
    assert len(model_symmetries(trimesh.creation.box([0.04, 0.04, 0.04]))) == 24
    assert len(model_symmetries(trimesh.creation.box([0.04, 0.05, 0.06]))) == 4
    assert len(model_symmetries(bumpy_mesh())) == 1


def test_square_plate_with_four_identical_blind_holes_has_four_symmetries():
    from twin.parts import workpieces as wp

    patches, holes = [], []
    for x, y in [(0.02, 0.02), (-0.02, 0.02), (0.02, -0.02), (-0.02, -0.02)]:
        prof, edges = wp._sample_profile([wp._line((0.005, 0.01), (0.005, 0.004)),
                                          wp._line((0.005, 0.004), (0.0, 0.004))], 0.001, 1e-5)
        v, f, rings = wp._revolve(prof, edges, origin=(x, y, 0.0))
        patches.append((v, f))
        holes.append(v[rings[0]])
    patches += wp._box_patches((-0.04, -0.04, 0.0), (0.04, 0.04, 0.01), 0.005, top_holes=holes)
    plate = wp._assemble(patches, "plate")
    S = model_symmetries(plate)
    assert len(S) == 4  # the turns by 90 degrees about the plate's axis (the holes are blind)
    assert all(np.allclose(s[:3, 2], [0, 0, 1], atol=EXACT_AXIS_TOL) for s in S)


def _cube_faces(rng, which, n=100, a=0.04):
    pts = []
    for ax, sign in which:
        p = np.zeros((n, 3))
        others = [i for i in range(3) if i != ax]
        p[:, others] = rng.uniform(-0.45 * a, 0.45 * a, (n, 2))
        p[:, ax] = sign * a / 2
        pts.append(p)
    return np.vstack(pts)


@pytest.mark.parametrize("which, solutions, free, feature", [
    ([(0, 1), (1, 1), (2, 1)], 24, 0, "freeform"),  # three faces: 24 equally good poses
    ([(0, 1), (2, 1)], 24, 1, "extruded"),  # two faces: slide along their edge, 24 ways
    ([(2, 1)], 6, 3, "plane"),  # one face: which of the 6 faces was measured
])
def test_cube_reports_every_equally_good_pose(which, solutions, free, feature):
    cube = trimesh.creation.box([0.04, 0.04, 0.04])
    rng = np.random.default_rng(5)
    X = _cube_faces(rng, which)
    T = _random_pose(rng)
    Y = transform_points(T, X) + rng.normal(0, DEFAULT_NOISE_M, X.shape)
    init = T @ exp_se3([0.03, -0.02, 0.02, 0.002, 0.001, -0.002])
    res = localize_symmetric(Y, cube, init=init)
    assert (res.feature, res.free_dofs, len(res.solutions)) == (feature, free, solutions)
    assert res.status is Status.AMBIGUOUS and not res.trusted
    # all equally good, pairwise distinct, one of them the truth (modulo the free motions)
    assert np.ptp(res.solution_rmse_m) < SAME_RMS_REL * res.solution_rmse_m.max() + 1e-12

    for j in range(len(res.solutions)):
        g_j = _move_group(res.group, res.solutions[0], res.solutions[j])  # G_0 seen from pose j
        for i in range(j):
            assert not g_j.contains(inv_pose(res.solutions[j]) @ res.solutions[i], 1e-2, 1e-3)
    err = [res.group.distance(inv_pose(T) @ S) for S in res.solutions]
    assert min(a for a, _ in err) < SCAN_FIXED_RAD
    assert np.array_equal(res.T_world_workpiece, res.solutions[0])
    assert rotation_error_rad(res.T_world_workpiece, init) < 0.1  # the one nearest the start first


# ---------------------------------------------------------------------------- bad input
def test_unknown_symmetric_choice_lists_the_valid_ones():
    mesh = trimesh.creation.box([0.04, 0.04, 0.04])
    Y = _cube_faces(np.random.default_rng(0), [(2, 1)])
    with pytest.raises(AlgorithmError, match="symmetric must be one of auto, none or a feature type.*circle2d"):
        localize_symmetric(Y, mesh, symmetric="cylindre")
    with pytest.raises(AlgorithmError, match="2D feature"):
        localize_symmetric(Y, mesh, symmetric="circle2d")
    with pytest.raises(AlgorithmError, match="give the symmetry group"):
        algorithm2(Y, mesh)


def test_a_named_feature_is_fitted_to_the_measured_faces():
    mesh = trimesh.creation.box([0.04, 0.04, 0.04])
    Y = _cube_faces(np.random.default_rng(0), [(2, 1)])
    res = localize_symmetric(Y, mesh, symmetric="plane")
    assert res.feature == "plane" and res.free_dofs == 3
    with pytest.raises(AlgorithmError, match="the faces are not a cylinder"):
        localize_symmetric(Y, mesh, symmetric="cylinder")
    none = localize_symmetric(Y, mesh, symmetric="none")
    assert none.algorithm == "1" and none.free_dofs == 3 and len(none.solutions) == 1
    assert none.method == "hong_tan" and none.status is Status.UNOBSERVABLE
    assert none.determined_directions.shape == (3, 6) and none.covariance.shape == (3, 3)


# ---------------------------------------------------------------- through the scan cell
@pytest.fixture(scope="module")
def scans():
    from twin.scan import scan_scenario

    out = {}
    over = {
        "bore_and_face": {"scan": {"line_spacing_m": 0.004}},
        "sphere": {"scan": {"line_spacing_m": 0.004}},
        "cube": {"scan": {"line_spacing_m": 0.006}},
    }
    for name, o in over.items():
        sc = scenario(name, **o)
        out[name] = (sc, scan_scenario(sc))
    return out


def _scan_result(scans, name):
    from twin.parts import make_workpiece

    sc, scan = scans[name]
    mesh = make_workpiece(sc.workpiece.shape, **sc.workpiece.params)
    res = localize_symmetric(scan.valid_points_base, mesh, init=scan.T_base_workpiece_nominal)
    return res, scan.T_base_workpiece_true


def test_bore_and_face_scan_leaves_the_rotation_about_the_bore_free(scans):
    res, T_true = _scan_result(scans, "bore_and_face")
    assert (res.feature, res.free_dofs, len(res.solutions)) == ("cone", 1, 1)
    axis, point = res.group.axis, res.group.origin
    assert abs(abs(axis[2]) - 1.0) < AXIS_TOL  # the bore axis (z), through the bore's centre
    assert np.hypot(point[0] - 0.012, point[1] - 0.006) < SCAN_FIXED_M
    ang, dist = res.group.distance(inv_pose(T_true) @ res.T_world_workpiece)
    assert ang < SCAN_FIXED_RAD and dist < SCAN_FIXED_M


def test_sphere_scan_fixes_the_centre_only(scans):
    res, T_true = _scan_result(scans, "sphere")
    assert (res.feature, res.free_dofs, len(res.solutions)) == ("sphere", 3, 1)
    assert res.group.origin == pytest.approx([0.0, 0.0, 0.047], abs=SCAN_FIXED_M)
    ang, dist = res.group.distance(inv_pose(T_true) @ res.T_world_workpiece)
    assert dist < SCAN_FIXED_M


def test_cube_scan_gives_all_24_poses_one_of_them_true(scans):
    res, T_true = _scan_result(scans, "cube")
    assert (res.feature, res.free_dofs, len(res.solutions)) == ("freeform", 0, 24)
    errs = [(rotation_error_rad(S, T_true), np.linalg.norm(S[:3, 3] - T_true[:3, 3])) for S in res.solutions]
    best = min(errs)
    assert best[0] < SCAN_FIXED_RAD and best[1] < SCAN_FIXED_M
    # the others are the cube's rotations: at least 90 degrees away
    assert sorted(e[0] for e in errs)[1] > np.radians(89.0)


# ------------------------------------------------------------------------------- the CLI
def _cli(capsys, *argv):
    from twin import cli

    rc = cli.main(["localize", *map(str, argv)])
    out, err = capsys.readouterr()
    return rc, out, err


@pytest.fixture(scope="module")
def cube_files(tmp_path_factory):
    import json

    from twin.io import write_points_ply

    d = tmp_path_factory.mktemp("sym_cli")
    cube = trimesh.creation.box([0.04, 0.04, 0.04])
    cube.export(d / "cube.ply")
    rng = np.random.default_rng(8)
    T = _random_pose(rng)
    write_points_ply(d / "three.ply", transform_points(T, _cube_faces(rng, [(0, 1), (1, 1), (2, 1)])))
    write_points_ply(d / "top.ply", transform_points(T, _cube_faces(rng, [(2, 1)])))
    (d / "init.json").write_text(json.dumps((T @ exp_se3([0.02, 0.01, -0.02, 0.001, 0, 0.001])).tolist()))
    return d, T


def test_cli_symmetric_auto_reports_free_directions_and_all_poses(cube_files, capsys):
    import json

    d, T = cube_files
    rc, out, err = _cli(capsys, "--model", d / "cube.ply", "--points", d / "three.ply", "--init", d / "init.json",
                        "--symmetric", "auto", "--json")
    # 24 equally good poses: the answer symmetric handling was asked for (exit 0), listed
    assert rc == 0, err
    res = json.loads(out)
    assert res["status"] == "ambiguous" and res["method"] == "algorithm2" and not res["trusted"]
    assert res["free_dofs"] == 0 and res["free_directions"] == [] and len(res["solutions"]) == 24
    assert np.asarray(res["covariance"]).shape == (6, 6)
    assert all(np.asarray(S).shape == (4, 4) for S in res["solutions"])
    assert rotation_error_rad(np.asarray(res["T_world_workpiece"]), T) < RECOVER_RAD
    rc, out, err = _cli(capsys, "--model", d / "cube.ply", "--points", d / "top.ply", "--init", d / "init.json",
                        "--symmetric", "plane", "--json")
    assert rc == 0, err
    res = json.loads(out)
    assert res["status"] == "ambiguous" and res["feature"] == "plane"
    assert res["free_dofs"] == 3 and len(res["solutions"]) == 6
    assert np.asarray(res["determined_directions"]).shape == (3, 6) and np.asarray(res["covariance"]).shape == (3, 3)
    W = np.asarray(res["free_directions"])
    assert W.shape == (3, 6)
    # angular part first, workpiece frame: one rotation about the top face's normal, two slides
    assert np.linalg.matrix_rank(W[:, :3], tol=1e-9) == 1
    assert abs(abs(W[np.argmax(np.linalg.norm(W[:, :3], axis=1)), 2]) - 1.0) < AXIS_TOL


def test_cli_default_json_has_the_new_fields(cube_files, capsys):
    import json

    d, _ = cube_files
    rc, out, err = _cli(capsys, "--model", d / "cube.ply", "--points", d / "top.ply", "--init", d / "init.json",
                        "--json")
    assert rc == EXIT_UNTRUSTED, err
    res = json.loads(out)
    assert res["method"] == "hong_tan" and res["free_dofs"] == 3 and len(res["solutions"]) == 1
    assert res["status"] == "unobservable" and "weak_directions" not in res
    assert np.asarray(res["free_directions"]).shape == (3, 6)


@pytest.mark.parametrize("argv, message", [
    (["--symmetric", "torus"], "--symmetric must be auto, none or a feature type (circle2d, line2d, sphere"),
    (["--symmetric", "circle2d"], "2D feature"),
    (["--symmetric", "cylinder"], "the faces are not a cylinder"),
    (["--symmetric", "auto", "--stock", "1"], "apply with --allowance only"),
])
def test_cli_symmetric_errors_are_one_line(cube_files, capsys, argv, message):
    d, _ = cube_files
    rc, out, err = _cli(capsys, "--model", d / "cube.ply", "--points", d / "top.ply", "--init", d / "init.json", *argv)
    assert rc == 2 and out == ""
    assert len(err.strip().splitlines()) == 1 and message in err
