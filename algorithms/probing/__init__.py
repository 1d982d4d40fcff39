"""Touch probing: the trigger model of a kinematic probe, probe qualification and radius
compensation, planned fine probe points, and CMM measurement programs (document 002).

Pure numerics (numpy, scipy, trimesh, python-fcl): no simulator, IK or viewer imports. Modules:
``pretravel`` (direction-dependent pre-travel and repeatability), ``qualification``
(reference-sphere qualification, compensation along the normal, cosine error),
``point_planning`` (candidate points, reachability by a probe with a fixed stylus direction,
D-optimal choice of the points), ``program`` (a measurement program's statements),
``dmis`` (DMIS 5 text out and in), ``safety_plane`` (document 002's definitions and a taught
path's penetrations), ``sweep`` (a probe's straight moves swept against the exact mesh) and
``cmm_planning`` (the safe-plane baseline, document 002's planner, the full-check variant).
"""

from algorithms.probing.point_planning import (
    REASONS,
    Candidates,
    Feasibility,
    d_optimal,
    feasible_candidates,
    log_det_information,
    predicted_pose_std,
    random_points,
    sample_candidates,
    spread_points,
)
from algorithms.probing.pretravel import PretravelModel
from algorithms.probing.qualification import (
    Qualification,
    SphereFit,
    compensate,
    cosine_error_m,
    fit_sphere,
    qualification_directions,
    qualify_ball,
)

__all__ = [
    "REASONS",
    "Candidates",
    "Feasibility",
    "PretravelModel",
    "Qualification",
    "SphereFit",
    "compensate",
    "cosine_error_m",
    "d_optimal",
    "feasible_candidates",
    "fit_sphere",
    "log_det_information",
    "predicted_pose_std",
    "qualification_directions",
    "qualify_ball",
    "random_points",
    "sample_candidates",
    "spread_points",
]
