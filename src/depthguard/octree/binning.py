"""The P bit (SAPHARI D4.1.1 §3.2): the octree nodes that hold a measured obstacle point, from points or from
a depth image's measured, non-robot pixels. Flag bit as in :mod:`depthguard.octree.sets` (P = 2).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

__all__ = ["bin_depth_points", "bin_points"]


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
