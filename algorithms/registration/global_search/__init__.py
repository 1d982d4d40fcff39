"""Global localization from any initial pose.

One entry point, :func:`global_localize` (:mod:`.search`), and its parts: the nearest-surface
oracles (:mod:`.fields`), document 000's Algorithm 5 (:mod:`.multistart`), document 001's
genetic algorithm (:mod:`.genetic`), document 003's particle swarm (:mod:`.pso`) and the
hypothesis verification (:mod:`.verify`).
"""

from algorithms.registration.global_search.genetic import (
    FINE_001_D,
    FINE_001_MAX_ITERATIONS,
    GA_BITS,
    GA_CROSSOVER_PROB,
    GA_FITNESS_STOP,
    GA_GENERATIONS,
    GA_MUTATION_PROB,
    GA_POPULATION,
    GeneticDiagnostics,
)
from algorithms.registration.global_search.multistart import (
    CONVERGENCE_RADIUS_DEG,
    LIU2001_START_ANGLES_DEG,
    NOISE_ACCEPT_FACTOR,
    PERTURBATION_STEPS_DEG,
    orientation_table,
)
from algorithms.registration.global_search.pso import (
    PSO_C1_FINAL,
    PSO_C1_INITIAL,
    PSO_C2_FINAL,
    PSO_C2_INITIAL,
    PSO_ITERATIONS,
    PSO_PARTICLES,
    PSO_W_MAX,
    PSO_W_MIN,
    PSODiagnostics,
)
from algorithms.registration.global_search.search import (
    DEFAULT_MODEL_ERROR_M,
    DEFAULT_POLISH,
    GLOBAL_METHODS,
    GlobalDiagnostics,
    GlobalLocalizationResult,
    global_localize,
    pso_refine,
)
from algorithms.registration.global_search.verify import (
    AMBIGUITY_CHI2,
    DISTINCT_ROTATION_RAD,
    DISTINCT_TRANSLATION_FRAC,
)

__all__ = [
    "pso_refine",
    "AMBIGUITY_CHI2",
    "CONVERGENCE_RADIUS_DEG",
    "DEFAULT_MODEL_ERROR_M",
    "DEFAULT_POLISH",
    "DISTINCT_ROTATION_RAD",
    "DISTINCT_TRANSLATION_FRAC",
    "FINE_001_D",
    "FINE_001_MAX_ITERATIONS",
    "GA_BITS",
    "GA_CROSSOVER_PROB",
    "GA_FITNESS_STOP",
    "GA_GENERATIONS",
    "GA_MUTATION_PROB",
    "GA_POPULATION",
    "GLOBAL_METHODS",
    "GeneticDiagnostics",
    "GlobalDiagnostics",
    "GlobalLocalizationResult",
    "LIU2001_START_ANGLES_DEG",
    "NOISE_ACCEPT_FACTOR",
    "PERTURBATION_STEPS_DEG",
    "PSODiagnostics",
    "PSO_C1_FINAL",
    "PSO_C1_INITIAL",
    "PSO_C2_FINAL",
    "PSO_C2_INITIAL",
    "PSO_ITERATIONS",
    "PSO_PARTICLES",
    "PSO_W_MAX",
    "PSO_W_MIN",
    "global_localize",
    "orientation_table",
]
