"""The secondary cameras' votes on principal cells and on blocks of cells (RA-L'16 §VI, conservative form).

Camera k clears (calls free) a cell only when the cell lies entirely in front of camera k and inside its
image and *every* pixel of its footprint (:mod:`depthguard.depthgrid.footprint`) sees past the cell's far
depth: ``vote > d_end``. For a single cell, a footprint pixel that does not see past is then checked
against the cell's exact projection (:func:`pixel_touches_cell`): a pixel of the bounding box that the
projected cell does not touch has no say about the cell (the same pixel-area sampling as the bounding box,
so the same tolerance). A missing pixel votes 0 and clears nothing; a cell that is not involved for camera
k gets no vote from it. A *block* (several cells of one pixel, or of a whole tile) is cleared when one
camera clears the frustum piece that contains them all: its footprint contains each cell's and its far
depth is at least theirs, and its pixels pass the monotone block rule (:func:`sees_all_before`: the pixel
sees past every depth up to the block's far depth), so every cell in it is cleared by the per-cell rule. (A
robot window behind the vote passes a single cell whose far depth lies in the window; a block whose far
depth lies there held the hidden space in front of the window too, and was cleared with it before.) A block
that is not cleared tells nothing (its cells are then tested one by one).

Records: ``mp`` :class:`~depthguard.depthgrid.records.MapArrays`, ``vt``
:class:`~depthguard.depthgrid.records.Votes`, ``grid`` :class:`~depthguard.depthgrid.records.Grid`.

Compile time: the three vote entry points (:func:`cell_occupied`, :func:`block_cleared`,
:func:`tile_block_cleared`, and ``chunks._blocks_cleared``) are compiled as functions of their own and
called, while their small helpers are inlined into them. numba's IR inliner deep-copies a callee block by
block with its whole variable scope (``InlineWorker.inline_ir``, numba 0.68: blocks x variables), so
inlining these into the column search and the tile loop made the fused query take about 120 s to
compile; as calls, about 30 s, and each call does a vote's work, so the queries lose 0-3 % (BENCHMARKS.md,
"Cold start").
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from depthguard.depthgrid.footprint import DEND_SCALE, cell_footprint, ray, rect_footprint, unpack
from depthguard.depthgrid.pyramid import pixel_sees_past, rect_sees_past
from depthguard.depthgrid.records import Votes

__all__ = [
    "pixel_sees_past",
    "sees_all_before",
    "footprint_sees_past",
    "centre_sees_past",
    "cell_occupied",
    "pixel_touches_cell",
    "block_cleared",
    "tile_block_cleared",
]


@nb.njit(cache=True, nogil=True, _nrt=False, inline="always")
def sees_all_before(k, pv, pu, dend, votes):
    """Pixel (pu, pv) of camera k sees past *every* depth up to ``dend``: its vote exceeds ``dend``, or its
    robot window starts no deeper than its vote and reaches ``dend`` (``lo <= vote``, ``dend <= hi``).

    The block rule: unlike :func:`pixel_sees_past` it is monotone (it holds for every ``d <= dend`` when it
    holds for ``dend``), so a block that passes it passes the per-cell rule for each of its cells, whose far
    depths are at most the block's. Without a window (``lo = +inf``) it is ``vote > dend``, as
    :func:`pixel_sees_past`. A window behind the vote (a box in front of the arm) lets a single cell pass at
    the arm's body, never the hidden space in front of it that a block would hold.
    """
    x = votes[k, pv, pu]
    if x > dend:
        return True
    hm = votes.shape[1] // 3
    return votes[k, hm + pv, pu] <= x and dend <= votes[k, 2 * hm + pv, pu]


@nb.njit(cache=True, nogil=True, _nrt=False, inline="always")
def footprint_sees_past(k, u0, v0, du, dv, q, votes):
    """True when camera k clears the block (or cell) whose footprint this is: every covered pixel sees past
    every depth up to ``d_end`` (:func:`sees_all_before`)."""
    if u0 < 0:
        return False  # not involved: no vote
    dend = q * DEND_SCALE
    for pv in range(v0, v0 + dv + 1):
        for pu in range(u0, u0 + du + 1):
            if not sees_all_before(k, pv, pu, dend, votes):
                return False
    return True


@nb.njit(cache=True, nogil=True, _nrt=False, inline="always")
def _corner(k, cu, cv, d, corner_rays, cams):
    """Image point (x, y) in camera k of the principal corner ray (cu, cv) at depth d; NaN where the corner
    is not in front of camera k (no projection: :func:`pixel_touches_cell` then keeps the pixel)."""
    mx, my, mz = ray(corner_rays, k, cv, cu)
    Z = d * mz + cams[k, 2]
    if not Z > 1e-6:
        return np.nan, np.nan
    return (
        cams[k, 3] * (d * mx + cams[k, 0]) / Z + cams[k, 5],
        cams[k, 4] * (d * my + cams[k, 1]) / Z + cams[k, 6],
    )


@nb.njit(cache=True, nogil=True, _nrt=False)
def pixel_touches_cell(k, u, v, d1, d2, pu, pv, corner_rays, cams):
    """False only when pixel square ``[pu, pu+1) x [pv, pv+1)`` of camera k is strictly separated from the
    projection of principal cell ``(u, v, [d1, d2])`` (the convex hull of its 8 projected corners).

    Separating-axis test: the square and the hull are disjoint exactly when a line through two projected
    corners has all 8 corners on one side and the square's 4 corners strictly (1e-6 px) on the other (the
    image axes do not separate them: the pixel lies in the hull's bounding box). Only ever *removes* a
    pixel that sees nothing of the cell, so it never clears more than the exact projection allows. A corner
    not in front of camera k (or a NaN or infinite depth) gives no separating line: True.
    """
    x0, y0 = _corner(k, u, v, d1, corner_rays, cams)
    x1, y1 = _corner(k, u, v, d2, corner_rays, cams)
    x2, y2 = _corner(k, u + 1, v, d1, corner_rays, cams)
    x3, y3 = _corner(k, u + 1, v, d2, corner_rays, cams)
    x4, y4 = _corner(k, u, v + 1, d1, corner_rays, cams)
    x5, y5 = _corner(k, u, v + 1, d2, corner_rays, cams)
    x6, y6 = _corner(k, u + 1, v + 1, d1, corner_rays, cams)
    x7, y7 = _corner(k, u + 1, v + 1, d2, corner_rays, cams)
    px = (x0, x1, x2, x3, x4, x5, x6, x7)
    py = (y0, y1, y2, y3, y4, y5, y6, y7)
    fu = float(pu)
    fv = float(pv)
    for m in range(8):  # a projected corner inside the square: touched, no separating line to look for
        if fu <= px[m] <= fu + 1.0 and fv <= py[m] <= fv + 1.0:
            return True
    sx = (fu, fu + 1.0, fu + 1.0, fu)
    sy = (fv, fv, fv + 1.0, fv + 1.0)
    for i in range(8):
        for j in range(8):
            ex = px[j] - px[i]
            ey = py[j] - py[i]
            if ex * ex + ey * ey < 1e-18:
                continue
            # every projected corner on the left of i -> j (or on the line, within 1e-9 px: rounding, so that
            # compiled and interpreted runs decide alike on collinear corners; the square must lie 1e-6 px
            # beyond the line, so the line still separates)
            ok = True
            tol = 1e-9 * math.sqrt(ex * ex + ey * ey)
            for m in range(8):
                if not ex * (py[m] - py[i]) - ey * (px[m] - px[i]) >= -tol:  # (NaN: no line)
                    ok = False
                    break
            if not ok:
                continue
            sep = True  # every square corner strictly on the right
            for c in range(4):
                if not ex * (sy[c] - py[i]) - ey * (sx[c] - px[i]) <= -1e-6 * math.sqrt(ex * ex + ey * ey):
                    sep = False
                    break
            if sep:
                return False
    return True


@nb.njit(cache=True, nogil=True, _nrt=False, inline="always")
def _cell_seen_past(k, u, v, d1, d2, u0, v0, du, dv, q, mp, votes):
    """:func:`footprint_sees_past` for one cell, with each failing pixel checked against the cell's exact
    projection (:func:`pixel_touches_cell`)."""
    dend = q * DEND_SCALE
    for pv in range(v0, v0 + dv + 1):
        for pu in range(u0, u0 + du + 1):
            if not pixel_sees_past(k, pv, pu, dend, votes):
                if pixel_touches_cell(k, u, v, d1, d2, pu, pv, mp.corner_rays, mp.cams):
                    return False
    return True


@nb.njit(cache=True, nogil=True, _nrt=False, inline="always")
def _sees_past(k, u0, v0, du, dv, q, vt, stack):
    """:func:`footprint_sees_past` for an involved block footprint, through the min pyramid when it is large.

    The pyramid is built from ``e = max(vote, hi)`` where ``lo <= vote`` (else the vote), and ``e > d_end``
    is the block rule of :func:`sees_all_before`. The walk is taken without windows: its nodes answer by
    ``e``, the pixels it reaches at the rectangle's edge by the vote alone (stricter where a window starts
    before the vote: a block fails that the pixel loop would clear, and its cells are tested one by one)."""
    if (du + 1) * (dv + 1) <= 128:
        return footprint_sees_past(k, u0, v0, du, dv, q, vt.votes)
    return rect_sees_past(k, u0, v0, u0 + du, v0 + dv, q * DEND_SCALE, Votes(vt.votes, vt.pyr, vt.meta, False), stack)


@nb.njit(cache=True, nogil=True, _nrt=False, inline="always")
def centre_sees_past(k, u, v, d1, d2, mp, votes):
    """Quick necessary test for camera k clearing the frustum piece ``(u, v, [d1, d2])``.

    The piece's centre lies inside its footprint and nearer than ``d_end``, so unless the pixel under the
    centre measures beyond the centre's depth, camera k cannot clear it. One projection and one read
    instead of eight projections; applied before every footprint test, in both map modes.
    """
    cams = mp.cams
    rays = mp.centre_rays
    dm = 0.5 * (d1 + d2)
    mx, my, mz = ray(rays, k, v, u)
    Z = dm * mz + cams[k, 2]
    if Z <= 1e-6:
        return False
    iz = 1.0 / Z
    pu = cams[k, 3] * (dm * mx + cams[k, 0]) * iz + cams[k, 5]
    pv = cams[k, 4] * (dm * my + cams[k, 1]) * iz + cams[k, 6]
    if not (pu >= 0.0 and pv >= 0.0 and pu < cams[k, 7] and pv < cams[k, 8]):
        return False
    # the vote, or the top of the pixel's robot window (pixel_sees_past needs hi >= d_end > Z)
    hm = votes.shape[1] // 3
    return votes[k, int(pv), int(pu)] > Z or votes[k, 2 * hm + int(pv), int(pu)] > Z


@nb.njit(cache=True, nogil=True, _nrt=False)  # called, not inlined: see module docstring
def cell_occupied(u, v, g, grid, mp, votes, need_vote):
    """RA-L'16 §VI: a cell is occupied unless some involved secondary camera sees past it entirely.

    With ``need_vote`` (case iv, behind a robot pixel of the principal camera) at least one secondary
    camera must be involved: space that only the robot hides from the principal camera and that no other
    camera watches stays unseen (``docs/conventions.md``), as with one camera.
    """
    involved = False
    d1 = grid.d_min + g * grid.dd
    d2 = d1 + grid.dd
    for k in range(mp.cams.shape[0]):
        if mp.stored:
            u0, v0, du, dv, q = unpack(mp.pmap[k, v, u, g])
        elif need_vote or centre_sees_past(k, u, v, d1, d2, mp, votes):
            u0, v0, du, dv, q = cell_footprint(k, u, v, d1, d2, mp.corner_rays, mp.cams)
        else:
            continue  # cannot clear; its involvement does not matter
        if u0 >= 0:
            involved = True
            if centre_sees_past(k, u, v, d1, d2, mp, votes) and _cell_seen_past(
                k, u, v, d1, d2, u0, v0, du, dv, q, mp, votes
            ):
                return False
    return involved or not need_vote


@nb.njit(cache=True, nogil=True, _nrt=False)  # called, not inlined: see module docstring
def block_cleared(u, v, g0, g1, grid, mp, vt, stack):
    """True when one secondary camera clears every cell ``g0 <= g < g1`` of pixel (u, v) at once.

    The block's footprint is that of the frustum piece between ``d_min + g0 Δd`` and ``d_min + g1 Δd``
    (widened by 1 nm); see the module docstring.
    """
    d1 = grid.d_min + g0 * grid.dd - 1e-9
    d2 = grid.d_min + g1 * grid.dd + 1e-9
    for k in range(mp.cams.shape[0]):
        if not centre_sees_past(k, u, v, d1, d2, mp, vt.votes):
            continue
        u0, v0, du, dv, q = cell_footprint(k, u, v, d1, d2, mp.corner_rays, mp.cams)
        if u0 >= 0 and _sees_past(k, u0, v0, du, dv, q, vt, stack):
            return True
    return False


@nb.njit(cache=True, nogil=True, _nrt=False)  # called, not inlined: see module docstring
def tile_block_cleared(ua, va, ub, vb, g0, g1, grid, mp, vt, stack):
    """True when one secondary camera clears the cells ``g0 <= g < g1`` of every pixel of a tile at once.

    Same argument as :func:`block_cleared`, for the frustum over the tile's pixels ``[ua, ub) x [va, vb)``.
    """
    cams = mp.cams
    cr = mp.corner_rays
    d1 = grid.d_min + g0 * grid.dd - 1e-9
    d2 = grid.d_min + g1 * grid.dd + 1e-9
    dm = 0.5 * (d1 + d2)
    for k in range(cams.shape[0]):
        # quick necessary test at the centre of the piece
        ax, ay, az = ray(cr, k, va, ua)
        bx, by, bz = ray(cr, k, va, ub)
        cx_, cy_, cz_ = ray(cr, k, vb, ua)
        ex, ey, ez = ray(cr, k, vb, ub)
        mx = 0.25 * (ax + bx + cx_ + ex)
        my = 0.25 * (ay + by + cy_ + ey)
        mz = 0.25 * (az + bz + cz_ + ez)
        Z = dm * mz + cams[k, 2]
        if Z <= 1e-6:
            continue
        pu = cams[k, 3] * (dm * mx + cams[k, 0]) / Z + cams[k, 5]
        pv = cams[k, 4] * (dm * my + cams[k, 1]) / Z + cams[k, 6]
        if not (pu >= 0.0 and pv >= 0.0 and pu < cams[k, 7] and pv < cams[k, 8]):
            continue
        hm = vt.votes.shape[1] // 3
        if not (vt.votes[k, int(pv), int(pu)] > Z or vt.votes[k, 2 * hm + int(pv), int(pu)] > Z):
            continue
        u0, v0, du, dv, q = rect_footprint(k, ua, va, ub, vb, d1, d2, cr, cams)
        if u0 >= 0 and _sees_past(k, u0, v0, du, dv, q, vt, stack):
            return True
    return False
