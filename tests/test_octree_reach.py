"""Reachability grid (SAPHARI §3.2): over-approximation against random joint trajectories, bad input."""

from __future__ import annotations

from functools import lru_cache
from importlib import resources
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial import cKDTree

from depthguard.octree.reach import ChainSweep, reachability_grid
from depthguard.robot.model import RobotModel, load_lwr4
from depthguard.robot.reach import chain_sweep, robot_reachability


@lru_cache(maxsize=1)
def omni():
    path = Path(str(resources.files("depthguard.robot") / "data" / "omni_lwr4" / "omni_lwr4.urdf"))
    return RobotModel.from_urdf(path, ee_frame="lwr_ee")


def capsule_samples(model, q, rng, per_capsule=6):
    """Points on the capsules' surfaces and axes at q (the link geometry the grid must hold)."""
    a, b, r = model.link_capsules(q)
    s = rng.random((len(a), per_capsule, 1))
    axis_pts = a[:, None] + s * (b - a)[:, None]
    d = rng.normal(size=axis_pts.shape)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return np.concatenate([axis_pts, axis_pts + d * r[:, None, None]], axis=1).reshape(-1, 3)


def random_trajectory_points(model, q0, horizon, rng, n_traj=12, n_t=10):
    """(M, 3) points and (M,) times of link geometry along random trajectories with |q̇| <= q̇_max."""
    pts, ts = [], []
    for _ in range(n_traj):
        # piecewise-constant velocities, each at a random fraction of the limit and a random sign,
        # mostly at the limit (the extreme trajectories bound the set)
        n_seg = rng.integers(1, 4)
        times = np.sort(rng.random(n_seg - 1)) * horizon
        vel = rng.choice([-1.0, 1.0], size=(n_seg, model.n_dof)) * np.where(
            rng.random((n_seg, model.n_dof)) < 0.7, 1.0, rng.random((n_seg, model.n_dof))
        )
        vel *= model.v_max
        q = q0.copy()
        t_prev = 0.0
        for t in np.linspace(0.0, horizon, n_t):
            seg = np.searchsorted(times, t)
            q = np.clip(q + vel[seg] * (t - t_prev), model.q_min, model.q_max)
            t_prev = t
            p = capsule_samples(model, q, rng)
            pts.append(p)
            ts.append(np.full(len(p), t))
    return np.concatenate(pts), np.concatenate(ts)


def check_over_approximation(model, q0, res, horizon=0.5, seed=0):
    grid = robot_reachability(model, q0, horizon=horizon, res=res)
    rng = np.random.default_rng(seed)
    pts, ts = random_trajectory_points(model, q0, horizon, rng)
    t_grid = grid.lookup(pts)
    bad = t_grid > ts + 1e-6
    assert not bad.any(), f"{bad.sum()} sampled points outside the grid or reached earlier than it says"
    return grid, pts


@pytest.mark.parametrize("seed", [0, 1])
def test_arm_grid_holds_every_sampled_trajectory_point(seed):
    model = load_lwr4()
    rng = np.random.default_rng(100 + seed)
    q0 = rng.uniform(model.q_min * 0.8, model.q_max * 0.8)
    check_over_approximation(model, q0, res=0.09, seed=seed)


def test_arm_grid_at_its_joint_limits():
    model = load_lwr4()
    q0 = model.q_max - 1e-9  # every joint at its upper limit: only half of each range is available
    check_over_approximation(model, q0, res=0.09, seed=3)


def test_mobile_manipulator_grid_holds_every_sampled_trajectory_point():
    model = omni()
    q0 = np.zeros(model.n_dof)
    q0[3:] = [0.3, 0.6, 0.0, -1.2, 0.2, 0.8, 0.0]
    q0[2] = 0.4
    check_over_approximation(model, q0, res=0.09, seed=5)


@pytest.mark.parametrize("which", ["arm", "omni"])
def test_random_configurations_of_the_joint_box_are_inside_no_earlier(which):
    """Every q with |q - q0| <= q̇_max T is reached at max |q - q0| / q̇_max on a straight line."""
    model = load_lwr4() if which == "arm" else omni()
    rng = np.random.default_rng(7)
    q0 = (
        rng.uniform(model.q_min * 0.5, model.q_max * 0.5)
        if which == "arm"
        else np.r_[0.1, -0.2, 0.3, 0.2, -0.6, 0, 1.0, 0, -0.5, 0]
    )
    grid = robot_reachability(model, q0, res=0.09)
    lo = np.maximum(q0 - model.v_max * 0.5, model.q_min)
    hi = np.minimum(q0 + model.v_max * 0.5, model.q_max)
    for _ in range(150):
        u = rng.random(model.n_dof)
        u = np.where(rng.random(model.n_dof) < 0.5, np.round(u), u)  # many at the box's faces and corners
        q = lo + u * (hi - lo)
        t = float(np.max(np.abs(q - q0) / model.v_max))
        p = capsule_samples(model, q, rng)
        assert np.all(grid.lookup(p) <= t + 1e-6)


def test_time_is_zero_on_the_robot_and_grows_away_from_it():
    model = load_lwr4()
    q0 = np.array([0.0, 0.5, 0.0, -1.0, 0.0, 0.5, 0.0])
    grid = robot_reachability(model, q0, res=0.09)
    a, b, _ = model.link_capsules(q0)
    assert np.all(grid.lookup(0.5 * (a + b)) == 0.0)
    assert np.all(grid.time[np.isfinite(grid.time)] <= grid.horizon + 1e-6)
    # a point 3 m away cannot be reached in 0.5 s
    assert grid.lookup(np.array([[3.0, 0.0, 0.5]]))[0] == np.inf


def test_fixed_joints_reach_only_their_own_cells():
    """All speeds tiny: the grid is the robot itself, dilated by the bounded sweep error only."""
    model = load_lwr4()
    q0 = np.zeros(7)
    grid = robot_reachability(model, q0, res=0.05, v_max=np.full(7, 1e-6))
    a, b, r = model.link_capsules(q0)
    assert grid.delta < 2 * np.sqrt(3) / 2 * 0.05  # at most two changes of lattice, half a diagonal each
    vol_capsules = float(np.sum(np.pi * r**2 * np.linalg.norm(b - a, axis=1) + 4 / 3 * np.pi * r**3))
    assert grid.reachable.sum() * 0.05**3 < 4 * vol_capsules + 0.2


def test_bad_input_names_the_field():
    model = load_lwr4()
    ch = chain_sweep(model, np.zeros(7))
    with pytest.raises(ValueError, match="horizon"):
        reachability_grid(ch, horizon=-1.0)
    with pytest.raises(ValueError, match="res"):
        reachability_grid(ch, res=0.5)
    with pytest.raises(ValueError, match="vmax"):
        reachability_grid(ch._replace(vmax=np.zeros(7)))
    with pytest.raises(ValueError, match="q"):
        chain_sweep(model, np.full(7, np.nan))
    with pytest.raises(ValueError, match="axis"):
        reachability_grid(ch._replace(axis=np.ones((7, 3))))


# ---------------------------------------------------------------------------------- small chains, densely
def _poe_points(kind, axis, point, offsets, x):
    """Points ``x`` (P, 3) of the last link moved by joint offsets (S, n): M_1(δ_1) ∘ ... ∘ M_n(δ_n) (x),
    each M_j the rotation (Rodrigues) or translation about / along joint j's current axis. (S, P, 3)."""
    p = np.broadcast_to(x, (offsets.shape[0],) + x.shape).copy()
    for j in range(len(kind) - 1, -1, -1):
        d = offsets[:, j][:, None, None]
        if kind[j] == 1:
            p = p + d * axis[j]
            continue
        v = p - point[j]
        k = axis[j]
        c, s = np.cos(d), np.sin(d)
        p = point[j] + v * c + np.cross(k, v) * s + k * (v @ k)[..., None] * (1 - c)
    return p


@st.composite
def small_chains(draw):
    n = draw(st.integers(1, 3))
    rng = np.random.default_rng(draw(st.integers(0, 2**31)))
    kind = (rng.random(n) < draw(st.floats(0.0, 0.5))).astype(np.int64)
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    # sometimes the first joints are prismatic along a lattice axis (an omnidirectional base), which the
    # grid slides exactly instead of sampling
    for j in range(min(n, draw(st.sampled_from([0, 0, 1, 2])))):
        if j < n - 1 or draw(st.booleans()):
            kind[j] = 1
            axis[j] = np.eye(3)[rng.integers(3)] * rng.choice([-1.0, 1.0])
    point = rng.uniform(-0.3, 0.3, (n, 3))
    vmax = rng.uniform(0.2, 2.5, n)
    lo = -rng.uniform(0.0, 1.5, n) * (rng.random(n) < 0.8)  # some joints at a limit
    hi = rng.uniform(0.0, 1.5, n) * (rng.random(n) < 0.8)
    a = rng.uniform(-0.8, 0.8, 3)
    b = a + rng.uniform(-0.2, 0.2, 3)
    res = draw(st.sampled_from([0.05, 0.09]))
    return kind, axis, point, lo, hi, vmax, a, b, res


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(small_chains())
def test_small_chains_hold_every_densely_sampled_point_no_earlier(chain):
    """1-3 joints and a thin segment on the last link, where the proven error bound is a cell or two, so the
    dilation is tight and a sampling step or an error term too small leaves true points outside: every
    point of a dense grid of joint offsets (and of the segment) lies in a cell reached no later."""
    kind, axis, point, lo, hi, vmax, a, b, res = chain
    n = len(kind)
    ch = ChainSweep(kind, axis, point, lo, hi, vmax, a[None], b[None], np.zeros(1), np.array([n]))
    horizon = 0.5
    grid = reachability_grid(ch, horizon=horizon, res=res)
    lo_t = np.maximum(lo, -vmax * horizon)
    hi_t = np.minimum(hi, vmax * horizon)
    per = {1: 3001, 2: 121, 3: 31}[n]
    axes = [np.linspace(lo_t[j], hi_t[j], per) for j in range(n)]
    offsets = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, n)
    t = np.max(np.abs(offsets) / vmax, axis=1)
    x = a + np.linspace(0.0, 1.0, 5)[:, None] * (b - a)
    pts = _poe_points(kind, axis, point, offsets, x)
    t_grid = grid.lookup(pts.reshape(-1, 3)).reshape(pts.shape[:2])
    late = t_grid > t[:, None] + 1e-6
    assert not late.any(), f"{late.sum()} of {late.size} true points outside or earlier (δ = {grid.delta:.3f} m)"
    # tight: every reachable cell lies within the dilation (k = ceil(δ / res) cells each way, a box) of a
    # cell holding a point within δ of the true set
    cells = grid.box.centres(np.argwhere(grid.reachable))
    gap = cKDTree(pts.reshape(-1, 3)).query(cells)[0]
    lattice = pts.reshape((per,) * n + pts.shape[1:])
    spacing = max(float(np.linalg.norm(np.diff(lattice, axis=j), axis=-1).max(initial=0.0)) for j in range(n))
    k = np.ceil(grid.delta / res)
    # each exact slide of the base's lattice-aligned prismatic joints may add the cell its cubes touch
    slides = 0
    while slides < n and kind[slides] == 1 and np.max(np.abs(axis[slides])) == 1.0:
        slides += 1
    assert gap.max() <= grid.delta + np.sqrt(3) * (k + 0.5) * res + slides * res + spacing + 1e-9


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(small_chains())
def test_small_chains_every_true_point_is_within_delta_of_a_kept_cell_no_later(chain):
    """The invariant behind the proof, before the final dilation hides its slack: every true point lies
    within δ of the cube of a kept cell whose time is no later (the kept sample is in that cube). A sampling
    step or an error term dropped from δ breaks it."""
    import depthguard.octree.reach as reach

    kind, axis, point, lo, hi, vmax, a, b, res = chain
    n = len(kind)
    ch = ChainSweep(kind, axis, point, lo, hi, vmax, a[None], b[None], np.zeros(1), np.array([n]))
    kept = []
    real = reach.dilate
    try:
        reach.dilate = lambda g, k: (kept.append(g.copy()), real(g, k))[1]
        grid = reachability_grid(ch, horizon=0.5, res=res)
    finally:
        reach.dilate = real
    before = kept[-1]
    lo_t = np.maximum(lo, -vmax * 0.5)
    hi_t = np.minimum(hi, vmax * 0.5)
    per = {1: 2001, 2: 61, 3: 15}[n]
    axes = [np.linspace(lo_t[j], hi_t[j], per) for j in range(n)]
    offsets = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, n)
    t = np.max(np.abs(offsets) / vmax, axis=1)
    x = a + np.linspace(0.0, 1.0, 3)[:, None] * (b - a)
    pts = _poe_points(kind, axis, point, offsets, x).reshape(-1, 3)
    t = np.repeat(t, len(x))
    idx = np.argwhere(np.isfinite(before))
    centres = grid.box.centres(idx)
    times = before[tuple(idx.T)]
    kk = min(len(centres), int(np.ceil(2 * grid.delta / res + 3) ** 3))
    dist, near = cKDTree(centres).query(pts, k=kk, distance_upper_bound=grid.delta + np.sqrt(3) * res)
    dist, near = np.atleast_2d(dist.T).T, np.atleast_2d(near.T).T
    ok = np.zeros(len(pts), bool)
    valid = near < len(centres)
    safe = np.where(valid, near, 0)
    gap = np.linalg.norm(np.maximum(np.abs(pts[:, None] - centres[safe]) - res / 2, 0.0), axis=-1)
    ok = np.any(valid & (gap <= grid.delta + 1e-9) & (times[safe] <= t[:, None] + 1e-6), axis=1)
    assert ok.all(), f"{(~ok).sum()} of {len(ok)} true points over δ = {grid.delta:.4f} m from a kept cell no later"


def test_lattice_aligned_base_joints_add_no_error():
    """An omnidirectional base's x and y slide the output cells exactly: the error bound of the chain with
    them is that of the chain without them, and the grid holds every base offset of the arm's set."""
    rng = np.random.default_rng(3)
    axis = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, 1.0]])
    point = np.array([[0, 0, 0], [0, 0, 0], [0.1, 0.0, 0.0]])
    # travels that are not whole cells, so the cells that the moved cubes only partly enter matter
    lo, hi, vmax = np.array([-0.3, -0.17, -0.8]), np.array([0.23, 0.0, 0.8]), np.array([0.5, 0.7, 1.5])
    a, b = np.array([[0.3, 0.0, 0.2]]), np.array([[0.6, 0.1, 0.4]])
    full = ChainSweep(np.array([1, 1, 0]), axis, point, lo, hi, vmax, a, b, np.array([0.05]), np.array([3]))
    r = np.array([0.05])
    arm = ChainSweep(np.array([0]), axis[2:], point[2:], lo[2:], hi[2:], vmax[2:], a, b, r, np.array([1]))
    g_full = reachability_grid(full, res=0.05)
    g_arm = reachability_grid(arm, box=g_full.box)
    assert abs(g_full.delta - g_arm.delta) < 1e-8
    # every arm cell, moved by every base offset (up to the horizon), is reached no later
    cells = np.argwhere(np.isfinite(g_arm.time))
    for _ in range(200):
        s = rng.uniform(np.maximum(lo[:2], -vmax[:2] * 0.5), np.minimum(hi[:2], vmax[:2] * 0.5))
        pts = g_arm.box.centres(cells) + rng.uniform(-0.025, 0.025, (len(cells), 3))
        t = np.maximum(g_arm.lookup(pts), np.max(np.abs(s) / vmax[:2]))
        moved = pts + s[0] * axis[0] + s[1] * axis[1]
        assert np.all(g_full.lookup(moved) <= t + 1e-6)


@settings(max_examples=30, deadline=None)
@given(
    st.integers(0, 1),
    st.floats(0.05, 0.3),
    st.floats(0.0, 1.2),
    st.floats(0.0, 1.2),
    st.floats(0.3, 3.0),
    st.floats(0.0, 0.4),
)
def test_one_sweep_keeps_every_offset_within_its_error_no_later(kind, r, lo_mag, hi, vmax, t0):
    """The sweep kernel alone, written into cells far finer than its step (so a cell centre stands for the
    sample in it): every offset θ of the range moves the sample to within the reported error (plus a fine
    cell's half diagonal) of a written cell whose time is <= max(t0, |θ| / v). A coarser step or a missing
    end sample shows here, where the final dilation's slack would hide it."""
    from depthguard.octree.reach_kernels import sweep

    eps, fine = 0.02, 0.001
    lo = -lo_mag
    axis = np.array([0.0, 0.0, 1.0]) if kind == 0 else np.array([1.0, 0.0, 0.0])
    point = np.zeros(3)
    centre = np.array([r, 0.0, 0.0])
    span = (r if kind == 0 else max(hi, lo_mag)) + 0.05
    if kind == 0:
        origin = np.array([-span, -span, -fine / 2])
        shape = (int(2 * span / fine) + 1, int(2 * span / fine) + 1, 1)
    else:
        origin = np.array([r - span, -fine / 2, -fine / 2])
        shape = (int(2 * span / fine) + 1, 1, 1)
    grid = np.full(shape, np.inf, np.float32)
    in_res = 0.01
    in_origin = centre - in_res / 2
    out, err, _ = sweep(
        np.array([0]), np.array([t0], np.float32), in_origin, in_res, np.array([1, 1, 1]), origin, fine, grid,
        kind, axis, point, lo, hi, vmax, eps,
    )  # fmt: skip
    assert out == 0 and err <= eps + 1e-12
    theta = np.linspace(lo, hi, 4001)
    if kind == 0:
        pts = np.column_stack([r * np.cos(theta), r * np.sin(theta), np.zeros_like(theta)])
    else:
        pts = centre + theta[:, None] * axis
    t_true = np.maximum(t0, np.abs(theta) / vmax)
    cells = np.argwhere(np.isfinite(grid))
    centres = origin + (cells + 0.5) * fine
    times = grid[tuple(cells.T)]
    d = np.linalg.norm(pts[:, None, :] - centres[None], axis=-1)
    ok = (d <= err + np.sqrt(3) / 2 * fine + 1e-9) & (times[None] <= t_true[:, None] + 1e-6)
    assert ok.any(axis=1).all(), f"{(~ok.any(axis=1)).sum()} offsets too far from an early enough sample"
