"""Pure numerical algorithms: localization, sampling, point clouds, paths.

Depends on numpy, scipy and trimesh only; never imports ``twin``, MuJoCo or rerun,
so it runs unchanged on scans from a real robot.
"""

from algorithms.errors import AlgorithmError

__all__ = ["AlgorithmError"]
