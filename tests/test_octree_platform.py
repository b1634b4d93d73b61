"""Platform sensor rig and the scanner model: poses follow the base, REP 117 readings, scan self-filter."""

from __future__ import annotations

import math

import numpy as np
import pytest

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
