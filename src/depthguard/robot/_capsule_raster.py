"""Numba ray casting of inflated capsules through the pixel centres, for the self-filter (no OpenGL).

Each capsule (segment ``a``-``b`` swept by a sphere) is intersected analytically with the pixel-centre
rays (``p_x = u + 0.5``) inside its projected bounding box; along a ray it occupies ``[t0, t1]`` in depth.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def _capsule_consts(a: np.ndarray, b: np.ndarray, r: float) -> np.ndarray:
    """Per-capsule constants for :func:`_line_capsule` (camera at the origin)."""
    # written out element by element: slice assignments would compile numba's shape-mismatch error
    # message (seconds of every cold start)
    c = np.empty(17)
    ax, ay, az, bx, by, bz = a[0], a[1], a[2], b[0], b[1], b[2]
    wx, wy, wz = bx - ax, by - ay, bz - az
    L = np.sqrt(wx * wx + wy * wy + wz * wz)
    if L > 1e-12:
        wx, wy, wz = wx / L, wy / L, wz / L
    else:
        wx, wy, wz, L = 0.0, 0.0, 1.0, 0.0
    ow = -(ax * wx + ay * wy + az * wz)  # (origin - a) . w
    qx, qy, qz = -ax - ow * wx, -ay - ow * wy, -az - ow * wz  # (origin - a) without its axial part
    vals = (ax, ay, az, bx, by, bz, wx, wy, wz, L, qx, qy, qz)
    for k in range(13):
        c[k] = vals[k]
    c[13] = qx * qx + qy * qy + qz * qz - r * r
    c[14] = ax * ax + ay * ay + az * az - r * r
    c[15] = bx * bx + by * by + bz * bz - r * r
    c[16] = ow
    return c


@njit(cache=True, nogil=True)
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


@njit(cache=True, nogil=True, inline="always")
def _point_in_capsule(px: float, py: float, pz: float, c: np.ndarray, r: float) -> bool:
    """Whether the point (camera frame) lies in the capsule of constants ``c`` (:func:`_capsule_consts`) and
    radius ``r``: its distance from the segment, clamped to its ends, is at most ``r``."""
    ex, ey, ez = px - c[0], py - c[1], pz - c[2]
    s = ex * c[6] + ey * c[7] + ez * c[8]
    s = min(max(s, 0.0), c[9])
    ex, ey, ez = ex - s * c[6], ey - s * c[7], ez - s * c[8]
    return ex * ex + ey * ey + ez * ez <= r * r


@njit(cache=True, nogil=True, inline="always")
def _sphere_span(x: float, z: float, r: float, f: float, cc: float) -> tuple[float, float]:
    """Exact pixel span (lo, hi) along one image axis of a sphere of radius ``r`` fully in front of the
    camera, its centre at ``x`` along that axis and depth ``z`` (camera frame, m)."""
    den = z * z - r * r
    root = np.sqrt(max(x * x + z * z - r * r, 0.0))
    lo = (x * z - r * root) / den
    hi = (x * z + r * root) / den
    return f * lo + cc, f * hi + cc


@njit(cache=True, nogil=True)
def _sphere_bbox(c: np.ndarray, r: float, fx: float, fy: float, cx: float, cy: float) -> tuple[float, ...]:
    """Exact image bounding box (pixel coordinates) of a sphere fully in front of the camera."""
    u_lo, u_hi = _sphere_span(c[0], c[2], r, fx, cx)
    v_lo, v_hi = _sphere_span(c[1], c[2], r, fy, cy)
    return u_lo, u_hi, v_lo, v_hi


@njit(cache=True, nogil=True)
def capsule_kernel(
    A: np.ndarray,
    B: np.ndarray,
    R: np.ndarray,
    margin: float,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    depth: np.ndarray,
    mask: np.ndarray,
    infl: np.ndarray,
    ubox: np.ndarray,
    with_depth: bool = True,
) -> None:
    """Ray cast the capsules inflated by ``margin`` through every pixel centre of their image boxes.

    ``infl`` (H, W): running minimum of the inflated depth (inf = none); ``mask`` (H, W) bool: set where a
    measured depth lies inside an inflated capsule; ``ubox`` (4,) int: union box (u_lo, u_hi, v_lo, v_hi).
    ``with_depth=False``: only the mask is wanted, so a measured pixel is tested as a point (is it within
    the inflated radius of the segment? the same answer as "is its depth inside the ray's interval", for a
    convex capsule, and about a quarter of the work) and ``infl`` is kept only where the depth is missing.
    """
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
                # the part's ends pa, pb (x and z only: the row span), in scalars (no arrays per row)
                pax = A[k, 0] + ta * (B[k, 0] - A[k, 0])
                paz = A[k, 2] + ta * (B[k, 2] - A[k, 2])
                pbx = A[k, 0] + tb * (B[k, 0] - A[k, 0])
                pbz = A[k, 2] + tb * (B[k, 2] - A[k, 2])
                if paz - ri <= 1e-6 or pbz - ri <= 1e-6:
                    continue  # cannot happen when both end balls are in front; kept for safety
                e0, e1 = _sphere_span(pax, paz, ri, fx, cx)
                g0, g1 = _sphere_span(pbx, pbz, ri, fx, cx)
                r0 = max(int(np.floor(min(e0, g0))) - 1, x0)
                r1 = min(int(np.floor(max(e1, g1))) + 1, x1)
            for u in range(r0, r1 + 1):
                dx = (u + 0.5 - cx) / fx
                if not with_depth:
                    d = depth[v, u]
                    if d > 0.0 and d < np.inf:
                        if _point_in_capsule(d * dx, d * dy, d, cc, ri):
                            mask[v, u] = True
                        continue
                t0, t1 = _line_capsule(dx, dy, cc)
                if t1 < max(t0, 0.0):
                    continue
                tin = max(t0, 0.0)
                if tin < infl[v, u]:
                    infl[v, u] = tin
                d = depth[v, u]
                if d > 0.0 and d < np.inf and t0 <= d <= t1:
                    mask[v, u] = True
    ubox[0], ubox[1] = min(ubox[0], u_lo), max(ubox[1], u_hi)
    ubox[2], ubox[3] = min(ubox[2], v_lo), max(ubox[3], v_hi)
