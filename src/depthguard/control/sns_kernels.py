"""Compiled kernels of the SNS solver (:mod:`depthguard.control.sns`, whose docstring gives the algorithm):
the largest task scale the free joints allow (``_task_scale``), the greedy saturation loop of Algorithm 1 with
the task scaling of Algorithm 2 (``_sns_greedy``), and the exact fallback for a task inside the zonotope
``Z = J [qmin, qmax]`` that the greedy search misses (``_zonotope_point`` and its facet helpers).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from depthguard.control.linalg import _damped_pinv, _masked, _mv


@njit(cache=True, nogil=True)
def _task_scale(
    a: np.ndarray, b: np.ndarray, qmin: np.ndarray, qmax: np.ndarray, free: np.ndarray
) -> tuple[float, int]:
    """Largest s in [0, 1] with ``qmin <= s a + b <= qmax`` on the free joints (SNS Algorithm 2).

    Returns the scale (0 when no s in [0, 1] is feasible) and the most critical joint (-1 if none).
    """
    lo, hi, crit = -np.inf, np.inf, -1
    for i in range(a.shape[0]):
        if not free[i]:
            continue
        smin = qmin[i] - b[i]
        smax = qmax[i] - b[i]
        if a[i] > 1e-12:
            l_i, h_i = smin / a[i], smax / a[i]
        elif a[i] < -1e-12:
            l_i, h_i = smax / a[i], smin / a[i]
        else:
            continue
        if l_i > lo:
            lo = l_i
        if h_i < hi:
            hi, crit = h_i, i
    if hi > 1.0:
        hi = 1.0
    if lo > hi or hi < 0.0:
        return 0.0, crit
    return hi, crit


@njit(cache=True, nogil=True)
def _violates(qdot: np.ndarray, qmin: np.ndarray, qmax: np.ndarray, tol: float) -> bool:
    """True if some ``qdot[i]`` is outside ``[qmin[i] - tol, qmax[i] + tol]`` or NaN."""
    for i in range(qdot.shape[0]):
        if not (qmin[i] - tol <= qdot[i] <= qmax[i] + tol):
            return True
    return False


@njit(cache=True, nogil=True)
def _sns_greedy(
    J: np.ndarray, xdot: np.ndarray, qmin: np.ndarray, qmax: np.ndarray, damping: float
) -> tuple[np.ndarray, float]:
    """SNS Algorithm 1 (greedy saturation of the most critical joint)."""
    m, n = J.shape
    tol = 1e-10
    free = np.ones(n, dtype=np.bool_)
    qN = np.zeros(n)
    best_s, best_free, best_qN = -1.0, free.copy(), qN.copy()
    rank0 = -1
    for _ in range(n + 1):
        JW = _masked(J, free)
        P, rank = _damped_pinv(JW, damping, 1e-10)
        if rank0 < 0:
            rank0 = rank
        elif rank < rank0:
            break  # the free joints cannot realise the task any more: use the best scaled solution
        qdot = qN + _mv(P, xdot - _mv(J, qN))
        if not _violates(qdot, qmin, qmax, tol):
            return qdot, 1.0
        a = _mv(P, xdot)
        b = qdot - a
        s, j = _task_scale(a, b, qmin, qmax, free)
        if s > best_s:
            best_s, best_free, best_qN = s, free.copy(), qN.copy()
        # saturate the most critical joint (or, failing that, the worst violator) at the bound it hits
        if j < 0:
            worst = 0.0
            for i in range(n):
                v = max(qdot[i] - qmax[i], qmin[i] - qdot[i])
                if free[i] and v > worst:
                    worst, j = v, i
            if j < 0:
                break
        if qdot[j] > qmax[j]:
            qN[j] = qmax[j]
        elif qdot[j] < qmin[j]:
            qN[j] = qmin[j]
        else:
            qN[j] = qmax[j] if a[j] > 0 else qmin[j]
        free[j] = False
        if not free.any():
            break
    if best_s < 0.0:
        return np.zeros(n), 0.0
    JW = _masked(J, best_free)
    P, _ = _damped_pinv(JW, damping, 1e-10)
    qdot = best_qN + _mv(P, best_s * xdot - _mv(J, best_qN))
    return qdot, best_s


@njit(cache=True, nogil=True)
def _facet_normal_into(J: np.ndarray, cols: np.ndarray, nrm: np.ndarray) -> None:
    """Unit normal of the span of the m-1 columns ``cols`` of J (m, n) into ``nrm`` (m,); zeros if they are
    dependent. Scalar loops, no temporaries (it runs for every (m-1)-subset of columns)."""
    m = J.shape[0]
    for i in range(m):
        nrm[i] = 0.0
    if m == 1:
        nrm[0] = 1.0
        return
    if m == 2:
        nrm[0], nrm[1] = -J[1, cols[0]], J[0, cols[0]]
    elif m == 3:
        a, b = cols[0], cols[1]
        nrm[0] = J[1, a] * J[2, b] - J[2, a] * J[1, b]
        nrm[1] = J[2, a] * J[0, b] - J[0, a] * J[2, b]
        nrm[2] = J[0, a] * J[1, b] - J[1, a] * J[0, b]
    else:  # generalised cross product by cofactors
        # (element by element: slice copies compile numba's shape-mismatch message, seconds of a cold start)
        A = np.empty((m - 1, m))
        for r in range(m - 1):
            for k in range(m):
                A[r, k] = J[k, cols[r]]
        for i in range(m):
            minor = np.empty((m - 1, m - 1))
            c = 0
            for k in range(m):
                if k != i:
                    for r in range(m - 1):
                        minor[r, c] = A[r, k]
                    c += 1
            nrm[i] = (-1.0) ** i * np.linalg.det(minor)
    norm2 = 0.0
    for i in range(m):
        norm2 += nrm[i] * nrm[i]
    norm = np.sqrt(norm2)
    scale = 1.0
    for k in range(cols.shape[0]):
        c2 = 0.0
        for i in range(m):
            c2 += J[i, cols[k]] * J[i, cols[k]]
        scale = max(scale, np.sqrt(c2))
    if norm <= 1e-9 * scale ** (m - 1):
        for i in range(m):
            nrm[i] = 0.0
        return
    for i in range(m):
        nrm[i] /= norm


@njit(cache=True, nogil=True)
def _ray_exit(
    J: np.ndarray, origin: np.ndarray, d: np.ndarray, qmin: np.ndarray, qmax: np.ndarray
) -> tuple[float, np.ndarray]:
    """Largest t with ``origin + t d`` in the zonotope ``Z = {J qdot : qmin <= qdot <= qmax}``.

    Z is the intersection of the slabs normal to its facets, and each facet normal is orthogonal to
    m-1 independent columns of J, so enumerating the (m-1)-subsets of columns is exact (J of full row
    rank, ``origin`` in Z). Returns t (inf if the ray never leaves Z) and the outward normal (m,) of
    the facet where it leaves (zeros if none).
    """
    m, n = J.shape
    best, best_n = np.inf, np.zeros(m)
    k = m - 1
    cols = np.arange(k).astype(np.int64)
    nrm = np.zeros(m)
    while True:
        _facet_normal_into(J, cols, nrm)
        nonzero = False
        nd = 0.0
        for i in range(m):
            nonzero = nonzero or nrm[i] != 0.0
            nd += nrm[i] * d[i]
        if nonzero and abs(nd) > 1e-15:
            sign = 1.0
            if nd < 0:
                sign, nd = -1.0, -nd
            h = 0.0
            for j in range(n):
                g = 0.0
                for i in range(m):
                    g += nrm[i] * J[i, j]
                g *= sign
                h += max(g * qmax[j], g * qmin[j])
            no = 0.0
            for i in range(m):
                no += nrm[i] * origin[i]
            t = (h - sign * no) / nd
            if t < best:
                best = max(t, 0.0)
                for i in range(m):
                    best_n[i] = sign * nrm[i]
        i = k - 1  # next combination of k out of n
        while i >= 0 and cols[i] == n - k + i:
            i -= 1
        if i < 0:
            break
        cols[i] += 1
        for r in range(i + 1, k):
            cols[r] = cols[r - 1] + 1
    return best, best_n


@njit(cache=True, nogil=True)
def _facet_solution(
    J: np.ndarray, target: np.ndarray, qmin: np.ndarray, qmax: np.ndarray, nrm: np.ndarray
) -> np.ndarray:
    """A qdot with ``J qdot = target`` for a target on the facet of Z with outward normal ``nrm``.

    Joints whose column has a component along ``nrm`` sit at the bound that maximises it; the joints
    parallel to the facet realise the rest (least squares; SNS if that leaves the bounds).
    """
    m, n = J.shape
    qdot = np.zeros(n)
    par = np.zeros(n, dtype=np.bool_)
    scale = 0.0
    for j in range(n):
        scale = max(scale, np.sqrt(np.sum(J[:, j] ** 2)))
    for j in range(n):
        g = 0.0
        for i in range(m):
            g += nrm[i] * J[i, j]
        if abs(g) <= 1e-9 * max(scale, 1e-300):
            par[j] = True
        else:
            qdot[j] = qmax[j] if g > 0 else qmin[j]
    rest = target - _mv(J, qdot)
    Jp = _masked(J, par)
    P, _ = _damped_pinv(Jp, 0.0, 1e-10)
    qp = _mv(P, rest)
    lo = np.zeros(n)  # the parallel joints' box, 0 elsewhere (a loop: np.where costs seconds of compiling)
    hi = np.zeros(n)
    for j in range(n):
        if par[j]:
            lo[j], hi[j] = qmin[j], qmax[j]
    if _violates(qp, lo, hi, 1e-9):
        qp, _ = _sns_greedy(Jp, rest, lo, hi, 0.0)
    return qdot + qp


@njit(cache=True, nogil=True)
def _zonotope_point(J: np.ndarray, target: np.ndarray, qmin: np.ndarray, qmax: np.ndarray) -> np.ndarray:
    """A qdot in the box with ``J qdot = target`` for a target inside Z (finite bounds).

    The ray from Z's centre ``J qc`` (qc = box centre) through the target leaves Z on a facet at
    ``t >= 1``; the facet point has a solution (:func:`_facet_solution`), and the target is the convex
    combination ``(1 - 1/t) qc + (1/t) q_facet`` of two points of the box.
    """
    qc = 0.5 * (qmin + qmax)
    c = _mv(J, qc)
    d = target - c
    if np.sqrt(np.sum(d * d)) <= 1e-15:
        return qc
    t, nrm = _ray_exit(J, c, d, qmin, qmax)
    if not np.isfinite(t) or t <= 0.0:
        return qc
    qf = _facet_solution(J, c + t * d, qmin, qmax, nrm)
    return qc + (qf - qc) / t
