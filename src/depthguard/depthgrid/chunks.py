"""Per-tile depth chunks: deciding at once the cells that a whole tile's column searches can reach.

Shadows (a person between the principal camera and the robot makes almost every pixel near the robot a
case-iii pixel). Before its columns, each tile tries its whole *depth chunk* at once: the cells that any
of its column searches can reach (ray points within the search bound T of P, so within a window of the
tile-centre ray, and no nearer than the tile's smallest start depth), as one frustum piece per secondary
camera; if that fails, its two halves. When every cell of the chunk is cleared, a column can only find
its first segment (the cell of a measured surface, occupied without a vote, or the unseen space before
``d_min``), and a robot column nothing, so robot columns are skipped; and when moreover the tile has no
case-ii pixel (no surface beyond P) and a lower bound of the distance to its first segments exceeds T,
the whole tile is skipped without visiting its pixels. All of this only skips cells that the per-cell
rule clears, so the answers are unchanged (``tests/test_depthgrid_search.py``).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from depthguard.depthgrid.records import KIND_SURFACE, KIND_UNKNOWN, TILE_BLOCK
from depthguard.depthgrid.votes import tile_block_cleared
from depthguard.kernels import FASTMATH

__all__ = ["tile_bounds", "tile_chunk_cleared", "tile_chunk_prepare"]


@nb.njit(cache=True, nogil=True)
def tile_bounds(start, kind, tile):
    """``(tmin, tmax)`` in one pass over the principal image: per tile the smallest start depth (inf when
    none) and the largest start depth of its non-robot pixels, surface or unknown (-inf when none),
    (ceil(H/tile), ceil(W/tile)) float32 each."""
    H, W = start.shape
    th = (H + tile - 1) // tile
    tw = (W + tile - 1) // tile
    tmin = np.full((th, tw), np.inf, dtype=np.float32)
    tmax = np.full((th, tw), -np.inf, dtype=np.float32)
    ninf = np.float32(-np.inf)
    for tv in range(th):
        for v in range(tv * tile, min(H, tv * tile + tile)):
            for tu in range(tw):
                lo = tmin[tv, tu]
                hi = tmax[tv, tu]
                for u in range(tu * tile, min(W, tu * tile + tile)):
                    s = start[v, u]
                    k = kind[v, u]
                    lo = s if s < lo else lo
                    x = s if (k == KIND_SURFACE or k == KIND_UNKNOWN) else ninf
                    hi = x if x > hi else hi
                tmin[tv, tu] = lo
                tmax[tv, tu] = hi
    return tmin, tmax


@nb.njit(cache=True, nogil=True, _nrt=False)  # called, not inlined: see module docstring
def _blocks_cleared(rect, tb0, tb1, grid, mp, vt, stack):
    """:func:`tile_block_cleared` for the tile blocks ``tb0..tb1`` of tile ``rect`` as one piece."""
    ua, va, ub, vb = rect
    g1 = min((tb1 + 1) * TILE_BLOCK, grid.n_cells)
    return tile_block_cleared(ua, va, ub, vb, tb0 * TILE_BLOCK, g1, grid, mp, vt, stack)


@nb.njit(cache=True, nogil=True, _nrt=False, inline="always")
def _known_states(tstate, tb0, tb1, windows):
    """What this frame's earlier searches of the tile decided of the blocks ``tb0..tb1`` (query.py keeps
    them per tile): ``(cleared, failed)``. ``cleared``: every block cleared, so the piece is. ``failed``: a
    block not cleared, so the piece and any piece that holds it fail too (a larger piece covers the same
    pixels beyond a farther depth); never with robot ``windows``, where a larger piece's far depth may
    fall into a window."""
    cleared = True
    failed = False
    for tb in range(tb0, tb1 + 1):
        cleared = cleared and tstate[tb] == 1
        failed = failed or tstate[tb] == 2
    return cleared, failed and not windows


@nb.njit(cache=True, nogil=True, _nrt=False)
def tile_chunk_cleared(rect, tb0, tb1, grid, mp, vt, sc, eager):
    """Decide at once the tile blocks ``tb0..tb1`` of tile ``rect`` = ``(ua, va, ub, vb)``.

    The whole chunk is tried first (one footprint test per camera through the min pyramid). If it fails,
    its blocks stay undecided (tested lazily by the column searches that reach them, which is cheaper
    where obstacles are near), unless ``eager``: then its two halves are tried, and the blocks of a half
    that fails one by one, until one fails. Marks ``sc.tstate`` (1 cleared, 2 not); returns True when every
    block of the chunk is cleared.
    """
    tstate = sc.tstate
    if tb0 > tb1:
        return True
    known, failed = _known_states(tstate, tb0, tb1, vt.windows)
    if known:
        return True
    if failed and (tb1 == tb0 or not eager):
        return False
    if not failed and _blocks_cleared(rect, tb0, tb1, grid, mp, vt, sc.stack):
        for tb in range(tb0, tb1 + 1):
            tstate[tb] = 1
        return True
    if tb1 == tb0:
        tstate[tb0] = 2
        return False
    if not eager:
        return False
    mid = (tb0 + tb1 + 1) // 2
    for half in range(2):
        a = tb0 if half == 0 else mid
        b = mid - 1 if half == 0 else tb1
        half_known, half_failed = _known_states(tstate, a, b, vt.windows)
        if half_known or (not half_failed and _blocks_cleared(rect, a, b, grid, mp, vt, sc.stack)):
            for tb in range(a, b + 1):
                tstate[tb] = 1
            continue
        allc = True  # decide each block now (the caller may then skip the whole tile)
        for tb in range(a, b + 1):
            if tstate[tb] == 2:
                allc = False
            elif tstate[tb] == 1 or _blocks_cleared(rect, tb, tb, grid, mp, vt, sc.stack):
                tstate[tb] = 1
            else:
                tstate[tb] = 2
                allc = False
        if not allc:
            return False  # (the other half, if not yet tried, stays undecided)
    return True


@nb.njit(cache=True, nogil=True, _nrt=False, error_model="numpy", fastmath=FASTMATH)
def tile_chunk_prepare(P, h, lim_t, rect, tmin_t, tmx, intr, grid, mp, vt, sc):
    """Per-tile chunk decision of the query: returns ``(allclear, pending, g0c, g1c, skip_tile, beyond_out)``.

    ``lim_t``: the current search limit; ``tmin_t`` / ``tmx``: the tile's smallest start and largest
    non-robot start. ``pending``: the chunk is to be tested at the tile's first column search, if any.
    ``beyond_out``: no column of the tile can reach the space beyond the grid.
    """
    px, py, pz = P
    ta, tva, tb_, tvb = rect
    d_min, dd, n_cells = grid.d_min, grid.dd, grid.n_cells
    # The depth chunk that the tile's column searches can reach: a visited segment holds a point x of a
    # pixel-centre ray with |P - x| <= T (T as in column_search, for the current limit, which only shrinks
    # later). The tile-centre ray point y at the same depth s lies within hT s of x, and s <= pz + T, so
    # |P - y| <= T2 = T + hT (pz + T): s lies within the window of the tile-centre ray where its distance
    # to P is at most T2, and no nearer than the tile's smallest start depth. One cell of margin each side.
    T_t = (lim_t + h * pz) / (1.0 - h)
    a_t = ((ta + tb_) * 0.5 - intr.cx) / intr.fx
    b_t = ((tva + tvb) * 0.5 - intr.cy) / intr.fy
    hT = 0.5 * math.sqrt(((tb_ - ta) / intr.fx) ** 2 + ((tvb - tva) / intr.fy) ** 2)
    rr_t = a_t * a_t + b_t * b_t + 1.0
    sl_t = (px * a_t + py * b_t + pz) / rr_t
    l2_t = max(0.0, px * px + py * py + pz * pz - sl_t * sl_t * rr_t)
    T2 = T_t + hT * (pz + T_t)
    dl_t = math.sqrt(max(0.0, T2 * T2 - l2_t) / rr_t) * (1.0 + 1e-9) + 1e-9
    zlo = max(tmin_t, pz - T_t, sl_t - dl_t)
    zhi = min(pz + T_t, sl_t + dl_t)
    g0c = max(0, int(math.floor((zlo - d_min) / dd)) - 1)
    g1c = min(n_cells - 1, int(math.floor((zhi - d_min) / dd)) + 1)
    # Skippable tile: no non-robot pixel beyond P (no case ii), the space beyond the grid out of reach,
    # and a lower bound of the distance to the tile frustum between its smallest start and the largest top
    # of a first segment above T. Only then are the chunk's blocks decided eagerly.
    skippable = False
    beyond_out = zhi < d_min + n_cells * dd - dd
    if beyond_out and tmx < pz:
        if tmx == -np.inf:
            skippable = True
        else:
            top = max(tmx, d_min) + dd
            s = min(max(sl_t, tmin_t), top)
            dx, dy, dz = px - s * a_t, py - s * b_t, pz - s
            dr_t = math.sqrt(dx * dx + dy * dy + dz * dz)
            skippable = dr_t * (1.0 - hT) - hT * pz > T_t * (1.0 + 1e-9) + 1e-9
    allclear = g0c > g1c  # (no grid cell within reach)
    pending = False
    if not allclear and not skippable:
        pending = True
    elif not allclear:
        allclear = tile_chunk_cleared(rect, g0c // TILE_BLOCK, g1c // TILE_BLOCK, grid, mp, vt, sc, skippable)
    return allclear, pending, g0c, g1c, allclear and skippable, beyond_out
