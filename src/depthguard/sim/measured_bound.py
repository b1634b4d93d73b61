"""The measured bound: how far each control sphere is from the space that no camera sees free.

A sound distance stage may not claim free what no camera measured free, so no sound method can report
more than this bound from the same images. Comparing the fused distance with it splits the under-report
(truth minus evaluation, :mod:`depthguard.sim.accuracy`) into two parts:

* ``truth - bound``: what the cameras leave unmeasured (projector shadows, space hidden behind the arm
  from the principal camera, missing pixels): only another camera or another placement removes it;
* ``bound - evaluation``: what the fusion adds on top (depth cells, pixel footprints, the tolerance).

It is a brute-force sampler, independent of the depth grid's cells, footprints and pyramids: points on a
cubic lattice of spacing ``h`` around each sphere centre, taken nearest first, each tested against every
camera's image with the same rules as the fusion's documented contract (README, "Several cameras"):

* camera ``k`` sees point ``p`` free when ``p`` projects into its image (``z_C`` above ``min_depth``,
  pixel ``(floor(p_x), floor(p_y))``) and lies in front of the pixel's depth;
* a missing pixel sees nothing free, except in the principal camera (index 0), where a missing non-robot
  pixel takes the minimum valid non-robot depth of its ``(2 fill_radius + 1)²`` window (the project's
  missing-depth policy), computed here with :func:`scipy.ndimage.minimum_filter`, and a *robot* pixel
  without a reading sees free the points in front of the robot (the fill rule for a depth edge on the
  robot, :func:`depthguard.robot.interior.principal_robot_pixels`): when its window holds a valid pixel and
  no valid non-robot pixel nearer than the point, and the camera's ray through the point meets the
  robot's inflated inner capsules beyond it and not before it;
* a robot pixel of a secondary camera sees past (the robot is not an obstacle to itself); one of the
  principal camera sees free only in front of its reading, except with a single camera, where the depth
  space skips robot pixels (ICRA'12 §IV-B: space that the robot hides is free, a documented limit);
* a point that some camera measures (within half the lattice's diagonal, along that camera's ray, of a
  valid non-robot reading) is an obstacle, whatever the other cameras see (a robot pixel of one camera
  does not erase a box that another measures);
* a point inside the robot's inner capsules inflated by the self-filter margin is the robot, not space;
  so is, for a robot described by meshes, a point that the self-filter itself counts as robot: within its
  inflation of a filter mesh (the margin, less what decimation moved the surface out; :func:`robot_meshes`)
  or inside a closed one (ray parity).

The first lattice point seen free by no camera gives the bound, minus half the lattice's diagonal (so
that a region holding a ball of that radius is not missed); an unmeasured sliver thinner than that can
be missed, which makes the bound larger, never smaller. Units: metres.
"""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import numpy as np
from numba import njit
from scipy.ndimage import maximum_filter, minimum_filter

from depthguard.camera import Camera

__all__ = ["MeasuredViews", "RobotMeshes", "measured_views", "measured_bound", "robot_meshes"]


class MeasuredViews:
    """The cameras and images of one frame set, packed for :func:`measured_bound`.

    Attributes: ``R`` (K, 3, 3), ``t`` (K, 3), ``intr`` (K, 5) = fx, fy, cx, cy, min_depth, ``size`` (K, 2) =
    width, height, ``depth`` (K, Hmax, Wmax) float32 m (NaN: nothing measured there; the principal's holes
    filled), ``robot`` (K, Hmax, Wmax) bool, ``measured`` (K, Hmax, Wmax) bool: a valid non-robot reading
    (not a filled hole), ``edge`` (Hmax, Wmax) float32 m: at the principal's robot pixels without a reading
    whose window holds a valid pixel, the nearest valid non-robot depth of the window (inf: none); NaN
    elsewhere.
    """

    def __init__(self, R, t, intr, size, depth, robot, measured, edge=None) -> None:
        self.R, self.t, self.intr, self.size, self.depth, self.robot = R, t, intr, size, depth, robot
        self.measured = measured
        self.edge = np.full(depth.shape[1:], np.nan, np.float32) if edge is None else edge


def _filled_principal(depth: np.ndarray, robot: np.ndarray, fill_radius: int) -> np.ndarray:
    valid = np.isfinite(depth) & (depth > 0)
    d = np.where(valid, depth, np.nan).astype(np.float32)
    if fill_radius <= 0:
        return d
    val = np.where(valid & ~robot, depth, np.inf).astype(np.float32)
    win = minimum_filter(val, size=2 * fill_radius + 1, mode="constant", cval=np.inf)
    hole = ~valid & ~robot & np.isfinite(win)
    d[hole] = win[hole]
    return d


def _robot_edges(depth: np.ndarray, robot: np.ndarray, fill_radius: int) -> np.ndarray:
    """(H, W) float32: at robot pixels without a reading whose window holds a valid pixel, the nearest valid
    non-robot depth of the window (inf: none); NaN elsewhere."""
    valid = np.isfinite(depth) & (depth > 0)
    out = np.full(depth.shape, np.nan, np.float32)
    if fill_radius <= 0:
        return out
    size = 2 * fill_radius + 1
    near = minimum_filter(np.where(valid & ~robot, depth, np.inf).astype(np.float32), size=size, mode="constant",
                          cval=np.inf)  # fmt: skip
    some = maximum_filter(valid, size=size, mode="constant", cval=False)
    edge = robot & ~valid & some
    out[edge] = near[edge]
    return out


def measured_views(
    cameras: list[Camera], depths: list[np.ndarray], robot_masks: list[np.ndarray], fill_radius: int = 4
) -> MeasuredViews:
    """Pack one frame set: cameras (principal first), (H, W) depth images in m (0/NaN/inf: no reading) and
    (H, W) bool robot masks (the self-filter's)."""
    K = len(cameras)
    if K == 0 or len(depths) != K or len(robot_masks) != K:
        raise ValueError("measured_views: one depth image and one robot mask per camera are needed")
    Hm = max(c.height for c in cameras)
    Wm = max(c.width for c in cameras)
    depth = np.full((K, Hm, Wm), np.nan, np.float32)
    robot = np.zeros((K, Hm, Wm), bool)
    measured = np.zeros((K, Hm, Wm), bool)
    for k, (c, d, m) in enumerate(zip(cameras, depths, robot_masks, strict=True)):
        d = np.asarray(c.check_image(d, f"depths[{k}]"), np.float64)
        m = np.asarray(c.check_image(m, f"robot_masks[{k}]"), bool)
        dk = _filled_principal(d, m, fill_radius) if k == 0 else np.where(np.isfinite(d) & (d > 0), d, np.nan)
        depth[k, : c.height, : c.width] = dk
        robot[k, : c.height, : c.width] = m
        measured[k, : c.height, : c.width] = np.isfinite(d) & (d > 0) & ~m
    edge = np.full((Hm, Wm), np.nan, np.float32)
    c0 = cameras[0]
    d0 = np.asarray(c0.check_image(depths[0], "depths[0]"), np.float64)
    edge[: c0.height, : c0.width] = _robot_edges(d0, np.asarray(robot_masks[0], bool), fill_radius)
    R = np.stack([np.asarray(c.R, float) for c in cameras])
    t = np.stack([np.asarray(c.t, float) for c in cameras])
    intr = np.array([[c.fx, c.fy, c.cx, c.cy, float(getattr(c, "min_depth", 0.0) or 0.0)] for c in cameras])
    size = np.array([[c.width, c.height] for c in cameras], np.int64)
    return MeasuredViews(R, t, intr, size, depth, robot, measured, edge)


@lru_cache(maxsize=8)
def _lattice(h: float, reach: float) -> tuple[np.ndarray, np.ndarray]:
    """Lattice offsets (M, 3) within ``reach`` of the origin, nearest first, and their norms (M,)."""
    n = int(np.ceil(reach / h))
    g = np.arange(-n, n + 1) * h
    o = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    r = np.linalg.norm(o, axis=1)
    keep = r <= reach
    o, r = o[keep], r[keep]
    order = np.argsort(r, kind="stable")
    return np.ascontiguousarray(o[order]), np.ascontiguousarray(r[order])


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
def _seen_free(p, R, t, intr, size, depth, robot, measured, band, edge, a, b, cr) -> bool:
    """Whether some camera sees ``p`` free and none measures a surface there (within ``band`` m in depth)."""
    free = False
    single = R.shape[0] == 1
    for k in range(R.shape[0]):
        x = R[k, 0, 0] * p[0] + R[k, 0, 1] * p[1] + R[k, 0, 2] * p[2] + t[k, 0]
        y = R[k, 1, 0] * p[0] + R[k, 1, 1] * p[1] + R[k, 1, 2] * p[2] + t[k, 1]
        z = R[k, 2, 0] * p[0] + R[k, 2, 1] * p[1] + R[k, 2, 2] * p[2] + t[k, 2]
        if not (z > intr[k, 4]) or z <= 0.0:
            continue
        fu = intr[k, 0] * x / z + intr[k, 2]
        fv = intr[k, 1] * y / z + intr[k, 3]
        if not (fu >= 0.0 and fv >= 0.0 and fu < size[k, 0] and fv < size[k, 1]):
            continue
        u, v = int(np.floor(fu)), int(np.floor(fv))
        if robot[k, v, u]:
            if k > 0 or single:
                free = True
                continue
            e = edge[v, u]  # a robot pixel of the principal without a reading: in front of the robot
            if e == e and e >= z and not free and _in_front_of_robot(p, R, t, a, b, cr):
                free = True
        d = depth[k, v, u]
        if d == d:
            if measured[k, v, u] and abs(z - d) <= band:
                return False  # a measured surface
            if z < d:
                free = True
    return free


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


@njit(cache=True, nogil=True)
def _bound_kernel(
    centres, radii, rho, offs, norms, half_diag, R, t, intr, size, depth, robot, measured, edge, a, b, cr,
    mtri, mranges, minfl, mclosed, mbox, mball, out,
):  # fmt: skip
    p = np.empty(3)
    for i in range(centres.shape[0]):
        best = rho
        for j in range(offs.shape[0]):
            dist = norms[j] - radii[i]
            if dist - half_diag >= rho:
                break
            p[0] = centres[i, 0] + offs[j, 0]
            p[1] = centres[i, 1] + offs[j, 1]
            p[2] = centres[i, 2] + offs[j, 2]
            if _inside_capsules(p, a, b, cr) or _seen_free(
                p, R, t, intr, size, depth, robot, measured, half_diag, edge, a, b, cr
            ):
                continue
            if mranges.shape[0] and _inside_meshes(p, mtri, mranges, minfl, mclosed, mbox, mball):
                continue  # (tested last: the candidates are few)
            best = min(max(dist - half_diag, 0.0), rho)
            break
        out[i] = best


def measured_bound(
    views: MeasuredViews,
    centres: np.ndarray,
    radii: np.ndarray,
    rho: float,
    capsules: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    margin: float = 0.0,
    spacing: float = 0.01,
    meshes: RobotMeshes | None = None,
) -> np.ndarray:
    """(N,) distance (m, from each sphere's surface, capped at ``rho``) to the nearest lattice point that no
    camera sees free and that lies outside the robot's capsules inflated by ``margin``.

    Args:
        views: :func:`measured_views` of the frame set.
        centres: (N, 3) sphere centres, world frame, m.  radii: (N,) m.
        rho: radius of surveillance, m (the search stops there).
        capsules: ``(a (L, 3), b (L, 3), r (L,))`` the robot's inner capsules at the frames' joint state
            (:func:`depthguard.robot.interior.interior_capsules`), or None.
        margin: the self-filter's margin, m.  spacing: lattice spacing ``h``, m.
        meshes: the self-filter's meshes at the frames' joint state (:func:`robot_meshes`), or None: points
            that the self-filter counts as robot (within its inflation of them, or inside a closed one) are
            not space either.
    """
    c = np.ascontiguousarray(centres, float).reshape(-1, 3)
    r = np.ascontiguousarray(radii, float).reshape(-1)
    if r.shape[0] != c.shape[0]:
        raise ValueError(f"radii must have shape ({c.shape[0]},), got {np.shape(radii)}")
    if not (np.isfinite(rho) and rho > 0 and np.isfinite(spacing) and spacing > 0):
        raise ValueError(f"rho and spacing must be positive, got {rho!r}, {spacing!r}")
    half = 0.5 * np.sqrt(3.0) * spacing
    reach = float(np.max(r, initial=0.0)) + rho + half
    offs, norms = _lattice(round(float(spacing), 6), round(reach + spacing, 3))
    if capsules is None:
        a = b = np.zeros((0, 3))
        cr = np.zeros(0)
    else:
        a, b, cr = (np.ascontiguousarray(x, float) for x in capsules)
        cr = cr + float(margin)
    out = np.empty(c.shape[0])
    v = views
    _bound_kernel(
        c,
        r,
        float(rho),
        offs,
        norms,
        half,
        v.R,
        v.t,
        v.intr,
        v.size,
        v.depth,
        v.robot,
        v.measured,
        v.edge,
        a,
        b,
        cr,
        *(meshes if meshes is not None else _NO_MESHES),
        out,
    )
    return out
