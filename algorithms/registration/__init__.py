"""Workpiece localization (registration of measured points to a CAD mesh).

One result family (:mod:`.result`: :class:`RegistrationResult` and :class:`Status`), shared
input checks (:mod:`.inputs`) and outlier rules (:mod:`.robust`), and the methods: ``local``
(document 000's Algorithm 1 and document 001's fine stage, from a given start),
``global_search`` (Algorithm 5's multistart, document 001's genetic algorithm, document
003's particle swarm: from any start), ``symmetric`` (Algorithm 2 and symmetry detection),
``hybrid`` (Algorithm 3), ``uncertainty`` (Fisher information, Cramer-Rao bound,
observability) and ``subsampling`` (Algorithm 4).

The local module never imports the global search; the global search polishes with the local
module; ``review`` (the package's ``localize``) reviews a local fit's rejected points with the
global search; the symmetric and hybrid methods start from a given pose.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from algorithms.registration.global_search import GlobalLocalizationResult, global_localize
    from algorithms.registration.hybrid import HybridResult, localize_hybrid
    from algorithms.registration.result import RegistrationResult, Status
    from algorithms.registration.review import localize
    from algorithms.registration.symmetric import SymmetricResult, localize_symmetric

#: Where each name of the package lives; a method's module is imported on first use, so that
#: ``from algorithms.registration import localize`` does not load the global searches.
_HOMES = {
    "GlobalLocalizationResult": "global_search", "global_localize": "global_search",
    "HybridResult": "hybrid", "localize_hybrid": "hybrid",
    "localize": "review",
    "RegistrationResult": "result", "Status": "result",
    "SymmetricResult": "symmetric", "localize_symmetric": "symmetric",
}


def __getattr__(name: str) -> Any:
    if name in _HOMES:
        return getattr(importlib.import_module(f"algorithms.registration.{_HOMES[name]}"), name)
    raise AttributeError(f"module 'algorithms.registration' has no attribute {name!r}")


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
