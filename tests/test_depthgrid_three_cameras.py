"""Three or more cameras: a robot pixel of one secondary camera never erases an obstacle that another one
measures (``depthgrid.votes.cell_occupied_abstain``); analytic scene, exact sphere depth images."""

from __future__ import annotations

import numpy as np
import pytest

from depthguard.camera import Camera, look_at
from depthguard.depthgrid import DepthGridFusion

WORKSPACE = (-1.2, 1.2, -1.2, 1.2, -0.3, 1.5)
BALL, BALL_R = np.array([0.35, 0.15, 0.45]), 0.05


def _cam(eye, w=160, h=120):
    R, t = look_at(np.asarray(eye, float), np.array([0.0, 0.0, 0.45]))
    f = 575.0 * w / 640
    return Camera(fx=f, fy=f, cx=w / 2, cy=h / 2, width=w, height=h, R=R, t=t, min_depth=0.4, max_depth=6.0)


def _sphere_depth(cam: Camera, centre, radius, background=4.0) -> np.ndarray:
    """Exact z-depth of a sphere over a fronto-parallel background at ``background`` m."""
    rays = cam.pixel_ray_directions()  # (H, W, 3), camera frame, z = 1
    c = cam.world_to_camera(np.asarray(centre, float)[None])[0]
    a = np.einsum("hwi,hwi->hw", rays, rays)
    b = np.einsum("hwi,i->hw", rays, c)
    disc = b * b - a * (c @ c - radius**2)
    t = (b - np.sqrt(np.maximum(disc, 0.0))) / a
    return np.where(disc > 0, t, background)


def _frames():
    cams = [_cam((1.75, -0.95, 1.5)), _cam((-0.75, 1.85, 1.5)), _cam((-0.9, -0.9, 2.0))]
    p0, p1, p2 = cams
    # principal: the arm hides the ball (robot pixels 0.3 m in front of it, around its projection)
    d0 = np.full((p0.height, p0.width), 4.0)
    u, v, _ = p0.project(BALL)
    m0 = np.zeros(d0.shape, bool)
    m0[int(v) - 6 : int(v) + 7, int(u) - 6 : int(u) + 7] = True
    d0[m0] = p0.world_to_camera(BALL[None])[0, 2] - 0.3
    # second camera: measures the ball
    d1 = _sphere_depth(p1, BALL, BALL_R)
    # third camera: the arm fills its view (robot pixels everywhere, in front of the ball)
    d2 = np.full((p2.height, p2.width), 0.8)
    m2 = np.ones(d2.shape, bool)
    return cams, [d0, d1, d2], [m0, np.zeros(d1.shape, bool), m2]


@pytest.mark.parametrize("n", [2, 3])
def test_a_robot_pixel_of_one_camera_does_not_erase_what_another_measures(n):
    cams, depths, masks = _frames()
    fusion = DepthGridFusion(cams[:n], dd=0.01, workspace=WORKSPACE)
    fusion.update(depths[:n], masks[:n])
    centre = BALL + np.array([0.0, 0.0, 0.2])
    r = fusion.query(centre[None], np.array([0.05]), rho=0.4, mode="min")
    true = 0.2 - BALL_R - 0.05
    d = float(r.distance[0])
    assert d <= true + float(fusion.tolerance(centre[None])[0]), (n, d, true)
    assert d > true - 0.06, (n, d, true)  # and the ball is found, not a phantom nearer than it


def test_space_that_the_robot_hides_from_every_secondary_camera_stays_free_as_documented():
    """The documented limit, unchanged with three cameras: where every involved secondary camera sees only
    the arm, the cell is not an obstacle (no camera confirms one)."""
    cams, depths, masks = _frames()
    depths[1] = np.full(depths[1].shape, 0.8)
    masks[1] = np.ones(depths[1].shape, bool)  # the second camera sees only the arm too
    fusion = DepthGridFusion(cams, dd=0.01, workspace=WORKSPACE)
    fusion.update(depths, masks)
    centre = BALL + np.array([0.0, 0.0, 0.2])
    r = fusion.query(centre[None], np.array([0.05]), rho=0.4, mode="min")
    assert float(r.distance[0]) > 0.2 - BALL_R - 0.05 + 0.02
