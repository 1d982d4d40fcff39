"""Tests of the procedural workpieces and of loading user meshes (twin/parts)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from twin.errors import TwinError
from twin.formats import read_mesh
from twin.parts import (
    MESH_EXTENSIONS,
    WORKPIECE_NAMES,
    bottle_profile_bezier,
    load_mesh,
    make_workpiece,
    s_surface,
    s_surface_height,
    s_surface_normal,
    through_hole,
)

# Named tolerances of this file.
S_CHORD_M = 2e-6  # S-surface top vs its analytic height (default tessellation)
CHORD_M = 1e-5  # curved surfaces vs exact (the default chord_tolerance_m)
MAX_FACES = 150_000  # well under MuJoCo's 200k-face limit
MIN_ANGLE_DEG = 10.0  # no slivers
MAX_ASPECT = 6.0  # longest edge / its altitude
MIN_FACE_AREA_M2 = 1e-9  # no degenerate faces (a 0.045 mm equilateral triangle)
NORMAL_DEG = 2.0  # S-surface face normal vs analytic normal
SYMMETRY_GAP_M = 1e-3  # a non-symmetry must move the surface at least this much
ROUND_TRIP_M = 1e-7  # float32 STL coordinates of a ~0.1 m part


@pytest.fixture(scope="module")
def meshes() -> dict[str, trimesh.Trimesh]:
    return {name: make_workpiece(name) for name in WORKPIECE_NAMES}


def _face_samples(mesh: trimesh.Trimesh, faces: np.ndarray) -> np.ndarray:
    """Centroids and edge midpoints of the given faces, (4 F, 3)."""
    tri = mesh.triangles[faces]
    return np.concatenate(
        [tri.mean(axis=1), 0.5 * (tri[:, 0] + tri[:, 1]), 0.5 * (tri[:, 1] + tri[:, 2]),
         0.5 * (tri[:, 2] + tri[:, 0])]
    )


def _surface_distance_m(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """Distance [m] from points to the mesh surface.

    Computed on a millimetre copy: trimesh's point-triangle test uses absolute epsilons that
    misplace the closest point on sub-millimetre triangles expressed in metres.
    """
    mesh_mm = mesh.copy()
    mesh_mm.apply_scale(1e3)
    _, dist, _ = trimesh.proximity.closest_point(mesh_mm, np.asarray(points) * 1e3)
    return np.asarray(dist) * 1e-3


def _faces_on(mesh: trimesh.Trimesh, on_vertex: np.ndarray) -> np.ndarray:
    return np.nonzero(on_vertex[mesh.faces].all(axis=1))[0]


# ---------------------------------------------------------------------------------------------
# Every generator: a valid, well-shaped solid on z = 0
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", WORKPIECE_NAMES)
def test_solid_is_closed_outward_and_well_shaped(meshes, name):
    mesh = meshes[name]
    assert mesh.is_watertight
    assert mesh.is_winding_consistent
    assert mesh.is_volume
    assert mesh.volume > 0.0  # consistent winding + positive volume: normals point out
    assert len(mesh.faces) <= MAX_FACES
    assert mesh.area_faces.min() > MIN_FACE_AREA_M2
    assert np.degrees(mesh.face_angles.min()) > MIN_ANGLE_DEG
    tri = mesh.triangles
    edges = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2)
    assert np.max(edges.max(axis=1) ** 2 / (2.0 * mesh.area_faces)) < MAX_ASPECT
    # Genus 0, except the through hole (genus 1).
    assert mesh.euler_number == (0 if name == "through_hole" else 2)


@pytest.mark.parametrize("name", WORKPIECE_NAMES)
def test_every_face_belongs_to_one_named_feature(meshes, name):
    features = meshes[name].metadata["features"]
    faces = np.concatenate(list(features.values()))
    assert np.array_equal(np.sort(faces), np.arange(len(meshes[name].faces)))
    top = [f for f in features if f.endswith("_top") or f == "s_surface"]
    assert len(top) == 1
    for f in [f for f in features if f.endswith(("_top", "_bottom", "_front", "_back", "_left", "_right"))]:
        normal = {"top": (0, 0, 1), "bottom": (0, 0, -1), "front": (0, -1, 0), "back": (0, 1, 0),
                  "left": (-1, 0, 0), "right": (1, 0, 0)}[f.rsplit("_", 1)[1]]
        assert np.allclose(meshes[name].face_normals[features[f]], normal, atol=1e-9), f


def test_the_hemisphere_feature_is_the_hemisphere(meshes):
    mesh = meshes["hemisphere_punch"]
    faces = mesh.metadata["features"]["hemisphere"]
    centre = np.array([0.01, 0.0, 0.02])     # the generator's defaults: offset 10 mm, plate 20 mm
    r = np.linalg.norm(mesh.vertices[mesh.faces[faces].ravel()] - centre, axis=1)
    assert np.allclose(r, 0.035, atol=1e-9)
    others = np.setdiff1d(np.arange(len(mesh.faces)), faces)
    assert not np.any(np.all(np.isclose(np.linalg.norm(mesh.vertices[mesh.faces[others]] - centre, axis=2),
                                        0.035, atol=1e-9), axis=1) & (mesh.triangles_center[others, 2] > 0.0201))


@pytest.mark.parametrize("name", WORKPIECE_NAMES)
def test_part_rests_on_z0_centred_in_xy(meshes, name):
    mesh = meshes[name]
    assert mesh.bounds[0, 2] == 0.0
    bottom = mesh.face_normals[:, 2] < -1.0 + 1e-12
    assert np.all(mesh.triangles[bottom][:, :, 2] == 0.0)
    # The bottom face spans the footprint: its area equals the xy extent's.
    ext = mesh.extents
    assert mesh.area_faces[bottom].sum() == pytest.approx(ext[0] * ext[1], rel=1e-9)
    assert np.all(np.abs(mesh.bounds[:, :2].mean(axis=0)) < 1e-9)


@pytest.mark.parametrize("name", WORKPIECE_NAMES)
def test_generation_is_deterministic(name):
    coarse = {"resolution_m": 0.003}
    if name != "s_surface":
        coarse["chord_tolerance_m"] = 1e-4
    first = make_workpiece(name, **coarse)
    again = make_workpiece(name, **coarse)
    assert np.array_equal(again.vertices, first.vertices)
    assert np.array_equal(again.faces, first.faces)
    assert first.is_watertight and first.is_winding_consistent and first.volume > 0


# ---------------------------------------------------------------------------------------------
# S-surface (document 004)
# ---------------------------------------------------------------------------------------------


def test_s_surface_top_matches_analytic_height_and_normal(meshes):
    mesh = meshes["s_surface"]
    rng = np.random.default_rng(4)
    n = 2000
    xy = rng.uniform([-0.0599, -0.0399], [0.0599, 0.0399], size=(n, 2))
    origins = np.column_stack([xy, np.full(n, 0.2)])
    directions = np.tile([0.0, 0.0, -1.0], (n, 1))
    hits, ray_idx, tri_idx = mesh.ray.intersects_location(origins, directions,
                                                          multiple_hits=False)
    assert len(hits) == n
    z_true = s_surface_height(hits[:, 0], hits[:, 1])
    assert np.max(np.abs(hits[:, 2] - z_true)) < S_CHORD_M
    n_true = s_surface_normal(hits[:, 0], hits[:, 1])
    cos = np.einsum("ij,ij->i", mesh.face_normals[tri_idx], n_true)
    assert np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))).max() < NORMAL_DEG


def test_s_surface_chord_error_over_every_top_face(meshes):
    mesh = meshes["s_surface"]
    top = np.nonzero(mesh.face_normals[:, 2] > 0.5)[0]
    pts = _face_samples(mesh, top)
    err = pts[:, 2] - s_surface_height(pts[:, 0], pts[:, 1])
    assert np.max(np.abs(err)) < S_CHORD_M


def test_s_surface_resolution_controls_chord_error():
    coarse = s_surface(resolution_m=0.002)
    top = np.nonzero(coarse.face_normals[:, 2] > 0.5)[0]
    pts = _face_samples(coarse, top)
    err = np.max(np.abs(pts[:, 2] - s_surface_height(pts[:, 0], pts[:, 1])))
    # Chord error grows with the square of the spacing: 4x the spacing, ~16x the error.
    assert S_CHORD_M < err < 16 * 2 * S_CHORD_M
    assert coarse.is_watertight and coarse.volume > 0


def test_s_surface_volume_and_parameters():
    params = dict(length_m=0.1, width_m=0.06, base_thickness_m=0.025, amplitude_m=0.008,
                  amplitude_gradient=-0.2, crown_m=-0.001)
    mesh = s_surface(resolution_m=0.001, **params)
    # The sine integrates to zero over its period; the crown y^2 term to crown / 3.
    expected = 0.1 * 0.06 * (0.025 + params["crown_m"] / 3.0)
    # |volume error| <= curved area x chord error; the chord error at 1 mm is ~4x the default.
    assert mesh.volume == pytest.approx(expected, abs=0.1 * 0.06 * 1.1 * 4 * S_CHORD_M)
    assert np.allclose(mesh.extents[:2], [0.1, 0.06], rtol=0, atol=1e-12)
    # Heights at the four top corners are the analytic ones.
    for x in (-0.05, 0.05):
        for y in (-0.03, 0.03):
            z = s_surface_height(x, y, **params)
            assert np.min(np.linalg.norm(mesh.vertices - [x, y, z], axis=1)) < 1e-12


def test_s_surface_normal_is_unit_and_orthogonal_to_gradient():
    rng = np.random.default_rng(0)
    x, y = rng.uniform(-0.06, 0.06, 50), rng.uniform(-0.04, 0.04, 50)
    n = s_surface_normal(x, y)
    assert n.shape == (50, 3)
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0)
    h = 1e-6
    tx = np.column_stack([np.full(50, 2 * h), np.zeros(50),
                          s_surface_height(x + h, y) - s_surface_height(x - h, y)])
    ty = np.column_stack([np.zeros(50), np.full(50, 2 * h),
                          s_surface_height(x, y + h) - s_surface_height(x, y - h)])
    assert np.max(np.abs(np.einsum("ij,ij->i", n, tx)) / (2 * h)) < 1e-6
    assert np.max(np.abs(np.einsum("ij,ij->i", n, ty)) / (2 * h)) < 1e-6


def test_s_surface_height_accepts_the_generator_keywords():
    z = s_surface_height(0.01, 0.02, resolution_m=0.001, amplitude_m=0.0)
    assert float(z) == pytest.approx(0.03 + 0.002 * 0.25)


@pytest.mark.parametrize("name", ["s_surface", "hemisphere_punch", "bottle_punch"])
def test_localization_parts_have_no_half_turn_symmetry(meshes, name):
    # A proper symmetry of a part resting on its flat bottom would be a rotation about a
    # vertical axis through its centroid; the footprint allows only the half turn.
    mesh = meshes[name]
    c = mesh.center_mass
    half_turn = trimesh.transformations.rotation_matrix(math.pi, [0, 0, 1], point=c)
    samples, _ = trimesh.sample.sample_surface_even(mesh, 100, seed=1)
    moved = trimesh.transform_points(samples, half_turn)
    assert _surface_distance_m(mesh, moved).max() > SYMMETRY_GAP_M


# ---------------------------------------------------------------------------------------------
# Document 000: hemisphere punch and bottle punch
# ---------------------------------------------------------------------------------------------


def test_hemisphere_punch_volume_and_exact_hemisphere(meshes):
    mesh = meshes["hemisphere_punch"]
    length, width, thick, radius, offset = 0.12, 0.10, 0.02, 0.035, 0.01
    pin_r, pin_h = 0.006, 0.015
    expected = (length * width * thick + 2.0 / 3.0 * math.pi * radius**3
                + 4 * math.pi * pin_r**2 * pin_h)
    curved_area = 2 * math.pi * radius**2 + 4 * 2 * math.pi * pin_r * pin_h
    assert mesh.volume == pytest.approx(expected, abs=curved_area * CHORD_M)
    # The hemisphere's vertices lie on the sphere; its faces deviate by < the chord tolerance.
    center = np.array([offset, 0.0, thick])
    on_sphere = np.abs(np.linalg.norm(mesh.vertices - center, axis=1) - radius) < 1e-12
    faces = _faces_on(mesh, on_sphere & (mesh.vertices[:, 2] >= thick))
    assert len(faces) > 1000
    dev = np.abs(np.linalg.norm(_face_samples(mesh, faces) - center, axis=1) - radius)
    assert dev.max() < CHORD_M
    assert mesh.bounds[1, 2] == pytest.approx(thick + radius, abs=1e-15)
    # Four pins reach pin height at the corners.
    tops = mesh.vertices[np.abs(mesh.vertices[:, 2] - (thick + pin_h)) < 1e-12]
    for sx in (-1, 1):
        for sy in (-1, 1):
            corner = np.array([sx * (length / 2 - 0.012), sy * (width / 2 - 0.012)])
            assert np.min(np.linalg.norm(tops[:, :2] - corner, axis=1)) < 1e-12


def test_hemisphere_punch_symmetric_when_centred():
    chord = 1e-4
    mesh = make_workpiece("hemisphere_punch", hemisphere_offset_x_m=0.0, resolution_m=0.003,
                             chord_tolerance_m=chord)
    half_turn = trimesh.transformations.rotation_matrix(math.pi, [0, 0, 1])
    samples, _ = trimesh.sample.sample_surface_even(mesh, 200, seed=2)
    dist = _surface_distance_m(mesh, trimesh.transform_points(samples, half_turn))
    assert dist.max() < 2 * chord  # documented: offset 0 gives the half-turn symmetry


def test_bottle_profile_is_tangent_continuous_and_volume_matches(meshes):
    ctrl = bottle_profile_bezier()
    assert ctrl.shape == (8, 4, 2)
    for a, b in zip(ctrl[:-1], ctrl[1:], strict=True):
        assert np.array_equal(a[3], b[0])  # C0
        ta, tb = a[3] - a[2], b[1] - b[0]
        assert abs(ta[0] * tb[1] - ta[1] * tb[0]) < 1e-15 and np.dot(ta, tb) > 0  # G1
    # Half a solid of revolution: (pi / 2) * integral r^2 dx along the Bezier profile.
    t = np.linspace(0.0, 1.0, 20001)[:, None]
    half_volume = 0.0
    for c in ctrl:
        s = 1.0 - t
        p = s**3 * c[0] + 3 * s**2 * t * c[1] + 3 * s * t**2 * c[2] + t**3 * c[3]
        dp = 3 * s**2 * (c[1] - c[0]) + 6 * s * t * (c[2] - c[1]) + 3 * t**2 * (c[3] - c[2])
        half_volume += 0.5 * math.pi * np.trapezoid(p[:, 1] ** 2 * dp[:, 0], t[:, 0])
    mesh = meshes["bottle_punch"]
    expected = 0.15 * 0.08 * 0.015 + half_volume
    bottle_area = mesh.area_faces[mesh.triangles_center[:, 2] > 0.015 + 1e-9].sum()
    assert mesh.volume == pytest.approx(expected, abs=bottle_area * CHORD_M)
    assert mesh.bounds[1, 2] == pytest.approx(0.015 + 0.025, abs=CHORD_M)
    assert np.allclose(mesh.extents[:2], [0.15, 0.08], rtol=0, atol=1e-12)


def test_bottle_punch_is_mirror_symmetric_only(meshes):
    # The documented symmetry: y -> -y (improper, so it cannot confuse a rigid fit).
    mesh = meshes["bottle_punch"]
    samples, _ = trimesh.sample.sample_surface_even(mesh, 200, seed=3)
    assert _surface_distance_m(mesh, samples * [1.0, -1.0, 1.0]).max() < 2 * CHORD_M


# ---------------------------------------------------------------------------------------------
# Document 002: inner sphere and through hole
# ---------------------------------------------------------------------------------------------


def test_inner_sphere_volume_and_cavity(meshes):
    mesh = meshes["inner_sphere"]
    length, width, height, radius, depth, post_r = 0.10, 0.10, 0.06, 0.04, 0.01, 0.01
    zc = height - depth
    w = math.sqrt(radius**2 - post_r**2)
    # Cavity: rp < r < sqrt(R^2 - (z - zc)^2) for zc - w < z < H.
    cavity = math.pi * ((radius**2 - post_r**2) * (depth + w) - (depth**3 + w**3) / 3.0)
    expected = length * width * height - cavity
    curved_area = (2 * math.pi * radius * (depth + w)
                   + 2 * math.pi * post_r * (height - (zc - w)))
    assert mesh.volume == pytest.approx(expected, abs=curved_area * CHORD_M)
    # A vertical ray down the annulus enters the cavity at the top face and stops on the
    # spherical floor; one down the axis stops on the post's top, flush with the top face.
    r = 0.5 * (post_r + math.sqrt(radius**2 - depth**2))
    hits, _, _ = mesh.ray.intersects_location([[r, 0.0, 0.1], [0.0, 0.0, 0.1]],
                                              [[0, 0, -1.0], [0, 0, -1.0]],
                                              multiple_hits=False)
    by_x = hits[np.argsort(-hits[:, 0])]
    assert by_x[0, 2] == pytest.approx(zc - math.sqrt(radius**2 - r**2), abs=CHORD_M)
    assert by_x[1, 2] == pytest.approx(height, abs=1e-12)


def test_through_hole_volume_is_box_minus_cylinder(meshes):
    mesh = meshes["through_hole"]
    length, width, height, radius = 0.08, 0.06, 0.04, 0.01
    expected = length * width * height - math.pi * radius**2 * length
    assert mesh.volume == pytest.approx(expected, abs=2 * math.pi * radius * length * CHORD_M)
    assert mesh.volume > expected  # the polygonal hole is inscribed in the circle
    # A ray along the hole axis passes through without hitting anything.
    assert not mesh.ray.intersects_any([[-0.1, 0.0, 0.02]], [[1.0, 0.0, 0.0]])[0]
    assert mesh.ray.intersects_any([[-0.1, 0.0, 0.008]], [[1.0, 0.0, 0.0]])[0]


def test_through_hole_parameters_change_the_hole():
    mesh = make_workpiece("through_hole", hole_diameter_m=0.01, hole_center_height_m=0.012,
                             resolution_m=0.002)
    expected = 0.08 * 0.06 * 0.04 - math.pi * 0.005**2 * 0.08
    assert mesh.volume == pytest.approx(expected, abs=2 * math.pi * 0.005 * 0.08 * CHORD_M)
    assert not mesh.ray.intersects_any([[-0.1, 0.0, 0.012]], [[1.0, 0.0, 0.0]])[0]


# ---------------------------------------------------------------------------------------------
# make_workpiece: refusals
# ---------------------------------------------------------------------------------------------


def _one_line_error(fn, *args, **kwargs) -> str:
    with pytest.raises(TwinError) as info:
        fn(*args, **kwargs)
    message = str(info.value)
    assert "\n" not in message
    return message


def test_make_workpiece_refuses_unknown_name():
    message = _one_line_error(make_workpiece, "teapot")
    assert "'teapot'" in message
    for name in WORKPIECE_NAMES:
        assert name in message


@pytest.mark.parametrize(
    ("name", "wrong", "listed"),
    [
        ("through_hole", "hole_radius_m", ("hole_diameter_m", "block_length_m")),
        ("cube", "edge_m", ("side_m", "resolution_m")),
        ("cast_blank", "stock_mm", ("stock_m", "core_shift_m", "chord_tolerance_m")),
    ],
)
def test_make_workpiece_refuses_unknown_parameter(name, wrong, listed):
    # The generator's keyword signature is the schema, for every family of the registry.
    message = _one_line_error(make_workpiece, name, **{wrong: 0.01})
    assert f"'{wrong}'" in message and f"'{name}'" in message
    for key in listed:
        assert key in message


def test_registry_names_its_generators():
    import twin.parts

    assert len(set(WORKPIECE_NAMES)) == len(WORKPIECE_NAMES)
    for name in WORKPIECE_NAMES:
        assert name in twin.parts.__all__ and callable(getattr(twin.parts, name))


@pytest.mark.parametrize(
    ("name", "params", "fragment"),
    [
        ("through_hole", {"hole_diameter_m": -0.01}, "hole_diameter_m"),
        ("through_hole", {"hole_diameter_m": 0.039}, "2 mm walls"),
        ("hemisphere_punch", {"hemisphere_radius_m": 0.06}, "hemisphere"),
        ("hemisphere_punch", {"pin_radius_m": "big"}, "pin_radius_m"),
        ("bottle_punch", {"neck_radius_m": 0.024}, "neck_radius_m"),
        ("inner_sphere", {"sphere_radius_m": 0.049}, "sphere_radius_m"),
        ("inner_sphere", {"post_radius_m": 0.05}, "post_radius_m"),
        ("s_surface", {"amplitude_m": 0.03}, "base_thickness_m"),
        ("s_surface", {"resolution_m": float("nan")}, "resolution_m"),
        ("s_surface", {"resolution_m": 1e-5}, "resolution_m"),
    ],
)
def test_generators_refuse_bad_values(name, params, fragment):
    assert fragment in _one_line_error(make_workpiece, name, **params)


# ---------------------------------------------------------------------------------------------
# load_mesh
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def small_part() -> trimesh.Trimesh:
    return through_hole(resolution_m=0.003)


def _in_units(part: trimesh.Trimesh, units: str) -> trimesh.Trimesh:
    """A copy of the part with its coordinates in ``units`` ("m" or "mm")."""
    stored = part.copy()
    stored.apply_scale(1e3 if units == "mm" else 1.0)
    return stored


@pytest.mark.parametrize("ext", [".stl", ".ply", ".obj", ".STL"])
@pytest.mark.parametrize("units", ["m", "mm"])
def test_load_mesh_round_trips_with_scaling(tmp_path, small_part, ext, units):
    stored = _in_units(small_part, units)
    path = tmp_path / f"part{ext}"
    stored.export(path, file_type=ext[1:].lower())
    mesh = load_mesh(path, units)
    assert isinstance(mesh, trimesh.Trimesh)
    assert len(mesh.faces) == len(small_part.faces)
    assert np.allclose(mesh.bounds, small_part.bounds, rtol=0, atol=ROUND_TRIP_M)
    assert mesh.is_watertight
    assert mesh.volume == pytest.approx(small_part.volume, rel=1e-5)


@pytest.mark.parametrize("fmt", ["stl", "stl_ascii", "ply", "obj"])
@pytest.mark.parametrize("units", ["m", "mm"])
def test_read_mesh_holds_what_trimesh_processing_holds(tmp_path, small_part, fmt, units):
    # twin.formats.read_mesh parses STL and PLY with numpy and merges vertices itself: the
    # arrays must be exactly those of trimesh's load and merge (same vertices, same order, same faces)
    stored = _in_units(small_part, units)
    path = tmp_path / f"part.{fmt[:3]}"
    if fmt == "stl_ascii":
        path.write_text(trimesh.exchange.stl.export_stl_ascii(stored))
    else:
        stored.export(path)
    as_stored = trimesh.load(path, process=False)
    expected = trimesh.Trimesh(np.asarray(as_stored.vertices) * (1e-3 if units == "mm" else 1.0), as_stored.faces,
                               process=True)
    got = read_mesh(path, units)
    assert len(got.vertices) < 3 * len(got.faces)  # merged
    assert np.array_equal(got.vertices, expected.vertices)
    assert np.array_equal(got.faces, expected.faces)


def test_load_mesh_concatenates_a_scene(tmp_path):
    a = trimesh.creation.box((1.0, 1.0, 1.0))
    b = trimesh.creation.box((1.0, 1.0, 1.0))
    b.apply_translation((3.0, 0.0, 0.0))
    lines = []
    for k, (name, box) in enumerate((("a", a), ("b", b))):
        lines.append(f"o {name}")
        lines += [f"v {x} {y} {z}" for x, y, z in box.vertices]
        lines += [f"f {i + 1 + 8 * k} {j + 1 + 8 * k} {m + 1 + 8 * k}" for i, j, m in box.faces]
    path = tmp_path / "two.obj"
    path.write_text("\n".join(lines) + "\n")
    mesh = load_mesh(path, "mm")
    assert len(mesh.faces) == 24
    assert np.allclose(mesh.bounds, [[-0.0005, -0.0005, -0.0005], [0.0035, 0.0005, 0.0005]])


def test_load_mesh_refuses_missing_file(tmp_path):
    message = _one_line_error(load_mesh, tmp_path / "nowhere.stl", "mm")
    assert "not found" in message and "nowhere.stl" in message


def test_load_mesh_refuses_unsupported_extension(tmp_path):
    path = tmp_path / "part.iges"
    path.write_text("S      1\n")
    message = _one_line_error(load_mesh, path, "mm")
    assert "'.iges'" in message
    for ext in MESH_EXTENSIONS:
        assert ext in message


def test_load_mesh_refuses_bad_units(tmp_path, small_part):
    path = tmp_path / "part.stl"
    small_part.export(path)
    message = _one_line_error(load_mesh, path, "cm")
    assert "'cm'" in message and "'m'" in message and "'mm'" in message


@pytest.mark.parametrize(
    ("filename", "content"),
    [
        ("empty.stl", "solid empty\nendsolid empty\n"),
        ("nothing.stl", ""),
        ("points.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n"
                       "property float y\nproperty float z\nend_header\n0 0 0\n1 0 0\n0 1 0\n"),
        ("points.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n"),
    ],
)
def test_load_mesh_refuses_a_file_without_faces(tmp_path, filename, content):
    path = tmp_path / filename
    path.write_text(content)
    assert "no faces" in _one_line_error(load_mesh, path, "m")


def test_load_mesh_refuses_a_directory(tmp_path):
    folder = tmp_path / "folder.stl"
    folder.mkdir()
    assert "not a file" in _one_line_error(load_mesh, folder, "m")


def test_a_part_built_again_is_the_same_part_and_a_copy_of_its_own():
    # generated parts are built once per process: the second call returns an equal mesh, and
    # changing what one caller got does not change what the next one gets
    first = make_workpiece("through_hole")
    first.vertices += 1.0
    first.metadata["features"].clear()
    again = make_workpiece("through_hole")
    assert np.abs(again.vertices).max() < 0.5 and again.metadata["features"]
    # other parameters, another part
    wider = make_workpiece("through_hole", hole_diameter_m=0.03)
    assert wider.volume < again.volume
