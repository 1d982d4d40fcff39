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

# registration: tests/test_localization.py, test_cli_localize.py, test_global_search.py
RECOVER_M = 1e-6                # translation error after noise-free localization [m]
RECOVER_RAD = 1e-6              # rotation error after noise-free localization [rad]
RECOVER_FRACTION = 0.8          # a local method recovers at least 4 starts of 5 (the rest: local minima)
CRLB_RATIO_BAND = 0.10          # RMS pose error within 10 % of the Cramer-Rao bound
CRLB_DIAG_RTOL = 0.05           # reported covariance vs the bound at the truth (given sigma)
CRLB_DIAG_EST_RTOL = 0.15       # the same with sigma estimated from 4000 residuals
SIGMA_ESTIMATE_REL = 0.05       # sigma estimated from 4000 residuals vs the true one
OUTLIER_RECOVER_M = 1e-9        # exact inliers among gross outliers
OUTLIER_BIAS_M = 1e-5           # the same points with every outlier kept: the pose is off by more
EXACT_FIT_M = 1e-9              # RMS of a fit to exact points (plane, cylinder, a chained run)
ORTHONORMAL_TOL = 1e-12         # R^T R - I of a returned rotation
GLOBAL_NOISY_M = 5e-5           # global search, 150 points, sigma 20 um: a few um; 50 um is a gross failure
GLOBAL_NOISY_RAD = 1e-3
GLOBAL_CLOSE_RAD = 0.0175       # the swarm alone (before the polish): within 1 degree
GLOBAL_CLOSE_M = 1e-3           # ... and 1 mm
EQUAL_FIT_M = 1e-6              # RMS of each equally good pose of a symmetric part, exact points

# symmetric and hybrid localization: tests/test_symmetric.py, test_features.py, test_hybrid.py
FIXED_TOL = 1e-6                # Algorithm 2: fixed directions recovered (rad and m), exact data
DETECTED_RAD = 1e-3             # pose vs the truth modulo the detected G_0, 2 um noise [rad]
DETECTED_M = 1e-4               # ... [m]
SCAN_FIXED_RAD = 1e-4           # scanned parts: fixed directions vs the truth (noise, linearity)
SCAN_FIXED_M = 2e-5
SAME_RMS_REL = 1e-3             # equally good poses: RMS spread relative to the largest
ON_FEATURE_M = 1e-12            # points moved along g_0 stay on the feature
OFF_FEATURE_M = 1e-4            # a unit m_0 motion of 0.05 moves some point at least this far
FIT_M = 1e-9                    # fitted primitive parameters vs the generating ones (exact vertices)
FIT_AXIS_RAD = 1e-9
FEASIBLE_M = 1e-9               # every measured rough point keeps its allowance at the result
# Checked against the true part, the stock may fall short of the allowance by the measurement
# error of the points that bound it: noise (2 um at normal incidence, more when slanted) plus
# the sensor's +-10 um linearity band.
TRUE_ALLOWANCE_M = 2e-5

# uncertainty and closest points: tests/test_uncertainty.py, test_closest_point.py
WEAK_REL = 1e-10                # relative eigenvalue of an exactly unconstrained direction
CONVENTION_TOL = 1e-12          # log/exp round trip of the error twist
ON_MESH_REL = 1e-12             # distance of a point sampled on the mesh to its foot, / mesh size
BRUTE_FORCE_REL = 1e-12         # reported distance vs brute force over all triangles, / size
SCALE_REL = 1e-12               # answers of a mesh and its scaled copy, relative
EXACT_M = 1e-9                  # geometry recovered from exact data: a sphere's centre, a margin [m]
AXIS_TOL = 1e-6                 # a detected axis vs the design axis (unit vectors), scanned or exact
EXACT_AXIS_TOL = 1e-9           # ... from exact geometry (a model's symmetry axis)
DATUM_M = 1e-5                  # hybrid: the finished datum plane's height vs the truth (2 um noise)
DATUM_COS_TOL = 1e-9            # ... and 1 - cos of its tilt
LIMIT_MARGIN_M = 1e-6           # hybrid: the limiting points' margins equal the smallest one
MAX_MIN_OPTIMA_M = 5e-6         # hybrid: best margins reached from starts 1e-9..1e-4 apart (nearby local optima)
ORTHOGONAL_TOL = 1e-12          # g_0 and m_0 orthogonal; a unit twist's zero angular part
CLOSED_FORM_M = 1e-15           # analytic closest points (rounding only)
INVERSE_TOL = 1e-8              # C F = I for the Cramer-Rao bound and the information
NULL_REL = 1e-9                 # information rows along a weak direction, relative to their scale
SPAN_TOL = 1e-9                 # a motion rebuilt from the weak directions' basis
FOOT_DISTANCE_REL = 1e-15       # reported distance vs |point - foot|, relative to the mesh size
FACET_NORMAL_TOL = 1e-12        # reported normal vs the face normal
BACKEND_DISTANCE_M = 1e-15      # the numba and numpy backends: distances ...
BACKEND_FOOT_M = 1e-12          # ... and feet
SMOOTH_NORMAL_TOL = 1e-12       # smooth normals of a tessellated cylinder: radial

# tests/test_bayes.py and tests/test_env.py: localization with a prior, active scanning
MAP_EXACT_M = 1e-8              # noise-free points: pose recovered (translation, and rotation x 1 m)
MAP_PRIOR_HOLD_REL = 1e-6       # a direction the points leave free stays at the prior (relative)
MAP_BIAS_M = 1e-8               # per-group offsets recovered from noise-free points
INNOVATION_RMS_OK = 1.5         # right pose and covariance: RMS normalised innovation about 1
INNOVATION_RMS_WRONG = 10.0     # a pose 0.5 mm off: far above
ENV_CALIBRATION_SIGMAS = 5.0    # an active-scan episode's final error within this many posterior sigmas
