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

__all__ = ["interior_capsules", "principal_robot_pixels", "robot_windows"]


def interior_capsules(model, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The capsules that the two corrections may use: world ends ``a``, ``b`` (L, 3) m and radii (L,) m.

    Both corrections skip or clear space inside these capsules inflated by the self-filter's margin, so
    they are sound only where that space lies within the self-filter's own geometry inflated by the same
    margin (where it already removes every measured point). That holds for capsules *inside* the robot's
    collision geometry (:meth:`RobotGeometry.inner_capsules`: the analytic capsules and spheres, which the
    self-filter renders exactly, and a capsule inscribed in every box, cylinder and closed mesh), and not for
    :meth:`RobotModel.link_capsules`: for a mesh robot those are a coarse fallback along the kinematic chain,
    r = 0.05 m, and up to 4 cm of them (plus the margin) lies outside a Panda's, a UR5's or an xArm's
    collision meshes (measured with coal; ``tests/test_robot_interior.py``); a URDF cylinder becomes a
    capsule there, whose end caps stick out of it. An open mesh gets no correction: conservative, as if
    these corrections did not exist there.

    Args:
        model: a :class:`~depthguard.robot.model.RobotModel`.  q: (n,) joint positions.
    """
    H, _ = model.joint_kinematics(model.check_q(q))
    return model.geometry.inner_capsules(H[:, :3, :3], H[:, :3, 3])


@njit(cache=True, nogil=True, inline="always")
def _capsule_chord(x, y, A, B, r):
    """Depth interval ``(s_in, s_out)`` of the ray ``s (x, y, 1)`` inside the capsule (A, B, r), camera
    frame; ``(inf, -inf)`` when the ray misses it. The capsule is convex: its chord is the hull of the
    chords of its two end spheres and of its cylinder between the end planes."""
    ux, uy, uz = B[0] - A[0], B[1] - A[1], B[2] - A[2]
    L2 = ux * ux + uy * uy + uz * uz
    au = A[0] * ux + A[1] * uy + A[2] * uz
    aa = A[0] * A[0] + A[1] * A[1] + A[2] * A[2]
    qc = aa * L2 - au * au - r * r * L2
    cA = A[0] * A[0] + A[1] * A[1] + A[2] * A[2] - r * r
    cB = B[0] * B[0] + B[1] * B[1] + B[2] * B[2] - r * r
    return _chord_core(x, y, A[0], A[1], A[2], B[0], B[1], B[2], ux, uy, uz, L2, au, qc, cA, cB)


N_CONSTS = 16


@njit(cache=True, nogil=True)
def _capsule_consts(A, B, R, grow):
    """(L, N_CONSTS) per-capsule constants of :func:`_chord_core` for capsules (A, B, R + grow), computed
    exactly as :func:`_capsule_chord` computes them (the same chords, bit for bit)."""
    L = A.shape[0]
    C = np.empty((L, N_CONSTS))
    for k in range(L):
        r = R[k] + grow
        ux, uy, uz = B[k, 0] - A[k, 0], B[k, 1] - A[k, 1], B[k, 2] - A[k, 2]
        L2 = ux * ux + uy * uy + uz * uz
        au = A[k, 0] * ux + A[k, 1] * uy + A[k, 2] * uz
        aa = A[k, 0] * A[k, 0] + A[k, 1] * A[k, 1] + A[k, 2] * A[k, 2]
        C[k, 0], C[k, 1], C[k, 2] = A[k, 0], A[k, 1], A[k, 2]
        C[k, 3], C[k, 4], C[k, 5] = B[k, 0], B[k, 1], B[k, 2]
        C[k, 6], C[k, 7], C[k, 8], C[k, 9], C[k, 10] = ux, uy, uz, L2, au
        C[k, 11] = aa * L2 - au * au - r * r * L2
        C[k, 12] = aa - r * r
        C[k, 13] = B[k, 0] * B[k, 0] + B[k, 1] * B[k, 1] + B[k, 2] * B[k, 2] - r * r
        C[k, 14], C[k, 15] = r, 0.0
    return C


@njit(cache=True, nogil=True, inline="always")
def _chord_pre(x, y, C, k):
    """:func:`_capsule_chord` of capsule ``k`` from its constants ``C`` (:func:`_capsule_consts`)."""
    return _chord_core(
        x, y, C[k, 0], C[k, 1], C[k, 2], C[k, 3], C[k, 4], C[k, 5],
        C[k, 6], C[k, 7], C[k, 8], C[k, 9], C[k, 10], C[k, 11], C[k, 12], C[k, 13],
    )  # fmt: skip


@njit(cache=True, nogil=True, inline="always")
def _chord_core(x, y, ax, ay, az, bx, by, bz, ux, uy, uz, L2, au, qc, cA, cB):
    """The chord of :func:`_capsule_chord`, from the capsule's ends, axis ``u = B - A``, ``L2 = |u|²``,
    ``au = A.u``, ``qc = |A|² L2 - au² - r² L2`` and the end spheres' ``|A|² - r²``, ``|B|² - r²``."""
    dx, dy, dz = x, y, 1.0
    s_in, s_out = np.inf, -np.inf
    dd = dx * dx + dy * dy + dz * dz
    du = dx * ux + dy * uy + dz * uz
    da = dx * ax + dy * ay + dz * az
    qa = dd * L2 - du * du
    qb = da * L2 - du * au
    # early out: the capsule lies inside the infinite cylinder of radius r around its axis, so a line that
    # misses that cylinder misses the capsule (the relative slack keeps rays near tangency exact)
    if L2 > 1e-12 and qa > 1e-15 and qb * qb - qa * qc < -1e-9 * (qb * qb + abs(qa * qc)):
        return s_in, s_out
    for cx, cy, cz, c in ((ax, ay, az, cA), (bx, by, bz, cB)):  # end spheres
        bh = dx * cx + dy * cy + dz * cz
        disc = bh * bh - dd * c
        if disc >= 0.0:
            sq = math.sqrt(disc)
            s_in = min(s_in, (bh - sq) / dd)
            s_out = max(s_out, (bh + sq) / dd)
    if L2 > 1e-12 and qa > 1e-15:
        # |(s d - A) x u|^2 = r^2 |u|^2 (infinite cylinder), then 0 <= (s d - A).u <= |u|^2 (the slab)
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


@njit(cache=True, nogil=True)
def _capsule_boxes(A, B, R, fx, fy, cx, cy, W, H):
    """(L, 4) int pixel boxes ``(u0, u1, v0, v1)`` (inclusive, clipped to the image; ``u0 > u1`` when
    empty) that hold every pixel whose centre ray meets capsule k (A, B, R), camera frame. From the
    capsule's axis-aligned bounding box: ``x / z`` and ``y / z`` are monotone in each coordinate for
    ``z > 0``, so their extremes over the box lie at its corners; the whole image when the box reaches
    ``z <= 1 mm``. One pixel of slack on every side."""
    L = A.shape[0]
    out = np.empty((L, 4), dtype=np.int64)
    for k in range(L):
        r = R[k]
        x0, x1 = min(A[k, 0], B[k, 0]) - r, max(A[k, 0], B[k, 0]) + r
        y0, y1 = min(A[k, 1], B[k, 1]) - r, max(A[k, 1], B[k, 1]) + r
        z0, z1 = min(A[k, 2], B[k, 2]) - r, max(A[k, 2], B[k, 2]) + r
        if r < 0.0 or z1 <= 0.0:
            out[k, 0], out[k, 1], out[k, 2], out[k, 3] = 0, -1, 0, -1
        elif z0 <= 1e-3:
            out[k, 0], out[k, 1], out[k, 2], out[k, 3] = 0, W - 1, 0, H - 1
        else:
            out[k, 0] = max(0, int(math.floor(fx * min(x0 / z0, x0 / z1) + cx - 0.5)) - 1)
            out[k, 1] = min(W - 1, int(math.ceil(fx * max(x1 / z0, x1 / z1) + cx - 0.5)) + 1)
            out[k, 2] = max(0, int(math.floor(fy * min(y0 / z0, y0 / z1) + cy - 0.5)) - 1)
            out[k, 3] = min(H - 1, int(math.ceil(fy * max(y1 / z0, y1 / z1) + cy - 0.5)) + 1)
    return out


@njit(cache=True, nogil=True, inline="always")
def _chords(x, y, u, v, C, box, ins, outs):
    """Chords of the pixel-centre ray ``(x, y, 1)`` of pixel (u, v) through every capsule (constants ``C``,
    :func:`_capsule_consts`) into ``ins``/``outs``; ``(inf, -inf)`` for a capsule whose ``box`` excludes
    the pixel."""
    for k in range(C.shape[0]):
        if box[k, 0] <= u <= box[k, 1] and box[k, 2] <= v <= box[k, 3]:
            ins[k], outs[k] = _chord_pre(x, y, C, k)
        else:
            ins[k], outs[k] = np.inf, -np.inf


@njit(cache=True, nogil=True, inline="always")
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


@njit(cache=True, nogil=True)
def _principal_kernel(depth, mask, A, B, R, margin, fill_radius, fx, fy, cx, cy, out_depth, out_mask):
    H, W = depth.shape
    n = A.shape[0]
    ins = np.empty(n)
    outs = np.empty(n)
    box = _capsule_boxes(A, B, R + margin, fx, fy, cx, cy, W, H)  # (the inflated capsules hold the others)
    c_in = _capsule_consts(A, B, R, margin)  # the inflated capsules
    c_0 = _capsule_consts(A, B, R, 0.0)  # the capsules themselves
    # (out_depth, out_mask arrive as copies of depth, mask: a slice copy here would compile numba's
    # shape-mismatch error message, about 5 s of every cold start)
    for v in range(H):
        for u in range(W):
            if not mask[v, u]:
                continue
            d = depth[v, u]
            x = (u + 0.5 - cx) / fx
            y = (v + 0.5 - cy) / fy
            if d > 0.0 and d < np.inf:
                _chords(x, y, u, v, c_in, box, ins, outs)
                out_depth[v, u] = _exit_from(d, ins, outs)
                continue
            # no reading: robot only if the ray meets the capsules themselves (not just the margin)
            entry = np.inf
            _chords(x, y, u, v, c_0, box, ins, outs)
            for k in range(n):
                if ins[k] <= outs[k] and outs[k] > 0.0:
                    entry = min(entry, ins[k])
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
            _chords(x, y, u, v, c_in, box, ins, outs)
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
    out_d, out_m = d.copy(), m.copy()
    _principal_kernel(
        d, m, A, B, R, float(margin), int(fill_radius), camera.fx, camera.fy, camera.cx, camera.cy, out_d, out_m
    )
    return out_d, out_m


@njit(cache=True, nogil=True)
def _windows_kernel(A, B, Reff, fx, fy, cx, cy, gap, lo_out, hi_out):
    """Fill ``lo_out``/``hi_out`` (H, W) float32 (NaN: no window), the windows of :func:`robot_windows`."""
    H, W = lo_out.shape
    box = _capsule_boxes(A, B, Reff, fx, fy, cx, cy, W, H)
    u_lo, u_hi, v_lo, v_hi = W, -1, H, -1  # the union of the boxes: only there is anything to do
    for k in range(A.shape[0]):
        if Reff[k] > 0.0 and box[k, 0] <= box[k, 1] and box[k, 2] <= box[k, 3]:
            u_lo, u_hi = min(u_lo, box[k, 0]), max(u_hi, box[k, 1])
            v_lo, v_hi = min(v_lo, box[k, 2]), max(v_hi, box[k, 3])
    lo_out[:, :] = np.nan
    hi_out[:, :] = np.nan
    if u_lo > u_hi:
        return
    lo = np.full((v_hi - v_lo + 1, u_hi - u_lo + 1), np.inf)  # the union box, float64 while sweeping
    hi = np.full((v_hi - v_lo + 1, u_hi - u_lo + 1), -np.inf)
    # the pixels where the first sweep met a chord apart from the window so far: only there can the
    # second sweep join chords that the first met out of order (elsewhere every chord is in the window)
    apart = np.zeros((v_hi - v_lo + 1, u_hi - u_lo + 1), dtype=np.bool_)
    n_apart = 0
    C = _capsule_consts(A, B, Reff, 0.0)
    for sweep in range(2):
        if sweep == 1 and n_apart == 0:
            break
        for k in range(A.shape[0]):
            r = Reff[k]
            if r <= 0.0:
                continue
            u0, u1, v0, v1 = box[k, 0], box[k, 1], box[k, 2], box[k, 3]
            for v in range(v0, v1 + 1):
                y = (v + 0.5 - cy) / fy
                j = v - v_lo
                for u in range(u0, u1 + 1):
                    i = u - u_lo
                    if sweep == 1 and not apart[j, i]:
                        continue
                    x = (u + 0.5 - cx) / fx
                    a, b = _chord_pre(x, y, C, k)
                    if not (a <= b) or b <= 0.0:
                        continue
                    a = max(a, 0.0)
                    if lo[j, i] <= hi[j, i] and a <= hi[j, i] + gap and b >= lo[j, i] - gap:
                        lo[j, i] = min(lo[j, i], a)  # meets the window so far (within gap): union
                        hi[j, i] = max(hi[j, i], b)
                    elif sweep == 0:
                        if lo[j, i] <= hi[j, i]:
                            apart[j, i] = True
                            n_apart += 1
                        if not (lo[j, i] <= hi[j, i]) or a < lo[j, i]:
                            lo[j, i] = a  # the first window, or a nearer disjoint one
                            hi[j, i] = b
    for j in range(lo.shape[0]):
        for i in range(lo.shape[1]):
            if lo[j, i] <= hi[j, i]:
                lo_out[v_lo + j, u_lo + i] = lo[j, i]
                hi_out[v_lo + j, u_lo + i] = hi[j, i]


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
    lo = np.empty(camera.shape, dtype=np.float32)
    hi = np.empty(camera.shape, dtype=np.float32)
    _windows_kernel(A, B, np.ascontiguousarray(Reff), camera.fx, camera.fy, camera.cx, camera.cy, float(gap), lo, hi)
    return lo, hi
