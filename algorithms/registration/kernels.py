"""The compiled (numba) parts of the local iteration (:mod:`algorithms.registration.local`):
the point-to-plane normal equations, the 6x6 minimum-norm solve, and Hong-Tan's plain
iterations (:func:`run`, see ``local._plain_steps``).

Module-level functions, so that numba's disk cache finds them again in the next process (the
same functions defined in a closure are compiled anew in every process). Without numba every
name below is None and the library uses numpy.
"""

from __future__ import annotations

from types import ModuleType
from typing import Any

import numpy as np

from algorithms.geometry.bvh_kernels import query_kernels
from algorithms.registration.robust import MAD_TO_SIGMA

_numba: ModuleType | None
try:
    import numba as _numba
except ImportError:  # pragma: no cover - depends on the environment
    _numba = None

__all__ = ["EDGE_COS_TOL", "plane_system", "solve", "settled", "run"]

#: A foot whose offset ``y - x`` is off its face's normal by more than this (1 - cos^2) lies on
#: an edge or a vertex: with ``edges`` its row of the point-to-plane system uses the direction
#: of the offset.
EDGE_COS_TOL = 1e-9

plane_system: Any = None
solve: Any = None
settled: Any = None
run: Any = None

if _numba is not None:
    _tree, _near = query_kernels()

    @_numba.njit(cache=True, nogil=True)
    def plane_system(Y, X, N, sel, edges):  # pragma: no cover - compiled
        n = Y.shape[0]
        c = np.zeros(3)
        m = 0
        for i in range(n):
            if sel[i]:
                for k in range(3):
                    c[k] += Y[i, k]
                m += 1
        for k in range(3):
            c[k] /= max(m, 1)
        A = np.zeros((6, 6))
        g = np.zeros(6)
        row = np.empty(6)
        for i in range(n):
            if not sel[i]:
                continue
            ux = Y[i, 0] - c[0]
            uy = Y[i, 1] - c[1]
            uz = Y[i, 2] - c[2]
            nx = N[i, 0]
            ny = N[i, 1]
            nz = N[i, 2]
            dx = Y[i, 0] - X[i, 0]
            dy = Y[i, 1] - X[i, 1]
            dz = Y[i, 2] - X[i, 2]
            s = dx * nx + dy * ny + dz * nz
            d2 = dx * dx + dy * dy + dz * dz
            if edges and s * s < (1.0 - EDGE_COS_TOL) * d2:
                # the foot is on an edge or a vertex: the distance grows along y - x, not
                # along the face's normal
                d = np.sqrt(d2)
                nx = dx / d
                ny = dy / d
                nz = dz / d
                s = d
            row[0] = uy * nz - uz * ny
            row[1] = uz * nx - ux * nz
            row[2] = ux * ny - uy * nx
            row[3] = nx
            row[4] = ny
            row[5] = nz
            for a in range(6):
                g[a] += row[a] * s
                for b in range(a, 6):
                    A[a, b] += row[a] * row[b]
        for a in range(6):
            for b in range(a):
                A[a, b] = A[b, a]
        return A, g, c


    @_numba.njit(cache=True, nogil=True)
    def jacobi_eigh(B):  # pragma: no cover - compiled
        """Eigenvalues (ascending) and vectors of a small symmetric matrix (cyclic Jacobi;
        compiles in a fraction of the time of numba's LAPACK binding)."""
        n = B.shape[0]
        a = B.copy()
        V = np.zeros((n, n))
        for k in range(n):
            V[k, k] = 1.0
        for _sweep in range(50):
            off = 0.0
            for p in range(n):
                for q in range(p + 1, n):
                    off += a[p, q] * a[p, q]
            if off <= 1e-300:
                break
            for p in range(n):
                for q in range(p + 1, n):
                    apq = a[p, q]
                    if apq == 0.0:
                        continue
                    tau = (a[q, q] - a[p, p]) / (2.0 * apq)
                    t = (1.0 if tau >= 0.0 else -1.0) / (abs(tau) + np.sqrt(1.0 + tau * tau))
                    cs = 1.0 / np.sqrt(1.0 + t * t)
                    sn = t * cs
                    for k in range(n):
                        akp = a[k, p]
                        akq = a[k, q]
                        a[k, p] = cs * akp - sn * akq
                        a[k, q] = sn * akp + cs * akq
                    for k in range(n):
                        apk = a[p, k]
                        aqk = a[q, k]
                        a[p, k] = cs * apk - sn * aqk
                        a[q, k] = sn * apk + cs * aqk
                    for k in range(n):
                        vkp = V[k, p]
                        vkq = V[k, q]
                        V[k, p] = cs * vkp - sn * vkq
                        V[k, q] = sn * vkp + cs * vkq
        w = np.empty(n)
        for k in range(n):
            w[k] = a[k, k]
        sort_ascending(w, V)
        return w, V

    @_numba.njit(cache=True, nogil=True)
    def sort_ascending(w, V):  # pragma: no cover - compiled
        """Sort the eigenvalues ``w`` ascending in place, with their vectors (the columns of
        ``V``): an insertion sort, n is 6."""
        n = w.shape[0]
        for i in range(n):
            j = i
            while j > 0 and w[j - 1] > w[j]:
                w[j - 1], w[j] = w[j], w[j - 1]
                for k in range(n):
                    V[k, j - 1], V[k, j] = V[k, j], V[k, j - 1]
                j -= 1

    @_numba.njit(cache=True, nogil=True)
    def solve(A, g):  # pragma: no cover - compiled
        """_solve(A, g) in one compiled call: the same scaling, minimum-norm truncation and
        result to about 1e-14 relative (the centred step itself stays in numpy: a fit that leaves
        directions free follows its round-off, and the tests pin that path)."""
        d = np.empty(6)
        for k in range(6):
            d[k] = np.sqrt(A[k, k]) if A[k, k] > 0.0 else 1.0
        B = np.empty((6, 6))
        for i in range(6):
            for j in range(6):
                B[i, j] = A[i, j] / d[i] / d[j]
        w, V = jacobi_eigh(B)
        gs = g / d
        xi = np.zeros(6)
        for k in range(6):
            if w[k] > w[5] * 1e-13:
                coef = 0.0
                for i in range(6):
                    coef += V[i, k] * gs[i]
                coef /= w[k]
                for i in range(6):
                    xi[i] += V[i, k] * coef
        xi /= d
        return xi


    @_numba.njit(cache=True, nogil=True)
    def upper_median(d):  # pragma: no cover - compiled
        k = len(d) // 2
        return np.partition(d, k)[k]

    @_numba.njit(cache=True, nogil=True)
    def inliers(d, mode, k, floor, fixed, min_points, sel):  # pragma: no cover - compiled
        """robust.inlier_mask into sel; True when it is every point (ALL)."""
        n = len(d)
        if mode == 0:
            sel[:] = True
            return True
        thr = max(k * MAD_TO_SIGMA * upper_median(d), floor) if mode == 1 else fixed
        m = 0
        for i in range(n):
            sel[i] = d[i] <= thr
            m += sel[i]
        if m == n:
            return True
        if m < min_points:
            med = upper_median(d)
            for i in range(n):
                sel[i] = d[i] <= med
        return False

    @_numba.njit(cache=True, nogil=True)
    def mse(d, sel):  # pragma: no cover - compiled
        s = 0.0
        m = 0
        for i in range(len(d)):
            if sel[i]:
                s += d[i] * d[i]
                m += 1
        return s / m

    @_numba.njit(cache=True, nogil=True)
    def centered(T, c, xi):  # pragma: no cover - compiled
        """_centered: T A_c exp(xi) A_c^-1 = T [R, c + V v - R c]."""
        wx, wy, wz = xi[0], xi[1], xi[2]
        th2 = wx * wx + wy * wy + wz * wz
        th = np.sqrt(th2)
        if th < 1e-9:
            a, b, cc = 1.0, 0.5, 1.0 / 6.0
        else:
            a = np.sin(th) / th
            b = (1.0 - np.cos(th)) / th2
            cc = (th - np.sin(th)) / (th2 * th)
        W = np.array([[0.0, -wz, wy], [wz, 0.0, -wx], [-wy, wx, 0.0]])
        WW = W @ W
        R = np.eye(3) + a * W + b * WW
        V = np.eye(3) + b * W + cc * WW
        D = np.eye(4)
        D[:3, :3] = R
        D[:3, 3] = c + V @ xi[3:] - R @ c
        return T @ D

    @_numba.njit(cache=True, nogil=True)
    def feet(Y, T, hint, shrink, use_near, anchor, nfaces, reach, data, leaf_data, nodes_f, nodes_i,
             hint_map, perm, normals):  # pragma: no cover - compiled
        """feet.Feet at the pose T: the points in the model frame and their closest points."""
        n = Y.shape[0]
        Ym = np.empty((n, 3))
        for i in range(n):
            x = Y[i, 0] - T[0, 3]
            y = Y[i, 1] - T[1, 3]
            z = Y[i, 2] - T[2, 3]
            for k in range(3):
                Ym[i, k] = T[0, k] * x + T[1, k] * y + T[2, k] * z
        face = np.empty(n, np.int64)
        foot = np.empty((n, 3))
        dist = np.empty(n)
        normal = np.empty((n, 3))
        if use_near:
            _near(Ym, anchor, nfaces, reach, data, leaf_data, nodes_f, nodes_i, hint_map, perm, normals, face,
                  foot, dist, normal, np.zeros(n, np.uint8))
        else:
            _tree(Ym, hint, data, leaf_data, nodes_f, nodes_i, hint_map, perm, normals, face, foot, dist,
                  normal, shrink)
        return Ym, foot, dist, face, normal

    @_numba.njit(cache=True, nogil=True)
    def settled(Ym, foot, normal, sel, g, xi, e, stop_m2):  # pragma: no cover - compiled
        """Whether the update ``xi`` (of the system ``A xi = g`` from these feet) and the one
        with the rows of feet on edges along their offsets would both lower the sum of squares
        by less than ``stop_m2`` sigma^2: move the pose by less than sqrt(stop_m2) of its
        standard deviation (sigma^2 estimated from the mean square ``e`` of the selected
        points; the decrease a step predicts is ``g^T xi``)."""
        m = 0
        for i in range(sel.shape[0]):
            m += sel[i]
        bound = stop_m2 * e * m / max(m - 6, 1)
        if np.dot(g, xi) >= bound:
            return False
        A_e, g_e, _c = plane_system(Ym, foot, normal, sel, True)
        return np.dot(g_e, solve(A_e, g_e)) < bound

    @_numba.njit(cache=True, nogil=True)
    def run(Y, T, Ym, foot, dist, face, normal, approx, sel, all_sel, e_prev, max_steps, floor2, tol, stop_m2,
            mode, k, floor, fixed, min_points, far, far_m2, shrink_far, use_near, anchor, nfaces, reach, data,
            leaf_data, nodes_f, nodes_i, hint_map, perm, normals):  # pragma: no cover - compiled
        """The plain Hong-Tan iterations of _iterate (see _plain_steps); sel is updated in place.
        Stops before a step when :func:`settled` (exact feet only; the last output True)."""
        n = Y.shape[0]
        hist = np.empty(max(max_steps, 0))
        poses = np.empty((max(max_steps, 0), 4, 4))
        new_sel = np.empty(n, np.bool_)
        m = 0
        while m < max_steps:
            A, g, c = plane_system(Ym, foot, normal, sel, False)
            xi = solve(A, g)
            if not approx and settled(Ym, foot, normal, sel, g, xi, e_prev, stop_m2):
                return (m, T, Ym, foot, dist, face, normal, approx, all_sel, e_prev, hist, poses, far,
                        False, T, Ym, foot, dist, face, normal, approx, e_prev, True)
            T_t = centered(T, c, xi)
            shrink = shrink_far if (far and not use_near) else 1.0
            Ym_t, foot_t, dist_t, face_t, normal_t = feet(Y, T_t, face, shrink, use_near, anchor, nfaces,
                                                          reach, data, leaf_data, nodes_f, nodes_i,
                                                          hint_map, perm, normals)
            approx_t = shrink < 1.0
            far_t = far
            if approx_t:
                ss = 0.0
                for i in range(n):
                    ss += dist_t[i] * dist_t[i]
                far_t = ss > far_m2 * n
            e_t = mse(dist_t, sel)
            plain = e_t <= e_prev
            if plain:
                all_new = inliers(dist_t, mode, k, floor, fixed, min_points, new_sel)
                changed = all_new != all_sel or (not all_new and not np.array_equal(new_sel, sel))
                e_next = mse(dist_t, new_sel)
                rel = 1.0 - e_t / e_prev if e_prev > 0 else 0.0
                plain = e_next > floor2 and (changed or not rel < tol)
            far = far_t
            if not plain:
                return (m, T, Ym, foot, dist, face, normal, approx, all_sel, e_prev, hist, poses, far,
                        True, T_t, Ym_t, foot_t, dist_t, face_t, normal_t, approx_t, e_t, False)
            T, Ym, foot, dist, face, normal, approx = T_t, Ym_t, foot_t, dist_t, face_t, normal_t, approx_t
            sel[:] = new_sel
            all_sel = all_new
            e_prev = e_next
            hist[m] = np.sqrt(e_t)
            poses[m] = T
            m += 1
        return (m, T, Ym, foot, dist, face, normal, approx, all_sel, e_prev, hist, poses, far,
                False, T, Ym, foot, dist, face, normal, approx, e_prev, False)
