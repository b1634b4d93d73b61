"""Self-filter: remove the robot from depth images (ICRA'12 §IV-B, Fig. 8; RA-L'16 §VII).

The robot's capsules (:meth:`depthguard.robot.model.RobotModel.link_capsules`) are ray cast through
every pixel centre (``p_x = u + 0.5``, DESIGN.md §3) with numba, without OpenGL: each capsule is
intersected analytically with the pixel rays inside its projected bounding box.

Output (:class:`SelfFilterResult`):

* ``mask`` (H, W) bool, the pixels to remove:
  - a *measured* pixel whose 3-D point lies inside a capsule inflated by ``margin`` (so depth noise,
    calibration error and joint-state latency up to ``margin`` metres are tolerated);
  - a pixel *without reading* (0, NaN, inf) inside the inflated silhouette, widened in the image by
    ``pad_px`` pixels: real cameras leave bands of missing depth along the robot's edges, and a missing
    pixel left next to the robot would become "unknown" (an obstacle at the near limit) downstream.
  A measured point in front of the inflated robot (a hand before the forearm) or behind it (background
  seen past a robot that has moved) is kept: it is not the robot.
* ``robot_depth`` (H, W) float: where the widened silhouette covers the pixel, the nearest depth
  ``z_C`` of the inflated robot within ``pad_px`` pixels, NaN elsewhere. It is a conservative
  (nearer) robot depth: along that ray nothing but the robot is known to start before it, which is
  what the distance stage needs for removed pixels (RA-L'16 case iv).

Limits: obstacles closer than ``margin`` to the robot's capsules are removed with it; mixed "flying"
pixels at depth edges outside the inflated robot are kept as obstacles.
"""

from __future__ import annotations

import threading
from functools import lru_cache
from typing import NamedTuple

import numpy as np
from numba import njit

from depthguard.camera import Camera

__all__ = ["SelfFilterResult", "self_filter", "self_filter_capsules", "render_capsules_depth"]


class SelfFilterResult(NamedTuple):
    """Self-filter output. ``mask``: (H, W) bool, True = robot (remove). ``robot_depth``: (H, W) float
    metres, conservative robot depth where the padded silhouette covers, NaN elsewhere."""

    mask: np.ndarray
    robot_depth: np.ndarray


@njit(cache=True)
def _capsule_consts(a: np.ndarray, b: np.ndarray, r: float) -> np.ndarray:
    """Per-capsule constants for :func:`_line_capsule` (camera at the origin)."""
    c = np.empty(17)
    c[0:3] = a
    c[3:6] = b
    w = b - a
    L = np.sqrt(np.sum(w * w))
    if L > 1e-12:
        w = w / L
    else:
        w = np.array([0.0, 0.0, 1.0])
        L = 0.0
    c[6:9] = w
    c[9] = L
    ow = -np.sum(a * w)  # (origin - a) . w
    q = -a - ow * w  # (origin - a) without its axial part
    c[10:13] = q
    c[13] = np.sum(q * q) - r * r
    c[14] = np.sum(a * a) - r * r
    c[15] = np.sum(b * b) - r * r
    c[16] = ow
    return c


@njit(cache=True)
def _line_capsule(dx: float, dy: float, c: np.ndarray) -> tuple[float, float]:
    """Interval [t0, t1] of the line ``t (dx, dy, 1)`` (camera at the origin) inside a capsule.

    ``c`` comes from :func:`_capsule_consts`. Returns (inf, -inf) when the line misses. t is the depth
    z_C since the direction has z = 1.
    """
    w0, w1, w2, L = c[6], c[7], c[8], c[9]
    dw = dx * w0 + dy * w1 + w2
    p0, p1, p2 = dx - dw * w0, dy - dw * w1, 1.0 - dw * w2
    A = p0 * p0 + p1 * p1 + p2 * p2
    B = p0 * c[10] + p1 * c[11] + p2 * c[12]
    C = c[13]
    disc = B * B - A * C
    # the capsule lies inside the infinite cylinder around its axis: missing that is missing it
    if A > 1e-18:
        if disc < 0.0:
            return np.inf, -np.inf
    elif C > 0.0:
        return np.inf, -np.inf
    t0, t1 = np.inf, -np.inf
    dd = dx * dx + dy * dy + 1.0
    # end spheres
    da = dx * c[0] + dy * c[1] + c[2]
    disc_a = da * da - dd * c[14]
    if disc_a >= 0.0:
        sq = np.sqrt(disc_a)
        t0, t1 = (da - sq) / dd, (da + sq) / dd
    db = dx * c[3] + dy * c[4] + c[5]
    disc_b = db * db - dd * c[15]
    if disc_b >= 0.0:
        sq = np.sqrt(disc_b)
        e0, e1 = (db - sq) / dd, (db + sq) / dd
        if e0 < t0:
            t0 = e0
        if e1 > t1:
            t1 = e1
    # cylinder body between the end discs
    if L > 0.0 and A > 1e-18:
        sq = np.sqrt(disc)
        s0, s1 = (-B - sq) / A, (-B + sq) / A
        ow = c[16]
        if abs(dw) > 1e-15:  # clip to 0 <= ow + s dw <= L
            u0, u1 = -ow / dw, (L - ow) / dw
            if u0 > u1:
                u0, u1 = u1, u0
            if u0 > s0:
                s0 = u0
            if u1 < s1:
                s1 = u1
        elif ow < 0.0 or ow > L:
            s0, s1 = np.inf, -np.inf
        if s0 <= s1:
            if s0 < t0:
                t0 = s0
            if s1 > t1:
                t1 = s1
    return t0, t1


@njit(cache=True)
def _sphere_bbox(c: np.ndarray, r: float, fx: float, fy: float, cx: float, cy: float) -> tuple[float, ...]:
    """Exact image bounding box (pixel coordinates) of a sphere fully in front of the camera."""
    out = np.empty(4)
    for k, (f, cc, x) in enumerate(((fx, cx, c[0]), (fy, cy, c[1]))):
        z = c[2]
        den = z * z - r * r
        root = np.sqrt(max(x * x + z * z - r * r, 0.0))
        lo = (x * z - r * root) / den
        hi = (x * z + r * root) / den
        out[2 * k] = f * lo + cc
        out[2 * k + 1] = f * hi + cc
    return out[0], out[1], out[2], out[3]


@njit(cache=True)
def _self_filter_kernel(
    A: np.ndarray,
    B: np.ndarray,
    R: np.ndarray,
    margin: float,
    pad: int,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    depth: np.ndarray,
    mask: np.ndarray,
    robot_depth: np.ndarray,
    exact_only: bool,
    infl: np.ndarray,
    tmp: np.ndarray,
) -> None:
    """Rasterise the capsules; ``infl`` and ``tmp`` are (H, W) work buffers, all inf on entry and on exit."""
    H, W = depth.shape
    u_lo, u_hi, v_lo, v_hi = W, -1, H, -1
    for k in range(A.shape[0]):
        ri = R[k] + margin
        cc = _capsule_consts(A[k], B[k], ri)
        # bounding box of the inflated capsule = union of its end spheres' boxes
        if A[k, 2] - ri <= 1e-6 or B[k, 2] - ri <= 1e-6:
            x0, x1, y0, y1 = 0, W - 1, 0, H - 1
        else:
            a0, a1, a2, a3 = _sphere_bbox(A[k], ri, fx, fy, cx, cy)
            b0, b1, b2, b3 = _sphere_bbox(B[k], ri, fx, fy, cx, cy)
            x0 = max(int(np.floor(min(a0, b0))) - 1, 0)
            x1 = min(int(np.floor(max(a1, b1))) + 1, W - 1)
            y0 = max(int(np.floor(min(a2, b2))) - 1, 0)
            y1 = min(int(np.floor(max(a3, b3))) + 1, H - 1)
        if x0 > x1 or y0 > y1:
            continue
        u_lo, u_hi, v_lo, v_hi = min(u_lo, x0), max(u_hi, x1), min(v_lo, y0), max(v_hi, y1)
        full_rows = A[k, 2] - ri <= 1e-6 or B[k, 2] - ri <= 1e-6
        for v in range(y0, y1 + 1):
            dy = (v + 0.5 - cy) / fy
            r0, r1 = x0, x1
            if not full_rows:
                # the row's pixel-centre rays span the plane y = dy z; only the part of the segment within
                # ri of that plane can meet it, and the balls at that part's ends bound the row span
                nn = np.sqrt(1.0 + dy * dy)
                sa = (A[k, 1] - dy * A[k, 2]) / nn
                sb = (B[k, 1] - dy * B[k, 2]) / nn
                ta, tb = 0.0, 1.0
                ds = sb - sa
                if abs(ds) > 1e-15:
                    ta, tb = (-ri - sa) / ds, (ri - sa) / ds
                    if ta > tb:
                        ta, tb = tb, ta
                    ta, tb = max(ta, 0.0), min(tb, 1.0)
                elif abs(sa) > ri:
                    continue
                if ta > tb:
                    continue
                pa = A[k] + ta * (B[k] - A[k])
                pb = A[k] + tb * (B[k] - A[k])
                if pa[2] - ri <= 1e-6 or pb[2] - ri <= 1e-6:
                    continue  # cannot happen when both end balls are in front; kept for safety
                e0, e1, _, _ = _sphere_bbox(pa, ri, fx, fy, cx, cy)
                g0, g1, _, _ = _sphere_bbox(pb, ri, fx, fy, cx, cy)
                r0 = max(int(np.floor(min(e0, g0))) - 1, x0)
                r1 = min(int(np.floor(max(e1, g1))) + 1, x1)
            for u in range(r0, r1 + 1):
                dx = (u + 0.5 - cx) / fx
                t0, t1 = _line_capsule(dx, dy, cc)
                if t1 < max(t0, 0.0):
                    continue
                tin = max(t0, 0.0)
                if tin < infl[v, u]:
                    infl[v, u] = tin
                if not exact_only:
                    d = depth[v, u]
                    if d > 0.0 and d < np.inf and t0 <= d <= t1:
                        mask[v, u] = True
    if u_hi < 0:
        return
    if exact_only:
        for v in range(v_lo, v_hi + 1):
            for u in range(u_lo, u_hi + 1):
                if infl[v, u] < np.inf:
                    robot_depth[v, u] = infl[v, u]
                    infl[v, u] = np.inf
        return
    # widen the silhouette by pad pixels: separable running minimum of the inflated depth
    x0, x1 = max(u_lo - pad, 0), min(u_hi + pad, W - 1)
    y0, y1 = max(v_lo - pad, 0), min(v_hi + pad, H - 1)
    for v in range(v_lo, v_hi + 1):
        for u in range(x0, x1 + 1):
            m = np.inf
            for uu in range(max(u - pad, u_lo), min(u + pad, u_hi) + 1):
                if infl[v, uu] < m:
                    m = infl[v, uu]
            tmp[v, u] = m
    for v in range(y0, y1 + 1):
        for u in range(x0, x1 + 1):
            m = np.inf
            for vv in range(max(v - pad, v_lo), min(v + pad, v_hi) + 1):
                if tmp[vv, u] < m:
                    m = tmp[vv, u]
            if m < np.inf:
                robot_depth[v, u] = m
                d = depth[v, u]
                if not (d > 0.0 and d < np.inf):  # no reading next to the robot: robot
                    mask[v, u] = True
    for v in range(v_lo, v_hi + 1):  # leave the work buffers as found
        for u in range(x0, x1 + 1):
            infl[v, u] = np.inf
            tmp[v, u] = np.inf


_WORK = threading.local()


def _work_buffers(shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Per-thread (H, W) work buffers (all inf between calls), so that frames do not allocate them."""
    bufs = getattr(_WORK, "bufs", None)
    if bufs is None or bufs[0].shape != shape:
        bufs = (np.full(shape, np.inf), np.full(shape, np.inf))
        _WORK.bufs = bufs
    return bufs


def _capsules_in_camera(camera: Camera, a: np.ndarray, b: np.ndarray, radius: np.ndarray):
    a = np.ascontiguousarray(camera.world_to_camera(np.asarray(a, dtype=float).reshape(-1, 3)))
    b = np.ascontiguousarray(camera.world_to_camera(np.asarray(b, dtype=float).reshape(-1, 3)))
    r = np.ascontiguousarray(np.asarray(radius, dtype=float).reshape(-1))
    if not (len(a) == len(b) == len(r)):
        raise ValueError(f"capsules: {len(a)} a, {len(b)} b and {len(r)} radii must match")
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b)) and np.all(np.isfinite(r)) and np.all(r >= 0)):
        raise ValueError("capsules must be finite with radii >= 0")
    return a, b, r


def self_filter_capsules(
    camera: Camera,
    depth: np.ndarray,
    a: np.ndarray,
    b: np.ndarray,
    radius: np.ndarray,
    *,
    margin: float = 0.03,
    pad_px: int = 3,
) -> SelfFilterResult:
    """Self-filter for robot geometry given as world-frame capsules.

    Args:
        camera: the depth camera (pose and intrinsics).
        depth: (H, W) measured depth ``z_C`` in metres; 0, NaN or inf = no reading.
        a, b: (L, 3) capsule segment ends in the world frame, m; radius: (L,) m.
        margin: inflation of every capsule, m (>= 0): noise, calibration and latency tolerance.
        pad_px: widening of the silhouette in the image for missing readings, pixels (>= 0).
    Returns:
        :class:`SelfFilterResult` (see the module docstring).
    """
    depth = camera.check_image(depth, "depth")
    if not (np.isfinite(margin) and margin >= 0):
        raise ValueError(f"margin must be a finite number >= 0, got {margin!r}")
    if isinstance(pad_px, bool) or int(pad_px) != pad_px or pad_px < 0:
        raise ValueError(f"pad_px must be an integer >= 0, got {pad_px!r}")
    A, B, R = _capsules_in_camera(camera, a, b, radius)
    d = np.ascontiguousarray(depth, dtype=np.float64)
    mask = np.zeros(camera.shape, dtype=np.bool_)
    robot_depth = np.full(camera.shape, np.nan)
    _self_filter_kernel(
        A,
        B,
        R,
        float(margin),
        int(pad_px),
        camera.fx,
        camera.fy,
        camera.cx,
        camera.cy,
        d,
        mask,
        robot_depth,
        False,
        *_work_buffers(camera.shape),
    )
    return SelfFilterResult(mask, robot_depth)


@lru_cache(maxsize=1)
def _default_model():
    from depthguard.robot.model import load_lwr4

    return load_lwr4()


def self_filter(
    camera: Camera,
    depth: np.ndarray,
    q: np.ndarray,
    model=None,
    *,
    margin: float = 0.03,
    pad_px: int = 3,
) -> SelfFilterResult:
    """Remove the robot at joint positions ``q`` (n,) rad from ``depth`` (H, W), metres (0/NaN = no reading).

    ``model`` is a :class:`depthguard.robot.model.RobotModel` (default: the shipped LWR,
    :func:`depthguard.robot.model.load_lwr4`); see :func:`self_filter_capsules` for the rest.
    Returns ``(mask (H, W) bool, robot_depth (H, W) float)`` as a :class:`SelfFilterResult`.
    """
    model = _default_model() if model is None else model
    a, b, r = model.link_capsules(q)
    return self_filter_capsules(camera, depth, a, b, r, margin=margin, pad_px=pad_px)


def render_capsules_depth(camera: Camera, a: np.ndarray, b: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """(H, W) depth ``z_C`` (m) of the capsules' first surface through each pixel centre, NaN where none."""
    A, B, R = _capsules_in_camera(camera, a, b, radius)
    out = np.full(camera.shape, np.nan)
    dummy = np.zeros(camera.shape)
    mask = np.zeros(camera.shape, dtype=np.bool_)
    cam = (camera.fx, camera.fy, camera.cx, camera.cy)
    _self_filter_kernel(A, B, R, 0.0, 0, *cam, dummy, mask, out, True, *_work_buffers(camera.shape))
    return out
