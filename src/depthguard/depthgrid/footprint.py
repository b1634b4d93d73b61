"""Footprints of principal-camera cells in the secondary cameras and the stored map (RA-L'16 §V).

A cell's footprint in camera k is the pixel bounding box ``[u0, u0+du] x [v0, v0+dv]`` of its 8 projected
corners, and ``q`` its quantised far depth: ``d_end = q * DEND_SCALE >= max_k z`` (rounded up, so
conservatively far; at worst one float64 ulp below ``max_k z`` by the product's rounding, a gap that holds no
float32 vote). ``u0 = -1`` marks a camera that is not involved (the cell is not entirely in front of
it and inside its image, its footprint is wider than ``FOOT_MAX`` pixels, its far depth beyond
``Q_MAX`` steps, or a depth is NaN or infinite); the stored map packs the
five numbers in one int64 (:func:`pack`). None of this is compiled with fast-math, so the stored map and
the on-the-fly footprints are bit-identical. Rays (:func:`ray`) and camera rows:
:mod:`depthguard.depthgrid.records`.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

__all__ = ["DEND_SCALE", "Q_MAX", "FOOT_MAX", "ray", "rect_footprint", "cell_footprint", "pack", "unpack", "build_map"]

DEND_SCALE = 4e-4  # metres per unit of the quantised far depth (15 bits): 0.4 mm steps, up to 13.1 m
Q_MAX = 32767
Z_FAR = 1e6  # metres: a far depth beyond this is refused before quantising (far beyond Q_MAX steps)
FOOT_MAX = 255  # largest footprint extent (pixels - 1) a cell may have in a secondary camera


@nb.njit(cache=True, nogil=True, _nrt=False, inline="always")
def ray(tab, k, v, u):
    """Ray (u, v) of a :class:`~depthguard.depthgrid.records.RayTable` for secondary camera k: ``M[k] @ (us[u],
    vs[v], 1)``, three float64."""
    M, us, vs = tab
    a = us[u]
    b = vs[v]
    return (
        M[k, 0, 0] * a + M[k, 0, 1] * b + M[k, 0, 2],
        M[k, 1, 0] * a + M[k, 1, 1] * b + M[k, 1, 2],
        M[k, 2, 0] * a + M[k, 2, 1] * b + M[k, 2, 2],
    )


@nb.njit(cache=True, nogil=True, _nrt=False, inline="always")
def rect_footprint(k, ua, va, ub, vb, d1, d2, corner_rays, cams):
    """Footprint in camera k of the principal frustum over pixels ``[ua, ub) x [va, vb)``, depths [d1, d2]."""
    bx = cams[k, 0]
    by = cams[k, 1]
    bz = cams[k, 2]
    fx = cams[k, 3]
    fy = cams[k, 4]
    cx = cams[k, 5]
    cy = cams[k, 6]
    umin = np.inf
    umax = -np.inf
    vmin = np.inf
    vmax = -np.inf
    zmax = 0.0
    for j in range(2):
        cv = va if j == 0 else vb
        for i in range(2):
            cu = ua if i == 0 else ub
            mx, my, mz = ray(corner_rays, k, cv, cu)
            for s in range(2):
                d = d1 if s == 0 else d2
                Z = d * mz + bz
                if not Z > 1e-6:  # (NaN too: a NaN depth projects nowhere)
                    return -1, 0, 0, 0, 0
                iz = 1.0 / Z
                pu = fx * (d * mx + bx) * iz + cx
                pv = fy * (d * my + by) * iz + cy
                umin = min(umin, pu)
                umax = max(umax, pu)
                vmin = min(vmin, pv)
                vmax = max(vmax, pv)
                zmax = max(zmax, Z)
    if not (umin >= 0.0 and vmin >= 0.0 and umax < cams[k, 7] and vmax < cams[k, 8]):
        return -1, 0, 0, 0, 0
    if not zmax < Z_FAR:  # far beyond Q_MAX (inf too): before int(), which overflows there
        return -1, 0, 0, 0, 0
    iu0 = int(math.floor(umin))
    iv0 = int(math.floor(vmin))
    du = int(math.floor(umax)) - iu0
    dv = int(math.floor(vmax)) - iv0
    q = int(math.ceil(zmax / DEND_SCALE))
    if du > FOOT_MAX or dv > FOOT_MAX or q > Q_MAX:
        return -1, 0, 0, 0, 0
    return iu0, iv0, du, dv, q


@nb.njit(cache=True, nogil=True, _nrt=False, inline="always")
def cell_footprint(k, u, v, d1, d2, corner_rays, cams):
    """Footprint ``(u0, v0, du, dv, q)`` of principal cell ``(u, v, [d1, d2])`` in secondary camera k."""
    return rect_footprint(k, u, v, u + 1, v + 1, d1, d2, corner_rays, cams)


@nb.njit(cache=True, nogil=True, _nrt=False)
def pack(u0, v0, du, dv, q):
    """One int64: du | dv << 8 | (u0 + 1) << 16 | v0 << 32 | q << 48 (all fields non-negative)."""
    if u0 < 0:
        return np.int64(0)
    return np.int64(du) | (np.int64(dv) << 8) | (np.int64(u0 + 1) << 16) | (np.int64(v0) << 32) | (np.int64(q) << 48)


@nb.njit(cache=True, nogil=True, _nrt=False, inline="always")
def unpack(w):
    """Inverse of :func:`pack`; ``u0 = -1`` for a camera that is not involved."""
    return (((w >> 16) & 0xFFFF) - 1, (w >> 32) & 0xFFFF, w & 0xFF, (w >> 8) & 0xFF, (w >> 48) & 0x7FFF)


@nb.njit(cache=True, nogil=True, parallel=True)
def build_map(corner_rays, cams, d_min, dd, n_cells, pmap):
    """Fill the stored map (RA-L'16 §V) for every cell and secondary camera; rows in parallel."""
    H = pmap.shape[1]
    W = pmap.shape[2]
    for vv in nb.prange(H):
        v = np.int64(vv)  # the prange index may be unsigned; keep index arithmetic in int64
        for k in range(cams.shape[0]):
            for u in range(W):
                for g in range(n_cells):
                    d1 = d_min + g * dd
                    u0, v0, du, dv, q = cell_footprint(k, u, v, d1, d1 + dd, corner_rays, cams)
                    pmap[k, v, u, g] = pack(u0, v0, du, dv, q)
