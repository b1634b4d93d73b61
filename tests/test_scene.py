"""The analytic scenes that serve as ground truth, checked against an independent library (coal/FCL)
and against their own ray casting."""

import coal  # the dev extra installs it: this ground truth is never skipped
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from depthguard.camera import Camera, look_at
from depthguard.scene import Box, Capsule, HalfSpace, Scene, Sphere, render_depth


def _rot(a, b, c):
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    Rz = np.array([[ca, -sa, 0], [sa, ca, 0], [0, 0, 1]])
    Ry = np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
    Rx = np.array([[1, 0, 0], [0, cc, -sc], [0, sc, cc]])
    return Rz @ Ry @ Rx


def _coal_distance(shape, R, t, p):
    return coal.distance(
        coal.Sphere(0.0),
        coal.Transform3s(np.eye(3), p),
        shape,
        coal.Transform3s(R, t),
        coal.DistanceRequest(),
        coal.DistanceResult(),
    )


f = st.floats(-1, 1)


@settings(max_examples=60, deadline=None)
@given(f, f, f, st.floats(0, 3), st.floats(0, 3), st.floats(0, 3), st.floats(0.05, 0.5), st.floats(0.05, 0.5))
def test_point_distances_match_coal(x, y, z, a, b, c, s1, s2):
    p = np.array([x, y, z]) * 2
    centre = np.array([0.1, -0.2, 0.3])
    R = _rot(a, b, c)
    box = Box(centre, np.array([s1, s2, 0.2]), R)
    ref = max(_coal_distance(coal.Box(2 * s1, 2 * s2, 0.4), R, centre, p), 0.0)
    assert box.distance(p[None])[0] == pytest.approx(ref, abs=1e-6)
    axis = R[:, 2]
    cap = Capsule(centre - axis * s2, centre + axis * s2, s1)
    ref = max(_coal_distance(coal.Capsule(s1, 2 * s2), R, centre, p), 0.0)
    assert cap.distance(p[None])[0] == pytest.approx(ref, abs=1e-6)
    sph = Sphere(centre, s1)
    assert sph.distance(p[None])[0] == pytest.approx(max(_coal_distance(coal.Sphere(s1), R, centre, p), 0.0), abs=1e-6)


def test_rendered_depth_lies_on_the_surfaces():
    R, t = look_at([2.0, 0.3, 1.0], [0.0, 0.0, 0.5])
    cam = Camera(width=80, height=60, fx=60.0, fy=60.0, cx=40, cy=30, R=R, t=t, max_depth=8.0)
    scene = Scene(
        (
            Box(np.array([0.0, 0.0, 0.5]), np.array([0.2, 0.3, 0.1]), _rot(0.3, 0.2, 0.1)),
            Capsule(np.array([0.3, -0.5, 0.2]), np.array([0.2, 0.5, 0.9]), 0.08),
            Sphere(np.array([-0.4, 0.4, 0.8]), 0.2),
            HalfSpace(np.array([0.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])),
        )
    )
    depth = render_depth(cam, scene)
    pts = cam.unproject_image(depth)[np.isfinite(depth)]
    assert len(pts) > 1000
    # every hit point is on the surface of the union: distance 0, and just outside along the ray it is free
    assert np.all(scene.distance(pts) < 1e-6)
    ray = pts - cam.position
    ray /= np.linalg.norm(ray, axis=1, keepdims=True)
    assert np.all(scene.distance(pts - 1e-3 * ray) > 0)
