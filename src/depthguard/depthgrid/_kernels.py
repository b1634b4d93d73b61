"""Numba kernels of the depth grid: cell footprints, the off-line map, cell votes, the on-line query.

All kernels use ``cache=True``: the first call on a new machine compiles them (measured on the 2-core
benchmark machine: about 4 s for the query kernel, 0.7 s for the frame kernels, 2 s for the stored-map
builder); later processes load them from numba's on-disk cache in well under a second.

Conventions shared by every kernel (see :mod:`depthguard.depthgrid.fusion` for the method):

* the principal camera's pixel-corner rays are ``c = ((u' - cx)/fx, (v' - cy)/fy, 1)``, ``u' = 0..W``;
  for secondary camera k, ``corner_rays[k, v', u'] = M_k c`` (``centre_rays[k, v, u]`` likewise for the
  pixel-centre rays) with ``M_k = R_k R_0^T``, and ``cams[k] = (b_k, fx, fy, cx, cy, W, H)`` with
  ``b_k = t_k - M_k t_0``, so the cell corner at depth ``d`` is ``X_k = d M_k c + b_k``;
* a cell's footprint in camera k is the pixel bounding box ``[u0, u0+du] x [v0, v0+dv]`` of its 8
  projected corners, and ``q`` its quantised far depth: ``d_end = q * DEND_SCALE >= max_k z`` (rounded up,
  so conservatively far). ``u0 = -1`` marks a camera that is not involved (the cell is not entirely in
  front of it and inside its image, or its footprint is wider than ``FOOT_MAX`` pixels); the stored map
  packs the five numbers in one int64 (:func:`pack`);
* principal pixel kinds: 0 nothing, 1 measured surface at ``start``, 2 unknown from ``start`` on
  (missing pixel at the near limit), 3 robot at ``start`` (RA-L'16 case iv).

Performance notes: the helpers are compiled with ``_nrt=False`` (no reference counting: every array
argument of a call would otherwise cost two atomic operations, which dominated the run time), take few
array arguments (each costs a dozen machine words per call), and the per-cell helpers are inlined into
the column search at numba IR level (``inline="always"``). None of the footprint code is compiled with
fast-math, so the stored map and the on-the-fly footprints are bit-identical.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

DEND_SCALE = 4e-4  # metres per unit of the quantised far depth (15 bits): 0.4 mm steps, up to 13.1 m
Q_MAX = 32767
FOOT_MAX = 255  # largest footprint extent (pixels - 1) a cell may have in a secondary camera
KIND_NONE, KIND_SURFACE, KIND_UNKNOWN, KIND_ROBOT = 0, 1, 2, 3
BLOCK = 8  # first block size (cells) tried along a column; then 2, then single cells
TILE_BLOCK = 8  # depth cells per tile-wide block
# fast-math for the query loop, without the no-NaN / no-inf assumptions (inf marks "nothing" everywhere)
_FAST = {"nsz", "arcp", "contract", "afn", "reassoc"}


@nb.njit(cache=True, _nrt=False, inline="always")
def cell_footprint(k, u, v, d1, d2, corner_rays, cams):
    """Footprint ``(u0, v0, du, dv, q)`` of principal cell ``(u, v, [d1, d2])`` in secondary camera k."""
    return rect_footprint(k, u, v, u + 1, v + 1, d1, d2, corner_rays, cams)


@nb.njit(cache=True, _nrt=False, inline="always")
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
            mx = corner_rays[k, cv, cu, 0]
            my = corner_rays[k, cv, cu, 1]
            mz = corner_rays[k, cv, cu, 2]
            for s in range(2):
                d = d1 if s == 0 else d2
                Z = d * mz + bz
                if Z <= 1e-6:
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
    iu0 = int(math.floor(umin))
    iv0 = int(math.floor(vmin))
    du = int(math.floor(umax)) - iu0
    dv = int(math.floor(vmax)) - iv0
    q = int(math.ceil(zmax / DEND_SCALE))
    if du > FOOT_MAX or dv > FOOT_MAX or q > Q_MAX:
        return -1, 0, 0, 0, 0
    return iu0, iv0, du, dv, q


@nb.njit(cache=True, _nrt=False)
def pack(u0, v0, du, dv, q):
    """One int64: du | dv << 8 | (u0 + 1) << 16 | v0 << 32 | q << 48 (all fields non-negative)."""
    if u0 < 0:
        return np.int64(0)
    return np.int64(du) | (np.int64(dv) << 8) | (np.int64(u0 + 1) << 16) | (np.int64(v0) << 32) | (np.int64(q) << 48)


@nb.njit(cache=True, _nrt=False, inline="always")
def unpack(w):
    """Inverse of :func:`pack`; ``u0 = -1`` for a camera that is not involved."""
    return (((w >> 16) & 0xFFFF) - 1, (w >> 32) & 0xFFFF, w & 0xFF, (w >> 8) & 0xFF, (w >> 48) & 0x7FFF)


@nb.njit(cache=True, _nrt=False, inline="always")
def pixel_sees_past(k, pv, pu, dend, votes):
    """Pixel (pu, pv) of camera k does not hold an obstacle before ``dend``: its vote depth exceeds
    ``dend``, or ``dend`` lies in the pixel's robot window (``lo <= dend <= hi``: the part of any cell
    that ends at ``dend`` and that this pixel sees lies inside the robot's inflated capsules).

    ``votes`` holds three row blocks of equal height (see ``DepthGridFusion``): the votes, then ``lo``
    (+inf where the pixel has no window), then ``hi`` (-inf where none).
    """
    if votes[k, pv, pu] > dend:
        return True
    hm = votes.shape[1] // 3
    return votes[k, hm + pv, pu] <= dend and dend <= votes[k, 2 * hm + pv, pu]


@nb.njit(cache=True, _nrt=False, inline="always")
def footprint_sees_past(k, u0, v0, du, dv, q, votes):
    """True when camera k calls the cell free: every covered pixel sees past ``d_end``
    (:func:`pixel_sees_past`)."""
    if u0 < 0:
        return False  # not involved: no vote
    dend = q * DEND_SCALE
    for pv in range(v0, v0 + dv + 1):
        for pu in range(u0, u0 + du + 1):
            if not pixel_sees_past(k, pv, pu, dend, votes):
                return False
    return True


@nb.njit(cache=True, _nrt=False, inline="always")
def sees_past(k, u0, v0, du, dv, q, votes, pyr, meta, stack):
    """:func:`footprint_sees_past` for an involved footprint, through the min pyramid when it is large."""
    if (du + 1) * (dv + 1) <= 128:
        return footprint_sees_past(k, u0, v0, du, dv, q, votes)
    return rect_sees_past(k, u0, v0, u0 + du, v0 + dv, q * DEND_SCALE, votes, pyr, meta, stack)


@nb.njit(cache=True, _nrt=False, inline="always")
def centre_sees_past(k, u, v, d1, d2, centre_rays, cams, votes):
    """Quick necessary test for camera k clearing the frustum piece ``(u, v, [d1, d2])``.

    The piece's centre lies inside its footprint and nearer than ``d_end``, so unless the pixel under the
    centre measures beyond the centre's depth, camera k cannot clear it. One projection and one read
    instead of eight projections; applied before every footprint test, in both map modes.
    """
    dm = 0.5 * (d1 + d2)
    Z = dm * centre_rays[k, v, u, 2] + cams[k, 2]
    if Z <= 1e-6:
        return False
    iz = 1.0 / Z
    pu = cams[k, 3] * (dm * centre_rays[k, v, u, 0] + cams[k, 0]) * iz + cams[k, 5]
    pv = cams[k, 4] * (dm * centre_rays[k, v, u, 1] + cams[k, 1]) * iz + cams[k, 6]
    if not (pu >= 0.0 and pv >= 0.0 and pu < cams[k, 7] and pv < cams[k, 8]):
        return False
    # the vote, or the top of the pixel's robot window (pixel_sees_past needs hi >= d_end > Z)
    hm = votes.shape[1] // 3
    return votes[k, int(pv), int(pu)] > Z or votes[k, 2 * hm + int(pv), int(pu)] > Z


@nb.njit(cache=True, _nrt=False, inline="always")
def cell_occupied(u, v, g, d_min, dd, corner_rays, centre_rays, cams, stored, pmap, votes, need_vote):
    """RA-L'16 §VI: a cell is occupied unless some involved secondary camera sees past it entirely.

    With ``need_vote`` (case iv, behind a robot pixel of the principal camera) at least one secondary
    camera must be involved: space that only the robot hides from the principal camera and that no
    other camera watches stays unseen (DESIGN.md §4), as with one camera.
    """
    involved = False
    d1 = d_min + g * dd
    for k in range(cams.shape[0]):
        if stored:
            u0, v0, du, dv, q = unpack(pmap[k, v, u, g])
        elif need_vote or centre_sees_past(k, u, v, d1, d1 + dd, centre_rays, cams, votes):
            u0, v0, du, dv, q = cell_footprint(k, u, v, d1, d1 + dd, corner_rays, cams)
        else:
            continue  # cannot clear; its involvement does not matter
        if u0 >= 0:
            involved = True
            if centre_sees_past(k, u, v, d1, d1 + dd, centre_rays, cams, votes) and footprint_sees_past(
                k, u0, v0, du, dv, q, votes
            ):
                return False
    return involved or not need_vote


@nb.njit(cache=True, _nrt=False, inline="always")
def block_cleared(u, v, g0, g1, d_min, dd, corner_rays, centre_rays, cams, votes, pyr, meta, stack):
    """True when one secondary camera clears every cell ``g0 <= g < g1`` of pixel (u, v) at once.

    The block's footprint is that of the frustum piece between ``d_min + g0 Δd`` and ``d_min + g1 Δd``
    (widened by 1 nm): it contains the footprint of each of its cells, and its far depth is at least
    theirs, so a cleared block implies that every cell is cleared by the per-cell rule. A block that is
    not cleared tells nothing; the caller then tests its cells one by one. Results are therefore
    identical to the per-cell search, only faster through free space (RA-L'16 case iii shadows).
    """
    d1 = d_min + g0 * dd - 1e-9
    d2 = d_min + g1 * dd + 1e-9
    for k in range(cams.shape[0]):
        if not centre_sees_past(k, u, v, d1, d2, centre_rays, cams, votes):
            continue
        u0, v0, du, dv, q = cell_footprint(k, u, v, d1, d2, corner_rays, cams)
        if u0 >= 0 and sees_past(k, u0, v0, du, dv, q, votes, pyr, meta, stack):
            return True
    return False


@nb.njit(cache=True, _nrt=False, inline="always")
def tile_block_cleared(ua, va, ub, vb, g0, g1, d_min, dd, corner_rays, cams, votes, pyr, meta, stack):
    """True when one secondary camera clears the cells ``g0 <= g < g1`` of every pixel of a tile at once.

    Same argument as :func:`block_cleared`, for the frustum over the tile's pixels ``[ua, ub) x [va, vb)``.
    Shared by all the columns of the tile within one query.
    """
    d1 = d_min + g0 * dd - 1e-9
    d2 = d_min + g1 * dd + 1e-9
    dm = 0.5 * (d1 + d2)
    for k in range(cams.shape[0]):
        # quick necessary test at the centre of the piece
        mx = 0.25 * (
            corner_rays[k, va, ua, 0]
            + corner_rays[k, va, ub, 0]
            + corner_rays[k, vb, ua, 0]
            + corner_rays[k, vb, ub, 0]
        )
        my = 0.25 * (
            corner_rays[k, va, ua, 1]
            + corner_rays[k, va, ub, 1]
            + corner_rays[k, vb, ua, 1]
            + corner_rays[k, vb, ub, 1]
        )
        mz = 0.25 * (
            corner_rays[k, va, ua, 2]
            + corner_rays[k, va, ub, 2]
            + corner_rays[k, vb, ua, 2]
            + corner_rays[k, vb, ub, 2]
        )
        Z = dm * mz + cams[k, 2]
        if Z <= 1e-6:
            continue
        pu = cams[k, 3] * (dm * mx + cams[k, 0]) / Z + cams[k, 5]
        pv = cams[k, 4] * (dm * my + cams[k, 1]) / Z + cams[k, 6]
        if not (pu >= 0.0 and pv >= 0.0 and pu < cams[k, 7] and pv < cams[k, 8]):
            continue
        if not votes[k, int(pv), int(pu)] > Z:
            continue
        u0, v0, du, dv, q = rect_footprint(k, ua, va, ub, vb, d1, d2, corner_rays, cams)
        if u0 >= 0 and sees_past(k, u0, v0, du, dv, q, votes, pyr, meta, stack):
            return True
    return False


# ---------------------------------------------------------------------------------------------------------
# Range-minimum pyramid of the vote images (per frame) and the exact "every pixel of a rectangle sees past"
# test built on it.
#
# A footprint test asks whether every pixel of a rectangle of camera k reads deeper than a far depth.
# For a 16x16-pixel tile over tens of centimetres of depth the footprint covers hundreds to thousands of
# pixels, and reading them one by one dominated the query in scenes where a person stands in front of
# the principal camera (RA-L'16 case iii almost everywhere). The pyramid holds, for l = 1..L, the
# minimum vote over each aligned 2^l x 2^l block (level 0 is the vote image itself). The test walks it
# from the coarsest level whose blocks span at most 4 per axis: a block whose minimum exceeds the
# threshold clears all its pixels at once (inside the rectangle or not); a block at or below the
# threshold that lies entirely inside the rectangle fails the test; a block straddling the rectangle's
# edge is split into its four children. It therefore answers exactly as the pixel loop does (the same
# float32 values compared with the same threshold), in a few lookups where the space is clearly free.
# ---------------------------------------------------------------------------------------------------------
PYR_STACK = 256  # entries (3 int64 each) of the explicit stack of the descent


def pyramid_layout(h, w):
    """(L, 3) int64 rows ``(offset, rows, cols)`` of levels 1..L of an (h, w) image's min pyramid.

    Levels are added until both dimensions are at most 4 blocks, so a rectangle spans at most 4 blocks
    per axis at the top level; returns the meta array and the total number of cells.
    """
    rows = []
    off = 0
    l = 1
    while True:
        hl = (h + (1 << l) - 1) >> l
        wl = (w + (1 << l) - 1) >> l
        rows.append((off, hl, wl))
        off += hl * wl
        if hl <= 4 and wl <= 4:
            break
        l += 1
    return np.array(rows, dtype=np.int64).reshape(-1, 3), off


@nb.njit(cache=True)
def build_pyramid(votes, meta, pyr):
    """Fill ``pyr[k]`` (levels 1..L, see :func:`pyramid_layout`) with block minima of ``votes[k]``."""
    H = votes.shape[1]
    W = votes.shape[2]
    for k in range(votes.shape[0]):
        for l in range(meta.shape[0]):
            off = meta[l, 0]
            hl = meta[l, 1]
            wl = meta[l, 2]
            if l == 0:
                for bv in range(hl):
                    va = 2 * bv
                    vb = min(H - 1, va + 1)
                    for bu in range(W // 2):
                        pyr[k, off + bv * wl + bu] = min(
                            min(votes[k, va, 2 * bu], votes[k, va, 2 * bu + 1]),
                            min(votes[k, vb, 2 * bu], votes[k, vb, 2 * bu + 1]),
                        )
                    if W % 2 == 1:
                        pyr[k, off + bv * wl + wl - 1] = min(votes[k, va, W - 1], votes[k, vb, W - 1])
            else:
                poff = meta[l - 1, 0]
                ph = meta[l - 1, 1]
                pw = meta[l - 1, 2]
                for bv in range(hl):
                    for bu in range(wl):
                        m = np.float32(np.inf)
                        for vv in range(2 * bv, min(ph, 2 * bv + 2)):
                            for uu in range(2 * bu, min(pw, 2 * bu + 2)):
                                x = pyr[k, poff + vv * pw + uu]
                                if x < m:
                                    m = x
                        pyr[k, off + bv * wl + bu] = m


@nb.njit(cache=True, _nrt=False)
def rect_sees_past(k, u0, v0, u1, v1, thr, votes, pyr, meta, stack):
    """True when every vote of camera k over pixels ``[u0, u1] x [v0, v1]`` (inclusive) exceeds ``thr``.

    Exactly the answer of the pixel loop of :func:`footprint_sees_past`, through the min pyramid (see
    the comment above :data:`PYR_STACK`).
    """
    if (u1 - u0 + 1) * (v1 - v0 + 1) <= 16:
        for pv in range(v0, v1 + 1):
            for pu in range(u0, u1 + 1):
                if not votes[k, pv, pu] > thr:
                    return False
        return True
    L = meta.shape[0]
    lv = 1
    while lv < L and ((u1 >> lv) - (u0 >> lv) > 3 or (v1 >> lv) - (v0 >> lv) > 3):
        lv += 1
    n = 0
    for bv in range(v0 >> lv, (v1 >> lv) + 1):
        for bu in range(u0 >> lv, (u1 >> lv) + 1):
            stack[3 * n] = lv
            stack[3 * n + 1] = bv
            stack[3 * n + 2] = bu
            n += 1
    while n > 0:
        n -= 1
        lv = stack[3 * n]
        bv = stack[3 * n + 1]
        bu = stack[3 * n + 2]
        if lv == 0:
            if not votes[k, bv, bu] > thr:
                return False
            continue
        if pyr[k, meta[lv - 1, 0] + bv * meta[lv - 1, 2] + bu] > thr:
            continue
        # the block holds a pixel at or below thr: fail if the block lies inside the rectangle
        pa = bu << lv
        pb = ((bu + 1) << lv) - 1
        qa = bv << lv
        qb = ((bv + 1) << lv) - 1
        if pa >= u0 and pb <= u1 and qa >= v0 and qb <= v1:
            return False
        # else split it into its children that meet the rectangle
        c = lv - 1
        for j in range(2):
            cv = 2 * bv + j
            if (((cv + 1) << c) - 1) < v0 or (cv << c) > v1:
                continue
            for i in range(2):
                cu = 2 * bu + i
                if (((cu + 1) << c) - 1) < u0 or (cu << c) > u1:
                    continue
                stack[3 * n] = c
                stack[3 * n + 1] = cv
                stack[3 * n + 2] = cu
                n += 1
    return True


@nb.njit(cache=True, _nrt=False)
def tile_chunk_cleared(
    ua, va, ub, vb, tb0, tb1, d_min, dd, n_cells, corner_rays, cams, votes, pyr, meta, stack, tstate, eager
):
    """Decide at once the tile blocks ``tb0..tb1`` of one tile (the depth chunk its column searches can reach).

    The whole chunk is tried first (one footprint test per camera through the min pyramid). If it fails,
    its blocks stay undecided (tested lazily, block by block, by the column searches that reach them,
    which is cheaper where obstacles are near), unless ``eager``: then its two halves are tried, and the
    blocks of a half that fails one by one, until one fails. Each cleared range is a :func:`tile_block_cleared`
    piece, so every cell in it is cleared by the per-cell rule. Returns True when every block of the chunk
    is cleared: then no column of the tile finds an occupied cell inside the grid within the chunk.
    """
    if tb0 > tb1:
        return True
    if tile_block_cleared(
        ua,
        va,
        ub,
        vb,
        tb0 * TILE_BLOCK,
        min((tb1 + 1) * TILE_BLOCK, n_cells),
        d_min,
        dd,
        corner_rays,
        cams,
        votes,
        pyr,
        meta,
        stack,
    ):
        for tb in range(tb0, tb1 + 1):
            tstate[tb] = 1
        return True
    if tb1 == tb0:
        tstate[tb0] = 2
        return False
    if not eager:
        return False
    mid = (tb0 + tb1 + 1) // 2
    allc = True
    for half in range(2):
        a = tb0 if half == 0 else mid
        b = mid - 1 if half == 0 else tb1
        if tile_block_cleared(
            ua,
            va,
            ub,
            vb,
            a * TILE_BLOCK,
            min((b + 1) * TILE_BLOCK, n_cells),
            d_min,
            dd,
            corner_rays,
            cams,
            votes,
            pyr,
            meta,
            stack,
        ):
            for tb in range(a, b + 1):
                tstate[tb] = 1
        else:
            allc = False
            if eager:  # decide each block now (the caller may then skip the whole tile)
                allc = True
                for tb in range(a, b + 1):
                    if tile_block_cleared(
                        ua,
                        va,
                        ub,
                        vb,
                        tb * TILE_BLOCK,
                        min((tb + 1) * TILE_BLOCK, n_cells),
                        d_min,
                        dd,
                        corner_rays,
                        cams,
                        votes,
                        pyr,
                        meta,
                        stack,
                    ):
                        tstate[tb] = 1
                    else:
                        tstate[tb] = 2
                        allc = False
                if not allc:
                    return False  # (the other half, if not yet tried, stays undecided)
            elif a == b:
                tstate[a] = 2
    return allc


@nb.njit(cache=True)
def tile_max_start(start, kind, tile):
    """Per tile, the largest start depth of its non-robot pixels (surface or unknown); -inf when none."""
    H, W = start.shape
    th = (H + tile - 1) // tile
    tw = (W + tile - 1) // tile
    out = np.full((th, tw), -np.inf, dtype=np.float32)
    for tv in range(th):
        for v in range(tv * tile, min(H, tv * tile + tile)):
            for tu in range(tw):
                m = out[tv, tu]
                for u in range(tu * tile, min(W, tu * tile + tile)):
                    x = start[v, u] if (kind[v, u] == KIND_SURFACE or kind[v, u] == KIND_UNKNOWN) else -np.inf
                    m = max(m, x)
                out[tv, tu] = m
    return out


@nb.njit(cache=True, parallel=True)
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


@nb.njit(cache=True, _nrt=False, inline="always")
def _seg_lo_hi(g, g_start, s0, d_min, dd, n_cells):
    """Depth interval of search segment g: cell g clipped to start at s0.

    Segment -1 is ``[s0, d_min)`` and segment ``n_cells`` is ``[d_max, inf)`` (outside the grid)."""
    if g < 0:
        return s0, d_min
    if g >= n_cells:
        lo = d_min + n_cells * dd
        return max(lo, s0), np.inf
    lo = d_min + g * dd
    return max(lo, s0), lo + dd


@nb.njit(cache=True, _nrt=False, inline="always")
def _ray_seg_dist(px, py, pz, a, b, s_line, lo, hi):
    """Distance from P to the ray points ``s (a, b, 1)``, ``s`` in ``[lo, hi]``."""
    s = s_line
    if s < lo:
        s = lo
    if s > hi:
        s = hi
    dx = px - s * a
    dy = py - s * b
    dz = pz - s
    return math.sqrt(dx * dx + dy * dy + dz * dz)


@nb.njit(cache=True, error_model="numpy", _nrt=False, inline="always")
def column_search(
    u,
    v,
    a,
    b,
    s0,
    surface,
    robot,
    px,
    py,
    pz,
    h,
    limit,
    d_min,
    dd,
    n_cells,
    corner_rays,
    centre_rays,
    cams,
    stored,
    pmap,
    votes,
    ua,
    va,
    ub,
    vb,
    tstate,
    pyr,
    meta,
    stack,
):
    """RA-L'16 §VI cases iii/iv along one principal pixel: the nearest occupied depth interval.

    Searches the cells of pixel (u, v) from ``s0`` on, nearest to P first (alternating outward from the
    cell nearest P), and stops at the first occupied one or when every remaining cell is at least
    ``limit`` away. Space before ``d_min`` and beyond ``d_max`` is outside the grid: no secondary camera
    can clear it, so it stays occupied (gray), except behind a robot pixel (``robot``, case iv), where only
    a secondary camera can confirm an obstacle. With ``surface`` the cell holding the measured surface at
    ``s0`` is occupied without a vote (the principal camera measured it).

    Returns:
        ``(found, lo, hi, tests)``: the depth interval of the occupied cell along the pixel, and the
        number of cell and block votes taken.
    """
    # |P - s r|^2 = l2 + rr (s - s_line)^2: the ray distance grows with |s - s_line|, so the cells are
    # visited by their depth gap to s_line, and only within the gap delta_max where the frustum bound
    # d_ray (1 - h) - h d_p stays below ``limit``
    rr = a * a + b * b + 1.0
    pr = px * a + py * b + pz
    s_line = pr / rr
    l2 = px * px + py * py + pz * pz - pr * s_line
    if l2 < 0.0:
        l2 = 0.0
    T = (limit + h * pz) / (1.0 - h)
    if not l2 < T * T:
        return False, 0.0, 0.0, 0
    delta_max = math.sqrt((T * T - l2) / rr)
    s_hi = s_line + delta_max
    if s_hi < s0:
        return False, 0.0, 0.0, 0
    if s0 < d_min:
        g_start = -1
    else:
        g_start = int(math.floor((s0 - d_min) / dd))
        if g_start > n_cells:
            g_start = n_cells
    if s_hi < d_min:
        g_end = -1
    else:
        g_end = int(math.floor((s_hi - d_min) / dd))
        if g_end > n_cells:
            g_end = n_cells
    s_c = s_line if s_line > s0 else s0
    if s_c < d_min:
        g_c = -1
    else:
        g_c = int(math.floor((s_c - d_min) / dd))
        if g_c > n_cells:
            g_c = n_cells
    if g_c < g_start:
        g_c = g_start
    s_lo = s_line - delta_max
    up = g_c
    dn = g_c - 1
    bu = BLOCK  # current block size in each direction: shrinks where blocks fail, near obstacles
    bd = BLOCK
    tests = 0
    while True:
        # depth gap between s_line and the next segment in each direction (inf when exhausted)
        gu = np.inf
        if up <= g_end:
            lo_u = s0 if up < 0 else max(d_min + up * dd, s0)
            gu = lo_u - s_line if lo_u > s_line else 0.0
        gd = np.inf
        if dn >= g_start:
            hi_d = d_min if dn < 0 else d_min + (dn + 1) * dd
            if hi_d >= s_lo:
                gd = s_line - hi_d if hi_d < s_line else 0.0
        if gu == np.inf and gd == np.inf:
            return False, 0.0, 0.0, tests
        going_up = gu <= gd
        if going_up:
            g = up
            up += 1
        else:
            g = dn
            dn -= 1
        lo, hi = _seg_lo_hi(g, g_start, s0, d_min, dd, n_cells)
        if g < 0 or g >= n_cells:
            if robot:
                continue
            return True, lo, hi, tests
        if surface and g == g_start:
            return True, lo, hi, tests
        # skip cleared space (seen free by another camera) a tile-wide block at a time, shared by the
        # tile's columns (tstate: 0 unknown, 1 cleared, 2 not cleared) ...
        tb = g // TILE_BLOCK
        if tstate[tb] == 0:
            tests += 1
            g1 = min((tb + 1) * TILE_BLOCK, n_cells)
            if tile_block_cleared(
                ua, va, ub, vb, tb * TILE_BLOCK, g1, d_min, dd, corner_rays, cams, votes, pyr, meta, stack
            ):
                tstate[tb] = 1
            else:
                tstate[tb] = 2
        if tstate[tb] == 1:
            # jump over the whole run of cleared blocks (decided eagerly per tile, see tile_chunk_cleared)
            if going_up:
                t2 = tb + 1
                while t2 < tstate.shape[0] and tstate[t2] == 1:
                    t2 += 1
                up = min(t2 * TILE_BLOCK, n_cells)
            else:
                t2 = tb - 1
                while t2 >= 0 and tstate[t2] == 1:
                    t2 -= 1
                lowest = g_start + 1 if surface else g_start
                dn = max((t2 + 1) * TILE_BLOCK, lowest) - 1
            continue
        # ... then a block of this column, then single cells
        if going_up:
            if bu > 1 and g + bu <= n_cells:
                tests += 1
                if block_cleared(u, v, g, g + bu, d_min, dd, corner_rays, centre_rays, cams, votes, pyr, meta, stack):
                    up = g + bu
                    continue
                bu = bu // 4
        else:
            lowest = g_start + 1 if surface else g_start
            if lowest < 0:
                lowest = 0
            if bd > 1 and g - bd + 1 >= lowest:
                tests += 1
                if block_cleared(
                    u, v, g - bd + 1, g + 1, d_min, dd, corner_rays, centre_rays, cams, votes, pyr, meta, stack
                ):
                    dn = g - bd
                    continue
                bd = bd // 4
        tests += 1
        if cell_occupied(u, v, g, d_min, dd, corner_rays, centre_rays, cams, stored, pmap, votes, robot):
            return True, lo, hi, tests


@nb.njit(cache=True, _nrt=False, error_model="numpy", fastmath=_FAST)
def tile_chunk_prepare(
    px,
    py,
    pz,
    h,
    lim_t,
    ta,
    tva,
    tb_,
    tvb,
    tmin_t,
    tmx,
    fx,
    fy,
    cx,
    cy,
    d_min,
    dd,
    n_cells,
    corner_rays,
    cams,
    votes,
    pyr,
    meta,
    stack,
    tstate,
):
    """Per-tile chunk decision of :func:`query_one` (see the comments); returns
    ``(allclear, pending, g0c, g1c, skip_tile)``. A separate function keeps the query loop small."""
    pending = False
    # The depth chunk that the tile's column searches can reach: a visited segment holds a
    # point x of a pixel-centre ray with |P - x| <= T (T as in column_search, for the current
    # limit, which only shrinks later). The tile-centre ray point y at the same depth s lies
    # within hT s of x, and s <= pz + T, so |P - y| <= T2 = T + hT (pz + T): s lies within
    # the window of the tile-centre ray where its distance to P is at most T2, and no nearer
    # than the tile's smallest start depth. One cell of margin on each side.
    T_t = (lim_t + h * pz) / (1.0 - h)
    a_t = ((ta + tb_) * 0.5 - cx) / fx
    b_t = ((tva + tvb) * 0.5 - cy) / fy
    hT = 0.5 * math.sqrt(((tb_ - ta) / fx) ** 2 + ((tvb - tva) / fy) ** 2)
    rr_t = a_t * a_t + b_t * b_t + 1.0
    sl_t = (px * a_t + py * b_t + pz) / rr_t
    l2_t = max(0.0, px * px + py * py + pz * pz - sl_t * sl_t * rr_t)
    T2 = T_t + hT * (pz + T_t)
    dl_t = math.sqrt(max(0.0, T2 * T2 - l2_t) / rr_t) * (1.0 + 1e-9) + 1e-9
    zlo = max(tmin_t, pz - T_t, sl_t - dl_t)
    zhi = min(pz + T_t, sl_t + dl_t)
    g0c = max(0, int(math.floor((zlo - d_min) / dd)) - 1)
    g1c = min(n_cells - 1, int(math.floor((zhi - d_min) / dd)) + 1)
    # Once every grid cell within reach is free for every column of the tile, a column search
    # can only find its first segment: the cell of a measured surface (occupied without a
    # vote), or the unknown space before d_min; behind a robot pixel nothing (case iv). If no
    # non-robot pixel lies beyond P (no case ii) and none of those first segments is within
    # reach (a lower bound of the distance to the tile frustum between the tile's smallest
    # start and the largest top of a first segment exceeds T), the whole tile can be skipped:
    # only then are the chunk's blocks decided eagerly (elsewhere lazily, which is cheaper
    # where obstacles are near).
    skippable = False
    if zhi < d_min + n_cells * dd - dd and tmx < pz:
        if tmx == -np.inf:
            skippable = True
        else:
            top = max(tmx, d_min) + dd
            dr_t = _ray_seg_dist(px, py, pz, a_t, b_t, sl_t, tmin_t, top)
            skippable = dr_t * (1.0 - hT) - hT * pz > T_t * (1.0 + 1e-9) + 1e-9
    allclear = g0c > g1c  # (no grid cell within reach)
    if not allclear and not skippable:
        pending = True  # decided at the tile's first column search, if any
    elif not allclear:
        allclear = tile_chunk_cleared(
            ta,
            tva,
            tb_,
            tvb,
            g0c // TILE_BLOCK,
            g1c // TILE_BLOCK,
            d_min,
            dd,
            n_cells,
            corner_rays,
            cams,
            votes,
            pyr,
            meta,
            stack,
            tstate,
            skippable,
        )
    return allclear, pending, g0c, g1c, allclear and skippable


@nb.njit(cache=True, error_model="numpy", _nrt=False, fastmath=_FAST)
def query_one(
    Pc,
    radius,
    rho,
    mode,
    alpha,
    start,
    kind,
    tmin,
    tmax,
    tile,
    chunks,
    fx,
    fy,
    cx,
    cy,
    near_limit,
    unseen,
    d_min,
    dd,
    n_cells,
    corner_rays,
    centre_rays,
    cams,
    stored,
    pmap,
    votes,
    pyr,
    meta,
    lbs,
    tstate,
    stack,
    out,
):
    """Fused distance query for one control sphere; out[0:10] = D, dir(3), nearest(3), count,
    column searches, votes.

    Everything in the principal camera frame; D is measured from the sphere centre (the caller subtracts
    the radius). ``mode``: 0 min, 1 all (ICRA'12 eq. 9), 2 hybrid (RA-L'16 eq. 11).
    """
    H, W = start.shape
    px = Pc[0]
    py = Pc[1]
    pz = Pc[2]
    reff = rho + radius
    best = reff
    bx = by = bz = 0.0
    nx = ny = nz = np.nan
    count = 0
    sx = sy = sz = 0.0
    h = 0.5 * math.sqrt(1.0 / (fx * fx) + 1.0 / (fy * fy))

    # unseen space of the principal camera: outside its field of view and nearer than its near limit
    # (DESIGN.md §5.2; identical to depthguard.depthspace so that one camera gives the same answer)
    if unseen:
        for k in range(5):
            if k == 0:
                a0 = (0.0 - cx) / fx
                nrm = math.sqrt(1.0 + a0 * a0)
                ux, uy, uz = 1.0 / nrm, 0.0, -a0 / nrm
            elif k == 1:
                a1 = (W - cx) / fx
                nrm = math.sqrt(1.0 + a1 * a1)
                ux, uy, uz = -1.0 / nrm, 0.0, a1 / nrm
            elif k == 2:
                b0 = (0.0 - cy) / fy
                nrm = math.sqrt(1.0 + b0 * b0)
                ux, uy, uz = 0.0, 1.0 / nrm, -b0 / nrm
            elif k == 3:
                b1 = (H - cy) / fy
                nrm = math.sqrt(1.0 + b1 * b1)
                ux, uy, uz = 0.0, -1.0 / nrm, b1 / nrm
            else:
                ux, uy, uz = 0.0, 0.0, 1.0
            s = px * ux + py * uy + pz * uz
            if k == 4:
                s -= near_limit
            if s < 0.0:
                s = 0.0
            if s < reff:
                w = 1.0
                if mode == 1:
                    w = 1.0 / (1.0 + math.exp(((s - radius) * 2.0 / rho - 1.0) * alpha))
                sx += w * ux
                sy += w * uy
                sz += w * uz
                if s < best:
                    best = s
                    bx, by, bz = ux, uy, uz
                    nx, ny, nz = px - s * ux, py - s * uy, pz - s * uz

    # region of surveillance: pixel bounding box of the cube of side 2 reff around P (eq. 8, DESIGN.md §4)
    u0, u1, v0, v1 = 0, W - 1, 0, H - 1
    if pz - reff > 1e-6:
        umin = vmin = np.inf
        umax = vmax = -np.inf
        for cxs in (-reff, reff):
            for cys in (-reff, reff):
                for czs in (-reff, reff):
                    z = pz + czs
                    qx = fx * (px + cxs) / z + cx
                    qy = fy * (py + cys) / z + cy
                    umin = min(umin, qx)
                    umax = max(umax, qx)
                    vmin = min(vmin, qy)
                    vmax = max(vmax, qy)
        u0 = max(0, int(math.floor(max(umin, -1.0))) - 1)
        u1 = min(W - 1, int(math.floor(min(umax, W + 1.0))) + 1)
        v0 = max(0, int(math.floor(max(vmin, -1.0))) - 1)
        v1 = min(H - 1, int(math.floor(min(vmax, H + 1.0))) + 1)
    cells = 0
    tests = 0
    if u0 <= u1 and v0 <= v1:
        t_u0, t_u1 = u0 // tile, u1 // tile
        t_v0, t_v1 = v0 // tile, v1 // tile
        ntu = t_u1 - t_u0 + 1
        ntiles = ntu * (t_v1 - t_v0 + 1)
        zmax = pz + reff
        for k in range(ntiles):
            tv = t_v0 + k // ntu
            tu = t_u0 + k % ntu
            dmin = tmin[tv, tu]
            if dmin > zmax:
                lbs[k] = np.inf
                continue
            # lower bound over the whole tile frustum beyond its minimum start depth
            ua = tu * tile
            ub = min(W, ua + tile)
            va = tv * tile
            vb = min(H, va + tile)
            a = ((ua + ub) * 0.5 - cx) / fx
            b = ((va + vb) * 0.5 - cy) / fy
            hT = 0.5 * math.sqrt(((ub - ua) / fx) ** 2 + ((vb - va) / fy) ** 2)
            dr = _ray_seg_dist(px, py, pz, a, b, (px * a + py * b + pz) / (a * a + b * b + 1.0), dmin, np.inf)
            lbs[k] = dr * (1.0 - hT) - hT * pz
        for kk in range(ntiles):
            if mode == 0:
                # nearest-first (ICRA'12 §III, shrinking region): the unvisited tile with the lowest bound;
                # stop when it is no nearer than the best distance so far
                k = 0
                for j in range(1, ntiles):
                    if lbs[j] < lbs[k]:
                        k = j
                if not lbs[k] < best:
                    break
                lbs[k] = np.inf
            else:
                k = kk
                if lbs[k] >= reff:
                    continue
            tv = t_v0 + k // ntu
            tu = t_u0 + k % ntu
            ta = tu * tile
            tb_ = min(W, ta + tile)
            tva = tv * tile
            tvb = min(H, tva + tile)
            for j in range(tstate.shape[0]):
                tstate[j] = 0
            allclear = False
            pending = False
            g0c = g1c = 0
            if chunks and tmin[tv, tu] < pz:  # (a tile wholly beyond P has no case-iii pixel)
                allclear, pending, g0c, g1c, skip_tile = tile_chunk_prepare(
                    px,
                    py,
                    pz,
                    h,
                    best if mode == 0 else reff,
                    ta,
                    tva,
                    tb_,
                    tvb,
                    tmin[tv, tu],
                    tmax[tv, tu],
                    fx,
                    fy,
                    cx,
                    cy,
                    d_min,
                    dd,
                    n_cells,
                    corner_rays,
                    cams,
                    votes,
                    pyr,
                    meta,
                    stack,
                    tstate,
                )
                tests += 1
                if skip_tile:
                    continue
            for v in range(max(v0, tv * tile), min(v1 + 1, tv * tile + tile)):
                b = (v + 0.5 - cy) / fy
                for u in range(max(u0, tu * tile), min(u1 + 1, tu * tile + tile)):
                    kd = kind[v, u]
                    if kd == KIND_NONE:
                        continue
                    s0 = start[v, u]
                    if s0 > zmax:
                        continue  # case i: the obstacle and its gray area lie beyond the region
                    if allclear and kd == KIND_ROBOT:
                        continue  # case iv in a cleared tile: nothing within reach (see above)
                    a = (u + 0.5 - cx) / fx
                    lim = best if mode == 0 else reff
                    if kd == KIND_SURFACE and s0 >= pz:
                        lo = s0  # case ii: the principal camera sees the obstacle beyond P
                        hi = np.inf
                    else:
                        # cases iii (d_o < d_p, or unknown) and iv (robot at d_r): ask the other cameras,
                        # unless the whole ray from s0 on is already out of reach
                        rr = a * a + b * b + 1.0
                        s = (px * a + py * b + pz) / rr
                        if s < s0:
                            s = s0
                        dx = px - s * a
                        dy = py - s * b
                        dz = pz - s
                        if not math.sqrt(dx * dx + dy * dy + dz * dz) * (1.0 - h) - h * pz < lim:
                            continue
                        if pending:
                            pending = False
                            tests += 1
                            allclear = tile_chunk_cleared(
                                ta,
                                tva,
                                tb_,
                                tvb,
                                g0c // TILE_BLOCK,
                                g1c // TILE_BLOCK,
                                d_min,
                                dd,
                                n_cells,
                                corner_rays,
                                cams,
                                votes,
                                pyr,
                                meta,
                                stack,
                                tstate,
                                False,
                            )
                            if allclear and kd == KIND_ROBOT:
                                continue
                        cells += 1
                        found, lo, hi, nt = column_search(
                            u,
                            v,
                            a,
                            b,
                            s0,
                            kd == KIND_SURFACE,
                            kd == KIND_ROBOT,
                            px,
                            py,
                            pz,
                            h,
                            lim,
                            d_min,
                            dd,
                            n_cells,
                            corner_rays,
                            centre_rays,
                            cams,
                            stored,
                            pmap,
                            votes,
                            ta,
                            tva,
                            tb_,
                            tvb,
                            tstate,
                            pyr,
                            meta,
                            stack,
                        )
                        tests += nt
                        if not found:
                            continue
                    rr = a * a + b * b + 1.0
                    s = (px * a + py * b + pz) / rr
                    if s < lo:
                        s = lo
                    if s > hi:
                        s = hi
                    dx = px - s * a
                    dy = py - s * b
                    dz = pz - s
                    dr = math.sqrt(dx * dx + dy * dy + dz * dz)
                    zf = pz + dr
                    if hi < zf:
                        zf = hi
                    D = dr - h * zf  # safe point-to-cell distance (RA-L'16 eqs. 5-7 with the pixel frustum)
                    if D < 0.0:
                        D = 0.0
                    if D >= reff:
                        continue
                    count += 1
                    if dr < 1e-12:  # the point sits on the ray: push away from the start of the interval
                        dx = px - lo * a
                        dy = py - lo * b
                        dz = pz - lo
                        dr = math.sqrt(dx * dx + dy * dy + dz * dz)
                        if dr < 1e-12:
                            dx, dy, dz, dr = 0.0, 0.0, 1.0, 1.0
                    ix = dx / dr
                    iy = dy / dr
                    iz = dz / dr
                    if mode == 1:
                        w = 1.0 / (1.0 + math.exp(((D - radius) * 2.0 / rho - 1.0) * alpha))
                        sx += w * ix
                        sy += w * iy
                        sz += w * iz
                    elif mode == 2:
                        sx += ix
                        sy += iy
                        sz += iz
                    if D < best:
                        best = D
                        bx, by, bz = ix, iy, iz
                        nx, ny, nz = s * a, s * b, s
    if mode != 0:
        nrm = math.sqrt(sx * sx + sy * sy + sz * sz)
        if nrm > 1e-9:
            bx, by, bz = sx / nrm, sy / nrm, sz / nrm
    out[0] = best
    out[1] = bx
    out[2] = by
    out[3] = bz
    out[4] = nx
    out[5] = ny
    out[6] = nz
    out[7] = count
    out[8] = cells
    out[9] = tests


@nb.njit(cache=True, parallel=True)
def query_many(
    R,
    t,
    centres,
    radii,
    rho,
    mode,
    alpha,
    start,
    kind,
    tmin,
    tmax,
    tile,
    chunks,
    fx,
    fy,
    cx,
    cy,
    near_limit,
    unseen,
    d_min,
    dd,
    n_cells,
    corner_rays,
    centre_rays,
    cams,
    stored,
    pmap,
    votes,
    pyr,
    meta,
):
    """:func:`query_one` for N control spheres, in parallel over the spheres (prange)."""
    n = centres.shape[0]
    out = np.empty((n, 10))
    scratch = np.empty((n, tmin.shape[0] * tmin.shape[1]))
    tstates = np.zeros((n, n_cells // TILE_BLOCK + 1), dtype=np.uint8)
    stacks = np.empty((n, 3 * PYR_STACK), dtype=np.int64)
    for i in nb.prange(n):
        Pc = R @ centres[i] + t
        query_one(
            Pc,
            radii[i],
            rho,
            mode,
            alpha,
            start,
            kind,
            tmin,
            tmax,
            tile,
            chunks,
            fx,
            fy,
            cx,
            cy,
            near_limit,
            unseen,
            d_min,
            dd,
            n_cells,
            corner_rays,
            centre_rays,
            cams,
            stored,
            pmap,
            votes,
            pyr,
            meta,
            scratch[i],
            tstates[i],
            stacks[i],
            out[i],
        )
    return out


@nb.njit(cache=True)
def query_many_serial(
    R,
    t,
    centres,
    radii,
    rho,
    mode,
    alpha,
    start,
    kind,
    tmin,
    tmax,
    tile,
    chunks,
    fx,
    fy,
    cx,
    cy,
    near_limit,
    unseen,
    d_min,
    dd,
    n_cells,
    corner_rays,
    centre_rays,
    cams,
    stored,
    pmap,
    votes,
    pyr,
    meta,
):
    """:func:`query_one` for N control spheres, one after the other (no thread start-up latency)."""
    n = centres.shape[0]
    out = np.empty((n, 10))
    scratch = np.empty(tmin.shape[0] * tmin.shape[1])
    tstate = np.zeros(n_cells // TILE_BLOCK + 1, dtype=np.uint8)
    stack = np.empty(3 * PYR_STACK, dtype=np.int64)
    for i in range(n):
        Pc = R @ centres[i] + t
        query_one(
            Pc,
            radii[i],
            rho,
            mode,
            alpha,
            start,
            kind,
            tmin,
            tmax,
            tile,
            chunks,
            fx,
            fy,
            cx,
            cy,
            near_limit,
            unseen,
            d_min,
            dd,
            n_cells,
            corner_rays,
            centre_rays,
            cams,
            stored,
            pmap,
            votes,
            pyr,
            meta,
            scratch,
            tstate,
            stack,
            out[i],
        )
    return out
