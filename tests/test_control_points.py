"""Control points: bounding spheres, presets, positions and Jacobians (finite differences)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

pytest.importorskip("pinocchio")

from depthguard.robot.control_points import (  # noqa: E402
    ControlPointSet,
    bounding_spheres,
    control_points,
)
from depthguard.robot.model import load_lwr4  # noqa: E402


@pytest.fixture(scope="module")
def lwr():
    return load_lwr4()


@settings(max_examples=40, deadline=None)
@given(
    L=st.floats(0.0, 0.5),
    r=st.floats(0.01, 0.1),
    k=st.integers(1, 6),
    seed=st.integers(0, 2**31 - 1),
)
def test_bounding_spheres_contain_the_capsule(L: float, r: float, k: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    a = rng.normal(size=3)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    b = a + L * axis
    centres, radii = bounding_spheres(a, b, r, k)
    assert centres.shape == (k, 3) and radii.shape == (k,)
    # random points of the capsule (surface included) must be inside some sphere
    t = rng.uniform(0, 1, 500)
    d = rng.normal(size=(500, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    pts = a + t[:, None] * (b - a) + r * d * rng.uniform(0, 1, (500, 1)) ** (1 / 3)
    pts = np.vstack([pts, a + t[:, None] * (b - a) + r * d])  # on the surface
    inside = np.linalg.norm(pts[:, None, :] - centres[None], axis=2) <= radii[None] + 1e-9
    assert inside.any(axis=1).all()


def test_presets_have_the_papers_counts(lwr) -> None:
    exp3 = ControlPointSet.build(lwr, "icra-exp3")
    ral = ControlPointSet.build(lwr, "ral-9")
    assert exp3.n_points == 6 and exp3.names[0] == "ee"  # EE + 5 on arm and forearm
    assert ral.n_points == 9 and ral.names[0] == "ee"
    assert not any(n.startswith(("lwr_link_0", "lwr_link_1")) for n in exp3.names)


def test_configurable_counts_and_errors(lwr) -> None:
    s = ControlPointSet.build(lwr, {"lwr_link_3": 4, "lwr_link_5": 3})
    assert s.n_points == 1 + 4 + 3
    with pytest.raises(ValueError, match="preset"):
        ControlPointSet.build(lwr, "nope")
    with pytest.raises(ValueError, match="no collision capsule"):
        ControlPointSet.build(lwr, {"not_a_link": 2})
    with pytest.raises(ValueError, match=">= 1"):
        ControlPointSet.build(lwr, {"lwr_link_3": 0})


def test_points_cover_the_links_they_bound(lwr) -> None:
    q = np.array([0.3, 0.8, -0.4, -1.2, 0.5, 0.9, 0.0])
    st_ = control_points(lwr, q, {"lwr_link_3": 3})
    a, b, r = lwr.link_capsules(q)
    k = [c.link for c in lwr.capsules].index("lwr_link_3")
    rng = np.random.default_rng(1)
    t = rng.uniform(0, 1, 400)
    d = rng.normal(size=(400, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    surface = a[k] + t[:, None] * (b[k] - a[k]) + r[k] * d  # points of the capsule, some on its surface
    dist = np.linalg.norm(surface[:, None] - st_.centres[None, 1:], axis=2) - st_.radii[None, 1:]
    assert np.all(dist.min(axis=1) <= 1e-9)
    _, ee = lwr.frame_pose(q)
    np.testing.assert_allclose(st_.centres[0], ee, atol=1e-12)


@pytest.mark.parametrize("seed", range(3))
def test_point_jacobians_match_finite_differences(lwr, seed: int) -> None:
    cps = ControlPointSet.build(lwr, "ral-9")
    rng = np.random.default_rng(seed)
    q = rng.uniform(lwr.q_min, lwr.q_max) * 0.9
    s0 = cps.evaluate(q)
    assert s0.jacobians.shape == (9, 3, 7)
    h = 1e-6
    for i in range(7):
        dq = np.zeros(7)
        dq[i] = h
        fd = (cps.evaluate(q + dq).centres - cps.evaluate(q - dq).centres) / (2 * h)
        np.testing.assert_allclose(s0.jacobians[:, :, i], fd, atol=1e-6)


def test_joints_after_a_point_do_not_move_it(lwr) -> None:
    cps = ControlPointSet.build(lwr, "ral-9")
    s = cps.evaluate(np.full(7, 0.3))
    i = s.names.index("lwr_link_3/0")  # on link 3: joints 4-7 cannot move it
    assert np.all(s.jacobians[i][:, 3:] == 0.0)
