"""Document 000's Algorithm 1 as printed: ``localize(..., variant="printed")``.

Steps 3-5 of the document and nothing else: the feet of every point at the current pose
(exact closest points on the mesh; the document solves them by Newton on the parametric
surface), the method's pose update from all the pairs, and the stopping test

    1 - eps_k / eps_(k-1) < delta

taken after each update (``eps`` the mean squared distance; ``delta`` the method's
``tolerance``). For ``fine_001`` document 001's own test, its step ``sum dtheta^2 + sum dDelta^2
< d``. The pose the test stops at is the answer, also after an update that raised ``eps`` (the
test holds then: ``1 - eps_k / eps_(k-1) < 0``).

Left out, as the document has none of them: the outlier rule (every point is used), the
halving of an update that raises the residual and the point-to-point or edge-offset fallback
steps, Hong-Tan's stop before an update of a fraction of its standard deviation, the subset
stage for many points, and the restarts from a wrong minimum (:mod:`.escape`). The verdict on
the pose (the fit check, the observability, the covariance) is the library's, as for every
variant. ``menq`` is its Levenberg-Marquardt step at the initial damping ``LM_LAMBDA0``, taken
as it is (the damping schedule and the acceptance test are ours).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from algorithms.arraytypes import FloatArray, Pose
from algorithms.geometry.mesh_index import ClosestPoints, MeshIndex
from algorithms.geometry.se3 import inv_pose, transform_points
from algorithms.registration.iteration_state import LocalFit
from algorithms.registration.robust import ALL

__all__ = ["VARIANTS", "iterate_printed"]

Update = Callable[[Pose, FloatArray, ClosestPoints], tuple[Pose, float | None]]

#: ``localize``'s variants: ``"ours"`` (the module docstring of :mod:`.local`) and ``"printed"``.
VARIANTS = ("ours", "printed")


def iterate_printed(method: str, update: Update, Y: FloatArray, index: MeshIndex, T0: Pose, max_it: int,
                    tol: float, floor2: float) -> LocalFit:
    """Algorithm 1 as printed (module docstring) from ``T0`` on the world points ``Y`` (M, 3) [m].

    Args:
        method: one of :data:`algorithms.registration.local.METHODS` (its stopping test).
        update: the method's pose update, ``(T, Ym, feet) -> (next T, its step measure or None)``.
        max_it: the most pose updates; tol: ``delta`` (``d`` for fine_001).
        floor2: a mean squared distance at or below which the fit is exact [m^2] (the test's
            ratio is then undefined; it stops).
    """

    def feet(T: Pose) -> tuple[ClosestPoints, FloatArray]:
        Ym = transform_points(inv_pose(T), Y)
        return index.query(Ym), Ym

    T = np.asarray(T0, dtype=np.float64)
    cp, Ym = feet(T)
    e_prev = float(np.mean(cp.distance**2))
    history, poses = [float(np.sqrt(e_prev))], [T]
    status, converged = f"not converged: reached max_iterations = {max_it}", False
    for k in range(1, max_it + 1):
        if e_prev <= floor2:
            status, converged = "converged: an exact fit (the residual at the floor)", True
            break
        T, step = update(T, Ym, cp)
        cp, Ym = feet(T)
        e = float(np.mean(cp.distance**2))
        history.append(float(np.sqrt(e)))
        poses.append(T)
        if method == "fine_001" and step is not None and step < tol:
            status, converged = f"converged after {k} update(s): document 001's step below d = {tol:g}", True
            break
        if method != "fine_001" and 1.0 - e / e_prev < tol:
            status, converged = f"converged after {k} update(s): 1 - eps_k / eps_(k-1) < {tol:g}", True
            break
        e_prev = e
    return LocalFit(T=T, cp=cp, mask=ALL, history=tuple(history), poses=tuple(poses), iterations=len(poses) - 1,
                    converged=converged, status=f"Algorithm 1 as printed: {status}")
