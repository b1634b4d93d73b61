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

import numpy as np
from numba import njit
from scipy.ndimage import maximum_filter, minimum_filter

from depthguard.camera import Camera
from depthguard.sim.bound_robot import (
    _NO_MESHES,
    RobotMeshes,
    _in_front_of_robot,
    _inside_capsules,
    _inside_meshes,
    robot_meshes,
)

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
