"""The node sets V, O, R, F of a 2-D laser scan (SAPHARI D4.1.1 §3.2; :mod:`depthguard.octree.sets` for the
cameras): only nodes that the scan plane cuts; the beam sectors that meet the node's slice and its planar
range ``[r_lo, r_hi]`` play the part of a camera's pixel rectangle and depth range. Flag bits as in
:mod:`depthguard.octree.sets` (V 1, O 4, R 8, F 16).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

__all__ = ["scanner_sets"]


@nb.njit(cache=True, nogil=True, inline="always")
def _ray_bits(obs, rob, rhi):
    """O (4) and R (8) bits of one ray for a node whose planar range ends at ``rhi``."""
    return (4 if obs <= rhi else 0) | (8 if rob <= rhi else 0)


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
    fl = 0
    if rc <= h:  # the node holds the scanner: every ray may meet it
        in_fov = False
        for r in range(n):
            fl |= _ray_bits(obs[r], rob[r], rhi)
    else:
        phic = math.atan2(yc, xc)
        lo_rel, hi_rel = math.atan(tlo), math.atan(thi)
        # the node's angle from ray 0, brought into [0, 2 pi] (phic - a0 lies in [-2 pi, 2 pi], a0 in [-pi, pi],
        # see scanner_sets), taken as it is and one turn either way: the sectors span [-inc/2, (n - 1/2) inc],
        # within [-pi, 3 pi) (less than a turn between the first and last ray, inc < 2 pi), and the node's own
        # angles lie within pi/2 of its centre's, so these three turns meet every sector that holds a node
        # angle (a wide fan's first and last sectors may overlap; the increment need not divide a turn)
        rel = phic - a0
        if rel < 0.0:
            rel += 2.0 * math.pi
        hit = False
        in_fov = False
        for turn in (0.0, 2.0 * math.pi, -2.0 * math.pi):
            i0 = int(math.ceil((rel + turn + lo_rel - 0.5 * inc) / inc))
            i1 = int(math.floor((rel + turn + hi_rel + 0.5 * inc) / inc))
            in_fov = in_fov or (i0 >= 0 and i1 < n)
            i0, i1 = max(i0, 0), min(i1, n - 1)
            if i0 > i1:
                continue
            hit = True
            for r in range(i0, i1 + 1):
                fl |= _ray_bits(obs[r], rob[r], rhi)
        if not hit:
            return 0
        in_fov = in_fov and rlo >= rlim[0] and rhi <= rlim[1]
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
    # ray 0's angle in [-pi, pi] (the same rays: any finite angle_min is legal); unchanged when it lies there
    a0 = float(scanner.angle_min)
    if abs(a0) > math.pi:
        a0 -= 2.0 * math.pi * round(a0 / (2.0 * math.pi))
    _scanner_kernel(
        mask, np.array(box.shape, np.int64), np.ascontiguousarray(box.origin, float), float(box.res),
        np.ascontiguousarray(scanner.R), np.ascontiguousarray(scanner.t), a0,
        scanner.angle_increment, scanner.n_rays, (scanner.range_min, scanner.range_max),
        np.ascontiguousarray(obstacle_range, float), np.ascontiguousarray(robot_range, float), flags,
    )  # fmt: skip
    return flags
