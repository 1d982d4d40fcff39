"""Workpiece localization (registration of measured points to a CAD mesh).

One result family (:mod:`.result`: :class:`RegistrationResult` and :class:`Status`), shared
input checks (:mod:`.inputs`) and outlier rules (:mod:`.robust`), and the methods: ``local``
(document 000's Algorithm 1 and document 001's fine stage, from a given start),
``global_search`` (Algorithm 5's multistart, document 001's genetic algorithm, document
003's particle swarm: from any start), ``symmetric`` (Algorithm 2 and symmetry detection),
``hybrid`` (Algorithm 3), ``uncertainty`` (Fisher information, Cramer-Rao bound,
observability) and ``subsampling`` (Algorithm 4).

The local module never imports the global search; the global search polishes with the local
module; the symmetric and hybrid methods start from a given pose.
"""

from algorithms.registration.global_search import GlobalLocalizationResult, global_localize
from algorithms.registration.hybrid import HybridResult, localize_hybrid
from algorithms.registration.local import localize
from algorithms.registration.result import RegistrationResult, Status
from algorithms.registration.symmetric import SymmetricResult, localize_symmetric

__all__ = [
    "GlobalLocalizationResult",
    "HybridResult",
    "RegistrationResult",
    "Status",
    "SymmetricResult",
    "global_localize",
    "localize",
    "localize_hybrid",
    "localize_symmetric",
]
