"""Named numeric tolerances used across the tests."""

FK_AGREEMENT_M = 1e-12          # DH product vs MuJoCo forward kinematics
ON_SURFACE_M = 1e-6             # noise-off reconstructed point to true mesh
ANALYTIC_DISTANCE_M = 1e-9      # reported distance vs analytic plane/sphere distance
RECORDING_FLOAT32_M = 1e-6      # a position read back from a rerun recording (float32) vs float64
