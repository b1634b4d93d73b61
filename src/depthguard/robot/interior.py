"""The robot's pixels in the principal camera, as depth-grid fusion should take them (RA-L'16 §VII).

Two corrections of the self-filter's output for the principal camera, both from the robot's own
capsules (:meth:`depthguard.robot.model.RobotModel.link_capsules`):

* **The robot's own body is not unseen space.** A robot pixel at depth ``d_r`` guarantees only that
  nothing lies in front of ``d_r``; the cells behind it are left to the other cameras (case iv). But the
  first stretch behind ``d_r`` is the robot itself. When no secondary camera sees that stretch (a box
  that a person holds in front of it, or one footprint pixel of the box's edge), those cells stay
  "unseen", lie inside the control sphere, and the evaluated distance drops to 0 while the true
  clearance is many centimetres (README, "Why a distance drops to 0"). So the pixel's depth is moved
  to where its pixel-centre ray leaves the capsules inflated by the self-filter's ``margin`` (the union
  of the inflated capsules that the ray crosses without a gap from ``d_r`` on). The space skipped this
  way lies within ``margin`` (plus half a pixel footprint) of the capsules: the space in which the
  self-filter already removes every measured point along with the robot (its documented limit).
* **A hole next to the robot is a hole.** A depth camera leaves a band of missing pixels along the
  far side of every depth edge, the robot's silhouette included; the self-filter marks missing pixels
  within its margin and padding as robot, and a robot pixel without a reading is searched from the
  near limit (case iv), so that band becomes unseen space right next to the robot. A missing pixel
  whose ray misses every (uninflated) capsule is not the robot: its mask bit is cleared and the
  hole-filling policy (DESIGN: the nearest valid non-robot depth within ``fill_radius``) applies, as to
  every other hole. A missing pixel whose ray meets a capsule stays a robot pixel without a reading.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from depthguard.camera import Camera

__all__ = ["principal_robot_pixels", "robot_windows"]


@njit(cache=True, inline="always")
def _capsule_chord(x, y, A, B, r):
    """Depth interval ``(s_in, s_out)`` of the ray ``s (x, y, 1)`` inside the capsule (A, B, r), camera
    frame; ``(inf, -inf)`` when the ray misses it. The capsule is convex: its chord is the hull of the
    chords of its two end spheres and of its cylinder between the end planes."""
    dx, dy, dz = x, y, 1.0
    s_in, s_out = np.inf, -np.inf
    for cx, cy, cz in ((A[0], A[1], A[2]), (B[0], B[1], B[2])):  # end spheres
        a = dx * dx + dy * dy + dz * dz
        bh = dx * cx + dy * cy + dz * cz
        c = cx * cx + cy * cy + cz * cz - r * r
        disc = bh * bh - a * c
        if disc >= 0.0:
            sq = math.sqrt(disc)
            s_in = min(s_in, (bh - sq) / a)
            s_out = max(s_out, (bh + sq) / a)
    ux, uy, uz = B[0] - A[0], B[1] - A[1], B[2] - A[2]
    L2 = ux * ux + uy * uy + uz * uz
    if L2 > 1e-12:
        # |(s d - A) x u|^2 = r^2 |u|^2 (infinite cylinder), then 0 <= (s d - A).u <= |u|^2 (the slab)
        du = dx * ux + dy * uy + dz * uz
        au = A[0] * ux + A[1] * uy + A[2] * uz
        dd = dx * dx + dy * dy + dz * dz
        da = dx * A[0] + dy * A[1] + dz * A[2]
        aa = A[0] * A[0] + A[1] * A[1] + A[2] * A[2]
        qa = dd * L2 - du * du
        qb = da * L2 - du * au
        qc = aa * L2 - au * au - r * r * L2
        if qa > 1e-15:
            disc = qb * qb - qa * qc
            if disc >= 0.0:
                sq = math.sqrt(disc)
                c0, c1 = (qb - sq) / qa, (qb + sq) / qa
                if abs(du) > 1e-15:
                    t0, t1 = au / du, (au + L2) / du
                    if t0 > t1:
                        t0, t1 = t1, t0
                    c0, c1 = max(c0, t0), min(c1, t1)
                elif not (0.0 <= -au <= L2):
                    c0, c1 = np.inf, -np.inf
                if c0 <= c1:
                    s_in = min(s_in, c0)
                    s_out = max(s_out, c1)
    return s_in, s_out


@njit(cache=True, inline="always")
def _exit_from(s, ins, outs):
    """Extend depth ``s`` through every chord ``[ins[k], outs[k]]`` that contains it (their union)."""
    grown = True
    while grown:
        grown = False
        for k in range(ins.shape[0]):
            if ins[k] <= s and outs[k] > s:
                s = outs[k]
                grown = True
    return s


@njit(cache=True)
def _principal_kernel(depth, mask, A, B, R, margin, fill_radius, fx, fy, cx, cy, out_depth, out_mask):
    H, W = depth.shape
    n = A.shape[0]
    ins = np.empty(n)
    outs = np.empty(n)
    for v in range(H):
        for u in range(W):
            d = depth[v, u]
            out_depth[v, u] = d
            out_mask[v, u] = mask[v, u]
            if not mask[v, u]:
                continue
            x = (u + 0.5 - cx) / fx
            y = (v + 0.5 - cy) / fy
            if d > 0.0 and d < np.inf:
                for k in range(n):
                    ins[k], outs[k] = _capsule_chord(x, y, A[k], B[k], R[k] + margin)
                out_depth[v, u] = _exit_from(d, ins, outs)
                continue
            # no reading: robot only if the ray meets the capsules themselves (not just the margin)
            entry = np.inf
            for k in range(n):
                a, b = _capsule_chord(x, y, A[k], B[k], R[k])
                if a <= b and b > 0.0:
                    entry = min(entry, a)
            if entry == np.inf:
                out_mask[v, u] = False  # a hole next to the robot: filled like any other hole
                continue
            # a robot pixel without a reading (a depth edge on the robot): by the hole-filling rule
            # nothing lies in front of the nearest valid surface around it; if no valid non-robot
            # neighbour is nearer than the inflated robot along this ray, the nearest surface is the
            # robot, and case iv starts where the ray leaves the inflated robot
            best = np.inf  # nearest valid non-robot depth around (an obstacle, or the background)
            valid = False
            for vv in range(max(0, v - fill_radius), min(H, v + fill_radius + 1)):
                for uu in range(max(0, u - fill_radius), min(W, u + fill_radius + 1)):
                    dv = depth[vv, uu]
                    if dv > 0.0 and dv < np.inf:
                        valid = True
                        if not mask[vv, uu] and dv < best:
                            best = dv
            for k in range(n):
                ins[k], outs[k] = _capsule_chord(x, y, A[k], B[k], R[k] + margin)
            s_in = np.inf
            for k in range(n):
                if ins[k] <= outs[k]:
                    s_in = min(s_in, ins[k])
            if valid and best >= s_in:
                out_depth[v, u] = _exit_from(s_in, ins, outs)


def principal_robot_pixels(
    camera: Camera,
    depth: np.ndarray,
    mask: np.ndarray,
    a: np.ndarray,
    b: np.ndarray,
    radius: np.ndarray,
    margin: float = 0.03,
    fill_radius: int = 4,
) -> tuple[np.ndarray, np.ndarray]:
    """The principal camera's depth image and robot mask as the fusion should take them.

    Args:
        camera: the principal camera.
        depth: (H, W) depth ``z_C`` in metres (0/NaN/inf = no reading).
        mask: (H, W) bool robot mask (the self-filter's).
        a, b: (L, 3) world capsule ends (m); radius: (L,) m (:meth:`RobotModel.link_capsules`).
        margin: the self-filter's inflation of every capsule, m.
        fill_radius: the hole-filling radius of the fusion, pixels.
    Returns:
        ``(depth', mask')``: ``depth'`` is ``depth`` except at robot pixels with a reading ``d_r`` inside
        an inflated capsule, where it is the depth at which the pixel-centre ray leaves the union of the
        inflated capsules it crosses from ``d_r`` on without a gap (case iv then starts there);
        ``mask'`` is ``mask`` except at robot pixels without a reading whose ray misses every capsule
        (it only crosses the margin, or the self-filter's padding): those are holes next to the robot,
        not robot pixels (the hole-filling policy then applies to them, as to every other hole). A robot
        pixel without a reading whose ray meets a capsule, with valid neighbours within ``fill_radius``
        pixels of which no non-robot one lies nearer than the inflated robot along its ray, gets
        the depth where the ray leaves the inflated robot (the hole-filling rule: nothing lies in front of
        the nearest surface around it); otherwise it stays a robot pixel without a reading (searched from
        the near limit).
    """
    if not (np.isfinite(margin) and margin >= 0):
        raise ValueError(f"margin must be a finite number of metres >= 0, got {margin!r}")
    d = np.asarray(camera.check_image(depth, "depth"), dtype=np.float32)
    m = np.asarray(camera.check_image(mask, "mask"), dtype=np.bool_)
    A = np.ascontiguousarray(camera.world_to_camera(np.asarray(a, float)))
    B = np.ascontiguousarray(camera.world_to_camera(np.asarray(b, float)))
    R = np.ascontiguousarray(np.asarray(radius, float))
    if A.shape != B.shape or A.ndim != 2 or A.shape[1] != 3 or R.shape != (A.shape[0],):
        raise ValueError(f"capsules: a and b must be (L, 3) and radius (L,), got {A.shape}, {B.shape}, {R.shape}")
    out_d = np.empty(camera.shape, dtype=np.float32)
    out_m = np.empty(camera.shape, dtype=np.bool_)
    _principal_kernel(
        d, m, A, B, R, float(margin), int(fill_radius), camera.fx, camera.fy, camera.cx, camera.cy, out_d, out_m
    )
    return out_d, out_m


@njit(cache=True)
def _windows_kernel(A, B, Reff, fx, fy, cx, cy, gap, lo, hi):
    H, W = lo.shape
    for sweep in range(2):  # the second sweep joins chords that the first met out of order
        for k in range(A.shape[0]):
            r = Reff[k]
            if r <= 0.0:
                continue
            # image bounding box of the capsule's bounding sphere (whole image if it reaches behind the camera)
            mx, my, mz = 0.5 * (A[k, 0] + B[k, 0]), 0.5 * (A[k, 1] + B[k, 1]), 0.5 * (A[k, 2] + B[k, 2])
            rb = 0.5 * math.sqrt((A[k, 0] - B[k, 0]) ** 2 + (A[k, 1] - B[k, 1]) ** 2 + (A[k, 2] - B[k, 2]) ** 2) + r
            if mz - rb <= 1e-3:
                u0, u1, v0, v1 = 0, W - 1, 0, H - 1
            else:
                zn, zf = mz - rb, mz + rb
                u0 = max(0, int(math.floor(fx * min((mx - rb) / zn, (mx - rb) / zf) + cx)) - 1)
                u1 = min(W - 1, int(math.ceil(fx * max((mx + rb) / zn, (mx + rb) / zf) + cx)) + 1)
                v0 = max(0, int(math.floor(fy * min((my - rb) / zn, (my - rb) / zf) + cy)) - 1)
                v1 = min(H - 1, int(math.ceil(fy * max((my + rb) / zn, (my + rb) / zf) + cy)) + 1)
            for v in range(v0, v1 + 1):
                y = (v + 0.5 - cy) / fy
                for u in range(u0, u1 + 1):
                    x = (u + 0.5 - cx) / fx
                    a, b = _capsule_chord(x, y, A[k], B[k], r)
                    if not (a <= b) or b <= 0.0:
                        continue
                    a = max(a, 0.0)
                    if lo[v, u] <= hi[v, u] and a <= hi[v, u] + gap and b >= lo[v, u] - gap:
                        lo[v, u] = min(lo[v, u], a)  # meets the window so far (within gap): union
                        hi[v, u] = max(hi[v, u], b)
                    elif sweep == 0 and (not (lo[v, u] <= hi[v, u]) or a < lo[v, u]):
                        lo[v, u] = a  # the first window, or a nearer disjoint one
                        hi[v, u] = b


def robot_windows(
    camera: Camera,
    a: np.ndarray,
    b: np.ndarray,
    radius: np.ndarray,
    margin: float = 0.03,
    shrink_px: float = 0.0,
    gap: float = 0.01,
) -> tuple[np.ndarray, np.ndarray]:
    """Where the robot's own body fills each pixel's frustum, for a secondary camera of the fusion.

    Along pixel (u, v)'s centre ray, ``[lo, hi]`` (depths ``z_C``, m) is a stretch inside the capsules
    inflated by ``margin`` and shrunk by ``shrink_px`` pixel footprints at the capsule's far depth (0.75
    keeps the whole pixel frustum over ``[lo, hi]`` inside the inflated capsules; the nearest such
    stretch when the ray crosses the robot twice).
    :meth:`depthguard.depthgrid.DepthGridFusion.update` (``windows=``) lets a
    pixel clear the part of a cell that lies there even when a nearer reading (a box in front of the
    robot) hides it: the robot's body holds no obstacle.

    Args:
        camera: the camera.
        a, b: (L, 3) world capsule ends (m); radius: (L,) m.
        margin: the self-filter's capsule inflation, m.
        shrink_px: shrink the inflated capsules by this many pixel footprints (>= 0).
        gap: chords of two capsules less than this far apart along the ray (m) join into one stretch.
    Returns:
        ``(lo, hi)``, two (H, W) float32 images; NaN where the ray does not cross the robot.
    """
    if not (np.isfinite(margin) and margin >= 0):
        raise ValueError(f"margin must be a finite number of metres >= 0, got {margin!r}")
    if not (np.isfinite(shrink_px) and shrink_px >= 0):
        raise ValueError(f"shrink_px must be a finite number >= 0, got {shrink_px!r}")
    A = np.ascontiguousarray(camera.world_to_camera(np.asarray(a, float)))
    B = np.ascontiguousarray(camera.world_to_camera(np.asarray(b, float)))
    R = np.asarray(radius, float)
    if A.shape != B.shape or A.ndim != 2 or A.shape[1] != 3 or R.shape != (A.shape[0],):
        raise ValueError(f"capsules: a and b must be (L, 3) and radius (L,), got {A.shape}, {B.shape}, {R.shape}")
    zfar = np.maximum(A[:, 2], B[:, 2]) + R
    Reff = R + float(margin) - float(shrink_px) * np.maximum(zfar, 0.0) / min(camera.fx, camera.fy)
    lo = np.full(camera.shape, np.inf)
    hi = np.full(camera.shape, -np.inf)
    _windows_kernel(A, B, np.ascontiguousarray(Reff), camera.fx, camera.fy, camera.cx, camera.cy, float(gap), lo, hi)
    ok = lo <= hi
    return np.where(ok, lo, np.nan).astype(np.float32), np.where(ok, hi, np.nan).astype(np.float32)
