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

from depthguard.octree.pyramids import any_le, mask_pyramid, max_pyramid, min_negmax_pyramids, min_pyramid

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


@nb.njit(cache=True, nogil=True, inline="always")
def _scan_node(xc, yc, ex, ey, nc, h, a0, inc, n, rlim, obs, rob):
    """Flags V, O, R, F of a node cut by the scan plane: its centre (xc, yc) in the plane (scanner frame, m),
    its corners at offsets (ex, ey)[:nc], ``h`` its half diagonal; 0 when no ray meets it."""
    rc2 = xc * xc + yc * yc
    r2hi = 0.0
    tlo, thi = 0.0, 0.0  # tangents of the corners' angles from the centre's direction
    for c in range(nc):
        px = xc + ex[c]
        py = yc + ey[c]
        r2hi = max(r2hi, px * px + py * py)
        # within h < rc of the centre, every corner lies within 90 degrees of its direction
        # (dot > rc (rc - h) > 0), where the tangent of the angle grows with the angle
        dot = xc * px + yc * py
        if dot > 0.0:
            tc = (xc * py - yc * px) / dot
            tlo, thi = min(tlo, tc), max(thi, tc)
    rhi = math.sqrt(r2hi)
    rc = math.sqrt(rc2)
    rlo = max(0.0, rc - h)
    if rc <= h:  # the node holds the scanner: every ray may meet it
        i0, i1 = 0, n - 1
        in_fov = False
    else:
        phic = math.atan2(yc, xc)
        lo_rel, hi_rel = math.atan(tlo), math.atan(thi)
        i0 = int(math.ceil((phic + lo_rel - a0 - 0.5 * inc) / inc))
        i1 = int(math.floor((phic + hi_rel - a0 + 0.5 * inc) / inc))
        if i1 < 0:  # the angle wrapped past -pi
            i0 += int(round(2 * math.pi / inc))
            i1 += int(round(2 * math.pi / inc))
        in_fov = i0 >= 0 and i1 < n and rlo >= rlim[0] and rhi <= rlim[1]
        i0, i1 = max(i0, 0), min(i1, n - 1)
        if i0 > i1:
            return 0
    fl = 0
    for r in range(i0, i1 + 1):
        if obs[r] <= rhi:
            fl |= 4
        if rob[r] <= rhi:
            fl |= 8
    if in_fov:
        fl |= 1
        if fl == 1:
            fl |= 16
    return fl


@nb.njit(cache=True, nogil=True)
def _scanner_kernel(mask, shape, origin, res, Rs, ts, a0, inc, n, rlim, obs, rob, flags):
    nx, ny, nz = shape[0], shape[1], shape[2]
    h = 0.5 * math.sqrt(3.0) * res
    ez = 0.5 * res * (abs(Rs[2, 0]) + abs(Rs[2, 1]) + abs(Rs[2, 2]))
    ex = np.empty(8)  # the corners' offsets from the node's centre, in the scan plane's x and y
    ey = np.empty(8)
    nc = 0  # distinct offsets only (a level scanner projects the top and bottom corners alike)
    for c in range(8):
        dx = ((c & 1) - 0.5) * res
        dy = (((c >> 1) & 1) - 0.5) * res
        dz = (((c >> 2) & 1) - 0.5) * res
        x = Rs[0, 0] * dx + Rs[0, 1] * dy + Rs[0, 2] * dz
        y = Rs[1, 0] * dx + Rs[1, 1] * dy + Rs[1, 2] * dz
        seen = False
        for m in range(nc):  # equal and nonzero: the same bits
            seen = seen or (ex[m] == x and ey[m] == y and x != 0.0 and y != 0.0)
        if not seen:
            ex[nc], ey[nc] = x, y
            nc += 1
    # the nodes that the plane z_S = 0 can cut: restrict the k range when the plane is horizontal enough
    for i in range(nx):
        for j in range(ny):
            x = origin[0] + (i + 0.5) * res
            y = origin[1] + (j + 0.5) * res
            kmin, kmax = 0, nz - 1
            if abs(Rs[2, 2]) > 1e-3:  # solve z_S(k) = +-ez for the node-centre height
                zs0 = Rs[2, 0] * x + Rs[2, 1] * y + ts[2]
                za = (-ez - zs0) / Rs[2, 2]
                zb = (ez - zs0) / Rs[2, 2]
                kmin = max(0, int(math.floor((min(za, zb) - origin[2]) / res - 0.5)) - 1)
                kmax = min(nz - 1, int(math.ceil((max(za, zb) - origin[2]) / res - 0.5)) + 1)
            pxc, pyc, fl = np.nan, np.nan, 0  # the last node's centre in the scan plane and its flags
            for k in range(kmin, kmax + 1):
                if not mask[i, j, k]:
                    continue
                z = origin[2] + (k + 0.5) * res
                xc = Rs[0, 0] * x + Rs[0, 1] * y + Rs[0, 2] * z + ts[0]
                yc = Rs[1, 0] * x + Rs[1, 1] * y + Rs[1, 2] * z + ts[1]
                zc = Rs[2, 0] * x + Rs[2, 1] * y + Rs[2, 2] * z + ts[2]
                if abs(zc) > ez:
                    continue  # the scan plane misses the node
                if not (xc == pxc and yc == pyc and xc != 0.0 and yc != 0.0):
                    # a new centre (a level scan plane on a node face cuts two nodes of each column alike)
                    fl = _scan_node(xc, yc, ex, ey, nc, h, a0, inc, n, rlim, obs, rob)
                    pxc, pyc = xc, yc
                flags[i, j, k] |= fl


def scanner_sets(mask: np.ndarray, box, scanner, obstacle_range: np.ndarray, robot_range: np.ndarray) -> np.ndarray:
    """(nx, ny, nz) uint8 flags V, O, R, F of the nodes of ``mask`` for one scan (see the module docstring).

    Args:
        obstacle_range: (n_rays,) range at which each ray is blocked by an obstacle (``inf`` = free to
            ``range_max``), e.g. from :func:`depthguard.octree.scanner.scan_obstacle_ranges`.
        robot_range: (n_rays,) range at which each ray is blocked by the robot, ``inf`` elsewhere.
    """
    flags = np.zeros(box.shape, np.uint8)
    _scanner_kernel(
        mask, np.array(box.shape, np.int64), np.ascontiguousarray(box.origin, float), float(box.res),
        np.ascontiguousarray(scanner.R), np.ascontiguousarray(scanner.t), scanner.angle_min,
        scanner.angle_increment, scanner.n_rays, (scanner.range_min, scanner.range_max),
        np.ascontiguousarray(obstacle_range, float), np.ascontiguousarray(robot_range, float), flags,
    )  # fmt: skip
    return flags


@nb.njit(cache=True, nogil=True)
def _bin(points, origin, res, mask, flags):
    nx, ny, nz = mask.shape
    for p in range(points.shape[0]):
        i = int(math.floor((points[p, 0] - origin[0]) / res))
        j = int(math.floor((points[p, 1] - origin[1]) / res))
        k = int(math.floor((points[p, 2] - origin[2]) / res))
        if 0 <= i < nx and 0 <= j < ny and 0 <= k < nz and mask[i, j, k]:
            flags[i, j, k] |= 2


def bin_points(points: np.ndarray, box, mask: np.ndarray, flags: np.ndarray) -> None:
    """Set the P bit of the nodes of ``mask`` holding any of the (K, 3) obstacle points."""
    pts = np.ascontiguousarray(np.asarray(points, dtype=float).reshape(-1, 3))
    _bin(pts, np.ascontiguousarray(box.origin, float), float(box.res), mask, flags)


@nb.njit(cache=True, nogil=True)
def _bin_depth(depth, robot, zlim, intr, Rt, pos, origin, res, mask, flags):
    fx, fy, cx, cy = intr
    H, W = depth.shape
    nx, ny, nz = mask.shape
    inv = 1.0 / res
    # a pixel's point in node units is d (a (u + 1/2 - cx) + b_v) + e: affine in u along a row, so a row's
    # nodes (flat index, -1 for none) are computed in a loop without branches (which vectorises), then
    # marked; mask and flags are C-contiguous (their flat views are the arrays)
    ax, ay, az = Rt[0, 0] * inv / fx, Rt[1, 0] * inv / fx, Rt[2, 0] * inv / fx
    e0, e1, e2 = (pos[0] - origin[0]) * inv, (pos[1] - origin[1]) * inv, (pos[2] - origin[2]) * inv
    node = np.empty(W, np.int64)
    mflat = mask.ravel()
    fflat = flags.ravel()
    for v in range(H):
        yv = (v + 0.5 - cy) / fy
        bx = (Rt[0, 1] * yv + Rt[0, 2]) * inv
        by = (Rt[1, 1] * yv + Rt[1, 2]) * inv
        bz = (Rt[2, 1] * yv + Rt[2, 2]) * inv
        for u in range(W):
            d = depth[v, u]
            xu = u + 0.5 - cx
            a = d * (ax * xu + bx) + e0
            b = d * (ay * xu + by) + e1
            c = d * (az * xu + bz) + e2
            # robot, missing (0, NaN, inf) or out of range: not a measured obstacle point
            ok = not robot[v, u] and d >= zlim[0] and d <= zlim[1]
            ok = ok and a >= 0.0 and b >= 0.0 and c >= 0.0 and a < nx and b < ny and c < nz
            node[u] = (int(a) * ny + int(b)) * nz + int(c) if ok else -1
        for u in range(W):
            m = node[u]
            if m >= 0 and mflat[m]:
                fflat[m] |= 2


def bin_depth_points(camera, depth: np.ndarray, robot: np.ndarray, box, mask: np.ndarray, flags: np.ndarray) -> None:
    """Set the P bit of the nodes of ``mask`` holding a measured, non-robot pixel of ``depth`` (H, W) metres."""
    out = flags if flags.flags.c_contiguous else np.ascontiguousarray(flags)
    _bin_depth(
        np.ascontiguousarray(depth, dtype=np.float32), np.ascontiguousarray(robot, dtype=np.bool_),
        (camera.min_depth, camera.max_depth), (camera.fx, camera.fy, camera.cx, camera.cy),
        np.ascontiguousarray(camera.R.T), np.ascontiguousarray(camera.position), np.ascontiguousarray(box.origin),
        float(box.res), np.ascontiguousarray(mask, dtype=np.bool_), out,
    )  # fmt: skip
    if out is not flags:
        flags[...] = out


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
