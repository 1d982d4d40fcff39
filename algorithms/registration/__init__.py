"""Workpiece localization (registration of measured points to a CAD mesh).

``local`` (document 000's Algorithm 1 and document 001's fine stage), ``global_search``
(Algorithm 5's multistart, document 001's genetic algorithm, document 003's particle swarm),
``symmetric`` (Algorithm 2 and symmetry detection), ``hybrid`` (Algorithm 3),
``uncertainty`` (Fisher information, Cramer-Rao bound, observability) and ``subsampling``
(Algorithm 4).
"""
