"""The direction lattice of modes ``all`` and ``hybrid`` (``direction_stride``).

At 640x480 the direction sum (RA-L'16 eq. 11, ICRA'12 eq. 9) is taken over every second pixel in each
direction; every pixel still competes for the distance. Checked here: the distance (and its nearest
point's distance) is exactly that of the full-resolution query, in both the single-camera depth space
and the fused depth grid; the direction stays within a few degrees of the full-resolution direction
wherever enough pixels are within reach, and equals the analytic normal of a wall; bad strides are
refused naming the field.
"""

from __future__ import annotations

import numpy as np
import pytest

from depthguard.camera import Camera, look_at
from depthguard.depthgrid import DepthGridFusion
from depthguard.depthspace import prepare_frame, query_distances
from depthguard.kernels.records import direction_stride
from depthguard.scene import Box, Capsule, HalfSpace, Scene, Sphere, render_depth

ROOM = (
    HalfSpace(np.array([0.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])),
    HalfSpace(np.array([-2.5, 0.0, 0.0]), np.array([1.0, 0.0, 0.0])),
    HalfSpace(np.array([0.0, -2.5, 0.0]), np.array([0.0, 1.0, 0.0])),
)


def camera(eye, target, w=640, h=480, f=525.0) -> Camera:
    R, t = look_at(np.asarray(eye, float), np.asarray(target, float))
    return Camera(width=w, height=h, fx=f, fy=f, cx=w / 2 - 0.5, cy=h / 2 - 0.5, R=R, t=t, min_depth=0.3, max_depth=6.0)


def random_scene(rng: np.random.Generator) -> Scene:
    prims = []
    for _ in range(3):
        c = rng.uniform([-0.5, -0.5, 0.3], [0.5, 0.5, 1.3])
        kind = rng.integers(0, 3)
        if kind == 0:
            prims.append(Sphere(c, rng.uniform(0.08, 0.2)))
        elif kind == 1:
            prims.append(Capsule(c, c + rng.uniform(-0.4, 0.4, 3), rng.uniform(0.06, 0.15)))
        else:
            prims.append(Box(c, rng.uniform(0.06, 0.25, 3)))
    return Scene((*prims, *ROOM))


def angles_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(np.sum(a * b, axis=1), -1.0, 1.0)))


def test_auto_stride_and_bad_strides():
    assert direction_stride("auto", 320) == 1
    assert direction_stride("auto", 639) == 1
    assert direction_stride("auto", 640) == 2
    assert direction_stride("auto", 1280) == 4
    assert direction_stride(3, 640) == 3
    for bad in (0, -1, 1.5, True, "2", None):
        with pytest.raises(ValueError, match="direction_stride"):
            direction_stride(bad, 640)


def check_against_full(full, lat, min_count=400, max_angle=3.0):
    """Same distances; direction within ``max_angle`` where the full query counted >= ``min_count`` pixels."""
    assert np.array_equal(full.distance, lat.distance)  # bit for bit: the distance uses every pixel
    found = np.isfinite(full.distance)
    many = found & (full.obstacle_pixels >= min_count)
    assert many.sum() >= 3, full.obstacle_pixels
    ang = angles_deg(full.direction[many], lat.direction[many])
    assert np.all(ang < max_angle), ang
    assert np.median(ang) < max_angle / 5, ang
    ratio = lat.obstacle_pixels[many] / full.obstacle_pixels[many]  # the count scaled to the whole image
    assert np.all((ratio > 0.85) & (ratio < 1.15)), ratio
    return ang


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_depth_space_lattice(seed):
    rng = np.random.default_rng(seed)
    cam = camera([2.2, 0.3, 1.4], [0.0, 0.0, 0.7])
    frame = prepare_frame(cam, render_depth(cam, random_scene(rng)))
    P = rng.uniform([-0.5, -0.5, 0.3], [0.5, 0.5, 1.3], size=(24, 3))
    radii = rng.uniform(0.0, 0.1, len(P))
    for mode in ("all", "hybrid"):
        full = query_distances(frame, P, radii, rho=0.4, mode=mode, direction_stride=1)
        for stride, max_angle in (("auto", 3.0), (3, 5.0)):  # (measured: at most 2.3 and 3.4 degrees)
            lat = query_distances(frame, P, radii, rho=0.4, mode=mode, direction_stride=stride)
            check_against_full(full, lat, max_angle=max_angle)
    # min mode: the stride changes nothing at all
    a = query_distances(frame, P, radii, rho=0.4, mode="min", direction_stride=1)
    b = query_distances(frame, P, radii, rho=0.4, mode="min", direction_stride=4)
    assert np.array_equal(a.direction, b.direction, equal_nan=True) and np.array_equal(a.distance, b.distance)


@pytest.mark.parametrize("seed", [3, 4])
def test_fused_lattice(seed):
    rng = np.random.default_rng(seed)
    cams = [camera([2.2, 0.3, 1.4], [0.0, 0.0, 0.7]), camera([0.3, 2.3, 1.6], [0.0, 0.0, 0.7], 320, 240, 262.5)]
    scene = random_scene(rng)
    scene = Scene((*scene.primitives, Box(np.array([1.3, 0.2, 0.9]), np.array([0.05, 0.2, 0.3]))))  # a shadow
    fusion = DepthGridFusion(cams, dd=0.02, workspace=(-0.8, 0.8, -0.8, 0.8, 0.0, 1.6))
    fusion.update([render_depth(c, scene) for c in cams])
    P = rng.uniform([-0.5, -0.5, 0.3], [0.5, 0.5, 1.3], size=(10, 3))
    radii = rng.uniform(0.0, 0.1, len(P))
    for mode in ("all", "hybrid"):
        full = fusion.query(P, radii, rho=0.3, mode=mode, direction_stride=1)
        check_against_full(full, fusion.query(P, radii, rho=0.3, mode=mode), min_count=200)


def test_wall_direction_is_its_normal():
    """In front of a wall the mean direction is the wall's normal, on the lattice as at full resolution."""
    cam = camera([2.0, 0.0, 1.0], [0.0, 0.0, 1.0])
    frame = prepare_frame(cam, render_depth(cam, Scene((HalfSpace(np.array([-0.5, 0, 0]), np.array([1.0, 0, 0])),))))
    P = np.array([[-0.3, 0.0, 1.0], [-0.2, 0.05, 0.95], [-0.35, -0.04, 1.03]])
    for stride in (1, "auto", 4):
        res = query_distances(frame, P, 0.0, rho=0.4, mode="hybrid", direction_stride=stride)
        truth = P[:, 0] + 0.5
        assert np.all(res.distance <= truth) and np.all(truth - res.distance < 5e-3)  # the frustum slack
        assert np.all(angles_deg(res.direction, np.tile([1.0, 0.0, 0.0], (3, 1))) < 1.5)
