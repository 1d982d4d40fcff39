"""Tool frames (eq. 11), flange poses (eq. 13), process paths, CAD raster and ray casts."""

import numpy as np
import pytest
import trimesh

from algorithms.errors import AlgorithmError
from algorithms.geometry.mesh_index import MeshIndex
from algorithms.geometry.raycast import raycast_parallel
from algorithms.geometry.se3 import make_pose
from algorithms.paths.toolpath import (
    ToolPathError,
    ToolSettings,
    build_path,
    cad_raster,
    contact_frames,
    flange_poses,
    tool_frames,
    transform_path,
)
from tests.tolerances import NORMAL_DEG, ON_MESH_M, ORTHONORMAL
from twin.parts import make_workpiece, s_surface_height, s_surface_normal


def wave_line(n=50, y=0.0):
    x = np.linspace(-0.04, 0.04, n)
    p = np.column_stack([x, np.full(n, y), 0.01 * np.sin(30 * x)])
    nn = np.column_stack([-0.3 * np.cos(30 * x), np.zeros(n), np.ones(n)])
    return p, nn / np.linalg.norm(nn, axis=1, keepdims=True)


def test_contact_frames_are_right_handed_eq11():
    p, n = wave_line()
    T = contact_frames(p, n)
    R = T[:, :3, :3]
    assert np.abs(np.einsum("nji,njk->nik", R, R) - np.eye(3)).max() < ORTHONORMAL
    assert np.allclose(np.linalg.det(R), 1.0)
    np.testing.assert_allclose(R[:, :, 2], n, atol=1e-12)               # z = v_n
    chord = np.diff(p, axis=0)
    assert np.all(np.einsum("ij,ij->i", R[:-1, :, 0], chord) > 0)       # x = v_t towards the next point
    np.testing.assert_allclose(np.cross(n, R[:, :, 0]), R[:, :, 1], atol=1e-12)  # v_e = v_n x v_t
    np.testing.assert_allclose(T[:, :3, 3], p)


def test_fixed_heading_and_fixed_axis():
    p, n = wave_line()
    T = contact_frames(p, n, heading="fixed", heading_direction=[0.0, 1.0, 0.0])
    assert np.allclose(T[:, :3, 0], [0.0, 1.0, 0.0])  # y is in every tangent plane here
    T = contact_frames(p, n, axis="fixed", axis_direction=[0, 0, 2.0])
    assert np.allclose(T[:, :3, 2], [0.0, 0.0, 1.0])
    with pytest.raises(ToolPathError, match="parallel to the tool axis"):
        contact_frames(p, n, heading="fixed", heading_direction=[0.0, 0.0, 1.0], axis="fixed",
                       axis_direction=[0.0, 0.0, 1.0])


@pytest.mark.parametrize("lead, tilt", [(0.0, 0.0), (0.2, 0.0), (0.0, -0.15), (0.1, 0.25)])
def test_lead_tilt_and_ball_end(lead, tilt):
    p, n = wave_line()
    Tc = contact_frames(p, n)
    r = 0.004
    T = tool_frames(Tc, lead, tilt, r)
    z = T[:, :3, 2]
    # the tool axis leans by lead towards x, then by tilt towards y of the contact frame
    zc = np.einsum("nji,nj->ni", Tc[:, :3, :3], z)
    np.testing.assert_allclose(zc, np.broadcast_to(
        [np.sin(lead), np.cos(lead) * np.sin(tilt), np.cos(lead) * np.cos(tilt)], zc.shape), atol=1e-12)
    # the ball (centre = TCP + r z_tool) touches the tangent plane at the contact point
    centre = T[:, :3, 3] + r * z
    np.testing.assert_allclose(centre, p + r * n, atol=1e-12)


def test_flange_poses_eq13_and_a_non_rigid_tool():
    p, n = wave_line()
    T_tool = tool_frames(contact_frames(p, n))
    T_ft = make_pose(np.diag([1.0, -1.0, -1.0]), [0.0, 0.01, 0.1])
    T_bf = flange_poses(T_tool, T_ft)
    np.testing.assert_allclose(T_bf @ T_ft, T_tool, atol=1e-12)
    sheared = T_ft.copy()
    sheared[0, 1] = 0.1
    with pytest.raises(ToolPathError, match="tool transform T_flange_tool rotation is not orthonormal"):
        flange_poses(T_tool, sheared)
    with pytest.raises(ToolPathError, match="reflection"):
        flange_poses(T_tool, np.diag([1.0, 1.0, -1.0, 1.0]))
    assert issubclass(ToolPathError, AlgorithmError)


def test_zigzag_path_segments():
    lines = [wave_line(40, y) for y in (0.0, 0.004, 0.008)]
    st = ToolSettings(heading="travel", retract_m=0.02, transit_step_m=0.002)
    path = build_path([ln[0] for ln in lines], [ln[1] for ln in lines], st)
    kinds = [s[2] for s in path.segments]
    assert kinds == ["approach", "process", "retract", "transit"] * 2 + ["approach", "process", "retract"]
    for a, b, kind, line in path.segments:
        pts = path.T_tool[a:b + 1, :3, 3]
        if kind == "process":
            c = lines[line][0]
            np.testing.assert_allclose(pts, c if line % 2 == 0 else c[::-1])
            np.testing.assert_allclose(path.contact[a:b + 1], pts)
            # eq. 11 heading: x along the travel, so it turns round on the odd lines
            assert np.sign(path.T_tool[a, 0, 0]) == (1 if line % 2 == 0 else -1)
        if kind == "approach":
            assert np.linalg.norm(pts[0] - pts[-1]) == pytest.approx(0.02)
    assert path.n_lines == 3
    assert np.isnan(path.contact[~path.process_mask()]).all()
    # consecutive segments share their junction pose
    for (_a0, b0, *_), (a1, *_rest) in zip(path.segments[:-1], path.segments[1:], strict=True):
        assert b0 == a1


def test_transform_path_moves_everything():
    lines = [wave_line(20, y) for y in (0.0, 0.004)]
    path = build_path([ln[0] for ln in lines], [ln[1] for ln in lines])
    T = make_pose(trimesh.transformations.rotation_matrix(0.3, [0, 0, 1])[:3, :3], [0.4, 0.1, 0.02])
    moved = transform_path(T, path)
    np.testing.assert_allclose(moved.T_tool, T @ path.T_tool)
    m = path.process_mask()
    np.testing.assert_allclose(moved.contact[m], path.contact[m] @ T[:3, :3].T + T[:3, 3])
    np.testing.assert_allclose(moved.normal[m], path.normal[m] @ T[:3, :3].T)


def test_rays_do_not_slip_through_shared_edges_and_vertices():
    # a grid-tessellated square: rays exactly through vertices and along shared edges
    g = np.linspace(0.0, 1.0, 5)
    X, Y = np.meshgrid(g, g)
    V = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])
    F = []
    for i in range(4):
        for j in range(4):
            a = i * 5 + j
            F += [[a, a + 1, a + 6], [a, a + 6, a + 5]]
    origins = np.column_stack([V[:, 0], V[:, 1], np.ones(len(V))])
    origins = np.vstack([origins, [[0.125, 0.125, 1.0], [0.5, 0.375, 1.0]]])  # on a diagonal, on an edge
    hit, P, face = raycast_parallel(V, np.array(F), origins, [0, 0, -1])
    assert hit.all() and np.allclose(P[:, 2], 0.0) and (face >= 0).all()
    hit, _, _ = raycast_parallel(V, np.array(F), [[2.0, 2.0, 1.0]], [0, 0, -1])
    assert not hit.any()
    # a handful of rays takes the bounding-box path: the same edges and vertices hit
    for o in origins:
        hit, P, face = raycast_parallel(V, np.array(F), o[None], [0, 0, -1])
        assert hit.all() and np.allclose(P[:, 2], 0.0) and (face >= 0).all()


def test_few_rays_hit_what_the_centroid_trees_hit():
    """The path for a handful of rays (bounding boxes, no trees) finds the same first hit, face
    and point, as the trees' path, rays through a sphere from every side."""
    import algorithms.geometry.raycast as raycast

    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.05)
    rng = np.random.default_rng(5)
    for _ in range(40):
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        origins = rng.uniform(-0.06, 0.06, (raycast.FEW_RAYS, 3)) - 0.3 * d
        few = raycast_parallel(mesh.vertices, mesh.faces, origins, d)
        many = raycast_parallel(mesh.vertices, mesh.faces, np.vstack([origins, origins]), d)
        assert few[0].any() and np.array_equal(few[0], many[0][: len(origins)])
        assert np.array_equal(few[2], many[2][: len(origins)])
        assert np.array_equal(few[1], many[1][: len(origins)], equal_nan=True)


def test_cad_raster_on_the_s_surface():
    mesh = make_workpiece("s_surface")
    index = MeshIndex(mesh)
    lines, normals = cad_raster(mesh, line_spacing_m=0.01, point_spacing_m=0.002, margin_m=0.005,
                                normals=index.smooth_normals)
    assert len(lines) == 7
    p = np.concatenate(lines)
    n = np.concatenate(normals)
    assert np.abs(p[:, 2] - s_surface_height(p[:, 0], p[:, 1])).max() < ON_MESH_M
    ang = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", n, s_surface_normal(p[:, 0], p[:, 1])), -1, 1)))
    assert ang.max() < NORMAL_DEG
    assert np.all(np.abs(p[:, 0]) <= 0.055 + 1e-12) and np.all(np.abs(p[:, 1]) <= 0.035 + 1e-12)
    with pytest.raises(ToolPathError, match="does not cover"):
        cad_raster(mesh, region=((1.0, 1.0), (1.1, 1.1)))
    with pytest.raises(ToolPathError, match="point_spacing_m must be > 0"):
        cad_raster(mesh, point_spacing_m=0.0)


def test_smooth_heading_does_not_twist_about_the_tool_axis():
    # normals sweep round a cone about +x: a fixed x heading spins about the tool axis here
    t = np.linspace(0, np.pi, 60)
    n = np.column_stack([np.full_like(t, 0.8), 0.6 * np.cos(t), 0.6 * np.sin(t)])
    p = np.column_stack([np.zeros_like(t), 0.01 * t, np.zeros_like(t)])
    from scipy.spatial.transform import Rotation

    def twist(T):
        rel = np.einsum("nji,njk->nik", T[:-1, :3, :3], T[1:, :3, :3])
        return np.abs(Rotation.from_matrix(rel).as_rotvec()[:, 2])  # about the (local) tool axis

    smooth = contact_frames(p, n, heading="smooth", heading_direction=[0.0, 0.0, 1.0])
    fixed = contact_frames(p, n, heading="fixed", heading_direction=[0.0, 0.0, 1.0])
    assert twist(smooth).max() < 0.02 * twist(fixed).max()  # second order in the step
    start = np.array([0.0, 0.0, 1.0]) - n[0] @ [0.0, 0.0, 1.0] * n[0]
    np.testing.assert_allclose(smooth[0, :3, 0], start / np.linalg.norm(start), atol=1e-12)
