"""Platform sensor rig and the scanner model: poses follow the base, REP 117 readings, scan self-filter."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from depthguard.octree.scanner import LaserScanner, scan_obstacle_ranges, scan_points, scan_robot_rays
from depthguard.robot.platform import platform_sensors


def test_sensors_follow_the_base_pose():
    cams0, scans0 = platform_sensors(np.zeros(3), 64, 48)
    q = np.array([1.0, -2.0, 0.7])
    cams1, scans1 = platform_sensors(q, 64, 48)
    c, s = math.cos(0.7), math.sin(0.7)
    Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    for a, b in zip(cams0 + scans0, cams1 + scans1, strict=True):
        np.testing.assert_allclose(b.position, Rz @ a.position + [1.0, -2.0, 0.0], atol=1e-12)
    # the arm's workspace in front of the platform is in both cameras' images
    for cam in cams0:
        p = cam.project(np.array([[0.5, 0.0, 0.8]]))[0]
        assert 0 <= p[0] < cam.width and 0 <= p[1] < cam.height and p[2] > cam.min_depth
    # scanners: 0.2 m above the floor, horizontal fans, 541 rays over 270°
    for sc in scans0:
        assert sc.position[2] == pytest.approx(0.2)
        assert np.allclose(sc.directions()[:, 2], 0.0)
        assert sc.n_rays == 541 and (sc.n_rays - 1) * sc.angle_increment == pytest.approx(1.5 * math.pi)


def test_rep117_readings():
    sc = LaserScanner(n_rays=5, angle_min=-0.2, angle_increment=0.1, range_min=0.1, range_max=8.0)
    r = np.array([2.0, np.inf, np.nan, 0.0, -np.inf])
    blocked = scan_obstacle_ranges(sc, r)
    np.testing.assert_array_equal(blocked, [2.0, np.inf, 0.1, 0.1, 0.1])  # missing -> blocked at range_min
    pts, idx = scan_points(sc, r)
    assert idx.tolist() == [0] and np.allclose(np.linalg.norm(pts - sc.position, axis=1), 2.0)
    with pytest.raises(ValueError, match="scan ranges"):
        scan_obstacle_ranges(sc, np.zeros(4))
    with pytest.raises(ValueError, match="angle_increment"):
        LaserScanner(angle_increment=0.0)
    with pytest.raises(ValueError, match="full turn"):
        LaserScanner(n_rays=1000, angle_increment=0.01)


def test_scan_self_filter_marks_rays_that_hit_the_robot():
    sc = LaserScanner(n_rays=181, angle_min=-math.pi / 2, angle_increment=math.pi / 180)
    d = sc.directions()
    ranges = np.full(sc.n_rays, 3.0)
    ranges[90] = 1.0  # straight ahead: hits the capsule at x = 1
    rob = scan_robot_rays(sc, ranges, np.array([[1.05, 0.0, -1.0]]), np.array([[1.05, 0.0, 1.0]]), np.array([0.05]))
    assert rob[90] and rob.sum() == 1
    assert np.allclose(d[90], [1.0, 0.0, 0.0])


def _robot_rays_by_numpy(sc, ranges, a, b, radius, margin):
    """The scan self-filter's formula in numpy: each valid hit point's distance to each capsule axis."""
    r = np.asarray(ranges, float)
    ok = np.isfinite(r) & (r > 0)
    p = sc.position + sc.directions()[ok] * r[ok, None]
    ab = b - a
    L2 = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-18)
    s = np.clip(np.einsum("kij,ij->ki", p[:, None, :] - a[None], ab) / L2, 0.0, 1.0)
    d = np.linalg.norm(p[:, None, :] - (a[None] + s[..., None] * ab[None]), axis=-1)
    return ok, d - (radius[None] + margin)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31), n_caps=st.integers(1, 12), margin=st.sampled_from([0.0, 0.03]))
def test_scan_self_filter_is_the_capsule_distance_test(seed, n_caps, margin):
    """The compiled scan self-filter against the numpy formula on random scans and capsules (some of zero
    length): the same rays, except that a ray within 1e-12 m of a capsule's limit may stay an obstacle
    (never the other way)."""
    rng = np.random.default_rng(seed)
    yaw = rng.uniform(-np.pi, np.pi)
    R_ws = np.array([[math.cos(yaw), -math.sin(yaw), 0.0], [math.sin(yaw), math.cos(yaw), 0.0], [0.0, 0.0, 1.0]])
    pos = rng.uniform(-0.5, 0.5, 3)
    sc = LaserScanner(R_ws.T, -R_ws.T @ pos, n_rays=181)
    ranges = rng.uniform(0.05, 2.0, sc.n_rays)
    ranges[rng.random(sc.n_rays) < 0.1] = np.nan
    ranges[rng.random(sc.n_rays) < 0.05] = np.inf
    a = rng.uniform(-1.0, 1.0, (n_caps, 3))
    b = np.where(rng.random((n_caps, 1)) < 0.2, a, a + rng.normal(0.0, 0.4, (n_caps, 3)))
    radius = rng.uniform(0.02, 0.3, n_caps)
    got = scan_robot_rays(sc, ranges, a, b, radius, margin)
    ok, excess = _robot_rays_by_numpy(sc, ranges, a, b, radius, margin)
    ref = np.zeros(sc.n_rays, bool)
    ref[ok] = (excess <= 0.0).any(axis=1)
    sure = np.zeros(sc.n_rays, bool)
    sure[ok] = (excess <= -1e-11).any(axis=1)
    assert not (got & ~ref).any()  # never a robot ray that the formula calls an obstacle
    assert not (sure & ~got).any()  # every ray clearly inside a capsule's limit is the robot's
