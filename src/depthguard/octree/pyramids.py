"""Image and mask pyramids for the octree's per-sensor sets (:mod:`depthguard.octree.sets`).

* :func:`min_pyramid` / :func:`max_pyramid`: per 2^l x 2^l pixel block the minimum (maximum) of a depth
  image, all levels in one flat array; :func:`min_negmax_pyramids`: both at once (the maximum negated);
* :func:`camera_pyramids`: a camera frame's missing-depth policy, robot depth and their pyramids in one pass;
* :func:`any_le`: whether some pixel of a rectangle is <= a threshold, descending the min-pyramid only into
  blocks that can hold one;
* :func:`mask_pyramid`: the any-True pyramid of a 3-D node mask (the octree's inner nodes).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from depthguard.kernels.holefill import column_minima_if_dense, window_min_at

__all__ = ["min_pyramid", "min_negmax_pyramids", "camera_pyramids", "max_pyramid", "any_le", "mask_pyramid"]


@nb.njit(cache=True, nogil=True)
def _layout(H, W):
    """Level offsets, heights and widths of a pyramid over an (H, W) image, up to one 1 x 1 level."""
    hs = [H]
    ws = [W]
    while hs[-1] > 1 or ws[-1] > 1:
        hs.append((hs[-1] + 1) // 2)
        ws.append((ws[-1] + 1) // 2)
    L = len(hs)
    offs = np.zeros(L, np.int64)
    tot = 0
    for lv in range(L):
        offs[lv] = tot
        tot += hs[lv] * ws[lv]
    return offs, np.array(hs, np.int64), np.array(ws, np.int64), tot


@nb.njit(cache=True, nogil=True, inline="always")
def _reduce_levels(data, offs, hs, ws):
    """Fill levels 1.. of ``data`` with the minima of their 2 x 2 blocks of the level below."""
    for lv in range(1, offs.size):
        h0, w0, o0 = hs[lv - 1], ws[lv - 1], offs[lv - 1]
        w1, o1 = ws[lv], offs[lv]
        full_u = w0 // 2  # blocks with two columns; an odd width leaves one block of one column
        for v in range(hs[lv]):
            r0 = o0 + 2 * v * w0
            r1 = r0 + w0 if 2 * v + 1 < h0 else r0  # an odd height: the last block row has one row
            out = o1 + v * w1
            for u in range(full_u):
                data[out + u] = min(
                    min(data[r0 + 2 * u], data[r0 + 2 * u + 1]), min(data[r1 + 2 * u], data[r1 + 2 * u + 1])
                )
            if full_u < w1:
                data[out + full_u] = min(data[r0 + 2 * full_u], data[r1 + 2 * full_u])


@nb.njit(cache=True, nogil=True)
def min_pyramid(img):
    """Min-pyramid of a (H, W) float32 image: (flat data, level offsets, level heights, level widths)."""
    H, W = img.shape
    offs, hs, ws, tot = _layout(H, W)
    data = np.empty(tot, np.float32)
    for v in range(H):
        for u in range(W):
            data[v * W + u] = img[v, u]
    _reduce_levels(data, offs, hs, ws)
    return data, offs, hs, ws


@nb.njit(cache=True, nogil=True)
def min_negmax_pyramids(img):
    """The min-pyramid of a (H, W) float32 image and the min-pyramid of its negation (a negated
    max-pyramid), read in one pass: (min data, negated max data, offsets, heights, widths)."""
    H, W = img.shape
    offs, hs, ws, tot = _layout(H, W)
    lo = np.empty(tot, np.float32)
    neg = np.empty(tot, np.float32)
    for v in range(H):
        for u in range(W):
            x = img[v, u]
            lo[v * W + u] = x
            neg[v * W + u] = -x
    _reduce_levels(lo, offs, hs, ws)
    _reduce_levels(neg, offs, hs, ws)
    return lo, neg, offs, hs, ws


@nb.njit(cache=True, nogil=True)
def _fill_holes(lo, robot, nh, r, near):
    """Fill the ``nh`` holes of level 0 of ``lo`` (inf on missing and robot pixels): each takes the minimum of
    its (2 r + 1)^2 window, else ``near`` (the window minima of :mod:`depthguard.kernels.holefill`)."""
    H, W = robot.shape
    inf = np.float32(np.inf)
    img = lo[: H * W].reshape((H, W))
    holes = np.empty(nh, np.int64)
    h = 0
    for v in range(H):
        for u in range(W):
            if img[v, u] == inf and not robot[v, u]:  # inf: missing or robot
                holes[h] = v * W + u
                h += 1
    dense, colmin = column_minima_if_dense(img, nh, r)
    fill = np.empty(nh, np.float32)
    for h in range(nh):
        fill[h] = window_min_at(img, colmin, dense, holes[h] // W, holes[h] % W, r)
    for h in range(nh):  # after all windows are read: a filled hole is no source
        lo[holes[h]] = fill[h] if fill[h] < inf else near


@nb.njit(cache=True, nogil=True)
def camera_pyramids(depth, robot, fill_radius, near, conservative):
    """One camera frame's obstacle and robot depths, straight into their pyramids, in one pass over the image.

    The same values as :func:`depthguard.depthspace.fill_missing_depth` (missing: 0, NaN or +-inf; a missing
    non-robot pixel takes the minimum valid non-robot depth of its (2 r + 1)^2 window, else ``near`` when
    ``conservative``, else inf; robot pixels inf) and
    :func:`depthguard.octree.fusion.robot_blocking_depth` (the robot pixels' reading, ``near`` where missing,
    inf elsewhere), without the intermediate images.

    Args:
        depth: (H, W) float32 metres; robot: (H, W) bool robot pixels; fill_radius: r >= 0, pixels;
        near: float32 near limit (``camera.min_depth``); conservative: the ``"conservative"`` policy.
    Returns:
        (obstacle min data, its negation's min data, robot min data, offsets, heights, widths): the layout of
        :func:`min_negmax_pyramids`, level 0 the (H, W) images row-major.
    """
    H, W = depth.shape
    offs, hs, ws, tot = _layout(H, W)
    lo = np.empty(tot, np.float32)
    neg = np.empty(tot, np.float32)
    rob = np.empty(tot, np.float32)
    nh = 0
    inf = np.float32(np.inf)
    for v in range(H):  # branch-free (it vectorises); the holes are listed after
        for u in range(W):
            d = depth[v, u]
            ms = not (d > 0.0 and d < inf)  # 0, negative, NaN, +-inf: no reading
            rb = robot[v, u]
            i = v * W + u
            lo[i] = inf if rb or ms else d  # the valid non-robot depth: the holes' source, then patched
            rob[i] = (near if ms else d) if rb else inf
            nh += ms and not rb
    if conservative and nh > 0:  # otherwise the holes stay inf (free)
        _fill_holes(lo, robot, nh, fill_radius, near)
    for i in range(H * W):
        neg[i] = -lo[i]
    _reduce_levels(lo, offs, hs, ws)
    _reduce_levels(neg, offs, hs, ws)
    _reduce_levels(rob, offs, hs, ws)
    return lo, neg, rob, offs, hs, ws


@nb.njit(cache=True, nogil=True)
def any_le(img, data, offs, hs, ws, u0, v0, u1, v1, thr, stack):
    """Whether some pixel of img[v0:v1+1, u0:u1+1] is <= thr: descends the min-pyramid only into blocks
    whose minimum is <= thr, so a negative answer costs a few lookups, not a scan.

    ``img`` is not read (level 0 of ``data`` is the image); ``stack`` is an (n, 3) int64 work buffer. The
    blocks of the top level (at least a quarter of the rectangle's longer side) are read in place and a
    block's children are tested before they are pushed, so only blocks that cross the rectangle's border
    and may hold a pixel <= thr go on the stack."""
    span = max(u1 - u0 + 1, v1 - v0 + 1)
    top = 0
    while (4 << top) < span and top + 1 < offs.size:
        top += 1
    n = 0
    base, w = offs[top], ws[top]
    for bv in range(v0 >> top, (v1 >> top) + 1):
        row = base + bv * w
        rows_in = (bv << top) >= v0 and ((bv + 1) << top) - 1 <= v1
        for bu in range(u0 >> top, (u1 >> top) + 1):
            if data[row + bu] > thr:
                continue
            if rows_in and (bu << top) >= u0 and ((bu + 1) << top) - 1 <= u1:
                return True  # the block lies inside the rectangle and holds a pixel <= thr
            stack[n, 0], stack[n, 1], stack[n, 2] = top, bv, bu
            n += 1
    while n > 0:  # a block on the stack holds a pixel <= thr and crosses the border (level >= 1)
        n -= 1
        lv, bv, bu = stack[n, 0], stack[n, 1], stack[n, 2]
        c_lv = lv - 1
        base, w = offs[c_lv], ws[c_lv]
        for c in range(4):
            cv, cu = 2 * bv + (c >> 1), 2 * bu + (c & 1)
            pv0, pu0 = cv << c_lv, cu << c_lv
            pv1, pu1 = ((cv + 1) << c_lv) - 1, ((cu + 1) << c_lv) - 1
            if cv >= hs[c_lv] or cu >= w or pv0 > v1 or pv1 < v0 or pu0 > u1 or pu1 < u0:
                continue  # outside the image or the rectangle
            if data[base + cv * w + cu] > thr:
                continue
            if pv0 >= v0 and pv1 <= v1 and pu0 >= u0 and pu1 <= u1:
                return True  # the block lies inside the rectangle and holds a pixel <= thr
            stack[n, 0], stack[n, 1], stack[n, 2] = c_lv, cv, cu  # level >= 1: a pixel is inside or outside
            n += 1
    return False


@nb.njit(cache=True, nogil=True)
def max_pyramid(img):
    """Max-pyramid of a (H, W) float32 image, same layout as :func:`min_pyramid`."""
    data, offs, hs, ws = min_pyramid(-img)
    return -data, offs, hs, ws


@nb.njit(cache=True, nogil=True)
def mask_pyramid(mask, levels):
    """Any-True pyramid of a (nx, ny, nz) bool mask: flat uint8 data, offsets (levels+1,), shapes (levels+1, 3)."""
    shp = np.empty((levels + 1, 3), np.int64)
    shp[0, 0], shp[0, 1], shp[0, 2] = mask.shape
    offs = np.zeros(levels + 1, np.int64)
    tot = shp[0, 0] * shp[0, 1] * shp[0, 2]
    for lv in range(1, levels + 1):
        for d in range(3):
            shp[lv, d] = (shp[lv - 1, d] + 1) // 2
        offs[lv] = tot
        tot += shp[lv, 0] * shp[lv, 1] * shp[lv, 2]
    data = np.zeros(tot, np.uint8)
    nx, ny, nz = mask.shape
    for i in range(nx):
        for j in range(ny):
            for k in range(nz):
                if mask[i, j, k]:
                    data[(i * ny + j) * nz + k] = 1
    for lv in range(1, levels + 1):
        a0, a1, a2 = shp[lv - 1, 0], shp[lv - 1, 1], shp[lv - 1, 2]
        b1, b2 = shp[lv, 1], shp[lv, 2]
        o0, o1 = offs[lv - 1], offs[lv]
        for i in range(a0):
            for j in range(a1):
                for k in range(a2):
                    if data[o0 + (i * a1 + j) * a2 + k]:
                        data[o1 + ((i // 2) * b1 + j // 2) * b2 + k // 2] = 1
    return data, offs, shp
