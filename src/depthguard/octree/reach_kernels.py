"""Compiled kernels of the reachability sweep (:mod:`depthguard.octree.reach`): capsule rasterisation, the
collapse of a grid into samples, one joint's sweep (serial and on two threads), the swept samples' box and
the final dilation. Shapes and the error bookkeeping are documented in :mod:`depthguard.octree.reach`."""

from __future__ import annotations

import math
import threading

import numba as nb
import numpy as np

__all__ = [
    "REVOLUTE", "PRISMATIC", "H", "rasterize", "collect", "sweep", "sweep_two", "slide", "threads_ok", "dilate",
    "swept_bounds",
]  # fmt: skip

REVOLUTE = 0
PRISMATIC = 1
H = math.sqrt(3.0) / 2.0  # half a cell diagonal, in cells


@nb.njit(cache=True, nogil=True)
def seg_dist2(px, py, pz, a, b):
    dx, dy, dz = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    L2 = dx * dx + dy * dy + dz * dz
    s = 0.0
    if L2 > 0:
        s = ((px - a[0]) * dx + (py - a[1]) * dy + (pz - a[2]) * dz) / L2
        s = min(1.0, max(0.0, s))
    ex, ey, ez = px - a[0] - s * dx, py - a[1] - s * dy, pz - a[2] - s * dz
    return ex * ex + ey * ey + ez * ez


@nb.njit(cache=True, nogil=True)
def rasterize(a, b, r, sel, origin, res, grid):
    """Set time 0 in every cell whose centre is within r + √3/2 res of a selected capsule; returns #outside."""
    nx, ny, nz = grid.shape
    out = 0
    h = H * res
    for c in range(a.shape[0]):
        if not sel[c]:
            continue
        rr = r[c] + h
        lo = np.empty(3, np.int64)
        hi = np.empty(3, np.int64)
        for d in range(3):
            lo[d] = int(math.floor((min(a[c, d], b[c, d]) - rr - origin[d]) / res))
            hi[d] = int(math.floor((max(a[c, d], b[c, d]) + rr - origin[d]) / res))
        if lo[0] < 0 or lo[1] < 0 or lo[2] < 0 or hi[0] >= nx or hi[1] >= ny or hi[2] >= nz:
            out += 1
        for i in range(max(lo[0], 0), min(hi[0], nx - 1) + 1):
            px = origin[0] + (i + 0.5) * res
            for j in range(max(lo[1], 0), min(hi[1], ny - 1) + 1):
                py = origin[1] + (j + 0.5) * res
                for k in range(max(lo[2], 0), min(hi[2], nz - 1) + 1):
                    pz = origin[2] + (k + 0.5) * res
                    if seg_dist2(px, py, pz, a[c], b[c]) <= rr * rr:
                        grid[i, j, k] = 0.0
    return out


@nb.njit(cache=True, nogil=True)
def collect(grid):
    """Flat indices and times of the finite cells; resets them to inf."""
    flat = grid.ravel()
    n = 0
    for f in range(flat.size):
        if flat[f] < np.inf:
            n += 1
    idx = np.empty(n, np.int64)
    tt = np.empty(n, np.float32)
    n = 0
    for f in range(flat.size):
        if flat[f] < np.inf:
            idx[n] = f
            tt[n] = flat[f]
            flat[f] = np.inf
            n += 1
    return idx, tt


@nb.njit(cache=True, nogil=True, fastmath=False)
def sweep(idx, tt, in_origin, in_res, in_shape, origin, res, grid, kind, axis, point, lo, hi, vmax, eps):
    """Sweep the kept samples (cell centres of the input grid) about (along) one joint into ``grid`` (min time).

    Samples are taken at offsets ``θ_k = k h`` from 0 outwards, ``h = 2 eps / r⊥`` rad for a sample at
    distance ``r⊥`` from a revolute axis (``2 eps`` m along a prismatic one), plus one at the end of the
    range; each sample after 0 gets the time of the midpoint between it and the sample before it,
    ``max(t, (θ_{k-1} + θ_k) / 2 / v)``. An offset ``θ`` in ``[θ_{k-1}, θ_k]`` is then within ``eps`` (half
    an arc of ``h``) of the sample on its side of the midpoint, which is no later than ``max(t, θ / v)``.
    This takes half the samples of a step of ``eps`` for the same error. A sample whose whole range moves it
    by at most ``eps`` stays where it is (its error is that motion; it has not "moved").
    Rotations are isometries, so the error that a sample already carries is kept, not grown. The angles
    advance by a rotation recurrence (one multiply per step instead of a cosine and a sine; its drift, below
    1e-12 m for the few hundred steps of a sweep, is covered by the caller's slack).

    Returns (#samples outside the grid, the largest sampling error, whether any sample left its cell centre).
    """
    nx, ny, nz = grid.shape
    iny, inz = in_shape[1], in_shape[2]
    inv = 1.0 / res
    out = 0
    err = 0.0
    moved = False
    rng = max(hi, -lo)
    c_hi, s_hi, c_lo, s_lo = math.cos(hi), math.sin(hi), math.cos(lo), math.sin(lo)  # the ranges' ends
    for m in range(idx.size):
        f = idx[m]
        i0 = f // (iny * inz)
        j0 = (f // inz) % iny
        k0 = f % inz
        cx = in_origin[0] + (i0 + 0.5) * in_res
        cy = in_origin[1] + (j0 + 0.5) * in_res
        cz = in_origin[2] + (k0 + 0.5) * in_res
        t0 = tt[m]
        if kind == 0:
            vx, vy, vz = cx - point[0], cy - point[1], cz - point[2]
            al = vx * axis[0] + vy * axis[1] + vz * axis[2]
            ox, oy, oz = point[0] + al * axis[0], point[1] + al * axis[1], point[2] + al * axis[2]
            px, py, pz = vx - al * axis[0], vy - al * axis[1], vz - al * axis[2]
            # axis x perp
            qx = axis[1] * pz - axis[2] * py
            qy = axis[2] * px - axis[0] * pz
            qz = axis[0] * py - axis[1] * px
            rp = math.sqrt(px * px + py * py + pz * pz)
        else:
            ox, oy, oz = cx, cy, cz
            px = py = pz = qx = qy = qz = 0.0
            rp = 1.0
        step = 0.0
        if rp * rng <= eps:  # the whole range moves the sample by at most eps: it stays
            err = max(err, rp * rng)
        else:
            err = max(err, eps)
            step = 2.0 * eps / rp
        cs = math.cos(step)
        for side in range(2):
            sgn = 1.0 if side == 0 else -1.0
            bound = (hi if side == 0 else -lo) if step > 0.0 else 0.0
            if side == 1 and bound <= 0.0:
                continue
            # side 0 starts with the sample itself (k = 0); k = 1..nk on the lattice; k = nk + 1 the range's end
            nk = int(bound / step) if bound > 0.0 else -1
            ss = sgn * math.sin(step)
            c, s = (1.0, 0.0) if side == 0 else (cs, ss)
            for kk in range(side, nk + 2):
                if kk == 0:
                    t = t0
                elif kk <= nk:
                    t = max(t0, (kk - 0.5) * step / vmax)
                else:  # the end, with the time of its midpoint with the last lattice sample
                    t = max(t0, 0.5 * (nk * step + bound) / vmax)
                    c, s = (c_hi, s_hi) if side == 0 else (c_lo, s_lo)
                    moved = True
                if kind == 0:
                    x, y, z = ox + c * px + s * qx, oy + c * py + s * qy, oz + c * pz + s * qz
                    c, s = c * cs - s * ss, s * cs + c * ss
                else:
                    th = 0.0 if kk == 0 else (sgn * kk * step if kk <= nk else sgn * bound)
                    x, y, z = ox + th * axis[0], oy + th * axis[1], oz + th * axis[2]
                fx = (x - origin[0]) * inv
                fy = (y - origin[1]) * inv
                fz = (z - origin[2]) * inv
                if not (fx >= 0.0 and fy >= 0.0 and fz >= 0.0 and fx < nx and fy < ny and fz < nz):
                    out += 1
                    continue
                i, j, k = int(fx), int(fy), int(fz)
                if t < grid[i, j, k]:
                    grid[i, j, k] = t
    return out, err, moved


@nb.njit(cache=True, nogil=True, fastmath={"nnan"})  # times are never NaN: lets min/max vectorise
def _slide_mid(x, lo_i, hi_i, m_lo, m_hi, dt):
    """:func:`slide` along axis 1 of a (P, n, Q) view whose finite cells lie in rows ``lo_i:hi_i``, in place."""
    P, n, Q = x.shape
    out = 0
    for p in range(P):
        for i in range(lo_i, hi_i):
            if i - m_lo < 0 or i + m_hi >= n:
                for q in range(Q):
                    if x[p, i, q] < np.inf:
                        out += 1
    src = np.ascontiguousarray(x[:, lo_i:hi_i, :])
    a, b = max(lo_i - m_lo, 0), min(hi_i + m_hi, n)
    dst = np.full((P, b - a, Q), np.inf, np.float32)
    for p in range(P):
        for i in range(a, b):
            row = dst[p, i - a]
            for s in range(-m_lo, m_hi + 1):
                i_src = i - s
                if i_src < lo_i or i_src >= hi_i:
                    continue
                c = np.float32(max(abs(s) - 1, 0) * dt)
                srow = src[p, i_src - lo_i]
                for q in range(Q):
                    row[q] = min(row[q], max(srow[q], c))
    x[:, a:b, :] = dst
    return out


def slide(grid: np.ndarray, d: int, lo: float, hi: float, vmax: float, res: float) -> int:
    """Sweep every finite cell of ``grid`` (C-contiguous float32 times) along grid axis ``d`` by every offset
    in ``[lo, hi]`` (m, ``lo <= 0 <= hi``), in place (min time), exactly for the cells' cubes: a point of a
    cell's cube moved by ``s`` lies in the closed cube of the cell ``m`` steps away for some
    ``|m| <= floor(|s| / res) + 1`` (in the direction of ``s``), and ``|s| >= (|m| - 1) res``, so that cell
    gets the time ``max(t, (|m| - 1)+ res / vmax)``. No position error is added (a prismatic joint along a
    lattice axis, such as an omnidirectional base's x and y). Returns the number of finite cells that would
    slide out of ``grid`` (0 when it holds everything)."""
    m_hi = int(math.floor(hi / res)) + 1 if hi > 0.0 else 0
    m_lo = int(math.floor(-lo / res)) + 1 if lo < 0.0 else 0
    b_lo, b_hi = finite_bounds(grid)
    if b_hi[0] == 0 or m_lo + m_hi == 0:
        return 0
    crop = [slice(int(a), int(b)) for a, b in zip(b_lo, b_hi, strict=True)]
    crop[d] = slice(None)
    view = grid[tuple(crop)]
    order = {0: (1, 0, 2), 1: (0, 1, 2), 2: (0, 2, 1)}[d]
    return int(_slide_mid(view.transpose(order), int(b_lo[d]), int(b_hi[d]), m_lo, m_hi, res / vmax))


@nb.njit(cache=True, nogil=True, parallel=True)
def sweep_two(idx, tt, in_origin, in_res, in_shape, origin, res, grid, kind, axis, point, lo, hi, vmax, eps):
    """:func:`sweep` on two threads: each half of the samples into its own grid, then the minimum."""
    half = idx.size // 2
    spare = np.full(grid.shape, np.inf, dtype=grid.dtype)
    outs = np.zeros(2, np.int64)
    errs = np.zeros(2)
    moves = np.zeros(2, np.bool_)
    for part in nb.prange(2):
        a, b = (0, half) if part == 0 else (half, idx.size)
        target = grid if part == 0 else spare
        o, e, m = sweep(
            idx[a:b], tt[a:b], in_origin, in_res, in_shape, origin, res, target, kind, axis, point, lo, hi, vmax, eps
        )
        outs[part], errs[part], moves[part] = o, e, m
    flat, other = grid.ravel(), spare.ravel()
    for f in range(flat.size):
        if other[f] < flat[f]:
            flat[f] = other[f]
    return outs[0] + outs[1], max(errs[0], errs[1]), moves[0] or moves[1]


@nb.njit(cache=True, nogil=True)
def min_filter_mid(x, k, out):
    """``out[a, i, b] = min x[a, i-k..i+k, b]`` (clipped to the array) for (A, n, B) arrays of any layout.

    Per slab ``a`` a padded (n + 2k, B) copy is doubled in place (the minimum over 2^p rows from two of
    2^(p-1)), then two overlapping windows of the largest power of two P <= 2k + 1 give the 2k + 1 rows;
    the inner loops run along B, so they vectorise."""
    A, n, B = x.shape
    w = 2 * k + 1
    p = 1
    while 2 * p <= w:
        p *= 2
    buf = np.empty((n + 2 * k, B), x.dtype)
    for a in range(A):
        buf[:] = np.inf
        for i in range(n):
            for b in range(B):
                buf[k + i, b] = x[a, i, b]
        span = 1
        while span < p:
            for t in range(n + 2 * k - span):
                row, ahead = buf[t], buf[t + span]
                for b in range(B):
                    row[b] = min(row[b], ahead[b])
            span *= 2
        for i in range(n):
            for b in range(B):
                out[a, i, b] = min(buf[i, b], buf[i + w - p, b])


def threads_ok() -> bool:
    """Whether a parallel kernel may run here: numba's ``workqueue`` threading layer must not be entered
    from two threads at once, so off the main thread only the thread-safe layers (tbb, omp) are used."""
    if threading.current_thread() is threading.main_thread():
        return True
    try:
        return nb.threading_layer() in ("tbb", "omp")
    except ValueError:  # no parallel kernel has run yet: the layer is not chosen
        return False


@nb.njit(cache=True, nogil=True)
def finite_bounds(grid):
    """(3,) first and (3,) one-past-last index of the finite cells of a 3-D grid along each axis (lo = hi =
    0 when there are none)."""
    nx, ny, nz = grid.shape
    lo = np.array([nx, ny, nz], np.int64)
    hi = np.zeros(3, np.int64)
    for i in range(nx):
        for j in range(ny):
            row = grid[i, j]
            first = 0  # the first finite cell from the front, then the last from the back
            while first < nz and not row[first] < np.inf:
                first += 1
            if first == nz:
                continue
            last = nz - 1
            while not row[last] < np.inf:
                last -= 1
            lo[0] = min(lo[0], i)
            hi[0] = max(hi[0], i + 1)
            lo[1] = min(lo[1], j)
            hi[1] = max(hi[1], j + 1)
            lo[2] = min(lo[2], first)
            hi[2] = max(hi[2], last + 1)
    if hi[0] == 0:
        lo[:] = 0
    return lo, hi


def dilate(grid: np.ndarray, k: int) -> np.ndarray:
    """``grid`` min-filtered with a (2k+1)^3 box (``scipy.ndimage.minimum_filter`` with an inf border):
    one running minimum per axis (:func:`min_filter_mid`), the vector axis the contiguous one where it can
    be, over the finite cells' bounding box grown by ``k`` (every other cell stays inf)."""
    grid = np.ascontiguousarray(grid)
    if k == 0:
        return grid.copy()
    lo, hi = finite_bounds(grid)
    region = tuple(slice(max(int(a) - k, 0), min(int(b) + k, n)) for a, b, n in zip(lo, hi, grid.shape, strict=True))
    result = np.full(grid.shape, np.inf, dtype=grid.dtype)
    if hi[0] > 0:
        result[region] = _dilate_dense(np.ascontiguousarray(grid[region]), k)
    return result


def _dilate_dense(out: np.ndarray, k: int) -> np.ndarray:
    nx, ny, nz = out.shape
    along_x, along_y = np.empty_like(out), np.empty_like(out)
    min_filter_mid(out.reshape(1, nx, ny * nz), k, along_x.reshape(1, nx, ny * nz))
    min_filter_mid(along_x, k, along_y)
    min_filter_mid(along_y.transpose(0, 2, 1), k, along_x.transpose(0, 2, 1))
    return along_x


@nb.njit(cache=True, nogil=True)
def swept_bounds(idx, in_origin, in_res, in_shape, kind, axis, point, rng, pad):
    """A box (lo, hi) holding the cell centres ``idx`` of the input grid swept by a joint over offsets up
    to ``rng`` (plus ``pad``): the centres' box grown by their largest displacement (a chord: at most
    ``r⊥ min(rng, 2)`` for a rotation, ``rng`` for a translation), a rotation's cut to the ball about the
    joint point that it keeps them in. Also returns the centres' largest distance from a revolute axis."""
    iny, inz = in_shape[1], in_shape[2]
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    perp2 = 0.0
    dist2 = 0.0
    c = np.empty(3)
    for m in range(idx.size):
        f = idx[m]
        c[0] = in_origin[0] + (f // (iny * inz) + 0.5) * in_res
        c[1] = in_origin[1] + ((f // inz) % iny + 0.5) * in_res
        c[2] = in_origin[2] + (f % inz + 0.5) * in_res
        for d in range(3):
            lo[d] = min(lo[d], c[d])
            hi[d] = max(hi[d], c[d])
        vx, vy, vz = c[0] - point[0], c[1] - point[1], c[2] - point[2]
        al = vx * axis[0] + vy * axis[1] + vz * axis[2]
        d2 = vx * vx + vy * vy + vz * vz
        dist2 = max(dist2, d2)
        perp2 = max(perp2, d2 - al * al)
    move = rng + pad if kind == PRISMATIC else math.sqrt(max(perp2, 0.0)) * min(rng, 2.0) + pad
    rad = math.sqrt(dist2) + pad
    for d in range(3):
        lo[d] -= move + pad
        hi[d] += move + pad
        if kind != PRISMATIC:
            lo[d] = max(lo[d], point[d] - rad)
            hi[d] = min(hi[d], point[d] + rad)
    return lo, hi, math.sqrt(max(perp2, 0.0))
