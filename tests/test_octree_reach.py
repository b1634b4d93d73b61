"""Reachability grid (SAPHARI §3.2): over-approximation against random joint trajectories, bad input."""

from __future__ import annotations

from functools import lru_cache
from importlib import resources
from pathlib import Path

import numpy as np
import pytest

from depthguard.octree.reach import reachability_grid
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
    assert grid.delta < 0.05
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
