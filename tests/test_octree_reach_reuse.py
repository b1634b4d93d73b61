"""C(t) reused across frames (depthguard.octree.reach_reuse): the reused grid must hold every point the robot
can reach within T from the *current* state, on random walks of the state, and bad input names the field."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from depthguard.octree.reach_reuse import ReachReuse, box_within, joint_box
from depthguard.robot.model import load_lwr4
from depthguard.robot.reach import robot_reachability
from test_octree_reach import omni, random_trajectory_points


def _walk(model, reuse, q0, rng, steps, speed, dt=1 / 30):
    """A random walk of the state at ``speed`` x v_max (per-joint random signs, changing now and then);
    at each step the grid in use (reused or recomputed) must hold sampled trajectory points from the state."""
    q = q0.copy()
    direction = rng.choice([-1.0, 1.0], model.n_dof)
    for k in range(steps):
        if not reuse.covers(q):
            reuse.store(q, robot_reachability(model, q, horizon=reuse.grid_horizon, res=0.09))
        if k % 3 == 0:  # the expensive check on every third state
            pts, _ = random_trajectory_points(model, q, reuse.horizon, rng, n_traj=6, n_t=6)
            t = reuse.grid.lookup(pts)
            assert np.all(t <= reuse.grid_horizon + 1e-9), f"step {k}: {np.sum(t > reuse.grid_horizon)} points outside"
        flip = rng.random(model.n_dof) < 0.1
        direction = np.where(flip, -direction, direction)
        q = np.clip(q + direction * speed * model.v_max * dt, model.q_min, model.q_max)
    return reuse


@pytest.mark.parametrize("which,speed", [("arm", 0.3), ("arm", 1.0), ("omni", 0.3)])
def test_reused_grid_holds_what_the_current_state_can_reach(which, speed):
    model = load_lwr4() if which == "arm" else omni()
    rng = np.random.default_rng(11)
    q0 = (
        rng.uniform(model.q_min * 0.6, model.q_max * 0.6)
        if which == "arm"
        else np.r_[0.1, -0.2, 0.3, 0.2, -0.6, 0, 1.0, 0, -0.5, 0]
    )
    reuse = _walk(model, ReachReuse.for_model(model, horizon=0.5, slack=0.1), q0, rng, steps=24, speed=speed)
    assert reuse.computed >= 2 and reuse.reused >= 1  # both kinds of frame happened
    if speed == 1.0:  # at full speed every joint uses the slack within 3 frames
        assert reuse.computed >= 24 // 3


def test_a_standing_robot_reuses_its_grid_for_ever_and_slack_zero_never_reuses_a_moved_one():
    model = load_lwr4()
    q = np.zeros(model.n_dof)
    reuse = ReachReuse.for_model(model, slack=0.1)
    assert not reuse.covers(q)
    reuse.store(q, robot_reachability(model, q, horizon=reuse.grid_horizon, res=0.09))
    assert all(reuse.covers(q) for _ in range(5)) and reuse.reused == 5
    strict = ReachReuse.for_model(model, slack=0.0)
    strict.store(q, robot_reachability(model, q, horizon=0.5, res=0.09))
    assert strict.covers(q)
    q2 = q.copy()
    q2[2] += 1e-6
    assert not strict.covers(q2)


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.floats(-3, 3), min_size=3, max_size=3),
    st.lists(st.floats(-0.5, 0.5), min_size=3, max_size=3),
    st.floats(0.0, 0.5),
)
def test_covers_exactly_when_the_joint_box_is_inside(q0, dq, slack):
    """The reuse rule against its definition, at and beyond joint limits: a state reuses the grid iff every
    configuration reachable from it within T is a configuration the grid was computed for (sampled)."""
    v = np.array([1.0, 2.0, 0.5])
    qmin, qmax = np.array([-2.0, -np.inf, -1.0]), np.array([2.0, np.inf, 1.0])
    reuse = ReachReuse(qmin, qmax, v, horizon=0.5, slack=slack)
    q0, q = np.array(q0), np.array(q0) + np.array(dq)

    class G:  # a stand-in grid: only its horizon is read
        horizon = reuse.grid_horizon

    reuse.store(q0, G)
    outer = joint_box(q0, v, qmin, qmax, reuse.grid_horizon)
    inner = joint_box(q, v, qmin, qmax, 0.5)
    assert reuse.covers(q) == box_within(inner, outer)
    # sampled: the ends of every reachable joint interval from q within T (straight motions) lie in the
    # grid's box whenever the rule says "covered"
    if reuse.covers(q):
        for t in (0.0, 0.25, 0.5):
            for s in (-1.0, 1.0):
                qt = np.clip(q + s * v * t, np.minimum(qmin, q), np.maximum(qmax, q))
                assert np.all(qt >= outer[0]) and np.all(qt <= outer[1])


def test_bad_input_names_the_field():
    v = np.ones(3)
    with pytest.raises(ValueError, match="v_max"):
        ReachReuse(np.zeros(3), np.ones(3), -v)
    with pytest.raises(ValueError, match="q_min"):
        ReachReuse(np.zeros(2), np.ones(3), v)
    with pytest.raises(ValueError, match="slack"):
        ReachReuse(np.zeros(3), np.ones(3), v, slack=float("nan"))
    with pytest.raises(ValueError, match="horizon"):
        ReachReuse(np.zeros(3), np.ones(3), v, horizon=0.0)
    r = ReachReuse(-np.ones(3), np.ones(3), v)
    with pytest.raises(ValueError, match="q must"):
        r.covers(np.array([0.0, np.nan, 0.0]))
    with pytest.raises(ValueError, match="q must"):
        r.covers(np.zeros(4))

    class G:
        horizon = 0.5

    with pytest.raises(ValueError, match="horizon"):
        r.store(np.zeros(3), G)  # computed with T, not T + slack
