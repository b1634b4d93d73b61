"""The column search (RA-L'16 §VI cases iii and iv): the nearest occupied depth interval of one pixel.

Along principal pixel (u, v) the search segments are: ``-1`` = ``[s0, d_min)`` (before the grid), the
cells ``g`` clipped to start at ``s0``, and ``n_cells`` = ``[d_max, inf)`` (beyond the grid). Space
outside the grid is occupied (no secondary camera can clear it: the principal camera's gray area stays an
obstacle), except behind a robot pixel (case iv), where only a secondary camera can confirm an obstacle.
The cell holding a measured surface at ``s0`` is occupied without a vote (the principal camera measured
it). Any other cell is occupied unless a secondary camera clears it (:mod:`depthguard.depthgrid.votes`).

Order: ``|P - s r|^2 = l2 + rr (s - s_line)^2``, so the ray distance grows with the depth gap to
``s_line`` (the depth of the ray point nearest P): the segments are visited by that gap, alternating
outward, and only within the gap ``delta_max`` where the frustum bound ``d_ray (1 - h) - h d_p`` stays
below ``limit``. The first occupied segment met is the nearest. Free space is skipped in blocks: first an
8-cell block shared by the whole tile (state in ``Scratch.tstate``, shared by the tile's columns), then an
8-cell and a 2-cell block of the column, then single cells; cleared blocks hold only cells that the
per-cell rule clears, so the answer is that of the cell-by-cell search.

Every cell decided by a vote (and every cell of a cleared column block) is written to the frame's
:class:`~depthguard.depthgrid.records.ColumnCache` (``Scratch.cache``): a later search of the same pixel,
by another point or another query of the same frame, skips the decided cells without voting again. A
cell's state depends on the frame only, so the answers are those of the search without the cache. The
cache is read only where a column vote would otherwise follow (after the tile-wide block test), so the
searches that never vote never touch its memory.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np
from numba.cpython.unsafe.numbers import leading_zeros, trailing_zeros
from numba.extending import overload

from depthguard.depthgrid.records import BLOCK, TILE_BLOCK
from depthguard.depthgrid.votes import block_cleared, cell_occupied, tile_block_cleared

__all__ = ["segment", "column_search"]


@nb.njit(cache=True, nogil=True, _nrt=False, inline="always")
def _cell_of(s, grid):
    """Search segment holding depth ``s``: -1 before the grid, ``n_cells`` beyond it (NaN and huge depths too:
    compared before ``int()``, which overflows there)."""
    if s < grid.d_min:
        return -1
    x = (s - grid.d_min) / grid.dd
    if not x < grid.n_cells:
        return grid.n_cells
    return int(math.floor(x))


@nb.njit(cache=True, nogil=True, _nrt=False, inline="always")
def segment(g, s0, grid):
    """Depth interval ``(lo, hi)`` of search segment ``g`` of a column starting at ``s0``."""
    if g < 0:
        return s0, grid.d_min
    if g >= grid.n_cells:
        return max(grid.d_min + grid.n_cells * grid.dd, s0), np.inf
    lo = grid.d_min + g * grid.dd
    return max(lo, s0), lo + grid.dd


_ONE = np.uint64(1)
_ALL = np.uint64(0xFFFFFFFFFFFFFFFF)


@nb.njit(cache=True, nogil=True, _nrt=False, inline="always")
def _has(words, v, u, base, g):
    """Bit ``g`` of the bit set at word ``base`` of pixel (u, v)'s
    :class:`~depthguard.depthgrid.records.ColumnCache` record."""
    return (words[v, u, base + (g >> 6)] & (_ONE << np.uint64(g & 63))) != np.uint64(0)


@nb.njit(cache=True, nogil=True, _nrt=False, inline="always")
def _put(words, v, u, base, g0, g1):
    """Set bits ``g0 <= g < g1`` of the bit set at word ``base`` of pixel (u, v)."""
    for g in range(g0, g1):
        words[v, u, base + (g >> 6)] |= _ONE << np.uint64(g & 63)


@nb.njit(cache=True, nogil=True, _nrt=False, inline="always")
def _refresh(cc, v, u):
    """Forget pixel (u, v)'s bits if they belong to an older frame."""
    gen = np.uint64(cc.gen)
    if cc.words[v, u, 0] != gen:
        for w in range(1, 1 + 2 * cc.nw):
            cc.words[v, u, w] = 0
        cc.words[v, u, 0] = gen


def _lowest_set_bit(x):
    """Index of the lowest set bit of the non-zero uint64 ``x`` (pure Python, for ``NUMBA_DISABLE_JIT``)."""
    x = int(x)
    return (x & -x).bit_length() - 1


def _highest_set_bit(x):
    """Index of the highest set bit of the non-zero uint64 ``x`` (pure Python, for ``NUMBA_DISABLE_JIT``)."""
    return int(x).bit_length() - 1


@overload(_lowest_set_bit, inline="always")
def _lowest_set_bit_jit(x):
    return lambda x: int(trailing_zeros(x))


@overload(_highest_set_bit, inline="always")
def _highest_set_bit_jit(x):
    return lambda x: 63 - int(leading_zeros(x))


@nb.njit(cache=True, nogil=True, _nrt=False, inline="always")
def _free_run(words, v, u, g, going_up, lowest, n_cells):
    """Next segment index after the run of cached free cells (bit set at word 1) from cell ``g`` (up: at
    most ``n_cells``, the space beyond the grid; down: at least ``lowest - 1``), a 64-bit word at a time
    (the first unset bit: count of trailing / leading zeros of the word's complement)."""
    if going_up:
        g += 1
        while g < n_cells:
            w = g >> 6
            x = ~words[v, u, 1 + w] & (_ALL << np.uint64(g & 63))  # unset bits at or above g
            if x != np.uint64(0):
                return min((w << 6) + _lowest_set_bit(x), n_cells)
            g = (w + 1) << 6
        return n_cells
    g -= 1
    while g >= lowest:
        w = g >> 6
        x = ~words[v, u, 1 + w] & (_ALL >> np.uint64(63 - (g & 63)))  # unset bits at or below g
        if x != np.uint64(0):
            r = (w << 6) + _highest_set_bit(x)
            return r if r >= lowest else lowest - 1
        g = (w << 6) - 1
    return lowest - 1


@nb.njit(cache=True, nogil=True, _nrt=False, inline="always")
def _skip_free(words, v, u, g, going_up, up, dn, lowest, n_cells):
    """``(up, dn)`` past the run of cached free cells from cell ``g`` in the search's direction."""
    if going_up:
        return _free_run(words, v, u, g, True, lowest, n_cells), dn
    return up, _free_run(words, v, u, g, False, lowest, n_cells)


@nb.njit(cache=True, nogil=True, _nrt=False, inline="always")
def _nearer_side(up, dn, g_start, g_end, s0, s_line, s_lo, grid):
    """Which segment a column search visits next: 1 the next one up (``up``), 0 the next one down
    (``dn``), -1 none left. By the depth gap between ``s_line`` and each (module docstring); a direction
    is exhausted above ``g_end``, below ``g_start`` or below ``s_lo``."""
    gu = np.inf
    if up <= g_end:
        lo_u = s0 if up < 0 else max(grid.d_min + up * grid.dd, s0)
        gu = lo_u - s_line if lo_u > s_line else 0.0
    gd = np.inf
    if dn >= g_start:
        hi_d = grid.d_min if dn < 0 else grid.d_min + (dn + 1) * grid.dd
        if hi_d >= s_lo:
            gd = s_line - hi_d if hi_d < s_line else 0.0
    if gu == np.inf and gd == np.inf:
        return -1
    return 1 if gu <= gd else 0


@nb.njit(cache=True, nogil=True, _nrt=False, inline="always")
def _skip_cleared_run(tstate, tb, going_up, lowest, n_cells):
    """Next segment index after a run of cleared tile blocks from block ``tb`` (up or down)."""
    if going_up:
        t2 = tb + 1
        while t2 < tstate.shape[0] and tstate[t2] == 1:
            t2 += 1
        return min(t2 * TILE_BLOCK, n_cells)
    t2 = tb - 1
    while t2 >= 0 and tstate[t2] == 1:
        t2 -= 1
    return max((t2 + 1) * TILE_BLOCK, lowest) - 1


@nb.njit(cache=True, nogil=True, error_model="numpy", _nrt=False, inline="always")
def column_search(u, v, a, b, s0, surface, robot, P, h, limit, rect, grid, mp, vt, sc):
    """Nearest occupied interval of pixel (u, v) (ray ``(a, b, 1)``) from ``s0`` on (module docstring).

    Args:
        surface / robot: the pixel's kind (a measured surface at ``s0``; a robot pixel, case iv).
        P: the point (camera frame); h: pixel frustum slack; limit: stop where the bound reaches it.
        rect: ``(ua, va, ub, vb)`` the pixel's tile; sc: the point's :class:`~depthguard.depthgrid.records.Scratch`.
    Returns:
        ``(found, lo, hi, tests)``: the depth interval of the occupied segment, and the number of cell and
        block votes taken.
    """
    px, py, pz = P
    n_cells = grid.n_cells
    tstate = sc.tstate
    rr = a * a + b * b + 1.0
    pr = px * a + py * b + pz
    s_line = pr / rr
    l2 = max(px * px + py * py + pz * pz - pr * s_line, 0.0)
    T = (limit + h * pz) / (1.0 - h)
    if not l2 < T * T:
        return False, 0.0, 0.0, 0
    delta_max = math.sqrt((T * T - l2) / rr)
    s_hi = s_line + delta_max
    if s_hi < s0:
        return False, 0.0, 0.0, 0
    g_start = _cell_of(s0, grid)
    g_end = _cell_of(s_hi, grid)
    g_c = max(_cell_of(s_line if s_line > s0 else s0, grid), g_start)
    s_lo = s_line - delta_max
    lowest = max(g_start + 1 if surface else g_start, 0)
    cc = sc.cache
    cw = cc.words
    occ0 = 1 + cc.nw  # first word of the occupied bits
    cached = cc.on
    fresh = False  # the pixel's record checked against this frame's generation
    up = g_c
    dn = g_c - 1
    bu = BLOCK  # current block size in each direction: shrinks where blocks fail, near obstacles
    bd = BLOCK
    tests = 0
    while True:
        side = _nearer_side(up, dn, g_start, g_end, s0, s_line, s_lo, grid)
        if side < 0:
            return False, 0.0, 0.0, tests
        going_up = side == 1
        if going_up:
            g = up
            up += 1
        else:
            g = dn
            dn -= 1
        lo, hi = segment(g, s0, grid)
        if g < 0 or g >= n_cells:
            if robot:
                continue
            return True, lo, hi, tests
        if surface and g == g_start:
            return True, lo, hi, tests
        # skip cleared space a tile-wide block at a time (tstate: 0 unknown, 1 cleared, 2 not cleared) ...
        tb = g // TILE_BLOCK
        if tstate[tb] == 0:
            tests += 1
            g1 = min((tb + 1) * TILE_BLOCK, n_cells)
            ua, va, ub, vb = rect
            tstate[tb] = 1 if tile_block_cleared(ua, va, ub, vb, tb * TILE_BLOCK, g1, grid, mp, vt, sc.stack) else 2
        if tstate[tb] == 1:
            if going_up:
                up = _skip_cleared_run(tstate, tb, True, lowest, n_cells)
            else:
                dn = _skip_cleared_run(tstate, tb, False, lowest, n_cells)
            continue
        # ... then what this frame's earlier searches decided (touched only where a vote would follow) ...
        if cached:
            if not fresh:
                _refresh(cc, v, u)
                fresh = True
            if _has(cw, v, u, occ0, g):
                return True, lo, hi, tests
            if _has(cw, v, u, 1, g):
                up, dn = _skip_free(cw, v, u, g, going_up, up, dn, lowest, n_cells)
                continue
        # ... then a block of this column, then single cells
        if going_up:
            if bu > 1 and g + bu <= n_cells:
                tests += 1
                if block_cleared(u, v, g, g + bu, grid, mp, vt, sc.stack):
                    if cached:
                        _put(cw, v, u, 1, g, g + bu)
                    up = g + bu
                    continue
                bu = bu // 4
        elif bd > 1 and g - bd + 1 >= lowest:
            tests += 1
            if block_cleared(u, v, g - bd + 1, g + 1, grid, mp, vt, sc.stack):
                if cached:
                    _put(cw, v, u, 1, g - bd + 1, g + 1)
                dn = g - bd
                continue
            bd = bd // 4
        tests += 1
        occupied = cell_occupied(u, v, g, grid, mp, vt.votes, robot)
        if cached:
            _put(cw, v, u, occ0 if occupied else 1, g, g + 1)
        if occupied:
            return True, lo, hi, tests
