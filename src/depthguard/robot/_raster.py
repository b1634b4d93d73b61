"""Numba triangle rasteriser of inflated meshes into a depth image (no OpenGL), for the self-filter.

For each shape (one rigid mesh) every triangle is projected with the pinhole model and filled at the
pixel centres it covers (``p = (u + 0.5, v + 0.5)``, edges inclusive); the depth ``z_C`` at a pixel centre
is exact for a planar triangle because ``1 / z`` is affine in the image. Per shape the kernel keeps the
nearest and the farthest depth of the shape along each pixel ray (``near``, ``far``): a measured depth in
``[near, far]`` lies inside the shape (exactly so for a convex shape; in a concavity the gap counts as
inside). Triangles that cross the near plane ``z = znear`` are clipped against it.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, inline="always")
def _scan_setup(x0, y0, x1, y1, x2, y2, H, W):
    """Scanline set-up of a projected triangle: the pixel-centre box (v_lo, v_hi, u_lo, u_hi; empty when
    lo > hi), the vertices sorted by y, ``(ax, ay) <= (bx, by) <= (cx, cy)``, and the inverse slopes of the
    edges a-c, a-b, b-c."""
    v_lo = max(int(np.ceil(min(y0, y1, y2) - 0.5 - 1e-7)), 0)
    v_hi = min(int(np.floor(max(y0, y1, y2) - 0.5 + 1e-7)), H - 1)
    u_lo = max(int(np.ceil(min(x0, x1, x2) - 0.5 - 1e-7)), 0)
    u_hi = min(int(np.floor(max(x0, x1, x2) - 0.5 + 1e-7)), W - 1)
    ax, ay, bx, by, cx_, cy_ = x0, y0, x1, y1, x2, y2
    if ay > by:
        ax, ay, bx, by = bx, by, ax, ay
    if by > cy_:
        bx, by, cx_, cy_ = cx_, cy_, bx, by
    if ay > by:
        ax, ay, bx, by = bx, by, ax, ay
    s_ac = (cx_ - ax) / (cy_ - ay) if cy_ > ay else 0.0
    s_ab = (bx - ax) / (by - ay) if by > ay else 0.0
    s_bc = (cx_ - bx) / (cy_ - by) if cy_ > by else 0.0
    return v_lo, v_hi, u_lo, u_hi, ax, ay, bx, by, cy_, s_ac, s_ab, s_bc


@njit(cache=True, nogil=True, inline="always")
def _row_span(v, u_lo, u_hi, ax, ay, bx, by, cy_, s_ac, s_ab, s_bc, rows):
    """The pixel columns [ua, ub] of row ``v`` whose centres the triangle covers (edges inclusive; empty
    when ua > ub); widens the row's touched span ``rows[v]``. The span lies between the long edge a-c and
    one of the two short ones."""
    py = v + 0.5
    xl = ax + (py - ay) * s_ac
    if py < by:
        xr = ax + (py - ay) * s_ab
    elif cy_ > by:
        xr = bx + (py - by) * s_bc
    else:  # py == by == cy: the flat edge b-c
        xr = bx
    lo, hi = min(xl, xr), max(xl, xr)
    ua = max(int(np.ceil(lo - 0.5 - 1e-7)), u_lo)
    ub = min(int(np.floor(hi - 0.5 + 1e-7)), u_hi)
    if ua <= ub:
        if ua < rows[v, 0]:
            rows[v, 0] = ua
        if ub > rows[v, 1]:
            rows[v, 1] = ub
    return ua, ub


@njit(cache=True, nogil=True, inline="always")
def _raster_tri(x0, y0, w0, x1, y1, w1, x2, y2, w2, snear, sfar, rows, depth, wn, sg) -> None:
    """Fill one projected triangle (image coordinates ``x, y``, inverse depths ``w = 1 / z > 0``) into the
    per-shape buffers of inverse depth: ``snear`` keeps the largest, ``sfar`` the smallest; ``rows`` (H, 2)
    holds each row's touched span [lo, hi]. ``wn`` (H, W) counts the crossings in front of the measured
    ``depth``: ``sg`` = +1 where the triangle's original face looks at the camera (the ray enters the
    shape), -1 where it looks away, so that ``wn > 0`` at a pixel means that its measured point lies inside
    the closed shape (its winding number). Scanline: the vertices sorted by y, each row's span lies between
    the long edge and one of the two short ones. (The set-up is written out here, not taken from
    :func:`_scan_setup` and :func:`_row_span` as :func:`_count_tri` does: sharing them made the Panda's
    filter 1.1-1.9 times slower, measured.)"""
    H, W = snear.shape
    area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
    if abs(area) < 1e-12:
        return  # edge-on: its neighbours cover the pixels
    v_lo = max(int(np.ceil(min(y0, y1, y2) - 0.5 - 1e-7)), 0)
    v_hi = min(int(np.floor(max(y0, y1, y2) - 0.5 + 1e-7)), H - 1)
    u_lo = max(int(np.ceil(min(x0, x1, x2) - 0.5 - 1e-7)), 0)
    u_hi = min(int(np.floor(max(x0, x1, x2) - 0.5 + 1e-7)), W - 1)
    if v_lo > v_hi or u_lo > u_hi:
        return
    inv = 1.0 / area
    # 1/z is affine in the image: iz = A px + B py + C (from the barycentric coordinates)
    d0, d1 = w0 - w2, w1 - w2
    A = ((y1 - y2) * d0 + (y2 - y0) * d1) * inv
    B = ((x2 - x1) * d0 + (x0 - x2) * d1) * inv
    C = w2 + ((x1 * y2 - x2 * y1) * d0 + (x2 * y0 - x0 * y2) * d1) * inv
    w_lo, w_hi = min(w0, w1, w2), max(w0, w1, w2)
    # sort the vertices by y: (ax, ay) <= (bx, by) <= (cx, cy)
    ax, ay, bx, by, cx_, cy_ = x0, y0, x1, y1, x2, y2
    if ay > by:
        ax, ay, bx, by = bx, by, ax, ay
    if by > cy_:
        bx, by, cx_, cy_ = cx_, cy_, bx, by
    if ay > by:
        ax, ay, bx, by = bx, by, ax, ay
    s_ac = (cx_ - ax) / (cy_ - ay) if cy_ > ay else 0.0
    s_ab = (bx - ax) / (by - ay) if by > ay else 0.0
    s_bc = (cx_ - bx) / (cy_ - by) if cy_ > by else 0.0
    for v in range(v_lo, v_hi + 1):
        py = v + 0.5
        xl = ax + (py - ay) * s_ac
        if py < by:
            xr = ax + (py - ay) * s_ab
        elif cy_ > by:
            xr = bx + (py - by) * s_bc
        else:  # py == by == cy: the flat edge b-c
            xr = bx
        lo, hi = min(xl, xr), max(xl, xr)
        ua = max(int(np.ceil(lo - 0.5 - 1e-7)), u_lo)
        ub = min(int(np.floor(hi - 0.5 + 1e-7)), u_hi)
        if ua > ub:
            continue
        if ua < rows[v, 0]:
            rows[v, 0] = ua
        if ub > rows[v, 1]:
            rows[v, 1] = ub
        row_n, row_f, row_d, row_w = snear[v], sfar[v], depth[v], wn[v]
        base = B * py + C
        for u in range(ua, ub + 1):  # branch-free, so that the compiler can vectorise the span
            iz = min(max(A * (u + 0.5) + base, w_lo), w_hi)  # clamp: rounding at the edges
            row_n[u] = max(row_n[u], iz)
            row_f[u] = min(row_f[u], iz)
            row_w[u] += sg if iz * row_d[u] > 1.0 else 0  # the face lies in front of the measured point


@njit(cache=True, nogil=True, inline="always")
def _count_tri(x0, y0, x1, y1, x2, y2, rows, wn) -> None:
    """Add the orientation (+1 counter-clockwise in the image, -1 clockwise) of one projected triangle to
    ``wn`` at the pixel centres it covers: summed over a fan of triangles from one point to the edges of
    closed polygons, the polygons' winding number at each pixel."""
    H, W = wn.shape
    area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
    if abs(area) < 1e-12:
        return
    sg = 1 if area > 0 else -1
    v_lo, v_hi, u_lo, u_hi, ax, ay, bx, by, cy_, s_ac, s_ab, s_bc = _scan_setup(x0, y0, x1, y1, x2, y2, H, W)
    if v_lo > v_hi or u_lo > u_hi:
        return
    for v in range(v_lo, v_hi + 1):
        ua, ub = _row_span(v, u_lo, u_hi, ax, ay, bx, by, cy_, s_ac, s_ab, s_bc, rows)
        row_w = wn[v]
        for u in range(ua, ub + 1):
            row_w[u] += sg


@njit(cache=True, nogil=True)
def _raster_clipped(p0, p1, p2, znear, fx, fy, cx, cy, snear, sfar, rows, depth, wn, sg) -> None:
    """Clip a triangle against ``z >= znear`` (Sutherland-Hodgman) and fill what is left."""
    pts = (p0, p1, p2)
    out = np.empty((4, 3))
    n = 0
    for i in range(3):
        a, b = pts[i], pts[(i + 1) % 3]
        ina, inb = a[2] >= znear, b[2] >= znear
        # (element by element: a row assignment compiles numba's shape-mismatch message, seconds of a cold start)
        if ina:
            out[n, 0], out[n, 1], out[n, 2] = a[0], a[1], a[2]
            n += 1
        if ina != inb:
            t = (znear - a[2]) / (b[2] - a[2])
            out[n, 0], out[n, 1] = a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])
            out[n, 2] = znear
            n += 1
    for i in range(n):  # project
        z = out[i, 2]
        out[i, 0], out[i, 1], out[i, 2] = fx * out[i, 0] / z + cx, fy * out[i, 1] / z + cy, 1.0 / z
    for k in range(1, n - 1):
        a, b, c = out[0], out[k], out[k + 1]
        _raster_tri(a[0], a[1], a[2], b[0], b[1], b[2], c[0], c[1], c[2], snear, sfar, rows, depth, wn, sg)


@njit(cache=True, nogil=True)
def _origin_winding(P, F, f0, f1, v_start) -> float:
    """Winding number of the origin (the camera) with respect to the triangles ``F[f0:f1]`` (outward wound)
    whose vertices are the rows ``P[F - v_start]`` (camera frame): the sum of their signed solid angles
    (Van Oosterom-Strackee) over 4 pi; 1 inside a closed shape, 0 outside it."""
    total = 0.0
    for f in range(f0, f1):
        a, b, c = P[F[f, 0] - v_start], P[F[f, 1] - v_start], P[F[f, 2] - v_start]
        la = np.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
        lb = np.sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2])
        lc = np.sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2])
        cx = b[1] * c[2] - b[2] * c[1]
        cy = b[2] * c[0] - b[0] * c[2]
        cz = b[0] * c[1] - b[1] * c[0]
        num = a[0] * cx + a[1] * cy + a[2] * cz
        ab = a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
        ac = a[0] * c[0] + a[1] * c[1] + a[2] * c[2]
        bc = b[0] * c[0] + b[1] * c[1] + b[2] * c[2]
        total += 2.0 * np.arctan2(num, la * lb * lc + ab * lc + ac * lb + bc * la)
    return total / (4.0 * np.pi)


@njit(cache=True, nogil=True)
def _near_plane_cap(P, F, f0, f1, v_start, znear, fx, fy, cx, cy, rows, wn) -> None:
    """Count into ``wn`` the winding number of the shape's cross-section with the near plane ``z = znear``
    at each pixel (the cap that clipping takes off a closed shape the camera lies just outside of): each
    triangle cut by the plane gives a segment of the section's boundary, oriented by the triangle's
    winding, and a fan of triangles from the first such point to every segment sums to the winding number
    (non-zero exactly inside the section, for any closed, possibly non-convex, shape). Each crossing point
    is interpolated from the edge's vertex in front of the plane, so the two faces of an edge agree to the
    bit and the segments close."""
    have_anchor = False
    qx0, qy0 = 0.0, 0.0
    seg = np.empty((2, 2))  # (exit, entry) points of the boundary of the kept side, image coordinates
    for f in range(f0, f1):
        n_found = 0
        for k in range(3):
            a, b = P[F[f, k] - v_start], P[F[f, (k + 1) % 3] - v_start]
            ina, inb = a[2] >= znear, b[2] >= znear
            if ina == inb:
                continue
            p, o = (a, b) if ina else (b, a)  # (in front of the plane, behind it)
            t = (znear - p[2]) / (o[2] - p[2])
            slot = 0 if ina else 1  # in -> out: where the boundary leaves the kept side; out -> in: returns
            seg[slot, 0] = fx * (p[0] + t * (o[0] - p[0])) / znear + cx
            seg[slot, 1] = fy * (p[1] + t * (o[1] - p[1])) / znear + cy
            n_found += 1
        if n_found != 2:
            continue
        if not have_anchor:
            qx0, qy0, have_anchor = seg[0, 0], seg[0, 1], True
            continue  # (its fan triangle is degenerate)
        _count_tri(qx0, qy0, seg[0, 0], seg[0, 1], seg[1, 0], seg[1, 1], rows, wn)


@njit(cache=True, nogil=True, inline="always")
def _mark_shape(rows, snear, sfar, wn, depth, whole, mask, near, ubox, inside=False, cap=False, znear=0.0) -> None:
    """After one shape is drawn: over its rows' spans, mark in ``mask`` the measured points inside it (depth
    in ``[near, far]`` and, unless ``whole``, winding number > 0), keep the nearest inflated depth in
    ``near``, grow ``ubox``, and reset the shape's buffers (``snear`` 0, ``sfar`` inf, ``wn`` 0, ``rows``).
    ``inside``: the camera lies inside the inflated shape, so along every ray it starts at depth 0 (the
    surfaces drawn are only where the rays leave it). ``cap``: the shape is cut by the near plane with the
    camera outside it, and ``wn`` holds its cross-section's winding number (:func:`_near_plane_cap`): rays
    through the section enter the shape before the plane ``znear``, so they start there (not at 0: between
    the camera and the entry a point may lie up to ``znear`` outside the shape)."""
    for v in range(depth.shape[0]):
        if rows[v, 1] < 0:
            continue
        ubox[0], ubox[1] = min(ubox[0], rows[v, 0]), max(ubox[1], rows[v, 1])
        ubox[2], ubox[3] = min(ubox[2], v), max(ubox[3], v)
        for u in range(rows[v, 0], rows[v, 1] + 1):
            izn = snear[v, u]
            w = wn[v, u]
            wn[v, u] = 0
            if izn == 0.0:
                continue
            zn, zf = 1.0 / izn, 1.0 / sfar[v, u]
            if inside:
                zn = 0.0
            elif cap and w != 0:
                zn = min(zn, znear)
            d = depth[v, u]
            if d > 0.0 and d < np.inf and zn <= d <= zf and (whole or w > 0):
                mask[v, u] = True
            if zn < near[v, u]:
                near[v, u] = zn
            snear[v, u] = 0.0
            sfar[v, u] = np.inf
        rows[v, 0], rows[v, 1] = 1 << 30, -1


@njit(cache=True, nogil=True)
def mesh_kernel(
    V: np.ndarray,
    O: np.ndarray,
    F: np.ndarray,
    vr: np.ndarray,
    fr: np.ndarray,
    T: np.ndarray,
    infl: np.ndarray,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    znear: float,
    depth: np.ndarray,
    mask: np.ndarray,
    near: np.ndarray,
    snear: np.ndarray,
    sfar: np.ndarray,
    wn: np.ndarray,
    NP: np.ndarray,
    closed: np.ndarray,
    watertight: np.ndarray,
    ubox: np.ndarray,
) -> None:
    """Rasterise every inflated mesh shape; mark measured pixels inside a shape in ``mask``.

    Args:
        V, O: (Vt, 3) vertices in their shape's parent-joint frame and inflation offsets (m per m of margin).
        F: (Ft, 3) vertex indices into V. vr, fr: (S, 2) vertex / face index ranges of each shape.
        T: (S, 3, 4) camera-from-joint transform of each shape. infl: (S,) inflation of each shape, m.
        depth: (H, W) measured z_C, m (no reading: not > 0 or not finite).
        mask: (H, W) bool, set True where a measured point lies in ``[near, far]`` of a shape and inside it
            (winding number > 0: not in a gap between two of its parts; for a shape cut by the near plane,
            whose crossings are incomplete, the interval alone decides).
        near: (H, W) running minimum of the inflated robot's depth (inf = none).
        snear, sfar: (H, W) work buffers of inverse depth (largest / smallest 1/z), 0 / inf on entry and exit.
        wn: (H, W) int work buffer of winding numbers, 0 on entry and exit.
        NP: (Ft, 4) outward unit normal and offset of each original face (``n . x = h``), joint frame.
        closed: (S,) bool, the shape is a closed, non-convex mesh: its winding number is meaningful.
        watertight: (S,) bool, the shape is a closed mesh (convex ones too): its cross-section with the near
            plane is closed, so that a camera just outside the shape keeps the rays that enter it before the
            plane (:func:`_near_plane_cap`).
        ubox: (4,) int union box (u_lo, u_hi, v_lo, v_hi) of the pixels touched, updated.
    """
    nv_max = 0
    for s in range(vr.shape[0]):
        nv_max = max(nv_max, vr[s, 1] - vr[s, 0])
    P = np.empty((nv_max, 3))  # camera frame
    S = np.empty((nv_max, 3))  # projected: x, y, 1 / z
    H = depth.shape[0]
    rows = np.empty((H, 2), dtype=np.int64)
    rows[:, 0], rows[:, 1] = 1 << 30, -1
    for s in range(vr.shape[0]):
        v_start = vr[s, 0]
        m = infl[s]
        zmin = np.inf
        for i in range(v_start, vr[s, 1]):
            x0 = V[i, 0] + m * O[i, 0]
            x1 = V[i, 1] + m * O[i, 1]
            x2 = V[i, 2] + m * O[i, 2]
            for r in range(3):
                P[i - v_start, r] = T[s, r, 0] * x0 + T[s, r, 1] * x1 + T[s, r, 2] * x2 + T[s, r, 3]
            z = P[i - v_start, 2]
            zmin = min(zmin, z)
            if z > znear:
                iz = 1.0 / z
                S[i - v_start, 0] = fx * P[i - v_start, 0] * iz + cx
                S[i - v_start, 1] = fy * P[i - v_start, 1] * iz + cy
                S[i - v_start, 2] = iz
        # the interval alone decides for an open mesh, or one cut by the near plane (crossings incomplete)
        whole = not closed[s] or zmin <= znear
        # a camera inside the inflated shape (within the margin of the robot): the shape has vertices behind
        # it, and its rays start inside, so their near side is the camera itself, not the first surface drawn
        inside = zmin <= znear and _origin_winding(P, F, fr[s, 0], fr[s, 1], v_start) > 0.5
        ex = -(T[s, 0, 0] * T[s, 0, 3] + T[s, 1, 0] * T[s, 1, 3] + T[s, 2, 0] * T[s, 2, 3])  # camera, joint frame
        ey = -(T[s, 0, 1] * T[s, 0, 3] + T[s, 1, 1] * T[s, 1, 3] + T[s, 2, 1] * T[s, 2, 3])
        ez = -(T[s, 0, 2] * T[s, 0, 3] + T[s, 1, 2] * T[s, 1, 3] + T[s, 2, 2] * T[s, 2, 3])
        # a camera just outside a closed shape that the near plane cuts: rays through the cut enter the shape
        # before the plane, so the cut's cross-section is counted into wn (the crossings are not needed: whole)
        cap = zmin <= znear and watertight[s] and not inside
        for f in range(fr[s, 0], fr[s, 1]):
            i0, i1, i2 = F[f, 0] - v_start, F[f, 1] - v_start, F[f, 2] - v_start
            # the original face's side, not the inflated one's: small faces in a hollow flip when inflated
            sg = 1 if NP[f, 0] * ex + NP[f, 1] * ey + NP[f, 2] * ez > NP[f, 3] else -1
            if cap:
                sg = 0
            if zmin > znear or (P[i0, 2] > znear and P[i1, 2] > znear and P[i2, 2] > znear):
                _raster_tri(
                    S[i0, 0], S[i0, 1], S[i0, 2], S[i1, 0], S[i1, 1], S[i1, 2], S[i2, 0], S[i2, 1], S[i2, 2],
                    snear, sfar, rows, depth, wn, sg,
                )  # fmt: skip
            elif P[i0, 2] > znear or P[i1, 2] > znear or P[i2, 2] > znear:
                _raster_clipped(P[i0], P[i1], P[i2], znear, fx, fy, cx, cy, snear, sfar, rows, depth, wn, sg)
        if cap:
            _near_plane_cap(P, F, fr[s, 0], fr[s, 1], v_start, znear, fx, fy, cx, cy, rows, wn)
        _mark_shape(rows, snear, sfar, wn, depth, whole, mask, near, ubox, inside, cap, znear)


@njit(cache=True, nogil=True)
def finish_kernel(
    depth: np.ndarray, mask: np.ndarray, near: np.ndarray, robot_depth: np.ndarray, ubox, with_depth: bool = True
) -> None:
    """Inside the inflated silhouette (``near`` < inf): robot depth = ``near`` (unless ``with_depth`` is
    False); a pixel without reading is robot. Outside it nothing is touched (a hole beside the robot follows
    the missing-depth policy). Resets ``near`` to inf over ``ubox``."""
    if ubox[1] < 0:
        return
    for v in range(ubox[2], ubox[3] + 1):
        for u in range(ubox[0], ubox[1] + 1):
            zn = near[v, u]
            if zn < np.inf:
                if with_depth:
                    robot_depth[v, u] = zn
                d = depth[v, u]
                if not (d > 0.0 and d < np.inf):
                    mask[v, u] = True
                near[v, u] = np.inf
