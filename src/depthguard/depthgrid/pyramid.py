"""Range-minimum pyramid of the vote images (per frame) and the exact "every pixel of a rectangle sees
past" test built on it.

A footprint test asks whether every pixel of a rectangle of camera k reads deeper than a far depth. For a
16x16-pixel tile over tens of centimetres of depth the footprint covers hundreds to thousands of pixels,
and reading them one by one dominated the query in scenes where a person stands in front of the principal
camera (RA-L'16 case iii almost everywhere). The pyramid holds, for l = 1..L, the minimum vote over each
aligned 2^l x 2^l block (level 0 is the vote image itself). The test walks it from the coarsest level
whose blocks span at most 4 per axis: a block whose minimum exceeds the threshold clears all its pixels at
once (inside the rectangle or not); a block at or below the threshold that lies entirely inside the
rectangle fails the test; a block straddling the rectangle's edge is split into its four children. It
therefore answers exactly as the pixel loop does (the same float32 values compared with the same
threshold), in a few lookups where the space is clearly free.
"""

from __future__ import annotations

import numba as nb
import numpy as np

__all__ = ["pyramid_layout", "build_pyramid", "rect_sees_past"]


def pyramid_layout(h: int, w: int) -> tuple[np.ndarray, int]:
    """(L, 3) int64 rows ``(offset, rows, cols)`` of levels 1..L of an (h, w) image's min pyramid.

    Levels are added until both dimensions are at most 4 blocks, so a rectangle spans at most 4 blocks
    per axis at the top level; returns the meta array and the total number of cells.
    """
    rows = []
    off = 0
    lv = 1
    while True:
        hl = (h + (1 << lv) - 1) >> lv
        wl = (w + (1 << lv) - 1) >> lv
        rows.append((off, hl, wl))
        off += hl * wl
        if hl <= 4 and wl <= 4:
            break
        lv += 1
    return np.array(rows, dtype=np.int64).reshape(-1, 3), off


@nb.njit(cache=True)
def build_pyramid(votes, meta, pyr):
    """Fill ``pyr[k]`` (levels 1..L, see :func:`pyramid_layout`) with block minima of ``votes[k]``."""
    H = votes.shape[1]
    W = votes.shape[2]
    for k in range(votes.shape[0]):
        for lv in range(meta.shape[0]):
            off = meta[lv, 0]
            hl = meta[lv, 1]
            wl = meta[lv, 2]
            if lv == 0:
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
                poff = meta[lv - 1, 0]
                ph = meta[lv - 1, 1]
                pw = meta[lv - 1, 2]
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
def rect_sees_past(k, u0, v0, u1, v1, thr, vt, stack):
    """True when every vote of camera k over pixels ``[u0, u1] x [v0, v1]`` (inclusive) exceeds ``thr``.

    ``vt``: the :class:`depthguard.depthgrid.records.Votes` record; ``stack``: (3 PYR_STACK,) int64 scratch.
    """
    votes = vt.votes
    pyr = vt.pyr
    meta = vt.meta
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
