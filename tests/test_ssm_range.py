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
