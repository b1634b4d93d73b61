"""The robot as the measured bound (:mod:`depthguard.sim.measured_bound`) sees it: the inner capsules
inflated by the self-filter's margin, the self-filter's own inflated meshes (:func:`robot_meshes`), and the
compiled geometry behind them (segment-segment and point-triangle distances, ray parity). Units: metres."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

__all__ = ["RobotMeshes", "robot_meshes"]


@njit(cache=True, nogil=True)
def _segment_distance2(p0, p1, q0, q1) -> float:
    """Squared distance between the segments ``p0 p1`` and ``q0 q1`` (3,)."""
    d1x, d1y, d1z = p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]
    d2x, d2y, d2z = q1[0] - q0[0], q1[1] - q0[1], q1[2] - q0[2]
    rx, ry, rz = p0[0] - q0[0], p0[1] - q0[1], p0[2] - q0[2]
    a = d1x * d1x + d1y * d1y + d1z * d1z
    e = d2x * d2x + d2y * d2y + d2z * d2z
    f = d2x * rx + d2y * ry + d2z * rz
    c = d1x * rx + d1y * ry + d1z * rz
    b = d1x * d2x + d1y * d2y + d1z * d2z
    # the minimum lies at the interior critical point or on an edge of the parameter square, where it is the
    # clamped projection of one segment's end onto the other: try them all
    best = np.inf
    den = a * e - b * b
    for k in range(5):
        if k == 0:
            if not (den > 1e-18 * a * e and a > 0.0 and e > 0.0):
                continue
            s, tt = (b * f - c * e) / den, (a * f - b * c) / den
            if not (0.0 <= s <= 1.0 and 0.0 <= tt <= 1.0):
                continue
        elif k <= 2:  # an end of p, the nearest point of q
            s = float(k - 1)
            tt = 0.0 if e <= 0.0 else min(max((f + s * b) / e, 0.0), 1.0)
        else:  # an end of q, the nearest point of p
            tt = float(k - 3)
            s = 0.0 if a <= 0.0 else min(max((tt * b - c) / a, 0.0), 1.0)
        x = rx + s * d1x - tt * d2x
        y = ry + s * d1y - tt * d2y
        z = rz + s * d1z - tt * d2z
        best = min(best, x * x + y * y + z * z)
    return best


@njit(cache=True, nogil=True)
def _in_front_of_robot(p, R, t, a, b, cr) -> bool:
    """Whether the principal camera's ray through ``p`` meets a capsule ``(a, b, cr)`` beyond ``p`` (within
    10 m) and none between the camera and ``p``."""
    eye = np.empty(3)
    for r in range(3):
        eye[r] = -(R[0, 0, r] * t[0, 0] + R[0, 1, r] * t[0, 1] + R[0, 2, r] * t[0, 2])
    dx, dy, dz = p[0] - eye[0], p[1] - eye[1], p[2] - eye[2]
    L = np.sqrt(dx * dx + dy * dy + dz * dz)
    far = np.empty(3)
    far[0], far[1], far[2] = p[0] + 10.0 * dx / L, p[1] + 10.0 * dy / L, p[2] + 10.0 * dz / L
    beyond = False
    for j in range(cr.shape[0]):
        r2 = cr[j] * cr[j]
        if _segment_distance2(eye, p, a[j], b[j]) <= r2:
            return False  # the robot lies between the camera and p
        if _segment_distance2(p, far, a[j], b[j]) <= r2:
            beyond = True
    return beyond


@njit(cache=True, nogil=True)
def _inside_capsules(p, a, b, cr) -> bool:
    for j in range(cr.shape[0]):
        ux, uy, uz = b[j, 0] - a[j, 0], b[j, 1] - a[j, 1], b[j, 2] - a[j, 2]
        L2 = ux * ux + uy * uy + uz * uz
        wx, wy, wz = p[0] - a[j, 0], p[1] - a[j, 1], p[2] - a[j, 2]
        s = 0.0 if L2 <= 0.0 else min(max((wx * ux + wy * uy + wz * uz) / L2, 0.0), 1.0)
        dx, dy, dz = wx - s * ux, wy - s * uy, wz - s * uz
        if dx * dx + dy * dy + dz * dz < cr[j] * cr[j]:
            return True
    return False


class RobotMeshes(NamedTuple):
    """The self-filter's meshes at one joint state, world frame: ``tri`` (T, 3, 3) m, ``ranges`` (S, 2) rows
    of ``tri`` per mesh, ``infl`` (S,) m its inflation, ``closed`` (S,) bool, ``box`` (S, 2, 3) its
    triangles' bounding box grown by ``infl``, ``ball`` (T, 4) each triangle's bounding ball (centroid,
    radius), m."""

    tri: np.ndarray
    ranges: np.ndarray
    infl: np.ndarray
    closed: np.ndarray
    box: np.ndarray
    ball: np.ndarray


def robot_meshes(model, q: np.ndarray, margin: float) -> RobotMeshes:
    """:class:`RobotMeshes` of a :class:`~depthguard.robot.model.RobotModel` at joint positions ``q`` with
    the self-filter's ``margin`` (m): each mesh inflated as :func:`depthguard.robot.selffilter.self_filter`
    inflates it, ``max(margin - excess, slack)``."""
    g = model.geometry
    H, _ = model.joint_kinematics(model.check_q(q))
    tri = np.ascontiguousarray(g.world_triangles(H[:, :3, :3], H[:, :3, 3]), float).reshape(-1, 3, 3)
    infl = np.ascontiguousarray(np.maximum(float(margin) - g.excess, g.slack), float)
    ranges = np.ascontiguousarray(g.fr, np.int64).reshape(-1, 2)
    box = np.empty((len(ranges), 2, 3))
    for s, (a, b) in enumerate(ranges):
        pts = tri[a:b].reshape(-1, 3)
        box[s, 0] = pts.min(axis=0) - infl[s] if len(pts) else np.inf
        box[s, 1] = pts.max(axis=0) + infl[s] if len(pts) else -np.inf
    centre = tri.mean(axis=1)
    ball = np.ascontiguousarray(
        np.column_stack([centre, np.linalg.norm(tri - centre[:, None], axis=2).max(axis=1, initial=0.0)])
    ).reshape(-1, 4)
    return RobotMeshes(tri, ranges, infl, np.ascontiguousarray(g.closed, np.bool_), box, ball)


_NO_MESHES = RobotMeshes(np.zeros((0, 3, 3)), np.zeros((0, 2), np.int64), np.zeros(0), np.zeros(0, np.bool_),
                         np.zeros((0, 2, 3)), np.zeros((0, 4)))  # fmt: skip


@njit(cache=True, nogil=True)
def _triangle_distance2(p, tri) -> float:
    """Squared distance from point ``p`` (3,) to the triangle ``tri`` (3, 3) (its closest point by regions,
    Ericson, Real-Time Collision Detection §5.1.5)."""
    ax, ay, az = tri[0, 0], tri[0, 1], tri[0, 2]
    abx, aby, abz = tri[1, 0] - ax, tri[1, 1] - ay, tri[1, 2] - az
    acx, acy, acz = tri[2, 0] - ax, tri[2, 1] - ay, tri[2, 2] - az
    nx, ny, nz = aby * acz - abz * acy, abz * acx - abx * acz, abx * acy - aby * acx
    if nx * nx + ny * ny + nz * nz <= 1e-12 * (abx * abx + aby * aby + abz * abz) * (acx * acx + acy * acy + acz * acz):
        # a degenerate (zero-area) triangle, the region tests below assume none: its nearest edge
        return min(
            _segment_distance2(p, p, tri[0], tri[1]),
            _segment_distance2(p, p, tri[1], tri[2]),
            _segment_distance2(p, p, tri[2], tri[0]),
        )
    apx, apy, apz = p[0] - ax, p[1] - ay, p[2] - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        s, w = 0.0, 0.0
    else:
        bpx, bpy, bpz = p[0] - tri[1, 0], p[1] - tri[1, 1], p[2] - tri[1, 2]
        d3 = abx * bpx + aby * bpy + abz * bpz
        d4 = acx * bpx + acy * bpy + acz * bpz
        cpx, cpy, cpz = p[0] - tri[2, 0], p[1] - tri[2, 1], p[2] - tri[2, 2]
        d5 = abx * cpx + aby * cpy + abz * cpz
        d6 = acx * cpx + acy * cpy + acz * cpz
        vc = d1 * d4 - d3 * d2
        vb = d5 * d2 - d1 * d6
        va = d3 * d6 - d5 * d4
        if d3 >= 0.0 and d4 <= d3:
            s, w = 1.0, 0.0
        elif d6 >= 0.0 and d5 <= d6:
            s, w = 0.0, 1.0
        elif vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
            s, w = (d1 / (d1 - d3) if d1 - d3 > 0.0 else 0.0), 0.0
        elif vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
            s, w = 0.0, (d2 / (d2 - d6) if d2 - d6 > 0.0 else 0.0)
        elif va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
            den = (d4 - d3) + (d5 - d6)
            w = (d4 - d3) / den if den > 0.0 else 0.0
            s = 1.0 - w
        else:
            den = 1.0 / (va + vb + vc)  # = 1 / |ab x ac|^2 > 0
            s, w = vb * den, vc * den
    dx = apx - s * abx - w * acx
    dy = apy - s * aby - w * acy
    dz = apz - s * abz - w * acz
    return dx * dx + dy * dy + dz * dz


@njit(cache=True, nogil=True)
def _ray_crossings(p, tri, a, b) -> int:
    """Triangles ``tri[a:b]`` that the ray from ``p`` along a fixed generic direction crosses (Moller-
    Trumbore): odd for a point inside a closed mesh."""
    dx, dy, dz = 0.5235987755982988, 0.6180339887498949, 0.5866068747318506
    n = 0
    for f in range(a, b):
        e1x, e1y, e1z = tri[f, 1, 0] - tri[f, 0, 0], tri[f, 1, 1] - tri[f, 0, 1], tri[f, 1, 2] - tri[f, 0, 2]
        e2x, e2y, e2z = tri[f, 2, 0] - tri[f, 0, 0], tri[f, 2, 1] - tri[f, 0, 1], tri[f, 2, 2] - tri[f, 0, 2]
        hx, hy, hz = dy * e2z - dz * e2y, dz * e2x - dx * e2z, dx * e2y - dy * e2x
        det = e1x * hx + e1y * hy + e1z * hz
        if abs(det) < 1e-15:
            continue
        inv = 1.0 / det
        sx, sy, sz = p[0] - tri[f, 0, 0], p[1] - tri[f, 0, 1], p[2] - tri[f, 0, 2]
        u = (sx * hx + sy * hy + sz * hz) * inv
        if u < 0.0 or u > 1.0:
            continue
        qx, qy, qz = sy * e1z - sz * e1y, sz * e1x - sx * e1z, sx * e1y - sy * e1x
        v = (dx * qx + dy * qy + dz * qz) * inv
        if v < 0.0 or u + v > 1.0:
            continue
        if (e2x * qx + e2y * qy + e2z * qz) * inv > 0.0:
            n += 1
    return n


@njit(cache=True, nogil=True)
def _inside_meshes(p, tri, ranges, infl, closed, box, ball) -> bool:
    """Whether ``p`` lies within ``infl[s]`` of mesh ``s`` or inside it when it is closed (the robot as the
    self-filter removes it); a triangle whose bounding ball is farther than ``infl[s]`` is skipped."""
    for s in range(ranges.shape[0]):
        if not (box[s, 0, 0] <= p[0] <= box[s, 1, 0] and box[s, 0, 1] <= p[1] <= box[s, 1, 1]
                and box[s, 0, 2] <= p[2] <= box[s, 1, 2]):  # fmt: skip
            continue
        a, b = ranges[s, 0], ranges[s, 1]
        r2 = infl[s] * infl[s]
        for f in range(a, b):
            dx, dy, dz = p[0] - ball[f, 0], p[1] - ball[f, 1], p[2] - ball[f, 2]
            reach = ball[f, 3] + infl[s]
            if dx * dx + dy * dy + dz * dz > reach * reach:
                continue
            if _triangle_distance2(p, tri[f]) <= r2:
                return True
        if closed[s] and _ray_crossings(p, tri, a, b) % 2 == 1:
            return True
    return False
