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

Rectangle minima come from a min-pyramid: the blocks covering the rectangle give a lower bound, the blocks
inside it an upper bound, and only undecided nodes (near a surface) scan their pixels exactly. The sets are
therefore exact for the per-pixel-cone sensor model, with O_i and R_i never smaller than the rays say.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

__all__ = ["V", "P", "O", "R", "F", "min_pyramid", "camera_sets", "scanner_sets", "bin_points"]

V, P, O, R, F = 1, 2, 4, 8, 16  # flag bits


@nb.njit(cache=True)
def min_pyramid(img):
    """Min-pyramid of a (H, W) float32 image: (flat data, level offsets, level heights, level widths)."""
    H, W = img.shape
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
    data = np.empty(tot, np.float32)
    for v in range(H):
        for u in range(W):
            data[v * W + u] = img[v, u]
    for lv in range(1, L):
        h0, w0, o0 = hs[lv - 1], ws[lv - 1], offs[lv - 1]
        h1, w1, o1 = hs[lv], ws[lv], offs[lv]
        for v in range(h1):
            for u in range(w1):
                m = np.inf
                for dv in range(2):
                    for du in range(2):
                        vv, uu = 2 * v + dv, 2 * u + du
                        if vv < h0 and uu < w0:
                            x = data[o0 + vv * w0 + uu]
                            if x < m:
                                m = x
                data[o1 + v * w1 + u] = m
    return data, offs, np.array(hs, np.int64), np.array(ws, np.int64)


@nb.njit(cache=True, inline="always")
def _any_le(img, data, offs, hs, ws, u0, v0, u1, v1, thr):
    """Whether some pixel of img[v0:v1+1, u0:u1+1] is <= thr (pyramid bounds, exact scan if undecided)."""
    span = min(u1 - u0 + 1, v1 - v0 + 1)
    lv = 0  # blocks of at most half the rectangle's short side: some lie inside it
    while (2 << lv) <= span // 2 and lv + 1 < offs.size:
        lv += 1
    # (1 << lv) <= max(1, span // 2)
    w = ws[lv]
    o = offs[lv]
    sup = np.inf
    sub = np.inf
    for bv in range(v0 >> lv, (v1 >> lv) + 1):
        inside_v = (bv << lv) >= v0 and ((bv + 1) << lv) - 1 <= v1
        for bu in range(u0 >> lv, (u1 >> lv) + 1):
            x = data[o + bv * w + bu]
            if x < sup:
                sup = x
            if inside_v and (bu << lv) >= u0 and ((bu + 1) << lv) - 1 <= u1 and x < sub:
                sub = x
    if sub <= thr:
        return True
    if sup > thr:
        return False
    for v in range(v0, v1 + 1):
        for u in range(u0, u1 + 1):
            if img[v, u] <= thr:
                return True
    return False


@nb.njit(cache=True)
def _camera_kernel(cand, shape, origin, res, Rc, tc, intr, W, H, zlim, obs, opyr, rob, rpyr, flags):
    fx, fy, cx, cy = intr
    ny, nz = shape[1], shape[2]
    od, oo, oh, ow = opyr
    rd, ro, rh, rw = rpyr
    for m in range(cand.size):
        f = cand[m]
        i, j, k = f // (ny * nz), (f // nz) % ny, f % nz
        zlo, zhi = np.inf, -np.inf
        pxl, pxh, pyl, pyh = np.inf, -np.inf, np.inf, -np.inf
        behind = False
        for c in range(8):
            x = origin[0] + (i + (c & 1)) * res
            y = origin[1] + (j + ((c >> 1) & 1)) * res
            z = origin[2] + (k + ((c >> 2) & 1)) * res
            xc = Rc[0, 0] * x + Rc[0, 1] * y + Rc[0, 2] * z + tc[0]
            yc = Rc[1, 0] * x + Rc[1, 1] * y + Rc[1, 2] * z + tc[1]
            zc = Rc[2, 0] * x + Rc[2, 1] * y + Rc[2, 2] * z + tc[2]
            zlo = min(zlo, zc)
            zhi = max(zhi, zc)
            if zc <= 1e-6:
                behind = True
                continue
            px = fx * xc / zc + cx
            py = fy * yc / zc + cy
            pxl, pxh, pyl, pyh = min(pxl, px), max(pxh, px), min(pyl, py), max(pyh, py)
        if zhi <= 1e-6:
            continue  # wholly behind the camera: no information
        if behind:  # straddles the camera plane: every pixel may meet it
            u0, v0, u1, v1 = 0, 0, W - 1, H - 1
            in_fov = False
        else:
            u0, u1 = int(math.floor(pxl)), int(math.floor(pxh))
            v0, v1 = int(math.floor(pyl)), int(math.floor(pyh))
            in_fov = u0 >= 0 and v0 >= 0 and u1 < W and v1 < H and zlo >= zlim[0] and zhi <= zlim[1]
            u0, v0, u1, v1 = max(u0, 0), max(v0, 0), min(u1, W - 1), min(v1, H - 1)
            if u0 > u1 or v0 > v1:
                continue  # outside the image
        fl = 0
        if _any_le(obs, od, oo, oh, ow, u0, v0, u1, v1, zhi):
            fl |= 4
        if _any_le(rob, rd, ro, rh, rw, u0, v0, u1, v1, zhi):
            fl |= 8
        if in_fov:
            fl |= 1
            if fl == 1:
                fl |= 16
        flags[m] |= fl


def camera_sets(cand: np.ndarray, box, camera, obstacle_depth: np.ndarray, robot_depth: np.ndarray) -> np.ndarray:
    """V, O, R, F flags (uint8, bits :data:`V` ...) of the candidate nodes ``cand`` (flat indices into ``box``).

    Args:
        obstacle_depth: (H, W) float32 depth at which each pixel is blocked by an obstacle (``inf`` = free;
            missing pixels already set by the missing-depth policy, e.g. :func:`depthguard.depthspace.prepare_frame`).
        robot_depth: (H, W) float32 depth at which each pixel is blocked by the robot, ``inf`` elsewhere.
    """
    flags = np.zeros(cand.size, np.uint8)
    obs = np.ascontiguousarray(obstacle_depth, dtype=np.float32)
    rob = np.ascontiguousarray(robot_depth, dtype=np.float32)
    _camera_kernel(
        cand, np.array(box.shape, np.int64), np.ascontiguousarray(box.origin, float), float(box.res),
        np.ascontiguousarray(camera.R), np.ascontiguousarray(camera.t),
        (camera.fx, camera.fy, camera.cx, camera.cy), camera.width, camera.height,
        (camera.min_depth, camera.max_depth), obs, min_pyramid(obs), rob, min_pyramid(rob), flags,
    )  # fmt: skip
    return flags


@nb.njit(cache=True)
def _scanner_kernel(cand, shape, origin, res, Rs, ts, a0, inc, n, rlim, obs, rob, flags):
    ny, nz = shape[1], shape[2]
    h = 0.5 * math.sqrt(3.0) * res
    for m in range(cand.size):
        f = cand[m]
        i, j, k = f // (ny * nz), (f // nz) % ny, f % nz
        # centre in the scanner frame
        x = origin[0] + (i + 0.5) * res
        y = origin[1] + (j + 0.5) * res
        z = origin[2] + (k + 0.5) * res
        xc = Rs[0, 0] * x + Rs[0, 1] * y + Rs[0, 2] * z + ts[0]
        yc = Rs[1, 0] * x + Rs[1, 1] * y + Rs[1, 2] * z + ts[1]
        zc = Rs[2, 0] * x + Rs[2, 1] * y + Rs[2, 2] * z + ts[2]
        # half-extent of the node along the scanner's z (plane normal) and the corner extremes
        ez = 0.5 * res * (abs(Rs[2, 0]) + abs(Rs[2, 1]) + abs(Rs[2, 2]))
        if abs(zc) > ez:
            continue  # the scan plane misses the node
        rc = math.sqrt(xc * xc + yc * yc)
        phic = math.atan2(yc, xc)
        rhi = 0.0
        lo_rel, hi_rel = 0.0, 0.0
        full = rc <= h
        for c in range(8):
            dx = ((c & 1) - 0.5) * res
            dy = (((c >> 1) & 1) - 0.5) * res
            dz = (((c >> 2) & 1) - 0.5) * res
            px = xc + Rs[0, 0] * dx + Rs[0, 1] * dy + Rs[0, 2] * dz
            py = yc + Rs[1, 0] * dx + Rs[1, 1] * dy + Rs[1, 2] * dz
            rhi = max(rhi, math.sqrt(px * px + py * py))
            rel = math.atan2(py, px) - phic
            if rel > math.pi:
                rel -= 2 * math.pi
            elif rel < -math.pi:
                rel += 2 * math.pi
            lo_rel, hi_rel = min(lo_rel, rel), max(hi_rel, rel)
        rlo = max(0.0, rc - h)
        if full:
            i0, i1 = 0, n - 1
            in_fov = False
        else:
            i0 = int(math.ceil((phic + lo_rel - a0 - 0.5 * inc) / inc))
            i1 = int(math.floor((phic + hi_rel - a0 + 0.5 * inc) / inc))
            # the sector may wrap: test both the raw and the +-2 pi shifted interval
            if i1 < 0:
                i0 += int(round(2 * math.pi / inc))
                i1 += int(round(2 * math.pi / inc))
            in_fov = i0 >= 0 and i1 < n and rlo >= rlim[0] and rhi <= rlim[1]
            i0, i1 = max(i0, 0), min(i1, n - 1)
            if i0 > i1:
                continue
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
        flags[m] |= fl


def scanner_sets(cand: np.ndarray, box, scanner, obstacle_range: np.ndarray, robot_range: np.ndarray) -> np.ndarray:
    """V, O, R, F flags of the candidate nodes for one scan (see the module docstring).

    Args:
        obstacle_range: (n_rays,) range at which each ray is blocked by an obstacle (``inf`` = free to
            ``range_max``), e.g. from :func:`depthguard.octree.scanner.scan_obstacle_ranges`.
        robot_range: (n_rays,) range at which each ray is blocked by the robot, ``inf`` elsewhere.
    """
    flags = np.zeros(cand.size, np.uint8)
    _scanner_kernel(
        cand, np.array(box.shape, np.int64), np.ascontiguousarray(box.origin, float), float(box.res),
        np.ascontiguousarray(scanner.R), np.ascontiguousarray(scanner.t), scanner.angle_min,
        scanner.angle_increment, scanner.n_rays, (scanner.range_min, scanner.range_max),
        np.ascontiguousarray(obstacle_range, float), np.ascontiguousarray(robot_range, float), flags,
    )  # fmt: skip
    return flags


@nb.njit(cache=True)
def _bin(points, origin, res, shape, slot, flags):
    nx, ny, nz = shape[0], shape[1], shape[2]
    for p in range(points.shape[0]):
        i = int(math.floor((points[p, 0] - origin[0]) / res))
        j = int(math.floor((points[p, 1] - origin[1]) / res))
        k = int(math.floor((points[p, 2] - origin[2]) / res))
        if 0 <= i < nx and 0 <= j < ny and 0 <= k < nz:
            s = slot[(i * ny + j) * nz + k]
            if s >= 0:
                flags[s] |= 2


def bin_points(points: np.ndarray, box, slot: np.ndarray, flags: np.ndarray) -> None:
    """Set the P bit of the candidate nodes holding any of the (K, 3) obstacle points (``slot``: flat -> m)."""
    pts = np.ascontiguousarray(np.asarray(points, dtype=float).reshape(-1, 3))
    _bin(pts, np.ascontiguousarray(box.origin, float), float(box.res), np.array(box.shape, np.int64), slot, flags)


@nb.njit(cache=True)
def _bin_depth(depth, robot, zlim, intr, Rt, pos, origin, res, shape, slot, flags):
    fx, fy, cx, cy = intr
    H, W = depth.shape
    nx, ny, nz = shape[0], shape[1], shape[2]
    for v in range(H):
        yv = (v + 0.5 - cy) / fy
        for u in range(W):
            d = depth[v, u]
            if robot[v, u] or not (d >= zlim[0] and d <= zlim[1]):
                continue  # robot, missing (0, NaN, inf) or out of range: not a measured obstacle point
            xc = (u + 0.5 - cx) / fx * d
            yc = yv * d
            x = Rt[0, 0] * xc + Rt[0, 1] * yc + Rt[0, 2] * d + pos[0]
            y = Rt[1, 0] * xc + Rt[1, 1] * yc + Rt[1, 2] * d + pos[1]
            z = Rt[2, 0] * xc + Rt[2, 1] * yc + Rt[2, 2] * d + pos[2]
            i = int(math.floor((x - origin[0]) / res))
            j = int(math.floor((y - origin[1]) / res))
            k = int(math.floor((z - origin[2]) / res))
            if 0 <= i < nx and 0 <= j < ny and 0 <= k < nz:
                s = slot[(i * ny + j) * nz + k]
                if s >= 0:
                    flags[s] |= 2


def bin_depth_points(camera, depth: np.ndarray, robot: np.ndarray, box, slot: np.ndarray, flags: np.ndarray) -> None:
    """Set the P bit of the candidate nodes holding a measured, non-robot pixel of ``depth`` (H, W) metres."""
    _bin_depth(
        np.ascontiguousarray(depth, dtype=np.float32), np.ascontiguousarray(robot, dtype=np.bool_),
        (camera.min_depth, camera.max_depth), (camera.fx, camera.fy, camera.cx, camera.cy),
        np.ascontiguousarray(camera.R.T), np.ascontiguousarray(camera.position), np.ascontiguousarray(box.origin),
        float(box.res), np.array(box.shape, np.int64), slot, flags,
    )  # fmt: skip


@nb.njit(cache=True)
def mark_overlaps(src, src_origin, src_res, origin, res, shape, out):
    """``out`` (dense bool over ``shape``) |= nodes overlapping any True cell of ``src`` (another lattice)."""
    sx, sy, sz = src.shape
    nx, ny, nz = shape[0], shape[1], shape[2]
    eps = 1e-9
    for a in range(sx):
        for b in range(sy):
            for c in range(sz):
                if not src[a, b, c]:
                    continue
                lo0 = src_origin[0] + a * src_res
                lo1 = src_origin[1] + b * src_res
                lo2 = src_origin[2] + c * src_res
                i0 = max(0, int(math.floor((lo0 - origin[0]) / res - eps)))
                i1 = min(nx - 1, int(math.ceil((lo0 + src_res - origin[0]) / res + eps)) - 1)
                j0 = max(0, int(math.floor((lo1 - origin[1]) / res - eps)))
                j1 = min(ny - 1, int(math.ceil((lo1 + src_res - origin[1]) / res + eps)) - 1)
                k0 = max(0, int(math.floor((lo2 - origin[2]) / res - eps)))
                k1 = min(nz - 1, int(math.ceil((lo2 + src_res - origin[2]) / res + eps)) - 1)
                for i in range(i0, i1 + 1):
                    for j in range(j0, j1 + 1):
                        for k in range(k0, k1 + 1):
                            out[i, j, k] = True
