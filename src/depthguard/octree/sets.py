"""Per-sensor node sets V_i, P_i, O_i, R_i, F_i (SAPHARI D4.1.1 §3.2) for depth cameras and 2-D scanners.

Instead of tracing every ray through the octree, each candidate node is projected into the sensor:

* camera: the node's 8 corners give its pixel rectangle (the pixels whose cones meet the node) and its
  depth range ``[z_lo, z_hi]``. The node is **occupied or occluded by obstacles** (O_i) when some pixel of
  the rectangle is blocked at a depth ``<= z_hi`` (some ray through the node meets an obstacle before it
  leaves the node); the same with robot pixels gives R_i. It is **in the field of view** (V_i) when the whole
  rectangle lies in the image and ``[z_lo, z_hi]`` in ``[min_depth, max_depth]``; F_i = V_i \\ (O_i ∪ R_i):
  every pixel that meets the node sees past it. P_i: nodes holding a measured (not hole-filled) obstacle point.
* 2-D scanner: only nodes that the scan plane cuts; the beam sectors that meet the node's slice and its
  planar range ``[r_lo, r_hi]`` play the part of the pixel rectangle and depth range.

Nodes are visited top-down in blocks (the octree's inner nodes): min/max image pyramids bound the depths
over a block's pixel rectangle, a block that every pixel sees past (or that every pixel sees blocked
before it) is decided at once, and only nodes near a surface reach the leaves, where undecided nodes scan
their pixels exactly. The sets are exact for the per-pixel-cone sensor model, with O_i and R_i never
smaller than the rays say.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from depthguard.octree.binning import bin_depth_points, bin_points
from depthguard.octree.pyramids import any_le, mask_pyramid, max_pyramid, min_negmax_pyramids, min_pyramid
from depthguard.octree.scan_sets import scanner_sets

__all__ = [
    "V", "P", "O", "R", "F", "min_pyramid", "max_pyramid", "mask_pyramid", "camera_sets", "camera_sets_from_pyramids",
    "scanner_sets",
    "bin_points", "bin_depth_points", "combine", "combine_cleared", "mark_overlaps",
]  # fmt: skip

V, P, O, R, F = 1, 2, 4, 8, 16  # flag bits


@nb.njit(cache=True, nogil=True, inline="always")
def _block_any(mp, lv, i, j, k):
    data, offs, shp = mp
    return data[offs[lv] + (i * shp[lv, 1] + j) * shp[lv, 2] + k] != 0


@nb.njit(cache=True, nogil=True, inline="always")
def _fill_block(flags, mask, lv, bi, bj, bk, val):
    nx, ny, nz = flags.shape
    s = 1 << lv
    for i in range(bi * s, min((bi + 1) * s, nx)):
        for j in range(bj * s, min((bj + 1) * s, ny)):
            for k in range(bk * s, min((bk + 1) * s, nz)):
                if mask[i, j, k]:
                    flags[i, j, k] |= val


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _camera_kernel(mask, mp, top, origin, res, Rc, tc, intr, W, H, zlim, opyr, omax, rd, flags, stats):
    # opyr: the obstacle depth's min-pyramid (level 0 the image); omax: the min-pyramid of its negation (a
    # negated max-pyramid), rd: the robot depth's min-pyramid, both in opyr's layout
    fx, fy, cx, cy = intr
    od, oo, oh, ow = opyr
    obs, rob = od, rd  # any_le's image argument (unused: level 0 of the pyramids is the image)
    shp = mp[2]
    stack = np.empty((64 * (top + 1) * 8, 5), np.int64)
    work = np.empty((4 * 64 + 64, 3), np.int64)
    gmin = min(od[od.size - 1], rd[rd.size - 1])  # the pyramids' top: the images' minima
    for ti in range(shp[top, 0]):
        for tj in range(shp[top, 1]):
            for tk in range(shp[top, 2]):
                if not _block_any(mp, top, ti, tj, tk):
                    continue
                n = 1
                stack[0, 0], stack[0, 1], stack[0, 2], stack[0, 3], stack[0, 4] = top, ti, tj, tk, 0
                while n > 0:
                    n -= 1
                    lv, bi, bj, bk, state = stack[n, 0], stack[n, 1], stack[n, 2], stack[n, 3], stack[n, 4]
                    size = (1 << lv) * res
                    stats[lv] += 1
                    zlo, zhi = np.inf, -np.inf
                    pxl, pxh, pyl, pyh = np.inf, -np.inf, np.inf, -np.inf
                    behind = False
                    # the block's lowest corner in the camera frame, then the other 7 by adding the edges
                    x0 = origin[0] + bi * size
                    y0 = origin[1] + bj * size
                    z0 = origin[2] + bk * size
                    xb = Rc[0, 0] * x0 + Rc[0, 1] * y0 + Rc[0, 2] * z0 + tc[0]
                    yb = Rc[1, 0] * x0 + Rc[1, 1] * y0 + Rc[1, 2] * z0 + tc[1]
                    zb = Rc[2, 0] * x0 + Rc[2, 1] * y0 + Rc[2, 2] * z0 + tc[2]
                    for c in range(8):
                        a, b, e = (c & 1) * size, ((c >> 1) & 1) * size, ((c >> 2) & 1) * size
                        xc = xb + Rc[0, 0] * a + Rc[0, 1] * b + Rc[0, 2] * e
                        yc = yb + Rc[1, 0] * a + Rc[1, 1] * b + Rc[1, 2] * e
                        zc = zb + Rc[2, 0] * a + Rc[2, 1] * b + Rc[2, 2] * e
                        zlo = min(zlo, zc)
                        zhi = max(zhi, zc)
                        # no branch: a corner behind the camera discards the rectangle (and divides by zero
                        # without raising)
                        behind = behind or zc <= 1e-6
                        iz = 1.0 / zc
                        px = fx * xc * iz + cx
                        py = fy * yc * iz + cy
                        pxl, pxh, pyl, pyh = min(pxl, px), max(pxh, px), min(pyl, py), max(pyh, py)
                    if zhi <= 1e-6:
                        continue  # wholly behind the camera: no information
                    if behind:
                        u0, v0, u1, v1 = 0, 0, W - 1, H - 1
                        in_fov = False
                    else:
                        u0, u1 = int(math.floor(pxl)), int(math.floor(pxh))
                        v0, v1 = int(math.floor(pyl)), int(math.floor(pyh))
                        in_fov = u0 >= 0 and v0 >= 0 and u1 < W and v1 < H and zlo >= zlim[0] and zhi <= zlim[1]
                        u0, v0, u1, v1 = max(u0, 0), max(v0, 0), min(u1, W - 1), min(v1, H - 1)
                        if u0 > u1 or v0 > v1:
                            continue  # outside the image
                    if zhi < gmin and zhi < zlim[0]:
                        continue  # nearer than every reading and than the near limit: no flag here or below
                    # state bits inherited from the parent block: 1 no O, 2 all O, 4 no R (they hold for children)
                    no_o = (state & 1) != 0
                    all_o = (state & 2) != 0
                    no_r = (state & 4) != 0
                    if lv > 0:
                        if not (no_o or all_o):  # exact decisions through the pyramids
                            mid = od[((v0 + v1) >> 1) * W + ((u0 + u1) >> 1)]  # one read answers most "some"
                            no_o = not (mid <= zhi or any_le(obs, od, oo, oh, ow, u0, v0, u1, v1, zhi, work))
                            if not no_o:  # every ray blocked before the block (no pixel beyond z_lo): occluded
                                all_o = not any_le(obs, omax, oo, oh, ow, u0, v0, u1, v1, -zlo - 1e-6, work)
                        if not no_r:
                            no_r = not any_le(rob, rd, oo, oh, ow, u0, v0, u1, v1, zhi, work)
                        if no_r and (all_o or (no_o and in_fov)):
                            val = 4 if all_o else 17  # O, or V|F
                            if in_fov and all_o:
                                val |= 1
                            _fill_block(flags, mask, lv, bi, bj, bk, val)
                            stats[8 + lv] += 1
                            continue
                        stats[
                            16 + (1 if no_o else 0) + (2 if all_o else 0) + (4 if no_r else 0) + (8 if in_fov else 0)
                        ] += 1
                        s1 = lv - 1
                        for c in range(8):
                            ci, cj, ck = 2 * bi + (c & 1), 2 * bj + ((c >> 1) & 1), 2 * bk + ((c >> 2) & 1)
                            if (
                                ci < shp[s1, 0]
                                and cj < shp[s1, 1]
                                and ck < shp[s1, 2]
                                and _block_any(mp, s1, ci, cj, ck)
                            ):
                                stack[n, 0], stack[n, 1], stack[n, 2], stack[n, 3] = s1, ci, cj, ck
                                stack[n, 4] = (1 if no_o else 0) | (2 if all_o else 0) | (4 if no_r else 0)
                                n += 1
                        continue
                    fl = 0
                    vc, uc = (v0 + v1) >> 1, (u0 + u1) >> 1  # the middle pixel first: one read answers most "yes"
                    if not no_o and (
                        all_o or od[vc * W + uc] <= zhi or any_le(obs, od, oo, oh, ow, u0, v0, u1, v1, zhi, work)
                    ):
                        fl |= 4
                    if not no_r and (rd[vc * W + uc] <= zhi or any_le(rob, rd, oo, oh, ow, u0, v0, u1, v1, zhi, work)):
                        fl |= 8
                    if in_fov:
                        fl |= 1
                        if fl == 1:
                            fl |= 16
                    flags[bi, bj, bk] |= fl


def _levels(shape) -> int:
    return max(0, min(4, int(math.ceil(math.log2(max(shape))))))


def camera_sets(
    mask: np.ndarray, box, camera, obstacle_depth: np.ndarray, robot_depth: np.ndarray, mp=None, stats=None
):
    """(nx, ny, nz) uint8 flags V, O, R, F of the nodes of ``mask`` (bool over ``box``) for one depth image.

    Nodes are visited top-down in blocks of up to 16^3: a block whose pixels all see past it (or are all
    blocked before it) is decided at once, so the cost follows the surfaces, not the volume.

    Args:
        obstacle_depth: (H, W) float32 depth at which each pixel is blocked by an obstacle (``inf`` = free;
            missing pixels already set by the missing-depth policy, e.g. :func:`depthguard.depthspace.prepare_frame`).
        robot_depth: (H, W) float32 depth at which each pixel is blocked by the robot, ``inf`` elsewhere.
        mp: the mask's :func:`mask_pyramid` (computed when None).
        stats: optional (32,) int64 counters: visits per level [0:8], blocks decided per level [8:16],
            undecided blocks by (no O, all O, no R, in view) [16:32].
    """
    obs = np.ascontiguousarray(obstacle_depth, dtype=np.float32)
    rob = np.ascontiguousarray(robot_depth, dtype=np.float32)
    lo, neg, *layout = min_negmax_pyramids(obs)
    return camera_sets_from_pyramids(mask, box, camera, (lo, *layout), neg, min_pyramid(rob)[0], mp, stats)


def camera_sets_from_pyramids(
    mask: np.ndarray, box, camera, opyr, neg: np.ndarray, rob: np.ndarray, mp=None, stats=None
) -> np.ndarray:
    """:func:`camera_sets` from the depths' pyramids (e.g. :func:`~depthguard.octree.pyramids.camera_pyramids`).

    Args:
        opyr: the obstacle depth's :func:`~depthguard.octree.pyramids.min_pyramid` (data, offsets, heights,
            widths; level 0 the (H, W) image row-major).
        neg: (n,) float32 data of the min-pyramid of the negated obstacle depth, the same layout.
        rob: (n,) float32 data of the robot depth's min-pyramid, the same layout.
        mp, stats: as :func:`camera_sets`.
    """
    flags = np.zeros(box.shape, np.uint8)
    top = _levels(box.shape)
    if mp is None:
        mp = mask_pyramid(mask, top)
    if stats is None:
        stats = np.zeros(32, np.int64)
    _camera_kernel(
        mask, mp, top, np.ascontiguousarray(box.origin, float), float(box.res),
        np.ascontiguousarray(camera.R), np.ascontiguousarray(camera.t),
        (camera.fx, camera.fy, camera.cx, camera.cy), camera.width, camera.height,
        (camera.min_depth, camera.max_depth), opyr, neg, rob, flags, stats,
    )  # fmt: skip
    return flags


@nb.njit(cache=True, nogil=True)
def combine(flags, mask, conservative, kind):
    """Fusion of SAPHARI §3.2 over (S, nx, ny, nz) flags into ``kind`` (0 free, 1 occupied, 2 occluded, 3 unseen).

    A node is occupied when it holds a measured point of some sensor (P), occluded when it is in some O_i
    that no other sensor sees free, and (conservative mode) unseen when no sensor sees it free, nor occupied,
    occluded or hidden by the robot. Two passes: the sensors' bits ORed and their F bits counted, sensor by
    sensor (these loops vectorise), then one decision per node; only a node with an O bit and a single F bit
    looks at the sensors again (is the F bit its O sensor's own?)."""
    S = flags.shape[0]
    nx, ny, nz = mask.shape
    bits = np.zeros((nx, ny, nz), np.uint8)
    nf = np.zeros((nx, ny, nz), np.uint8)
    for s in range(S):
        for i in range(nx):
            for j in range(ny):
                for k in range(nz):
                    f = flags[s, i, j, k]
                    bits[i, j, k] |= f
                    nf[i, j, k] += (f >> 4) & 1
    _decide(flags, mask, bits, nf, conservative, kind)


@nb.njit(cache=True, nogil=True)
def combine_cleared(flags, mask, conservative, kind, clear, drop_f):
    """:func:`combine`, editing ``flags`` in its first pass: zero outside ``mask`` when ``clear``, and the F
    bit cleared for the sensors ``s`` with ``drop_f[s]`` ((S,) bool: a 2-D scan in conservative mode)."""
    S = flags.shape[0]
    nx, ny, nz = mask.shape
    bits = np.zeros((nx, ny, nz), np.uint8)
    nf = np.zeros((nx, ny, nz), np.uint8)
    for s in range(S):
        keep = np.uint8(~F & 0xFF) if drop_f[s] else np.uint8(0xFF)
        for i in range(nx):
            for j in range(ny):
                for k in range(nz):
                    f = flags[s, i, j, k] & keep
                    if clear and not mask[i, j, k]:
                        f = np.uint8(0)
                    flags[s, i, j, k] = f
                    bits[i, j, k] |= f
                    nf[i, j, k] += (f >> 4) & 1
    _decide(flags, mask, bits, nf, conservative, kind)


@nb.njit(cache=True, nogil=True, inline="always")
def _decide(flags, mask, bits, nf, conservative, kind):
    """:func:`combine`'s second pass: each node's kind from its ORed bits and its number of F bits."""
    S = flags.shape[0]
    nx, ny, nz = mask.shape
    for i in range(nx):
        for j in range(ny):
            for k in range(nz):
                b = bits[i, j, k]
                n = nf[i, j, k]
                if not mask[i, j, k]:
                    kind[i, j, k] = 0
                elif b & 2:
                    kind[i, j, k] = 1
                elif b & 4 and n == 0:
                    kind[i, j, k] = 2
                elif b & 4 and n == 1:
                    occ = False
                    for s in range(S):
                        f = flags[s, i, j, k]
                        if (f & 4) != 0 and (f & 16) != 0:  # O_i and the only F is its own
                            occ = True
                    kind[i, j, k] = 2 if occ else 0
                elif conservative and n == 0 and not (b & 12):
                    kind[i, j, k] = 3
                else:
                    kind[i, j, k] = 0


@nb.njit(cache=True, nogil=True)
def _overlap_ranges(src_n, src_origin, src_res, n, origin, res):
    """Per node index i of one axis, the range [lo[i], hi[i]] of source cells whose interval overlaps the
    node's (lo > hi: none); the source cells' node ranges computed as before, then inverted."""
    eps = 1e-9
    lo = np.full(n, src_n, np.int64)
    hi = np.full(n, -1, np.int64)
    for a in range(src_n):
        c0 = src_origin + a * src_res
        i0 = max(0, int(math.floor((c0 - origin) / res - eps)))
        i1 = min(n - 1, int(math.ceil((c0 + src_res - origin) / res + eps)) - 1)
        for i in range(i0, i1 + 1):
            lo[i] = min(lo[i], a)
            hi[i] = max(hi[i], a)
    return lo, hi


@nb.njit(cache=True, nogil=True)
def mark_overlaps(src, src_origin, src_res, origin, res, shape, out):
    """``out`` (dense bool over ``shape``) |= nodes overlapping any True cell of ``src`` (another lattice).

    Overlap is a product of per-axis interval overlaps, so it is three separable "any" passes (z, y, x)
    over the per-axis ranges of :func:`_overlap_ranges`, not a stamp of every source cell's nodes."""
    sx, sy, sz = src.shape
    nx, ny, nz = shape[0], shape[1], shape[2]
    xl, xh = _overlap_ranges(sx, src_origin[0], src_res, nx, origin[0], res)
    yl, yh = _overlap_ranges(sy, src_origin[1], src_res, ny, origin[1], res)
    zl, zh = _overlap_ranges(sz, src_origin[2], src_res, nz, origin[2], res)
    along_z = np.zeros((sx, sy, nz), np.bool_)
    for a in range(sx):
        for b in range(sy):
            for k in range(nz):
                for c in range(zl[k], zh[k] + 1):
                    if src[a, b, c]:
                        along_z[a, b, k] = True
                        break
    along_y = np.zeros((sx, ny, nz), np.bool_)
    for a in range(sx):
        for j in range(ny):
            for b in range(yl[j], yh[j] + 1):
                for k in range(nz):
                    along_y[a, j, k] |= along_z[a, b, k]
    for i in range(nx):
        for a in range(xl[i], xh[i] + 1):
            for j in range(ny):
                for k in range(nz):
                    out[i, j, k] |= along_y[a, j, k]
