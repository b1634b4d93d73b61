"""The range of the monitor's distances (``--ssm`` runs): beyond the repulsion's ρ, the same lower bound.

``DistanceStage.query_far`` keeps the ρ query's answers where it found something and asks a ``"min"`` query
at ``ssm_range`` elsewhere; the end effector's repulsion ignores whatever lies at or beyond ρ; the truth of
the accuracy metrics leaves out the geom groups that a background model removes on purpose.
"""

from __future__ import annotations

import numpy as np
import pytest

from depthguard.camera import Camera, look_at
from depthguard.control.endeffector import repulsive_velocity
from depthguard.scene import HalfSpace, Scene, Sphere, render_depth

WALL = HalfSpace(np.array([0.0, 0.0, 4.0]), np.array([0.0, 0.0, -1.0]))  # z >= 4 is solid


def _camera(width=160, height=120, f=70.0) -> Camera:  # wide: the view's edges lie > 0.7 m from the probes
    R, t = look_at((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.0, -1.0, 0.0))
    return Camera(width=width, height=height, fx=f, fy=f, cx=width / 2, cy=height / 2, R=R, t=t, max_depth=6.0)


@pytest.mark.parametrize("n_cameras", [1, 2])
def test_query_far_finds_beyond_rho_what_the_rho_query_calls_nothing(n_cameras):
    from depthguard.sim.pipeline import DistanceStage

    ball = Sphere(np.array([0.0, 0.0, 2.0]), 0.15)
    scene = Scene((ball, WALL))
    cams = [_camera()]
    if n_cameras == 2:  # a second camera beside the first, looking at the same point
        R, t = look_at((0.8, 0.0, 0.0), (0.0, 0.0, 2.0), (0.0, -1.0, 0.0))
        c0 = cams[0]
        cams.append(Camera(width=160, height=120, fx=c0.fx, fy=c0.fy, cx=c0.cx, cy=c0.cy, R=R, t=t, max_depth=6.0))
    rho = 0.3
    stage = DistanceStage(cams, rho=rho, ssm_range=0.7, workspace=(-1.5, 1.5, -1.5, 1.5, 0.3, 3.9))
    stage.update([render_depth(c, scene) for c in cams], [np.zeros(c.shape, bool) for c in cams])
    # in front of the ball (camera side), at gaps from 0.05 to 0.6 m; radius 0.02
    gaps = np.array([0.05, 0.2, 0.35, 0.5, 0.6])
    centres = ball.center + np.array([0.0, 0.0, -1.0]) * (ball.radius + gaps + 0.02)[:, None]
    radii = np.full(len(gaps), 0.02)
    res = stage.query(centres, radii)
    far = stage.query_far(centres, radii, res)
    dist, dirs = far.distance, far.direction
    truth = scene.distance(centres) - radii
    near = gaps < rho
    assert np.all(np.isfinite(far.nearest[~near])) and np.all(far.obstacle_pixels[~near] > 0)
    assert np.all(np.isfinite(res.distance[near])) and not np.any(np.isfinite(res.distance[~near]))
    np.testing.assert_array_equal(dist[near], res.distance[near])  # within ρ: the ρ query's answers
    assert np.all(np.isfinite(dist)), dist  # beyond ρ, within the range: found
    tol = stage.tolerance(centres)
    assert np.all(dist <= truth + tol), (dist, truth, tol)  # a lower bound within its tolerance ...
    assert np.all(dist >= truth - 0.1), (dist, truth)  # ... and close to the truth on a visible ball
    assert np.allclose(np.linalg.norm(dirs[~near], axis=1), 1.0)
    # without a range: the ρ query's answers, inf included
    plain = DistanceStage(cams, rho=rho, workspace=(-1.5, 1.5, -1.5, 1.5, 0.3, 3.9))
    plain.update([render_depth(c, scene) for c in cams], [np.zeros(c.shape, bool) for c in cams])
    res0 = plain.query(centres, radii)
    assert plain.query_far(centres, radii, res0) is res0


def test_ssm_range_must_exceed_rho():
    from depthguard.sim.pipeline import DistanceStage

    with pytest.raises(ValueError, match="ssm_range"):
        DistanceStage([_camera()], rho=0.4, ssm_range=0.3)


def test_repulsion_ignores_distances_at_or_beyond_rho():
    n = np.array([0.0, 0.0, 1.0])
    for d in (0.4, 0.41, 0.6, np.inf):
        assert np.array_equal(repulsive_velocity(d, n, 2.0, 0.4, 6.0), np.zeros(3)), d
    below = repulsive_velocity(0.399, n, 2.0, 0.4, 6.0)
    assert 0.0 < below[2] <= 2.0 / (1.0 + np.exp(5.9))  # eq. 7 just inside ρ: tiny, so the cut is no jump


def test_point_clearance_leaves_out_the_background_groups():
    pytest.importorskip("mujoco")
    pytest.importorskip("coal")
    from depthguard.sim import scenario_setup as setup
    from depthguard.sim import scenarios as S
    from depthguard.sim.pointtruth import PointClearance

    cell, _, _ = setup.build_scenario_cell(S.load_scenario("ral-hexagon"), quick=True, cameras=1)
    full, bg_out = PointClearance(cell), PointClearance(cell, exclude_groups=(0,))
    assert "table" in full.names and "table" not in bg_out.names and "parcel" in bg_out.names
    assert bg_out.excluded_groups == (0,) and len(bg_out.planes) == 0
    rng = np.random.default_rng(2)
    c = rng.uniform([-0.8, -0.8, 0.0], [0.8, 0.8, 1.2], (50, 3))
    r = np.full(50, 0.05)
    a, _ = full.evaluate(c, r, full.snapshot(cell.data))
    b, _ = bg_out.evaluate(c, r, bg_out.snapshot(cell.data))
    assert np.all(b >= a - 1e-12) and np.any(b > a + 1e-3)  # fewer obstacles: never nearer, sometimes farther


def test_the_age_of_the_distances_is_reported_as_closed_separation_not_a_changed_decision():
    """``data_age`` a beyond the camera period (a late frame): the decision is that of a configuration whose
    period is a (the same ``T_r``), while the reported separation and ``S_p`` are both smaller by
    ``(v_h + v_r,k) a``, what the person (ISO 13855: 1.6-2.0 m/s) and the point may have closed since the
    frames (random states). Within the period the decision does not depend on a at all."""
    pytest.importorskip("pinocchio")
    from dataclasses import replace

    from depthguard.control.braking import chain_lengths
    from depthguard.control.ssm import SsmConfig, SsmMonitor
    from depthguard.robot.control_points import ControlPointSet
    from depthguard.robot.model import load_lwr4

    points = ControlPointSet.build(load_lwr4(), "ral-9")
    model, N = points.model, points.n_points
    L = chain_lengths(model, points.joints, points.offsets)
    rng = np.random.default_rng(7)
    for _ in range(30):
        q = rng.uniform(np.asarray(model.q_min) + 0.3, np.asarray(model.q_max) - 0.3)
        model.update(q)
        J = points.evaluate(q, updated=True).jacobians
        qd, qdd, qn = rng.uniform(-0.8, 0.8, 7), rng.uniform(-3, 3, 7), rng.uniform(-1.0, 1.0, 7)
        dist = rng.uniform(0.05, 0.6, N)
        dirs = rng.normal(size=(N, 3))
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        base = SsmConfig()
        a = float(rng.uniform(base.camera_period, 0.08))
        aged = SsmMonitor(L, 10.0, 500.0, base).update(J, qd, qdd, qn, dist, dirs, data_age=a)
        longer = replace(base, camera_period=a)
        ref = SsmMonitor(L, 10.0, 500.0, longer).update(J, qd, qdd, qn, dist, dirs)
        young = SsmMonitor(L, 10.0, 500.0, base).update(J, qd, qdd, qn, dist, dirs, data_age=0.5 * base.camera_period)
        fresh = SsmMonitor(L, 10.0, 500.0, base).update(J, qd, qdd, qn, dist, dirs)
        assert young.scale == fresh.scale and young.state == fresh.state
        np.testing.assert_allclose(young.margin, fresh.margin, atol=1e-12)
        assert aged.scale == ref.scale and aged.state == ref.state and aged.binding == ref.binding
        np.testing.assert_allclose(aged.margin, ref.margin, atol=1e-12)
        shift = ref.separation - aged.separation
        np.testing.assert_allclose(ref.s_p - aged.s_p, shift, atol=1e-12)
        v_r = np.maximum(np.linalg.norm(J @ qd, axis=1), aged.scale * np.linalg.norm(J @ qn, axis=1))
        assert np.all(shift >= 1.6 * a - 1e-12) and np.all(shift <= (2.0 + v_r) * a + 1e-12)


@pytest.mark.parametrize("age", [float("nan"), float("inf"), -0.5, 1e9])
def test_a_bad_or_huge_data_age_stops_or_counts_as_fresh_never_raises(age):
    """NaN, +inf and huge ages count as data of unknown age: a protective stop (never a larger separation);
    a negative age (clock skew) counts as fresh data."""
    pytest.importorskip("pinocchio")
    from depthguard.control.braking import chain_lengths
    from depthguard.control.ssm import MonitorState, SsmConfig, SsmMonitor
    from depthguard.robot.control_points import ControlPointSet
    from depthguard.robot.model import load_lwr4

    points = ControlPointSet.build(load_lwr4(), "ral-9")
    model, N = points.model, points.n_points
    L = chain_lengths(model, points.joints, points.offsets)
    q = np.array([0.0, 0.5, 0.0, -1.2, 0.0, 0.8, 0.0])
    model.update(q)
    J = points.evaluate(q, updated=True).jacobians
    args = (J, np.zeros(7), np.zeros(7), np.full(7, 0.2), np.full(N, 0.8), np.tile([1.0, 0.0, 0.0], (N, 1)))
    fresh = SsmMonitor(L, 10.0, 500.0, SsmConfig()).update(*args)
    out = SsmMonitor(L, 10.0, 500.0, SsmConfig()).update(*args, data_age=age)
    assert fresh.state == MonitorState.MONITOR_OK
    if age < 0:
        assert out.scale == fresh.scale and np.array_equal(out.separation, fresh.separation)
    else:
        assert out.state == MonitorState.PROTECTIVE_STOP and out.scale == 0.0
        assert np.all(out.separation <= fresh.separation)
