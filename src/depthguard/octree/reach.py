"""Reachability grid: the robot's close range (SAPHARI D4.1.1 §3.2, Fig. 1; Anderson-Sprecher & Simmons).

For the current state ``q`` of a serial chain with joint limits and maximum joint velocities (accelerations
ignored, which only enlarges the set), every cell gets the minimum time at which some part of the robot
can be in it, and ``C(t)`` is the set of cells reachable within the horizon ``T``.

Method (the joint-by-joint sweep of SAPHARI ref. [1], made provably conservative):

* Product of exponentials about the *current* world-frame joint axes: a configuration ``q + δ`` places a
  point ``x`` of link ``i`` at ``M_1(δ_1) ∘ ... ∘ M_i(δ_i) (x)``, ``M_j`` the rotation (or translation) about
  joint ``j``'s axis at ``q``. So the links are swept from the tip towards the base: the set of link ``n``
  is swept by joint ``n``, link ``n-1`` is added, both are swept by joint ``n-1``, and so on.
* Joints move at the same time, so reaching offsets ``δ`` takes ``max_j |δ_j| / v_j``: a swept sample gets
  ``t' = max(t, |δ_j| / v_j)``. The offset range of joint ``j`` is ``[-v_j T, v_j T] ∩ [q_min - q, q_max - q]``.
* The set is carried as cell centres on an internal grid (one sample per cell, the minimum time), so its
  size stays bounded (the "collapse" of [1]). The internal grid adapts to the set: ``cells`` cells along its
  longest side, between ``res / 8`` and ``res``, so the small distal sets collapse finely. Each step has a
  bounded position error: ``h = √3/2 res_i`` per collapse and ``eps = res_i / 2`` per sweep (samples every
  ``eps / r⊥`` rad, the sample on the side of zero, so that its time is never later; a rotation is an
  isometry, so the error a sample already carries is kept, not grown).
  Every true point lies within ``δ = Σ errors`` of a
  kept sample whose time is no later, so the final grid, min-pooled to ``res`` and dilated by
  ``ceil(δ / res)`` cells (L∞ box), is an **over-approximation** in space and an under-estimate in time.
  ``tests/test_octree_reach.py`` checks this against random joint trajectories with ``|q̇| ≤ q̇_max``.

An omnidirectional base is the same chain with two prismatic joints (x, y) and one revolute joint (yaw) in
front of the arm (SAPHARI §3.2); see :mod:`depthguard.robot.reach` for building the inputs from a URDF.
"""

from __future__ import annotations

import math
import threading
from typing import NamedTuple

import numba as nb
import numpy as np

from depthguard.octree.grid import VoxelBox, check_res
from depthguard.validation import check_finite_array, check_positive

__all__ = ["ChainSweep", "ReachabilityGrid", "reachability_grid"]

REVOLUTE = 0
PRISMATIC = 1
_H = math.sqrt(3.0) / 2.0
_PARALLEL_FROM = 400  # kept cells from which a sweep runs on two threads
_ROUNDING = 1e-9  # m per sweep: the rotation recurrence's drift and float rounding, far above both


class ChainSweep(NamedTuple):
    """A serial chain at its current state, in the world frame (n joints, L capsules).

    Attributes:
        kind: (n,) int, 0 revolute, 1 prismatic, base first.
        axis: (n, 3) unit joint axes (positive direction of the coordinate).
        point: (n, 3) a point on each revolute axis (ignored for prismatic joints), metres.
        lo, hi: (n,) offset range of each joint from its current value (rad or m), ``lo <= 0 <= hi``;
            :func:`reachability_grid` intersects it with ``[-v T, v T]``.
        vmax: (n,) maximum joint speeds (rad/s or m/s), > 0.
        cap_a, cap_b: (L, 3) capsule segment ends at the current state, metres.
        cap_r: (L,) capsule radii, metres.
        cap_joint: (L,) int, the joint that carries each capsule (1..n), 0 for the fixed base.
    """

    kind: np.ndarray
    axis: np.ndarray
    point: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    vmax: np.ndarray
    cap_a: np.ndarray
    cap_b: np.ndarray
    cap_r: np.ndarray
    cap_joint: np.ndarray

    def check(self) -> ChainSweep:
        """Validated copy (shapes, finite values, unit axes, lo <= 0 <= hi, vmax > 0) or ``ValueError``."""
        kind = np.asarray(self.kind, dtype=np.int64)
        n = kind.shape[0]
        if kind.ndim != 1 or np.any((kind != REVOLUTE) & (kind != PRISMATIC)):
            raise ValueError("chain kind must be an (n,) array of 0 (revolute) or 1 (prismatic)")
        axis = check_finite_array(self.axis, (n, 3), "chain axis")
        if np.any(np.abs(np.linalg.norm(axis, axis=1) - 1.0) > 1e-6):
            raise ValueError("chain axis rows must be unit vectors")
        point = check_finite_array(self.point, (n, 3), "chain point")
        lo = check_finite_array(self.lo, (n,), "chain lo")
        hi = check_finite_array(self.hi, (n,), "chain hi")
        if np.any(lo > 1e-12) or np.any(hi < -1e-12):
            raise ValueError("chain offset ranges must contain 0 (lo <= 0 <= hi): the state is outside its limits")
        vmax = check_finite_array(self.vmax, (n,), "chain vmax")
        if np.any(vmax <= 0):
            raise ValueError("chain vmax must be > 0")
        a = check_finite_array(self.cap_a, (-1, 3), "chain cap_a")
        L = a.shape[0]
        b = check_finite_array(self.cap_b, (L, 3), "chain cap_b")
        r = check_finite_array(self.cap_r, (L,), "chain cap_r")
        if np.any(r < 0):
            raise ValueError("chain cap_r must be >= 0")
        cj = np.asarray(self.cap_joint, dtype=np.int64)
        if cj.shape != (L,) or np.any((cj < 0) | (cj > n)):
            raise ValueError(f"chain cap_joint must be an (L,) array of joint numbers 0..{n}")
        return ChainSweep(kind, axis, point, np.minimum(lo, 0.0), np.maximum(hi, 0.0), vmax, a, b, r, cj)


class ReachabilityGrid(NamedTuple):
    """Minimum time to reach each cell (SAPHARI Fig. 1) and the reachable set C(t).

    Attributes:
        box: the cells.
        time: (nx, ny, nz) float32 lower bound of the time (s) at which some robot point can be in the cell;
            ``inf`` when no point can within the horizon.
        horizon: the time horizon T, s.
        delta: the position error bound of the sweep that the dilation covers, metres.
    """

    box: VoxelBox
    time: np.ndarray
    horizon: float
    delta: float

    @property
    def reachable(self) -> np.ndarray:
        """(nx, ny, nz) bool, the set C(t)."""
        return self.time <= self.horizon

    def lookup(self, points: np.ndarray) -> np.ndarray:
        """(M,) time of the cells holding (M, 3) points; ``inf`` outside the box."""
        idx = self.box.index(points)
        ok = self.box.inside(idx)
        out = np.full(len(idx), np.inf)
        out[ok] = self.time[idx[ok, 0], idx[ok, 1], idx[ok, 2]]
        return out


# ------------------------------------------------------------------------------------------------ kernels
@nb.njit(cache=True, nogil=True)
def _seg_dist2(px, py, pz, a, b):
    dx, dy, dz = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    L2 = dx * dx + dy * dy + dz * dz
    s = 0.0
    if L2 > 0:
        s = ((px - a[0]) * dx + (py - a[1]) * dy + (pz - a[2]) * dz) / L2
        s = min(1.0, max(0.0, s))
    ex, ey, ez = px - a[0] - s * dx, py - a[1] - s * dy, pz - a[2] - s * dz
    return ex * ex + ey * ey + ez * ez


@nb.njit(cache=True, nogil=True)
def _rasterize(a, b, r, sel, origin, res, grid):
    """Set time 0 in every cell whose centre is within r + √3/2 res of a selected capsule; returns #outside."""
    nx, ny, nz = grid.shape
    out = 0
    h = _H * res
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
                    if _seg_dist2(px, py, pz, a[c], b[c]) <= rr * rr:
                        grid[i, j, k] = 0.0
    return out


@nb.njit(cache=True, nogil=True)
def _collect(grid):
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
def _sweep(idx, tt, in_origin, in_res, in_shape, origin, res, grid, kind, axis, point, lo, hi, vmax, eps):
    """Sweep the kept samples (cell centres of the input grid) about (along) one joint into ``grid`` (min time).

    A sample at distance ``r⊥`` from a revolute axis is taken every ``eps / r⊥`` rad (every ``eps`` m along a
    prismatic one), from 0 outwards, so a rotation by any angle in the range lies within ``eps`` of a taken
    sample that is no later. Rotations are isometries, so the error that a sample already carries is kept,
    not grown. The angles advance by a rotation recurrence (one multiply per step instead of a cosine and a
    sine; its drift, below 1e-12 m for the few hundred steps of a sweep, is covered by the caller's slack).

    Returns (#samples outside the grid, the largest sampling error, whether any sample left its cell centre).
    """
    nx, ny, nz = grid.shape
    iny, inz = in_shape[1], in_shape[2]
    inv = 1.0 / res
    out = 0
    err = 0.0
    moved = False
    rng = max(hi, -lo)
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
            step = eps / rp if rp * rng > 0.0 else 0.0
            err = max(err, min(eps, rp * rng))
        else:
            ox, oy, oz = cx, cy, cz
            px = py = pz = qx = qy = qz = 0.0
            step = eps
            err = max(err, min(eps, rng))
        cs = math.cos(step)
        for sgn in (1.0, -1.0):
            bound = hi if sgn > 0 else -lo
            nk = int(bound / step) if step > 0.0 else 0
            if nk >= 1:
                moved = True
            kstart = 0 if sgn > 0 else 1
            ss = sgn * math.sin(step)
            c, s = (1.0, 0.0) if kstart == 0 else (cs, ss)
            for kk in range(kstart, nk + 1):
                th = kk * step
                t = max(t0, th / vmax)
                if kind == 0:
                    x = ox + c * px + s * qx
                    y = oy + c * py + s * qy
                    z = oz + c * pz + s * qz
                    c, s = c * cs - s * ss, s * cs + c * ss
                else:
                    x = ox + sgn * th * axis[0]
                    y = oy + sgn * th * axis[1]
                    z = oz + sgn * th * axis[2]
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


@nb.njit(cache=True, nogil=True, parallel=True)
def _sweep_two(idx, tt, in_origin, in_res, in_shape, origin, res, grid, kind, axis, point, lo, hi, vmax, eps):
    """:func:`_sweep` on two threads: each half of the samples into its own grid, then the minimum."""
    half = idx.size // 2
    spare = np.full(grid.shape, np.inf, dtype=grid.dtype)
    outs = np.zeros(2, np.int64)
    errs = np.zeros(2)
    moves = np.zeros(2, np.bool_)
    for part in nb.prange(2):
        a, b = (0, half) if part == 0 else (half, idx.size)
        target = grid if part == 0 else spare
        o, e, m = _sweep(
            idx[a:b], tt[a:b], in_origin, in_res, in_shape, origin, res, target, kind, axis, point, lo, hi, vmax, eps
        )
        outs[part], errs[part], moves[part] = o, e, m
    flat, other = grid.ravel(), spare.ravel()
    for f in range(flat.size):
        if other[f] < flat[f]:
            flat[f] = other[f]
    return outs[0] + outs[1], max(errs[0], errs[1]), moves[0] or moves[1]


@nb.njit(cache=True, nogil=True)
def _min_filter_mid(x, k, out):
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


def _threads_ok() -> bool:
    """Whether a parallel kernel may run here: numba's ``workqueue`` threading layer must not be entered
    from two threads at once, so off the main thread only the thread-safe layers (tbb, omp) are used."""
    if threading.current_thread() is threading.main_thread():
        return True
    try:
        return nb.threading_layer() in ("tbb", "omp")
    except ValueError:  # no parallel kernel has run yet: the layer is not chosen
        return False


def _dilate(grid: np.ndarray, k: int) -> np.ndarray:
    """``grid`` min-filtered with a (2k+1)^3 box (``scipy.ndimage.minimum_filter`` with an inf border):
    one running minimum per axis (:func:`_min_filter_mid`), the vector axis the contiguous one where it can
    be."""
    out = np.ascontiguousarray(grid)
    if k == 0:
        return out.copy()
    nx, ny, nz = out.shape
    along_x, along_y = np.empty_like(out), np.empty_like(out)
    _min_filter_mid(out.reshape(1, nx, ny * nz), k, along_x.reshape(1, nx, ny * nz))
    _min_filter_mid(along_x, k, along_y)
    _min_filter_mid(along_y.transpose(0, 2, 1), k, along_x.transpose(0, 2, 1))
    return along_x


# ----------------------------------------------------------------------------------------------- public
def chain_box(chain: ChainSweep, horizon: float, res: float, margin: float = 0.0, scale: float = 1.0) -> VoxelBox:
    """A box likely to hold every point the chain can reach within ``horizon`` (plus ``margin``).

    A guess, not a bound: twice the circumradius of the robot and its joint points, times ``scale``, plus
    the prismatic travel; :func:`reachability_grid` checks that nothing falls outside and retries with a
    larger box. (With ``scale`` >= the number of revolute joints it is a bound: each rotation about a point
    of the box moves a point by at most twice the circumradius further from its centre.)
    """
    # the geometry and the revolute joints' axis points: a rotation about a point inside this box keeps what
    # it moves within the box's circumradius of that point
    lo = np.vstack([np.minimum(chain.cap_a, chain.cap_b) - chain.cap_r[:, None], chain.point[chain.kind == REVOLUTE]])
    hi = np.vstack([np.maximum(chain.cap_a, chain.cap_b) + chain.cap_r[:, None], chain.point[chain.kind == REVOLUTE]])
    travel = float(
        np.sum(
            np.where(chain.kind == PRISMATIC, np.minimum(np.maximum(-chain.lo, chain.hi), chain.vmax * horizon), 0.0)
        )
    )
    centre = 0.5 * (lo.min(axis=0) + hi.max(axis=0))
    rad = 0.5 * float(np.linalg.norm(hi.max(axis=0) - lo.min(axis=0)))
    pad = scale * (2.0 * rad) + travel + margin
    return VoxelBox.around(centre - pad, centre + pad, res)


def reachability_grid(
    chain: ChainSweep,
    horizon: float = 0.5,
    res: float = 0.09,
    box: VoxelBox | None = None,
    cells: int = 24,
) -> ReachabilityGrid:
    """Minimum-time reachability grid of a serial chain (SAPHARI §3.2, Fig. 1).

    Args:
        chain: the chain at its current state (:class:`ChainSweep`; see :mod:`depthguard.robot.reach`).
        horizon: time horizon T, s (> 0).
        res: output cell size, metres (0.02-0.1).
        box: output cells (default: :func:`chain_box`); its ``res`` overrides ``res``.
        cells: the internal grids' size along the swept set's longest side (>= 8); more is tighter and slower.
    Returns:
        :class:`ReachabilityGrid` over ``box``.
    Raises:
        ValueError: bad input, or a reachable point outside ``box`` (the set must not be cut).
    """
    ch = chain.check()
    horizon = check_positive(horizon, "horizon")
    if isinstance(cells, bool) or int(cells) != cells or cells < 8:
        raise ValueError(f"cells must be an integer >= 8, got {cells!r}")
    if box is not None:
        return _reach(ch, horizon, box, int(cells), strict=True)
    res = check_res(res)
    for scale in (1.0, 2.0, 4.0):
        out = _reach(ch, horizon, chain_box(ch, horizon, res, margin=2 * res, scale=scale), int(cells), False)
        if out is not None:
            return out
    raise ValueError("reachability: the reachable set does not fit in a box 4x the robot's size")


def _grid_for(lo: np.ndarray, hi: np.ndarray, cells: int, res_floor: float, res_cap: float):
    """A dense internal grid (origin, res, float32 array of inf) over [lo, hi]: ``cells`` cells along its
    longest side, cells between ``res_floor`` and ``res_cap``, two cells of padding."""
    res = min(max(res_floor, float(np.max(hi - lo)) / cells), res_cap)
    origin = np.floor(lo / res) * res - 2 * res
    shape = tuple(int(x) for x in np.ceil((hi - origin) / res) + 3)
    return np.ascontiguousarray(origin), res, np.full(shape, np.inf, dtype=np.float32)


def _caps_bbox(ch: ChainSweep, sel: np.ndarray, pad: float):
    if not sel.any():
        return None
    lo = (np.minimum(ch.cap_a[sel], ch.cap_b[sel]) - ch.cap_r[sel, None]).min(axis=0) - pad
    hi = (np.maximum(ch.cap_a[sel], ch.cap_b[sel]) + ch.cap_r[sel, None]).max(axis=0) + pad
    return lo, hi


def _union(a, b):
    if a is None:
        return b
    if b is None:
        return a
    return np.minimum(a[0], b[0]), np.maximum(a[1], b[1])


@nb.njit(cache=True, nogil=True)
def _swept_bounds(idx, in_origin, in_res, in_shape, kind, axis, point, rng, pad):
    """A box (lo, hi) holding the cell centres ``idx`` of the input grid swept by a joint over offsets up
    to ``rng`` (plus ``pad``): the centres' box grown by their largest displacement (a chord: at most
    ``r⊥ min(rng, 2)`` for a rotation, ``rng`` for a translation), a rotation's cut to the ball about the
    joint point that it keeps them in."""
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
    return lo, hi


def _reach(ch: ChainSweep, horizon: float, box: VoxelBox, cells: int, strict: bool) -> ReachabilityGrid | None:
    """The sweep with adaptive internal grids: ``cells`` cells along the set's longest side, between
    ``res / 8`` and ``res``, so the small distal sets collapse finely (small error) and the large proximal ones
    coarsely (bounded size)."""
    res_out = float(box.res)
    res_floor = res_out / 8.0
    n = len(ch.kind)
    lo = np.maximum(ch.lo, -ch.vmax * horizon)
    hi = np.minimum(ch.hi, ch.vmax * horizon)
    out = np.full(box.shape, np.inf, dtype=np.float32)
    box_origin = np.ascontiguousarray(box.origin, dtype=float)
    outside = 0
    bb = _caps_bbox(ch, ch.cap_joint == n, 0.0)
    if bb is None:  # no geometry on the last link: start from an empty set at the last joint
        bb = (ch.point[n - 1] - res_out, ch.point[n - 1] + res_out)
    g_origin, g_res, grid = _grid_for(bb[0], bb[1], cells, res_floor, res_out)
    outside += _rasterize(ch.cap_a, ch.cap_b, ch.cap_r, ch.cap_joint == n, g_origin, g_res, grid)
    delta = _H * g_res
    for j in range(n, 0, -1):
        idx, tt = _collect(grid)
        jj = j - 1
        in_spec = (g_origin, g_res, np.array(grid.shape, np.int64))
        if j > 1:
            swept = (
                _swept_bounds(idx, *in_spec, int(ch.kind[jj]), ch.axis[jj], ch.point[jj], max(-lo[jj], hi[jj]), 1e-6)
                if idx.size
                else None
            )
            bb_next = _union(swept, _caps_bbox(ch, ch.cap_joint == j - 1, 0.0))
            g_origin, g_res, grid = _grid_for(bb_next[0], bb_next[1], cells, res_floor, res_out)
            target, t_origin, t_res, eps = grid, g_origin, g_res, 0.5 * g_res
        else:
            target, t_origin, t_res, eps = out, box_origin, res_out, 0.5 * res_out
        n_out, err, moved = (_sweep_two if idx.size >= _PARALLEL_FROM and _threads_ok() else _sweep)(
            idx, tt, *in_spec, t_origin, t_res, target, int(ch.kind[jj]), np.ascontiguousarray(ch.axis[jj]),
            np.ascontiguousarray(ch.point[jj]), float(lo[jj]), float(hi[jj]), float(ch.vmax[jj]), eps,
        )  # fmt: skip
        outside += n_out
        # the sampling error, plus the collapse of moved samples to cell centres (the last sweep writes into
        # the output cells, whose containment the final dilation covers)
        delta += err + _ROUNDING + (_H * g_res if moved and j > 1 else 0.0)
        if j > 1:
            outside += _rasterize(ch.cap_a, ch.cap_b, ch.cap_r, ch.cap_joint == j - 1, g_origin, g_res, grid)
            delta = max(delta, _H * g_res)
    if outside:
        if not strict:
            return None
        raise ValueError(f"reachability box {box} is too small: {outside} reachable samples fall outside it")
    k = math.ceil(delta / res_out - 1e-9)
    dil = _dilate(out, k)
    # the fixed base: cells that meet its capsules, time 0 (exact, no dilation needed)
    _rasterize(ch.cap_a, ch.cap_b, ch.cap_r, ch.cap_joint == 0, box_origin, res_out, dil)
    return ReachabilityGrid(box, dil, float(horizon), float(delta))
