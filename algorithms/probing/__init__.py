"""Touch probing: the trigger model of a kinematic probe, probe qualification and radius
compensation, and planned fine probe points.

Pure numerics (numpy, scipy, trimesh): no simulator, IK or viewer imports. Modules:
``pretravel`` (direction-dependent pre-travel and repeatability), ``qualification``
(reference-sphere qualification, compensation along the normal, cosine error) and
``point_planning`` (candidate points, reachability by a probe with a fixed stylus direction,
D-optimal choice of the points).
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
