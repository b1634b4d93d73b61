"""Minimum distance from control spheres and link capsules to the occupied nodes (SAPHARI D4.1.1 §3.2).

Exact distances to the node *boxes* (not their centres), so the result is a lower bound of the distance to
anything inside an occupied node. Spheres: the point-to-box distance in closed form. Capsules: the
segment-to-box distance, a convex function of the segment parameter, minimised by golden-section search to
1e-9 of the segment length (then lowered by that much). Both scan only the nodes within ρ of the sphere or
capsule; ``tests/test_octree_distance.py`` compares them with brute force over all nodes and with coal.

Same result type as the depth-space backend (:class:`depthguard.depthspace.PointDistances`): distance from
the sphere's surface (``inf`` beyond ρ), unit repulsive direction (node -> point), nearest node point, and
the number of occupied nodes within ρ in ``obstacle_pixels``.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from depthguard.depthspace import MODES, PointDistances
from depthguard.octree.grid import VoxelBox
from depthguard.validation import check_finite_array, check_points

__all__ = ["sphere_distances", "capsule_distances"]

_GOLD = 0.5 * (math.sqrt(5.0) - 1.0)


@nb.njit(cache=True, nogil=True, inline="always")
def _pbox(px, py, pz, lx, ly, lz, res):
    """Nearest point of the box [l, l + res]^3 to p and the squared distance."""
    nx = min(max(px, lx), lx + res)
    ny = min(max(py, ly), ly + res)
    nz = min(max(pz, lz), lz + res)
    dx, dy, dz = px - nx, py - ny, pz - nz
    return nx, ny, nz, dx * dx + dy * dy + dz * dz


@nb.njit(cache=True, nogil=True, inline="always")
def _span(lo, hi, origin, res, n):
    """Node indices ``[i0, i1]`` along one axis whose cells meet ``[lo, hi]`` (metres), clipped to ``[0, n)``
    (``i0 > i1``: none). Clipped as floats before the conversion to integers, which a huge ρ (or a far
    point) would overflow, and which then scanned no node at all."""
    f0 = np.floor((lo - origin) / res)  # a float (math.floor gives an int64 in numba)
    f1 = np.floor((hi - origin) / res)
    return int(min(max(f0, 0.0), float(n))), int(max(min(f1, n - 1.0), -1.0))


@nb.njit(cache=True, nogil=True)
def _spheres(occ, origin, res, centres, radii, rho, mode, alpha, out):
    nx, ny, nz = occ.shape
    for n in range(centres.shape[0]):
        px, py, pz = centres[n, 0], centres[n, 1], centres[n, 2]
        reach = rho + radii[n]
        i0, i1 = _span(px - reach, px + reach, origin[0], res, nx)
        j0, j1 = _span(py - reach, py + reach, origin[1], res, ny)
        k0, k1 = _span(pz - reach, pz + reach, origin[2], res, nz)
        best = reach * reach
        found = False
        bx = by = bz = 0.0
        ci = cj = ck = 0
        sx = sy = sz = 0.0
        count = 0
        for i in range(i0, i1 + 1):
            lx = origin[0] + i * res
            for j in range(j0, j1 + 1):
                ly = origin[1] + j * res
                for k in range(k0, k1 + 1):
                    if not occ[i, j, k]:
                        continue
                    lz = origin[2] + k * res
                    qx, qy, qz, d2 = _pbox(px, py, pz, lx, ly, lz, res)
                    if d2 >= reach * reach:
                        continue
                    count += 1
                    if mode != 0:
                        d = math.sqrt(d2)
                        if d > 1e-12:
                            ux, uy, uz = (px - qx) / d, (py - qy) / d, (pz - qz) / d
                        else:
                            ux, uy, uz = px - lx - 0.5 * res, py - ly - 0.5 * res, pz - lz - 0.5 * res
                            nn = math.sqrt(ux * ux + uy * uy + uz * uz) + 1e-300
                            ux, uy, uz = ux / nn, uy / nn, uz / nn
                        w = 1.0
                        if mode == 1:
                            w = 1.0 / (1.0 + math.exp((max(d - radii[n], 0.0) * 2.0 / rho - 1.0) * alpha))
                        sx += w * ux
                        sy += w * uy
                        sz += w * uz
                    if d2 < best or not found:
                        best = d2
                        found = True
                        bx, by, bz = qx, qy, qz
                        ci, cj, ck = i, j, k
        if not found:
            out[n, 0] = np.inf
            continue
        d = math.sqrt(best)
        if d > 1e-12:
            ux, uy, uz = (px - bx) / d, (py - by) / d, (pz - bz) / d
        else:  # inside the node: away from its centre
            ux = px - (origin[0] + (ci + 0.5) * res)
            uy = py - (origin[1] + (cj + 0.5) * res)
            uz = pz - (origin[2] + (ck + 0.5) * res)
            nn = math.sqrt(ux * ux + uy * uy + uz * uz)
            if nn < 1e-12:
                ux, uy, uz, nn = 0.0, 0.0, 1.0, 1.0
            ux, uy, uz = ux / nn, uy / nn, uz / nn
        if mode != 0:
            nn = math.sqrt(sx * sx + sy * sy + sz * sz)
            if nn > 1e-9:
                ux, uy, uz = sx / nn, sy / nn, sz / nn
        out[n, 0] = d
        out[n, 1], out[n, 2], out[n, 3] = ux, uy, uz
        out[n, 4], out[n, 5], out[n, 6] = bx, by, bz
        out[n, 7] = count


def _check_occ(occupied: np.ndarray, box: VoxelBox) -> np.ndarray:
    occ = np.asarray(occupied)
    if occ.shape != box.shape:
        raise ValueError(f"occupied grid has shape {occ.shape}, expected the box's {box.shape}")
    return np.ascontiguousarray(occ, dtype=np.bool_)


def _result(raw: np.ndarray, radii: np.ndarray, rho: float) -> PointDistances:
    found = raw[:, 0] < rho + radii
    dist = np.where(found, np.maximum(raw[:, 0] - radii, 0.0), np.inf)
    direction = np.where(found[:, None], raw[:, 1:4], np.nan)
    nearest = np.where(found[:, None], raw[:, 4:7], np.nan)
    return PointDistances(dist, direction, nearest, np.where(found, raw[:, 7], 0).astype(np.int64))


def sphere_distances(
    occupied: np.ndarray,
    box: VoxelBox,
    centres: np.ndarray,
    radii: np.ndarray | float = 0.0,
    rho: float = 0.4,
    mode: str = "min",
    alpha: float = 6.0,
) -> PointDistances:
    """Distances from N control spheres to the occupied nodes.

    Args:
        occupied: (nx, ny, nz) bool over ``box``.
        centres: (N, 3) world-frame sphere centres, metres; ``radii`` (N,) or one number.
        rho: radius of surveillance from the sphere's surface, metres.
        mode: ``"min"`` (nearest node's direction), ``"all"`` (eq. 7-weighted sum of the directions of all
            nodes within ρ, ICRA'12 eq. 9) or ``"hybrid"`` (their mean, RA-L'16 eq. 11).
    """
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    if not (np.isfinite(rho) and rho > 0):
        raise ValueError(f"rho must be a positive number of metres, got {rho!r}")
    c = np.atleast_2d(np.asarray(centres, dtype=float))
    r = np.broadcast_to(np.asarray(radii, dtype=float), (c.shape[0],)) if c.ndim == 2 else radii
    c, r = check_points(c, r)
    out = np.zeros((len(c), 8))
    _spheres(_check_occ(occupied, box), np.ascontiguousarray(box.origin), float(box.res), np.ascontiguousarray(c),
             np.ascontiguousarray(r), float(rho), MODES.index(mode), float(alpha), out)  # fmt: skip
    return _result(out, r, float(rho))


@nb.njit(cache=True, nogil=True, inline="always")
def _seg_box_d2(ax, ay, az, ex, ey, ez, lx, ly, lz, res, iters):
    """min over s in [0, 1] of the squared distance from a + s e to the box (convex in s): golden section."""
    lo, hi = 0.0, 1.0
    g = 0.6180339887498949
    s1 = hi - g * (hi - lo)
    s2 = lo + g * (hi - lo)
    f1 = _pbox(ax + s1 * ex, ay + s1 * ey, az + s1 * ez, lx, ly, lz, res)[3]
    f2 = _pbox(ax + s2 * ex, ay + s2 * ey, az + s2 * ez, lx, ly, lz, res)[3]
    for _ in range(iters):
        if f1 <= f2:
            hi = s2
            s2, f2 = s1, f1
            s1 = hi - g * (hi - lo)
            f1 = _pbox(ax + s1 * ex, ay + s1 * ey, az + s1 * ez, lx, ly, lz, res)[3]
        else:
            lo = s1
            s1, f1 = s2, f2
            s2 = lo + g * (hi - lo)
            f2 = _pbox(ax + s2 * ex, ay + s2 * ey, az + s2 * ez, lx, ly, lz, res)[3]
    s = 0.5 * (lo + hi)
    best = _pbox(ax + s * ex, ay + s * ey, az + s * ez, lx, ly, lz, res)
    for s_end in (0.0, 1.0):
        q = _pbox(ax + s_end * ex, ay + s_end * ey, az + s_end * ez, lx, ly, lz, res)
        if q[3] < best[3]:
            best = q
            s = s_end
    return best[3], s, best[0], best[1], best[2]


@nb.njit(cache=True, nogil=True)
def _capsules(occ, origin, res, a, b, radii, rho, out):
    nx, ny, nz = occ.shape
    for n in range(a.shape[0]):
        ax, ay, az = a[n, 0], a[n, 1], a[n, 2]
        ex, ey, ez = b[n, 0] - ax, b[n, 1] - ay, b[n, 2] - az
        L = math.sqrt(ex * ex + ey * ey + ez * ez)
        reach = rho + radii[n]
        lo = (min(ax, b[n, 0]), min(ay, b[n, 1]), min(az, b[n, 2]))
        hi = (max(ax, b[n, 0]), max(ay, b[n, 1]), max(az, b[n, 2]))
        i0, i1 = _span(lo[0] - reach, hi[0] + reach, origin[0], res, nx)
        j0, j1 = _span(lo[1] - reach, hi[1] + reach, origin[1], res, ny)
        k0, k1 = _span(lo[2] - reach, hi[2] + reach, origin[2], res, nz)
        best = reach * reach
        found = False
        count = 0
        bs = 0.0
        bx = by = bz = 0.0
        for i in range(i0, i1 + 1):
            lx = origin[0] + i * res
            gx = max(lo[0] - lx - res, 0.0, lx - hi[0])
            for j in range(j0, j1 + 1):
                ly = origin[1] + j * res
                gy = max(lo[1] - ly - res, 0.0, ly - hi[1])
                for k in range(k0, k1 + 1):
                    if not occ[i, j, k]:
                        continue
                    lz = origin[2] + k * res
                    gz = max(lo[2] - lz - res, 0.0, lz - hi[2])
                    lb = gx * gx + gy * gy + gz * gz  # box to the segment's bounding box
                    if lb >= reach * reach:
                        continue
                    d2, s, qx, qy, qz = _seg_box_d2(ax, ay, az, ex, ey, ez, lx, ly, lz, res, 48)
                    if d2 >= reach * reach:
                        continue
                    count += 1
                    if d2 < best or not found:
                        best, bs, bx, by, bz, found = d2, s, qx, qy, qz, True
        if not found:
            out[n, 0] = np.inf
            continue
        d = max(math.sqrt(best) - 1e-9 * (L + 1.0), 0.0)
        px, py, pz = ax + bs * ex, ay + bs * ey, az + bs * ez
        ux, uy, uz = px - bx, py - by, pz - bz
        nn = math.sqrt(ux * ux + uy * uy + uz * uz)
        if nn < 1e-12:
            ux, uy, uz, nn = 0.0, 0.0, 1.0, 1.0
        out[n, 0] = d
        out[n, 1], out[n, 2], out[n, 3] = ux / nn, uy / nn, uz / nn
        out[n, 4], out[n, 5], out[n, 6] = bx, by, bz
        out[n, 7] = count


def capsule_distances(
    occupied: np.ndarray, box: VoxelBox, a: np.ndarray, b: np.ndarray, radii: np.ndarray, rho: float = 0.4
) -> PointDistances:
    """Distances from L capsules (segments ``a``-``b`` (L, 3), ``radii`` (L,), world, metres) to the occupied
    nodes; ``nearest`` is the nearest node point, ``direction`` points from it to the segment."""
    a_ = check_finite_array(a, (-1, 3), "capsule a")
    b_ = check_finite_array(b, (a_.shape[0], 3), "capsule b")
    _, r = check_points(a_, np.broadcast_to(np.asarray(radii, dtype=float), (a_.shape[0],)), "capsules")
    if not (np.isfinite(rho) and rho > 0):
        raise ValueError(f"rho must be a positive number of metres, got {rho!r}")
    out = np.zeros((len(a_), 8))
    _capsules(_check_occ(occupied, box), np.ascontiguousarray(box.origin), float(box.res), a_, b_,
              np.ascontiguousarray(r), float(rho), out)  # fmt: skip
    return _result(out, r, float(rho))
