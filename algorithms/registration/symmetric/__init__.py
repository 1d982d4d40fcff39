"""Localization of symmetric parts (document 000, section 4).

The feature table and symmetry subgroups ``G_0`` (:mod:`.groups`), features as geometry and
primitives fitted to mesh faces (:mod:`.features`), the subgroup the data leave free
(:mod:`.detect`), a model's discrete symmetries and pseudo-normals (:mod:`.discrete`),
Algorithm 2 on the quotient ``SE(3)/G_0`` (:mod:`.quotient`) and the whole pipeline
(:mod:`.pipeline`).
"""

from algorithms.registration.symmetric.detect import DETECTION_TOL, MATCH_TOL, SymmetryDetection, detect_symmetry
from algorithms.registration.symmetric.discrete import SYMMETRY_TOL_REL, model_symmetries, pseudo_normals
from algorithms.registration.symmetric.features import (
    EXTRUDED_TOL_RAD,
    FIT_NORMAL_TOL_RAD,
    FIT_TOL_REL,
    Feature,
    FeatureProjection,
    make_feature,
)
from algorithms.registration.symmetric.groups import (
    FEATURE_TABLE,
    FEATURE_TYPES,
    FeatureInfo,
    SymmetryGroup,
    check_feature_type,
    other_group,
    symmetry_group,
)
from algorithms.registration.symmetric.pipeline import SAME_SOLUTION_TOL, SYMMETRIC_CHOICES, localize_symmetric
from algorithms.registration.symmetric.quotient import SymmetricResult, algorithm2

__all__ = [
    "DETECTION_TOL",
    "EXTRUDED_TOL_RAD",
    "FEATURE_TABLE",
    "FEATURE_TYPES",
    "FIT_NORMAL_TOL_RAD",
    "FIT_TOL_REL",
    "MATCH_TOL",
    "SAME_SOLUTION_TOL",
    "SYMMETRIC_CHOICES",
    "SYMMETRY_TOL_REL",
    "Feature",
    "FeatureInfo",
    "FeatureProjection",
    "SymmetricResult",
    "SymmetryDetection",
    "SymmetryGroup",
    "algorithm2",
    "check_feature_type",
    "detect_symmetry",
    "localize_symmetric",
    "make_feature",
    "model_symmetries",
    "other_group",
    "pseudo_normals",
    "symmetry_group",
]
