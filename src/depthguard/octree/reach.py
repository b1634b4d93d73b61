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
* The set is carried as cells on an internal grid (one time per cell, the minimum), so its size stays
  bounded (the "collapse" of [1]). The internal grid adapts to the set: ``cells`` cells along its longest
  side, between ``res / 8`` and ``res``, so the small distal sets collapse finely.
* Error bound ``δ``, the invariant: every true point at time ``t`` lies within ``δ`` of the closed cube of a
  kept cell whose time is ``<= t``. Rasterising a capsule adds nothing (its points lie in the cubes of the
  cells it marks). A sampled sweep moves each cell's centre, every ``2 eps / r⊥`` rad (every ``2 eps`` m
  along a prismatic axis; ``eps`` half the target cell; each sample timed at the midpoint before it, so the
  nearer sample on the side of zero is never later; see :func:`~depthguard.octree.reach_kernels.sweep`),
  and adds half the input cell's diagonal (the cube about its centre; a rotation is an isometry, so
  the error a point already carries is kept, not grown) plus the sampling error. A joint too slow to move
  any sample keeps the lattice and adds only its motion.
* The base's prismatic joints along a lattice axis (an omnidirectional base's x and y) *slide* the output
  cells instead: a cube moved by ``s`` lies in the cells up to ``floor(|s| / res) + 1`` away, reached no
  earlier than ``(m - 1) res / v``, exactly, so they add no error.
* The final grid is dilated by ``ceil(δ / res)`` cells (an L∞ box), which makes it an **over-approximation**
  in space and an under-estimate in time. ``tests/test_octree_reach.py`` checks this against random joint
  trajectories with ``|q̇| <= q̇_max`` and, on small chains, the invariant itself.

An omnidirectional base is the same chain with two prismatic joints (x, y) and one revolute joint (yaw) in
front of the arm (SAPHARI §3.2); see :mod:`depthguard.robot.reach` for building the inputs from a URDF.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from depthguard.octree.grid import VoxelBox, check_res
from depthguard.octree.reach_kernels import (
    PRISMATIC,
    REVOLUTE,
    H,
    collect,
    dilate,
    rasterize,
    slide,
    sweep,
    sweep_two,
    swept_bounds,
    threads_ok,
)
from depthguard.validation import check_finite_array, check_positive

__all__ = ["ChainSweep", "ReachabilityGrid", "reachability_grid"]

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
        """Validated copy (shapes, finite values, unit axes, lo <= 0 <= hi, vmax > 0, at least one capsule) or
        ``ValueError``."""
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
        if L == 0:  # nothing to sweep: an empty C(t) would silently mask out every obstacle
            raise ValueError("chain cap_a: the chain has no capsules, so no robot geometry to reach anything")
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
        check_res(box.res, "box.res")
        if len(box.shape) != 3 or any(isinstance(n, bool) or int(n) != n or n < 1 for n in box.shape):
            raise ValueError(f"box.shape must be 3 whole numbers of cells >= 1, got {box.shape!r}")
        check_finite_array(box.origin, (3,), "box.origin")
        return _reach(ch, horizon, box, int(cells), strict=True)
    res = check_res(res)
    for scale in (1.0, 2.0, 4.0):
        out = _reach(ch, horizon, chain_box(ch, horizon, res, margin=2 * res, scale=scale), int(cells), False)
        if out is not None:
            return out
    raise ValueError("reachability: the reachable set does not fit in a box 4x the robot's size")


def _grid_for(lo: np.ndarray, hi: np.ndarray, cells: int, res_floor: float, res_cap: float, res: float = 0.0):
    """A dense internal grid (origin, res, float32 array of inf) over [lo, hi]: ``cells`` cells along its
    longest side, cells between ``res_floor`` and ``res_cap`` (or exactly ``res`` when given), two cells of
    padding, the origin on a multiple of the cell size (so grids of one cell size share their lattice)."""
    if res <= 0.0:
        res = min(max(res_floor, float(np.max(hi - lo)) / cells), res_cap)
    origin = np.floor(lo / res) * res - 2 * res
    shape = tuple(int(x) for x in np.ceil((hi - origin) / res) + 3)
    return np.ascontiguousarray(origin), res, np.full(shape, np.inf, dtype=np.float32)


def _same_lattice(origin_a: np.ndarray, res_a: float, origin_b: np.ndarray, res_b: float) -> bool:
    """Whether two grids have the same cells (equal size, origins a whole number of cells apart)."""
    if abs(res_a - res_b) > 1e-12 * res_a:
        return False
    f = (np.asarray(origin_a) - np.asarray(origin_b)) / res_a
    return bool(np.all(np.abs(f - np.round(f)) < 1e-9))


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


def _leading_slides(ch: ChainSweep) -> list[tuple[int, float, float]]:
    """The joints at the chain's base (joint 1 upwards) that are prismatic along a lattice axis, as
    ``(axis index, sign, deviation)``: swept exactly by :func:`slide` on the output lattice. ``deviation``
    (m per m of travel) is how far the axis is off the lattice axis (below 1e-9), added to the error bound."""
    out = []
    for j in range(len(ch.kind)):
        if ch.kind[j] != PRISMATIC:
            break
        d = int(np.argmax(np.abs(ch.axis[j])))
        c = float(ch.axis[j, d])
        if abs(c) < 1.0 - 1e-9:
            break
        out.append((d, math.copysign(1.0, c), math.sqrt(max(0.0, 1.0 - c * c))))
    return out


def _slide_base(ch: ChainSweep, slides: list, lo: np.ndarray, hi: np.ndarray, out: np.ndarray, origin, res: float):
    """The exact slides of the base's lattice-aligned prismatic joints (:func:`_leading_slides`) on the output
    cells ``out``, tip-most first, adding the links that they carry; returns (#cells outside, error added)."""
    outside, delta = 0, 0.0
    for j in range(len(slides), 0, -1):
        jj = j - 1
        d, sign, deviation = slides[jj]
        a, b = (float(lo[jj]), float(hi[jj])) if sign > 0 else (-float(hi[jj]), -float(lo[jj]))
        outside += slide(out, d, a, b, float(ch.vmax[jj]), res)
        delta += deviation * max(-a, b)  # cell indices: no rounding
        if j - 1 > 0:
            outside += rasterize(ch.cap_a, ch.cap_b, ch.cap_r, ch.cap_joint == j - 1, origin, res, out)
    return outside, delta


def _reach(ch: ChainSweep, horizon: float, box: VoxelBox, cells: int, strict: bool) -> ReachabilityGrid | None:
    """The sweep with adaptive internal grids: ``cells`` cells along the set's longest side, between
    ``res / 8`` and ``res``, so the small distal sets collapse finely (small error) and the large proximal ones
    coarsely (bounded size). The base's lattice-aligned prismatic joints slide exactly on the output cells.

    Invariant (the error bound ``delta``): every true point at time ``t`` lies within ``delta`` of the closed
    cube of a kept cell whose time is ``<= t``. A capsule rasterised with :func:`rasterize` adds nothing (its
    points lie in the cubes of the marked cells); a sampled sweep adds half the input cells' diagonal (the
    cube about its swept centre) and the sampling error; a slide adds nothing."""
    res_out = float(box.res)
    res_floor = res_out / 8.0
    n = len(ch.kind)
    slides = _leading_slides(ch)
    m = len(slides)
    lo = np.maximum(ch.lo, -ch.vmax * horizon)
    hi = np.minimum(ch.hi, ch.vmax * horizon)
    out = np.full(box.shape, np.inf, dtype=np.float32)
    box_origin = np.ascontiguousarray(box.origin, dtype=float)
    outside = 0
    if m == n:  # only slides: the last link's geometry goes straight onto the output cells
        g_origin, g_res, grid = box_origin, res_out, out
    else:
        bb = _caps_bbox(ch, ch.cap_joint == n, 0.0)
        if bb is None:  # no geometry on the last link: start from an empty set at the last joint
            bb = (ch.point[n - 1] - res_out, ch.point[n - 1] + res_out)
        g_origin, g_res, grid = _grid_for(bb[0], bb[1], cells, res_floor, res_out)
    outside += rasterize(ch.cap_a, ch.cap_b, ch.cap_r, ch.cap_joint == n, g_origin, g_res, grid)
    delta = 0.0
    for j in range(n, m, -1):  # sampled sweeps, tip first
        idx, tt = collect(grid)
        jj = j - 1
        in_spec = (g_origin, g_res, np.array(grid.shape, np.int64))
        in_origin, in_res = g_origin, g_res
        rng = max(-lo[jj], hi[jj])
        revolute = ch.kind[jj] == REVOLUTE
        if j > m + 1:
            swept, r_perp = None, 0.0
            if idx.size:
                s_lo, s_hi, r_perp = swept_bounds(idx, *in_spec, int(ch.kind[jj]), ch.axis[jj], ch.point[jj], rng, 1e-6)
                swept = (s_lo, s_hi)
            # a joint too slow to move any sample keeps the input lattice, so the cells carry over exactly
            bb_next = _union(swept, _caps_bbox(ch, ch.cap_joint == j - 1, 0.0))
            if bb_next is None:  # nothing swept and no geometry on this link: an empty set at its joint
                bb_next = (ch.point[jj - 1] - res_out, ch.point[jj - 1] + res_out)
            still = (r_perp if revolute else 1.0) * rng < 0.5 * in_res
            still = still and float(np.max(bb_next[1] - bb_next[0])) <= 2 * cells * in_res  # size stays bounded
            g_origin, g_res, grid = _grid_for(
                bb_next[0], bb_next[1], cells, res_floor, res_out, res=in_res if still else 0.0
            )
        else:  # the last sampled sweep writes onto the output cells
            g_origin, g_res, grid = box_origin, res_out, out
        n_out, err, moved = (sweep_two if idx.size >= _PARALLEL_FROM and threads_ok() else sweep)(
            idx, tt, *in_spec, g_origin, g_res, grid, int(ch.kind[jj]), np.ascontiguousarray(ch.axis[jj]),
            np.ascontiguousarray(ch.point[jj]), float(lo[jj]), float(hi[jj]), float(ch.vmax[jj]), 0.5 * g_res,
        )  # fmt: skip
        outside += n_out
        if not moved and _same_lattice(in_origin, in_res, g_origin, g_res):
            # every sample stayed on its own cell: a point of its cube moved by at most rng times its distance
            # from the axis (<= the centre's err + half a diagonal), a translation by err
            delta += err + (rng * H * in_res if revolute else 0.0) + _ROUNDING
        else:
            delta += H * in_res + err + _ROUNDING
        if j - 1 > 0:
            outside += rasterize(ch.cap_a, ch.cap_b, ch.cap_r, ch.cap_joint == j - 1, g_origin, g_res, grid)
    n_out, d_slides = _slide_base(ch, slides, lo, hi, out, box_origin, res_out)
    outside += n_out
    delta += d_slides
    if outside:
        if not strict:
            return None
        raise ValueError(f"reachability box {box} is too small: {outside} reachable samples fall outside it")
    k = math.ceil(delta / res_out - 1e-9)
    dil = dilate(out, k)
    # the fixed base: cells that meet its capsules, time 0 (exact, no dilation needed)
    rasterize(ch.cap_a, ch.cap_b, ch.cap_r, ch.cap_joint == 0, box_origin, res_out, dil)
    return ReachabilityGrid(box, dil, float(horizon), float(delta))
