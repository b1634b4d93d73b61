"""The single-camera distance query kernels (ICRA'12 §III-IV; the method, the distance models and the
direction lattice: :mod:`depthguard.depthspace`, which calls :func:`query_many`).

Per control sphere: the unseen space and the region of surveillance (:mod:`depthguard.kernels.region`),
its tiles (nearest first in ``min`` mode), and per pixel the distance to its frustum from the obstacle
depth on (``model`` 0 frustum lower bound, 1 ICRA'12 eq. 4, 2 literal RA-L'16 eqs. 5-7), aggregated by
:mod:`depthguard.kernels.hits`. All kernels: ``cache=True``.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from depthguard.kernels import FASTMATH
from depthguard.kernels.hits import OUT_WIDTH, add_hit, nearer_hit, no_hits, write_hits
from depthguard.kernels.region import (
    first_index,
    next_tile,
    ray_distance_from,
    surveillance_box,
    tile_lower_bounds,
    unseen_space,
)

__all__ = ["query_many", "query_many_parallel"]


@nb.njit(cache=True, nogil=True, inline="always", _nrt=False, fastmath=FASTMATH)
def _pixel_distance(px, py, pz, a, b, do, u, v, h, intr, model):
    """Distance from P to pixel (u, v)'s obstacle from depth ``do`` on (see the module docstring).

    Returns ``(D, dx, dy, dz, dr, s, a, b)``: the distance, P minus the point at depth ``s`` of the ray
    ``(a, b, 1)`` used, and its norm.
    """
    if model == 0:  # frustum lower bound
        dx, dy, dz, s = ray_distance_from(px, py, pz, a, b, do)
        dr = math.sqrt(dx * dx + dy * dy + dz * dz)
        D = dr * (1.0 - h) - h * pz
        if D < 0.0:
            D = 0.0
        return D, dx, dy, dz, dr, s, a, b
    if model == 2:  # literal RA-L'16 eqs. 5-7: nearest pixel edge, evaluated at the point's depth
        qx = intr.fx * px / pz + intr.cx
        qy = intr.fy * py / pz + intr.cy
        a = (min(max(qx, u), u + 1.0) - intr.cx) / intr.fx
        b = (min(max(qy, v), v + 1.0) - intr.cy) / intr.fy
    s = do if do > pz else pz  # ICRA'12 eq. 4 (model 1) and eqs. 5-7: the gray area as d_o := d_p
    dx, dy, dz = px - s * a, py - s * b, pz - s
    dr = math.sqrt(dx * dx + dy * dy + dz * dz)
    return dr, dx, dy, dz, dr, s, a, b


@nb.njit(cache=True, nogil=True, inline="always", _nrt=False, fastmath=FASTMATH)
def _pixel_hit(hits, obs, u, v, b, px, py, pz, radius, reff, zmax, h, intr, qp, model, summed):
    """``hits`` plus pixel (u, v) (``b``: its ray's y slope) if within reach; ``summed``: in the direction
    sum and count (else it competes for the nearest distance only)."""
    do = obs[v, u]
    if do > zmax:
        return hits
    a = (u + 0.5 - intr.cx) / intr.fx
    D, dx, dy, dz, dr, s, ra, rb = _pixel_distance(px, py, pz, a, b, do, u, v, h, intr, model)
    if D >= (reff if summed else hits.best):
        return hits
    if dr < 1e-12:  # the point sits on the ray: push away from the visible surface
        dx, dy, dz = px - do * ra, py - do * rb, pz - do
        dr = math.sqrt(dx * dx + dy * dy + dz * dz)
        if dr < 1e-12:
            dx, dy, dz, dr = 0.0, 0.0, 1.0, 1.0
    if summed:
        return add_hit(hits, D, dx / dr, dy / dr, dz / dr, s * ra, s * rb, s, True, radius, qp.rho, qp.mode, qp.alpha)
    return nearer_hit(hits, D, dx / dr, dy / dr, dz / dr, s * ra, s * rb, s)


@nb.njit(cache=True, nogil=True, _nrt=False, fastmath=FASTMATH)
def _tile_pixels(hits, obs, tu, tv, u0, u1, v0, v1, px, py, pz, radius, h, intr, qp, model, st, lattice_only):
    """``hits`` plus the obstacle pixels of one tile within the box (RA-L'16 case i skipped); ``st``: the
    direction lattice's stride (only its pixels with ``lattice_only``). Two loops: with ``st == 1`` (and in
    ``min`` mode) every pixel is summed, and the loop is the plain one of before the lattice."""
    tile = qp.tile
    reff = qp.rho + radius
    zmax = pz + reff
    va, ua = max(v0, tv * tile), max(u0, tu * tile)
    vb, ub = min(v1 + 1, tv * tile + tile), min(u1 + 1, tu * tile + tile)
    if st == 1:
        for v in range(va, vb):
            b = (v + 0.5 - intr.cy) / intr.fy
            for u in range(ua, ub):
                hits = _pixel_hit(hits, obs, u, v, b, px, py, pz, radius, reff, zmax, h, intr, qp, model, True)
        return hits
    step = st if lattice_only else 1
    if lattice_only:
        va, ua = first_index(va, st), first_index(ua, st)
    for iv in range(max(0, (vb - va + step - 1) // step)):
        v = va + iv * step
        b = (v + 0.5 - intr.cy) / intr.fy
        row_on = v % st == 0
        for iu in range(max(0, (ub - ua + step - 1) // step)):
            u = ua + iu * step
            on = row_on and u % st == 0  # on the direction lattice
            hits = _pixel_hit(hits, obs, u, v, b, px, py, pz, radius, reff, zmax, h, intr, qp, model, on)
    return hits


@nb.njit(cache=True, nogil=True, _nrt=False, fastmath=FASTMATH, error_model="numpy")
def _query_one(obs, tmin, intr, qp, model, Pc, radius, lbs, out, stride):
    """Distance query for one sphere; writes out[0:8] = distance from the centre, direction (3), nearest
    point (3), count (camera frame). ``lbs``: scratch for the tile bounds; ``stride``: the direction
    lattice (:func:`depthguard.kernels.records.direction_stride`)."""
    px, py, pz = Pc[0], Pc[1], Pc[2]
    reff = qp.rho + radius
    h = 0.5 * math.sqrt(1.0 / (intr.fx * intr.fx) + 1.0 / (intr.fy * intr.fy))
    hits = no_hits(reff)
    if qp.unseen:
        hits = unseen_space(hits, px, py, pz, radius, intr, qp)
    u0, u1, v0, v1 = surveillance_box(px, py, pz, reff, intr)
    if u0 <= u1 and v0 <= v1:
        t_u0, t_v0, ntu, ntiles = tile_lower_bounds(tmin, px, py, pz, reff, (u0, u1, v0, v1), intr, qp.tile, lbs)
        for kk in range(ntiles + 1):
            k, lattice_only = next_tile(lbs, ntiles, kk, hits.best, reff, qp.mode, stride)
            if k < 0:
                break
            if k == ntiles:
                continue
            hits = _tile_pixels(
                hits,
                obs,
                t_u0 + k % ntu,
                t_v0 + k // ntu,
                u0,
                u1,
                v0,
                v1,
                px,
                py,
                pz,
                radius,
                h,
                intr,
                qp,
                model,
                stride,
                lattice_only,
            )
    write_hits(hits, qp.mode, out)
    if qp.mode != 0:
        out[7] *= stride * stride  # the lattice's count, scaled to the whole image


def _query_many_py(obs, tmin, intr, qp, model, R, t, centres, radii, stride):
    """:func:`_query_one` for N spheres (world frame in, camera frame out); rows of ``OUT_WIDTH``."""
    n = centres.shape[0]
    out = np.empty((n, OUT_WIDTH))
    lbs = np.empty((n, tmin.shape[0] * tmin.shape[1]))
    for i in nb.prange(n):
        Pc = R @ centres[i] + t
        _query_one(obs, tmin, intr, qp, model, Pc, radii[i], lbs[i], out[i], stride)
    return out


# One thread by default: on a loaded machine (a robot PC runs the controller too) a parallel kernel waits for
# a free core and its latency jumps by a scheduler time slice (several ms); opt in with parallel=True.
query_many = nb.njit(cache=True, nogil=True, error_model="numpy")(_query_many_py)
query_many_parallel = nb.njit(cache=True, nogil=True, parallel=True, error_model="numpy")(_query_many_py)
