"""Independent references for the distance kernels, written from the papers' definitions (no kernel code).

* :func:`piece_distance`: the exact Euclidean distance from a point to pixel frustum pieces
  ``{(x, y, z): z0 <= z <= z1, a0 z <= x <= a1 z, b0 z <= y <= b1 z}`` (camera frame), pixel ``(u, v)``
  covering the image rectangle ``[u, u+1] x [v, v+1]``, so ``a0 = (u - cx)/fx``, ``a1 = (u + 1 - cx)/fx``.
  For a fixed depth z the nearest point of the slice is the clamp of P to it (the slice is a rectangle), and
  the distance to a convex set restricted to the slices is convex in z: a golden-section search on z is
  exact to ~1e-12 m.
* :func:`depthspace_exact`: ICRA'12 / RA-L'16 single camera: every pixel with a measured (or filled) depth
  ``d_o`` is an obstacle from ``d_o`` on (the surface and its gray area); the exact distance to the union.
* :func:`grid_exact`: RA-L'16 §VI-VII by definition: the occupied part of each principal pixel's ray from its
  start on (the cell of a measured surface; cells that no secondary camera clears, a camera clearing a cell
  when the cell lies in front of it and inside its image and every pixel of the bounding box of the cell's
  8 projected corners reads beyond the cell's far depth; outside the grid: occupied except behind a robot
  pixel), and the exact distance to it. Returned twice, with the footprints perturbed by +-1e-9 pixel and
  the far depth quantised or not (``lax``: fewer cells occupied, ``strict``: more), so that rounding at
  exact pixel boundaries cannot decide a comparison.
"""

from __future__ import annotations

import math

import numpy as np

from depthguard.camera import Camera

INVPHI = (math.sqrt(5.0) - 1.0) / 2.0
FOOT_MAX = 255  # largest footprint extent of a cell (pixels - 1) for which a camera votes (method parameter)
DEND_QUANTUM = 4e-4  # far depths are stored rounded up to this (method parameter)


def piece_distance(P, a0, a1, b0, b1, z0, z1, iters: int = 90) -> np.ndarray:
    """Exact distance from P (3,) to the frustum pieces (arrays broadcast; z1 finite, z0 <= z1)."""
    px, py, pz = (float(x) for x in P)
    a0, a1, b0, b1, z0, z1 = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in (a0, a1, b0, b1, z0, z1)))

    def f(z):
        x = np.clip(px, np.minimum(a0 * z, a1 * z), np.maximum(a0 * z, a1 * z))
        y = np.clip(py, np.minimum(b0 * z, b1 * z), np.maximum(b0 * z, b1 * z))
        return np.sqrt((px - x) ** 2 + (py - y) ** 2 + (pz - z) ** 2)

    lo, hi = z0.copy(), z1.copy()
    c = hi - INVPHI * (hi - lo)
    d = lo + INVPHI * (hi - lo)
    fc, fd = f(c), f(d)
    for _ in range(iters):
        left = fc < fd
        hi = np.where(left, d, hi)
        lo = np.where(left, lo, c)
        c2 = hi - INVPHI * (hi - lo)
        d2 = lo + INVPHI * (hi - lo)
        c, d = c2, d2
        fc, fd = f(c), f(d)
    return np.minimum.reduce([f(0.5 * (lo + hi)), f(z0), f(z1)])


def _pixel_bounds(cam: Camera, u, v):
    return (u - cam.cx) / cam.fx, (u + 1 - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, (v + 1 - cam.cy) / cam.fy


def _aabb_lower_bound(Pc, a0, a1, b0, b1, z0, z1):
    """Distance from P to the axis-aligned box around the pieces (a lower bound of the exact distance)."""
    xs = np.stack([a0 * z0, a0 * z1, a1 * z0, a1 * z1])
    ys = np.stack([b0 * z0, b0 * z1, b1 * z0, b1 * z1])
    gx = np.maximum(np.maximum(xs.min(0) - Pc[0], Pc[0] - xs.max(0)), 0.0)
    gy = np.maximum(np.maximum(ys.min(0) - Pc[1], Pc[1] - ys.max(0)), 0.0)
    gz = np.maximum(np.maximum(z0 - Pc[2], Pc[2] - z1), 0.0)
    return np.sqrt(gx * gx + gy * gy + gz * gz)


def depthspace_exact(cam: Camera, obstacle_depth: np.ndarray, Pc: np.ndarray, reach: float):
    """Exact distance from Pc (camera frame) to the obstacles and gray areas of one frame.

    Args:
        obstacle_depth: (H, W) start depth of each pixel's obstacle, +inf where none.
        reach: distances at or beyond this are not needed (reported as inf).
    Returns:
        ``(distance, per_pixel)``: the minimum (inf if none below reach) and the (H, W) distances (inf
        where none or not below reach).
    """
    H, W = obstacle_depth.shape
    v, u = np.mgrid[0:H, 0:W]
    a0, a1, b0, b1 = _pixel_bounds(cam, u, v)
    z0 = obstacle_depth.astype(float)
    zcap = max(float(Pc[2]), 0.0) + 2.0 * reach + 1.0
    out = np.full((H, W), np.inf)
    ok = np.isfinite(z0) & (z0 < zcap)
    z1 = np.maximum(z0, zcap)
    ok[ok] = _aabb_lower_bound(Pc, a0[ok], a1[ok], b0[ok], b1[ok], z0[ok], z1[ok]) < reach
    d = piece_distance(Pc, a0[ok], a1[ok], b0[ok], b1[ok], z0[ok], z1[ok])
    out[ok] = np.where(d < reach, d, np.inf)
    return float(out.min()), out


# ------------------------------------------------------------------------------------------ depth grid
def _rect_min(img: np.ndarray, v0, v1, u0, u1, mask) -> np.ndarray:
    """Minimum of ``img`` over each inclusive rectangle (where ``mask``; +inf elsewhere): a 2-D sparse table
    (the minimum over every 2^i x 2^j block), four overlapping blocks per rectangle."""
    H, W = img.shape
    table = {}
    rows = [img.astype(float)]
    for _ in range(1, int(np.log2(H)) + 1):
        r = rows[-1]
        k = 1 << (len(rows) - 1)
        rows.append(np.minimum(r[:-k], r[k:]))
    for i, r in enumerate(rows):
        cols = [r]
        for _ in range(1, int(np.log2(W)) + 1):
            c = cols[-1]
            k = 1 << (len(cols) - 1)
            cols.append(np.minimum(c[:, :-k], c[:, k:]))
        for j, c in enumerate(cols):
            table[i, j] = c
    out = np.full(len(v0), np.inf)
    idx = np.nonzero(mask)[0]
    kv = np.floor(np.log2(v1[idx] - v0[idx] + 1)).astype(int)
    ku = np.floor(np.log2(u1[idx] - u0[idx] + 1)).astype(int)
    for i, j in set(zip(kv.tolist(), ku.tolist(), strict=True)):
        m = idx[(kv == i) & (ku == j)]
        t = table[i, j]
        va, vb = v0[m], v1[m] - (1 << i) + 1
        ua, ub = u0[m], u1[m] - (1 << j) + 1
        out[m] = np.minimum.reduce([t[va, ua], t[vb, ua], t[va, ub], t[vb, ub]])
    return out


def _clears(cam0: Camera, cam: Camera, votes, u, v, d1, d2, eps: float, quantise: bool):
    """Whether secondary camera ``cam`` clears principal cells (u, v, [d1, d2]) and whether it is involved.

    ``eps`` > 0 widens each footprint and raises its far depth (fewer clears, for the strict reference);
    ``eps`` < 0 shrinks it (more clears, for the lax one).
    """
    n = len(u)
    corners = []
    for du_, dv_ in ((0, 0), (1, 0), (0, 1), (1, 1)):
        a = (u + du_ - cam0.cx) / cam0.fx
        b = (v + dv_ - cam0.cy) / cam0.fy
        for d in (d1, d2):
            corners.append(np.stack([a * d, b * d, d], axis=1))
    X = cam.world_to_camera(cam0.camera_to_world(np.concatenate(corners)))
    X = X.reshape(8, n, 3)
    Z = X[..., 2]
    front = np.all(Z > 1e-6, axis=0)
    Zs = np.where(Z > 1e-6, Z, 1.0)
    pu = cam.fx * X[..., 0] / Zs + cam.cx
    pv = cam.fy * X[..., 1] / Zs + cam.cy
    umin, umax, vmin, vmax = pu.min(0) - eps, pu.max(0) + eps, pv.min(0) - eps, pv.max(0) + eps
    inside = front & (umin >= 0) & (vmin >= 0) & (umax < cam.width) & (vmax < cam.height)
    iu0 = np.floor(np.where(inside, umin, 0)).astype(int)
    iv0 = np.floor(np.where(inside, vmin, 0)).astype(int)
    iu1 = np.floor(np.where(inside, umax, 0)).astype(int)
    iv1 = np.floor(np.where(inside, vmax, 0)).astype(int)
    involved = inside & (iu1 - iu0 <= FOOT_MAX) & (iv1 - iv0 <= FOOT_MAX)
    far = Z.max(0)
    if quantise:
        far = np.ceil(far / DEND_QUANTUM) * DEND_QUANTUM + 1e-9
    lo = _rect_min(votes, iv0, iv1, iu0, iu1, involved)
    clear = involved & (lo > far)
    # a pixel of the bounding box that the projected cell does not touch has no say (exact projection):
    # every (cell, failing pixel) pair at once, flattened over the cells' bounding boxes
    idx = np.nonzero(involved & ~clear)[0]
    if len(idx):
        w, h = iu1[idx] - iu0[idx] + 1, iv1[idx] - iv0[idx] + 1
        sz = w * h
        ci = np.repeat(np.arange(len(idx)), sz)
        off = np.arange(int(sz.sum())) - np.repeat(np.cumsum(sz) - sz, sz)
        uu, vv = iu0[idx][ci] + off % w[ci], iv0[idx][ci] + off // w[ci]
        bad = votes[vv, uu] <= far[idx][ci]
        ci, uu, vv = ci[bad], uu[bad], vv[bad]
        touch = _squares_touch_hulls(pu[:, idx[ci]].T, pv[:, idx[ci]].T, uu, vv, eps)
        clear[idx] = np.bincount(ci[touch], minlength=len(idx)) == 0
    return clear, involved


def _squares_touch_hull(px, py, su, sv, eps: float) -> np.ndarray:
    """(M,) bool: pixel squares [su, su+1] x [sv, sv+1] (grown by ``eps``) that meet the convex hull of the
    points (px, py) (8,) (:func:`_squares_touch_hulls` with one hull for every square)."""
    m = len(su)
    return _squares_touch_hulls(np.broadcast_to(px, (m, 8)), np.broadcast_to(py, (m, 8)), su, sv, eps)


def _squares_touch_hulls(px, py, su, sv, eps: float, chunk: int = 4096) -> np.ndarray:
    """(M,) bool: pixel square ``[su, su+1] x [sv, sv+1]`` (grown by ``eps``) meets the convex hull of the 8
    points ``(px[i], py[i])`` (M, 8), by the separating-axis theorem over the image axes and the normals of
    every pair of points (the hull's edges are among them)."""
    out = np.empty(len(su), bool)
    for s in range(0, len(su), chunk):
        P = np.stack([px[s : s + chunk], py[s : s + chunk]], axis=-1)  # (m, 8, 2)
        d = P[:, None, :, :] - P[:, :, None, :]
        n = np.stack([-d[..., 1], d[..., 0]], axis=-1).reshape(len(P), -1, 2)
        n = np.concatenate([n, np.broadcast_to([[1.0, 0.0], [0.0, 1.0]], (len(P), 2, 2))], axis=1)
        norm = np.linalg.norm(n, axis=-1, keepdims=True)
        usable = norm[..., 0] > 1e-12  # (m, A): a pair of coincident points gives no axis
        n = n / np.where(norm > 1e-12, norm, 1.0)
        hp = np.einsum("mpk,mak->mpa", P, n)  # (m, 8, A)
        u0, v0 = su[s : s + chunk] - eps, sv[s : s + chunk] - eps
        u1, v1 = u0 + 1 + 2 * eps, v0 + 1 + 2 * eps
        sq = np.stack([np.stack([u0, v0], 1), np.stack([u1, v0], 1), np.stack([u1, v1], 1), np.stack([u0, v1], 1)], 1)
        sp = np.einsum("mck,mak->mca", sq, n)  # (m, 4, A)
        sep = usable & ((hp.max(1) < sp.min(1)) | (sp.max(1) < hp.min(1)))
        out[s : s + chunk] = ~np.any(sep, axis=1)
    return out


def grid_exact(cams, votes, start, kind, d_min, dd, n_cells, Pc, reach, strict: bool):
    """Exact distance from Pc (principal camera frame) to the occupied space of the depth grid.

    Args:
        cams: the cameras, principal first. votes: one (H_k, W_k) image per secondary camera, the depth
            each pixel sees past (measured depth; 0 where missing; +inf on robot pixels).
        start, kind: (H, W) per principal pixel: start depth and kind ("none", "surface", "unknown",
            "robot") from the principal image (see ``docs/conventions.md``).
        d_min, dd, n_cells: the depth grid (RA-L'16 eq. 4).
        strict: the reference with more cells occupied (footprints widened, far depths quantised up).
    """
    cam0 = cams[0]
    H, W = start.shape
    pz = float(Pc[2])
    zcap = max(pz, 0.0) + 2.0 * reach + 1.0
    d_max = d_min + n_cells * dd
    best = np.inf
    v, u = np.mgrid[0:H, 0:W]
    a0, a1, b0, b1 = _pixel_bounds(cam0, u, v)
    has = (kind != "none") & (start < zcap)
    # candidate pixels: the AABB of the whole ray from the start on must come within reach
    cand = np.zeros((H, W), bool)
    cand[has] = _aabb_lower_bound(Pc, a0[has], a1[has], b0[has], b1[has], start[has], np.full(has.sum(), zcap)) < reach
    vs, us = np.nonzero(cand)
    segs = []  # (pixel index, lo, hi) occupied pieces
    for i, (vv, uu) in enumerate(zip(vs, us, strict=True)):
        s0, k = float(start[vv, uu]), kind[vv, uu]
        if k == "surface" and s0 >= pz:
            segs.append((i, s0, zcap))  # case ii: the surface and its gray area
            continue
        if k != "robot":
            if s0 < d_min:
                segs.append((i, s0, min(d_min, zcap)))
            segs.append((i, max(d_max, s0), max(zcap, d_max, s0)))
    segs_out = list(segs)
    # grid cells of the candidate pixels within the depth window
    g_lo = max(0, int(math.floor((max(pz, 0.0) - reach - 2 * dd - d_min) / dd)))
    g_hi = min(n_cells - 1, int(math.floor((pz + reach + 2 * dd - d_min) / dd)))
    s0s = start[vs, us].astype(float)
    kinds = kind[vs, us]
    g_st = np.where(s0s >= d_min, np.floor((s0s - d_min) / dd), -1).astype(int)
    G = np.arange(g_lo, g_hi + 1)
    sel = (G[None, :] >= g_st[:, None]) & ~((kinds == "surface") & (s0s >= pz))[:, None]
    pix, gi = np.nonzero(sel)
    g = G[gi]
    d1 = d_min + g * dd
    d2 = d1 + dd
    lo_c = np.maximum(d1, s0s[pix])
    pv, pu = vs[pix], us[pix]
    # only cells whose bounding box comes within reach matter (a lower bound of their exact distance)
    near = _aabb_lower_bound(Pc, a0[pv, pu], a1[pv, pu], b0[pv, pu], b1[pv, pu], lo_c, d2) < reach
    pix, g, d1, d2, lo_c, pv, pu = pix[near], g[near], d1[near], d2[near], lo_c[near], pv[near], pu[near]
    if len(pix):
        measured = (g == g_st[pix]) & (kinds[pix] == "surface")
        robot = kinds[pix] == "robot"
        cleared = np.zeros(len(pix), bool)
        involved = np.zeros(len(pix), bool)
        eps = 1e-9 if strict else -1e-9
        for cam, vote in zip(cams[1:], votes, strict=True):
            c_, _ = _clears(cam0, cam, vote, pu, pv, d1, d2, eps, quantise=strict)
            # involvement makes a robot cell occupied: the strict reference involves more cameras
            _, inv_ = _clears(cam0, cam, vote, pu, pv, d1, d2, -eps, quantise=False)
            cleared |= c_
            involved |= inv_
        occupied = measured | (~cleared & (~robot | involved))
        segs_out += [
            (int(i), float(lo), float(hi))
            for i, lo, hi in zip(pix[occupied], lo_c[occupied], d2[occupied], strict=True)
        ]
    if not segs_out:
        return np.inf
    S = np.array(segs_out)
    idx = S[:, 0].astype(int)
    lo, hi = S[:, 1], np.maximum(S[:, 2], S[:, 1])
    pa0, pa1, pb0, pb1 = a0[vs[idx], us[idx]], a1[vs[idx], us[idx]], b0[vs[idx], us[idx]], b1[vs[idx], us[idx]]
    d = piece_distance(Pc, pa0, pa1, pb0, pb1, lo, hi)
    best = float(d.min())
    return best if best < reach else np.inf


def unseen_distance(cam: Camera, Pc: np.ndarray) -> float:
    """Exact distance from Pc (camera frame) to the unseen space: outside the viewing pyramid (the image
    rectangle ``[0, W] x [0, H]``) or nearer than ``min_depth``; 0 inside it."""
    c = [np.array([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1.0]) for u, v in ((0, 0), (cam.width, 0))]
    c += [
        np.array([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1.0])
        for u, v in ((cam.width, cam.height), (0, cam.height))
    ]
    inside = np.mean(c, axis=0)
    best = max(float(Pc[2]) - cam.min_depth, 0.0)
    for i in range(4):
        n = np.cross(c[i], c[(i + 1) % 4])
        n /= np.linalg.norm(n)
        if n @ inside < 0:
            n = -n
        best = min(best, max(float(n @ Pc), 0.0))  # the side planes pass through the camera centre
    return best
