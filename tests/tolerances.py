"""Named numeric tolerances used across the tests."""

FK_AGREEMENT_M = 1e-12          # DH product vs MuJoCo forward kinematics
ON_SURFACE_M = 1e-6             # noise-off reconstructed point to true mesh
ANALYTIC_DISTANCE_M = 1e-9      # reported distance vs analytic plane/sphere distance
RECORDING_FLOAT32_M = 1e-6      # a position read back from a rerun recording (float32) vs float64

# tests/test_run.py: bars of the issue (default S-surface scenario, IL-065 noise on)
MAX_DEVIATION_MM = 0.5          # replayed tool path vs the planned one
MAX_SURFACE_ERROR_MM = 0.05     # reconstructed surface vs the true part
TRIANGULATION_RMS_DEG = 2.0     # RMS of the triangulation normals vs the true normals

# tests/test_trajectory.py
LIMIT_RATIO = 1.0 + 1e-9        # joint velocity/acceleration over its limit (time law)
FEED_REL = 1e-3                 # TCP speed on a process line vs the feed, relative

# tests/test_toolpath.py
ORTHONORMAL = 1e-12             # R^T R - I of a tool frame
ON_MESH_M = 2e-6                # S-surface chord error against the analytic top (mesh default: < 2 um)
NORMAL_DEG = 0.05               # CAD raster smooth normals against the analytic normals

# tests/test_normals.py
EXACT_DEG = 1e-5                # planar data: the floor of arccos near 1 in float64
TRIANGULATION_BAR_DEG = 2.0     # issue bar: RMS against the true normals, S-surface, noise off

# tests/test_pointcloud.py
ON_TRUE_SURFACE_M = 1e-4        # bar: noise-off contact points on the true surface
ANALYTIC_CURVE_M = 1e-6         # B-spline fit of an exact smooth curve
EVEN_SPACING_REL = 1e-3         # resampled spacing vs the requested one
