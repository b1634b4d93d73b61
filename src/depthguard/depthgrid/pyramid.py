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

With robot windows (``Votes.windows``, :func:`depthguard.depthgrid.votes.pixel_sees_past`) a pixel sees
past ``d`` when ``vote > d`` or ``lo <= d <= hi``. The pyramid is then built from the window-aware value
``e = max(vote, hi)`` where the window starts no deeper than the vote (``lo <= vote``: the pixel sees past
every ``d < e``), else ``e = vote`` (:func:`window_aware_votes`); ``e > d`` still implies "sees past". A
block at or below the threshold no longer fails the test by itself (a pixel's window may still let ``d``
through): the walk goes down to the pixels, which apply the exact rule. The answer is again exactly that of
the pixel loop, with no pixel-by-pixel fallback over the whole footprint.
"""

from __future__ import annotations

import numba as nb
import numpy as np

__all__ = ["pyramid_layout", "build_pyramid", "rect_sees_past", "window_aware_votes", "pixel_sees_past"]


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


def window_aware_votes(votes: np.ndarray, hm: int) -> np.ndarray:
    """(K, hm, W) float32 values ``e`` that the pyramid is built from when robot windows are set (module
    docstring); ``votes``: the (K, 3 hm, W) vote, ``lo`` and ``hi`` row blocks."""
    return _window_aware(np.ascontiguousarray(votes, dtype=np.float32), int(hm))


@nb.njit(cache=True, nogil=True)
def _window_aware(votes, hm):
    K, _, W = votes.shape
    out = np.empty((K, hm, W), dtype=np.float32)
    for k in range(K):
        for v in range(hm):
            for u in range(W):
                e = votes[k, v, u]
                if votes[k, hm + v, u] <= e:
                    e = max(e, votes[k, 2 * hm + v, u])
                out[k, v, u] = e
    return out


@nb.njit(cache=True, nogil=True, _nrt=False, inline="always")
def pixel_sees_past(k, pv, pu, dend, votes):
    """Pixel (pu, pv) of camera k does not hold an obstacle before ``dend``: its vote depth exceeds
    ``dend``, or ``dend`` lies in the pixel's robot window (``lo <= dend <= hi``: the part of any cell
    that ends at ``dend`` and that this pixel sees lies inside the robot's inflated body).

    ``votes`` holds three row blocks of equal height (see ``DepthGridFusion``): the votes, then ``lo``
    (+inf where the pixel has no window), then ``hi`` (-inf where none).
    """
    if votes[k, pv, pu] > dend:
        return True
    hm = votes.shape[1] // 3
    return votes[k, hm + pv, pu] <= dend and dend <= votes[k, 2 * hm + pv, pu]


@nb.njit(cache=True, nogil=True, _nrt=False, inline="always")
def _leaf_ok(k, pv, pu, thr, vt):
    """The exact per-pixel rule: the vote alone, or with the robot window when windows are set."""
    if vt.windows:
        return pixel_sees_past(k, pv, pu, thr, vt.votes)
    return vt.votes[k, pv, pu] > thr


@nb.njit(cache=True, nogil=True)
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


@nb.njit(cache=True, nogil=True, _nrt=False)
def rect_sees_past(k, u0, v0, u1, v1, thr, vt, stack):
    """True when every pixel of camera k over ``[u0, u1] x [v0, v1]`` (inclusive) sees past ``thr``: its
    vote exceeds ``thr``, or (``vt.windows``) ``thr`` lies in its robot window.

    ``vt``: the :class:`depthguard.depthgrid.records.Votes` record; ``stack``: (3 PYR_STACK,) int64 scratch.
    """
    pyr = vt.pyr
    meta = vt.meta
    if (u1 - u0 + 1) * (v1 - v0 + 1) <= 16:
        for pv in range(v0, v1 + 1):
            for pu in range(u0, u1 + 1):
                if not _leaf_ok(k, pv, pu, thr, vt):
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
            if not _leaf_ok(k, bv, bu, thr, vt):
                return False
            continue
        if pyr[k, meta[lv - 1, 0] + bv * meta[lv - 1, 2] + bu] > thr:
            continue
        # the block holds a pixel at or below thr: fail if the block lies inside the rectangle
        pa = bu << lv
        pb = ((bu + 1) << lv) - 1
        qa = bv << lv
        qb = ((bv + 1) << lv) - 1
        if not vt.windows and pa >= u0 and pb <= u1 and qa >= v0 and qb <= v1:
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
