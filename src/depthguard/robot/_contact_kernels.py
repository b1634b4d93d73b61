"""Compiled kernels of the contact-point search (:mod:`depthguard.robot.contact_point`): vertex posing,
the masked depth window, the nearest vertex, the foreground mask and the robot's image box."""

from __future__ import annotations

import numpy as np
from numba import njit

__all__: list[str] = []


@njit(cache=True, nogil=True)
def _pose_points(H, joint, start, local, out):  # pragma: no cover - compiled
    """``out[k] = R_j local[k] + p_j`` for the points ``start[g] <= k < start[g + 1]`` of joint ``j = joint[g]``,
    with ``H[j]`` (4, 4) its world pose."""
    for g in range(joint.shape[0]):
        M = H[joint[g]]
        r00, r01, r02, p0 = M[0, 0], M[0, 1], M[0, 2], M[0, 3]
        r10, r11, r12, p1 = M[1, 0], M[1, 1], M[1, 2], M[1, 3]
        r20, r21, r22, p2 = M[2, 0], M[2, 1], M[2, 2], M[2, 3]
        for k in range(start[g], start[g + 1]):
            x, y, z = local[k, 0], local[k, 1], local[k, 2]
            out[k, 0] = x * r00 + y * r01 + z * r02 + p0
            out[k, 1] = x * r10 + y * r11 + z * r12 + p1
            out[k, 2] = x * r20 + y * r21 + z * r22 + p2


@njit(cache=True, nogil=True)
def _masked_window(d, f):  # pragma: no cover - compiled
    """``(np.where(f, d, nan), ~f)`` of a float32 (h, w) window ``d`` and its bool mask ``f``, in one pass."""
    h, w = d.shape
    dm = np.empty((h, w), np.float32)
    nf = np.empty((h, w), np.bool_)
    nan32 = np.float32(np.nan)
    for v in range(h):
        for u in range(w):
            dm[v, u] = d[v, u] if f[v, u] else nan32
            nf[v, u] = not f[v, u]
    return dm, nf


@njit(cache=True, nogil=True)
def _nearest_vertex_kernel(V, p):  # pragma: no cover - compiled
    """(index, squared distance) of the row of ``V`` (N >= 1, 3) nearest to ``p`` (3,): the first minimum,
    or the first NaN distance (as ``np.argmin`` has it)."""
    best, bi = np.inf, 0
    p0, p1, p2 = p[0], p[1], p[2]
    for i in range(V.shape[0]):
        d0, d1, d2 = V[i, 0] - p0, V[i, 1] - p1, V[i, 2] - p2
        d = d0 * d0 + d1 * d1 + d2 * d2
        if d < best:
            best, bi = d, i
        elif np.isnan(d):
            return i, d
    return bi, best


@njit(cache=True, nogil=True)
def _foreground_kernel(d, bg, robot, margin, scalar, erode, out):  # pragma: no cover - compiled
    """:func:`foreground_mask` on one window, into ``out`` (h, w) bool: ``d``, ``bg`` (h, w) float32,
    ``robot`` (h, w) bool, ``margin`` (h, w) float32/float64 or, with ``scalar``, (1, 1); ``bg - margin``
    and the comparison in the types numpy computes them in."""
    h, w = d.shape
    inf32 = np.float32(np.inf)
    fg = np.empty((h, w), np.bool_) if erode else out
    for v in range(h):
        for u in range(w):
            z, b = d[v, u], bg[v, u]
            bf = b if (np.isfinite(b) and b > 0) else inf32
            m = margin[0, 0] if scalar else margin[v, u]
            fg[v, u] = np.isfinite(z) and z > 0 and z < bf - m and not robot[v, u]
    if erode:
        for v in range(h):
            for u in range(w):
                out[v, u] = (
                    fg[v, u]
                    and (v == 0 or fg[v - 1, u])
                    and (v == h - 1 or fg[v + 1, u])
                    and (u == 0 or fg[v, u - 1])
                    and (u == w - 1 or fg[v, u + 1])
                )


@njit(cache=True, nogil=True)
def _box_kernel(pc, reach, fx, fy, cx, cy):  # pragma: no cover - compiled
    """:func:`image_box`'s bounds before clipping: (behind, floor(min u_lo) - 1, ceil(max u_hi) + 2,
    floor(min v_lo) - 1, ceil(max v_hi) + 2) over the spheres' exact image spans (:func:`sphere_span`), NaN
    propagated like numpy's min and max."""
    n = pc.shape[0]
    for k in range(n):
        if pc[k, 2] - reach[k] <= 1e-3:
            return True, 0.0, 0.0, 0.0, 0.0
    a0, a1, b0, b1 = np.inf, -np.inf, np.inf, -np.inf
    for k in range(n):
        xl, xh = sphere_span(pc[k, 0], pc[k, 2], reach[k])
        yl, yh = sphere_span(pc[k, 1], pc[k, 2], reach[k])
        a0, a1 = _nanmin(a0, fx * xl + cx), _nanmax(a1, fx * xh + cx)
        b0, b1 = _nanmin(b0, fy * yl + cy), _nanmax(b1, fy * yh + cy)
    return False, np.floor(a0) - 1, np.ceil(a1) + 2, np.floor(b0) - 1, np.ceil(b1) + 2


@njit(cache=True, nogil=True)
def sphere_span(x, z, r):  # pragma: no cover - compiled
    """(lo, hi) of x/z over a ball of radius ``r`` about (x, z) with ``z > r`` (one image axis of a sphere
    fully in front of the camera): the slopes of the two tangent lines through the optical centre,
    ``(x z -+ r sqrt(x^2 + z^2 - r^2)) / (z^2 - r^2)``. Off the axis this is wider than ``x/z -+ r/(z - r)``."""
    root = np.sqrt(max(x * x + z * z - r * r, 0.0))
    den = (z - r) * (z + r)
    return (x * z - r * root) / den, (x * z + r * root) / den


@njit(cache=True, nogil=True)
def _nanmin(a, b):  # pragma: no cover - compiled
    return a if (a <= b or np.isnan(a)) else b


@njit(cache=True, nogil=True)
def _nanmax(a, b):  # pragma: no cover - compiled
    return a if (a >= b or np.isnan(a)) else b
