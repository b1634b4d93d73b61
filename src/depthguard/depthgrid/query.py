"""The fused distance query of the depth grid (RA-L'16 §VI-VII): per control sphere, per tile, per pixel.

For each sphere: the unseen space and the region of surveillance (shared with the single-camera query,
:mod:`depthguard.kernels.region`); its tiles, pruned by their lower bound (nearest first in ``min``
mode); per tile the depth-chunk test (:mod:`depthguard.depthgrid.chunks`); per pixel the case:

i.   the pixel's start (and its gray area) lies beyond ``d_p + ρ``: nothing to do;
ii.  a measured surface at ``d_o >= d_p``: the distance to the pixel frustum from ``d_o`` on, no vote;
iii. ``d_o < d_p``, or an unknown pixel: the column search (:mod:`depthguard.depthgrid.column`) finds the
     nearest segment that no secondary camera clears;
iv.  a robot pixel at ``d_r``: the column search from ``d_r`` on, where a cell needs a witness (an involved
     secondary camera that does not clear it) to be occupied.

Point-to-segment distance (RA-L'16 eqs. 5-7, safe form): for the pixel-centre ray ``r = (a, b, 1)`` and
the occupied depth interval ``[lo, hi]``, ``s* = clamp(P.r / r.r, lo, hi)``, ``d_ray = |P - s* r|``,
``D = max(0, d_ray - h min(hi, d_p + d_ray))`` with ``h = ½ sqrt(fx⁻² + fy⁻²)``: never more than the
distance to anything in the piece. Everything in the principal camera frame; distances from the sphere
centre (the caller subtracts the radius). All kernels: ``cache=True`` (compiled once per machine).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from depthguard.depthgrid.chunks import tile_chunk_cleared, tile_chunk_prepare
from depthguard.depthgrid.column import column_search
from depthguard.depthgrid.records import KIND_NONE, KIND_ROBOT, KIND_SURFACE, PYR_STACK, TILE_BLOCK, Scratch
from depthguard.kernels import FASTMATH
from depthguard.kernels.hits import HITS_WIDTH, OUT_WIDTH, add_hit, nearer_hit, no_hits, store_hits, write_hits
from depthguard.kernels.region import first_index, next_tile, surveillance_box, tile_lower_bounds, unseen_space

__all__ = ["sphere_hits", "query_one", "query_many", "query_many_parallel", "query_part"]


@nb.njit(cache=True, nogil=True, _nrt=False, inline="always", fastmath=FASTMATH)
def _segment_hit(hits, P, a, b, lo, hi, h, radius, qp, summed):
    """``hits`` plus the piece of pixel ray ``(a, b, 1)`` between depths lo and hi, if within ρ + r
    (``summed``: in the direction sum and count; else only if nearer than ``hits.best``)."""
    px, py, pz = P
    s = (px * a + py * b + pz) / (a * a + b * b + 1.0)
    s = min(max(s, lo), hi)
    dx, dy, dz = px - s * a, py - s * b, pz - s
    dr = math.sqrt(dx * dx + dy * dy + dz * dz)
    D = max(dr - h * min(hi, pz + dr), 0.0)
    if D >= (qp.rho + radius if summed else hits.best):
        return hits
    if dr < 1e-12:  # the point sits on the ray: push away from the start of the interval
        dx, dy, dz = px - lo * a, py - lo * b, pz - lo
        dr = math.sqrt(dx * dx + dy * dy + dz * dz)
        if dr < 1e-12:
            dx, dy, dz, dr = 0.0, 0.0, 1.0, 1.0
    if not summed:
        return nearer_hit(hits, D, dx / dr, dy / dr, dz / dr, s * a, s * b, s)
    return add_hit(hits, D, dx / dr, dy / dr, dz / dr, s * a, s * b, s, True, radius, qp.rho, qp.mode, qp.alpha)


@nb.njit(cache=True, nogil=True, _nrt=False, inline="always", fastmath=FASTMATH)
def _first_segment(s0, surface, P, a, b, h, lim, grid):
    """Column search of a pixel of a cleared tile (every grid cell within reach cleared, the space beyond
    the grid out of reach): only the column's first segment can be occupied, the space ``[s0, d_min)``
    before the grid or the cell of a measured surface. Returns ``(found, lo, hi)`` as the column search
    does: found when the segment comes within the search bound ``T`` of P."""
    if s0 < grid.d_min:
        lo, hi = s0, grid.d_min
    elif surface:
        g = int(math.floor((s0 - grid.d_min) / grid.dd))
        if g >= grid.n_cells:
            return False, 0.0, 0.0
        lo, hi = s0, grid.d_min + (g + 1) * grid.dd
    else:
        return False, 0.0, 0.0  # an unknown pixel inside the grid: its cells are cleared
    px, py, pz = P
    s = min(max((px * a + py * b + pz) / (a * a + b * b + 1.0), lo), hi)
    dx, dy, dz = px - s * a, py - s * b, pz - s
    T = (lim + h * pz) / (1.0 - h)
    return dx * dx + dy * dy + dz * dz < T * T, lo, hi


@nb.njit(cache=True, nogil=True, _nrt=False, inline="always")
def _tile_scratch(sc, tid):
    """``sc`` whose ``tstate`` holds what this frame has decided of tile ``tid``'s blocks: the frame's
    :class:`~depthguard.depthgrid.records.ColumnCache` row ``tiles[tid]`` itself, so the tile's searches
    decide for the frame's later searches too; without the cache, ``sc.tstate`` cleared."""
    cc = sc.cache
    if not cc.on:
        sc.tstate[:] = 0
        return sc
    if cc.tile_gen[tid] != cc.gen:
        cc.tiles[tid, :] = 0
        cc.tile_gen[tid] = cc.gen
    return Scratch(sc.lbs, cc.tiles[tid], sc.stack, cc)


@nb.njit(cache=True, nogil=True, _nrt=False, inline="always", fastmath=FASTMATH)
def _tile_columns(hits, tu, tv, box, P, radius, h, qp, intr, pr, grid, mp, vt, sc, chunks, st, lattice_only):
    """``hits`` plus the pixels of tile (tu, tv) inside ``box``; ``st``: the direction lattice's stride (only
    its pixels with ``lattice_only``); returns ``(hits, column searches, tests)``."""
    px, py, pz = P
    tile = qp.tile
    u0, u1, v0, v1 = box
    reff = qp.rho + radius
    zmax = pz + reff
    rect = (tu * tile, tv * tile, min(intr.width, tu * tile + tile), min(intr.height, tv * tile + tile))
    sc = _tile_scratch(sc, tv * ((intr.width + tile - 1) // tile) + tu)
    allclear = pending = beyond_out = False
    g0c = g1c = 0
    cells = tests = 0
    if chunks and pr.tmin[tv, tu] < pz:  # (a tile wholly beyond P has no case-iii pixel)
        lim_t = hits.best if qp.mode == 0 else reff
        allclear, pending, g0c, g1c, skip, beyond_out = tile_chunk_prepare(
            P, h, lim_t, rect, pr.tmin[tv, tu], pr.tmax[tv, tu], intr, grid, mp, vt, sc
        )
        tests += 1
        if skip:
            return hits, cells, tests
    step = st if lattice_only else 1
    va, ua = max(v0, rect[1]), max(u0, rect[0])
    if lattice_only:
        va, ua = first_index(va, st), first_index(ua, st)
    nv = max(0, (min(v1 + 1, rect[3]) - va + step - 1) // step)
    nu = max(0, (min(u1 + 1, rect[2]) - ua + step - 1) // step)
    for iv in range(nv):
        v = va + iv * step
        b = (v + 0.5 - intr.cy) / intr.fy
        row_on = v % st == 0
        for iu in range(nu):
            u = ua + iu * step
            kd = pr.kind[v, u]
            if kd == KIND_NONE:
                continue
            s0 = pr.start[v, u]
            if s0 > zmax:
                continue  # case i
            if allclear and kd == KIND_ROBOT:
                continue  # case iv in a cleared tile: nothing within reach
            a = (u + 0.5 - intr.cx) / intr.fx
            summed = qp.mode == 0 or (row_on and u % st == 0)  # on the direction lattice
            if kd == KIND_SURFACE and s0 >= pz:
                hits = _segment_hit(hits, P, a, b, s0, np.inf, h, radius, qp, summed)  # case ii
                continue
            # cases iii and iv: ask the other cameras, unless the whole ray from s0 on is out of reach
            lim = reff if qp.mode != 0 and summed else hits.best
            s = max((px * a + py * b + pz) / (a * a + b * b + 1.0), s0)
            dx, dy, dz = px - s * a, py - s * b, pz - s
            if not math.sqrt(dx * dx + dy * dy + dz * dz) * (1.0 - h) - h * pz < lim:
                continue
            if pending:
                pending = False
                tests += 1
                allclear = tile_chunk_cleared(rect, g0c // TILE_BLOCK, g1c // TILE_BLOCK, grid, mp, vt, sc, False)
                if allclear and kd == KIND_ROBOT:
                    continue
            if allclear and beyond_out:  # (robot pixels were skipped above)
                found, lo, hi = _first_segment(s0, kd == KIND_SURFACE, P, a, b, h, lim, grid)
            else:
                cells += 1
                found, lo, hi, nt = column_search(
                    u, v, a, b, s0, kd == KIND_SURFACE, kd == KIND_ROBOT, P, h, lim, rect, grid, mp, vt, sc
                )
                tests += nt
            if found:
                hits = _segment_hit(hits, P, a, b, lo, hi, h, radius, qp, summed)
    return hits, cells, tests


@nb.njit(cache=True, nogil=True, error_model="numpy", _nrt=False, fastmath=FASTMATH)
def sphere_hits(P, radius, qp, intr, pr, grid, mp, vt, sc, chunks, stride, part, nparts):
    """The hits of one sphere at P (principal camera frame, a 3-tuple) in part ``part`` of ``nparts`` of the
    image: the tiles of the rows ``tv % nparts == part``, and the unseen space in part 0. Returns
    ``(hits, column searches, votes taken)``; :func:`query_one` is part 0 of 1.

    The parts of one sphere share no pixel and no tile, so that threads may run them at once on one
    :class:`~depthguard.depthgrid.records.ColumnCache` (whose records are per pixel and per tile).
    Each part prunes its tiles with its own nearest distance, which is never below the whole query's:
    it may search more, never less, and :func:`~depthguard.kernels.hits.merge_hits` gives the whole answer.

    Records: ``qp`` :class:`~depthguard.kernels.records.QueryParams`, ``intr``
    :class:`~depthguard.kernels.records.Intrinsics` (principal camera), ``pr`` / ``grid`` / ``mp`` / ``vt`` /
    ``sc`` from :mod:`depthguard.depthgrid.records`; ``chunks``: use the per-tile chunk tests; ``stride``:
    the direction lattice (:func:`depthguard.kernels.records.direction_stride`).
    """
    px, py, pz = P
    reff = qp.rho + radius
    h = 0.5 * math.sqrt(1.0 / (intr.fx * intr.fx) + 1.0 / (intr.fy * intr.fy))
    hits = no_hits(reff)
    if qp.unseen and part == 0:
        hits = unseen_space(hits, px, py, pz, radius, intr, qp)
    box = surveillance_box(px, py, pz, reff, intr)
    cells = tests = 0
    if box[0] <= box[1] and box[2] <= box[3]:
        lbs = sc.lbs
        t_u0, t_v0, ntu, ntiles = tile_lower_bounds(
            pr.tmin, px, py, pz, reff, box, intr, qp.tile, lbs, part, nparts
        )  # (another part's tiles at +inf: never visited here)
        for kk in range(ntiles + 1):
            k, lattice_only = next_tile(lbs, ntiles, kk, hits.best, reff, qp.mode, stride)
            if k < 0:
                break
            if k == ntiles:
                continue
            hits, c, t = _tile_columns(
                hits,
                t_u0 + k % ntu,
                t_v0 + k // ntu,
                box,
                P,
                radius,
                h,
                qp,
                intr,
                pr,
                grid,
                mp,
                vt,
                sc,
                chunks,
                stride,
                lattice_only,
            )
            cells += c
            tests += t
    return hits, cells, tests


@nb.njit(cache=True, nogil=True, error_model="numpy", _nrt=False, fastmath=FASTMATH)
def query_one(P, radius, qp, intr, pr, grid, mp, vt, sc, chunks, out, stride):
    """Fused distance query for one sphere at P (principal camera frame, a 3-tuple); writes ``out[0:10]``
    = distance from the centre, direction (3), nearest point (3), count, column searches, votes taken.
    Arguments as :func:`sphere_hits`."""
    hits, cells, tests = sphere_hits(P, radius, qp, intr, pr, grid, mp, vt, sc, chunks, stride, 0, 1)
    write_hits(hits, qp.mode, out)
    if qp.mode != 0:
        out[7] *= stride * stride  # the lattice's count, scaled to the whole image
    out[8] = cells
    out[9] = tests


def _query_many_py(R, t, centres, radii, qp, intr, pr, grid, mp, vt, chunks, cache, stride):
    """:func:`query_one` for N spheres (world frame in): rows of ``OUT_WIDTH``. ``cache``: the frame's
    :class:`~depthguard.depthgrid.records.ColumnCache`, shared by the spheres (disabled for the threaded
    compilation); ``stride``: the direction lattice."""
    n = centres.shape[0]
    out = np.empty((n, OUT_WIDTH))
    lbs = np.empty((n, pr.tmin.shape[0] * pr.tmin.shape[1]))
    tstates = np.zeros((n, grid.n_cells // TILE_BLOCK + 1), dtype=np.uint8)
    stacks = np.empty((n, 3 * PYR_STACK), dtype=np.int64)
    for i in nb.prange(n):
        Pc = R @ centres[i] + t
        sc = Scratch(lbs[i], tstates[i], stacks[i], cache)
        query_one((Pc[0], Pc[1], Pc[2]), radii[i], qp, intr, pr, grid, mp, vt, sc, chunks, out[i], stride)
    return out


# One implementation, two compilations: one thread (default; no thread start-up latency on a loaded
# machine) and numba's threads over the spheres (``DepthGridFusion(parallel=True)``).
query_many = nb.njit(cache=True, nogil=True)(_query_many_py)
query_many_parallel = nb.njit(cache=True, nogil=True, parallel=True)(_query_many_py)


@nb.njit(cache=True, nogil=True)
def query_part(R, t, centres, radii, qp, intr, pr, grid, mp, vt, chunks, cache, stride, part, nparts):
    """Part ``part`` of ``nparts`` of :func:`query_many` (:func:`sphere_hits`): rows of ``HITS_WIDTH``
    (:func:`~depthguard.kernels.hits.store_hits`), to be merged by :func:`~depthguard.kernels.hits.merge_hits`.
    The parts may run at once on threads of their own with the same ``cache``."""
    n = centres.shape[0]
    out = np.empty((n, HITS_WIDTH))
    lbs = np.empty(pr.tmin.shape[0] * pr.tmin.shape[1])
    tstate = np.zeros(grid.n_cells // TILE_BLOCK + 1, dtype=np.uint8)
    stack = np.empty(3 * PYR_STACK, dtype=np.int64)
    sc = Scratch(lbs, tstate, stack, cache)
    for i in range(n):
        Pc = R @ centres[i] + t
        hits, cells, tests = sphere_hits(
            (Pc[0], Pc[1], Pc[2]), radii[i], qp, intr, pr, grid, mp, vt, sc, chunks, stride, part, nparts
        )
        store_hits(hits, cells, tests, out[i])
    return out
