"""Robot-to-octree distance: spheres and capsules against brute force over all node boxes, and against coal."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from depthguard.octree.distance import capsule_distances, sphere_distances
from depthguard.octree.grid import VoxelBox

BOX = VoxelBox.around([-0.5, -0.5, 0.0], [0.5, 0.5, 0.8], 0.05)


def random_occupancy(seed: int, p: float = 0.01) -> np.ndarray:
    return np.random.default_rng(seed).random(BOX.shape) < p


def brute_point(occ, P):
    """Distances from P (3,) to every occupied node box."""
    lo = BOX.corner_lo(np.argwhere(occ))
    q = np.clip(P, lo, lo + BOX.res)
    return np.linalg.norm(P - q, axis=1), q


def brute_segment(occ, a, b, n=1601):
    lo = BOX.corner_lo(np.argwhere(occ))
    s = np.linspace(0.0, 1.0, n)[:, None]
    pts = a + s * (b - a)
    best = np.inf
    for P in pts:
        q = np.clip(P, lo, lo + BOX.res)
        best = min(best, np.linalg.norm(P - q, axis=1).min())
    return best


@settings(deadline=None, max_examples=60)
@given(seed=st.integers(0, 10_000), x=st.floats(-0.6, 0.6), y=st.floats(-0.6, 0.6), z=st.floats(-0.1, 0.9),
       r=st.floats(0.0, 0.1))  # fmt: skip
@example(seed=130, x=0.55, y=0.0625, z=0.0, r=0.0)  # a node exactly at the reach (fresh seeds found it)
def test_sphere_distance_equals_brute_force(seed, x, y, z, r):
    occ = random_occupancy(seed)
    P = np.array([x, y, z])
    res = sphere_distances(occ, BOX, P[None], r, rho=0.4)
    d, q = brute_point(occ, P)
    within = d < 0.4 + r
    if not within.any():
        assert res.distance[0] == np.inf and res.obstacle_pixels[0] == 0
        return
    assert res.distance[0] == pytest.approx(max(d.min() - r, 0.0), abs=1e-12)
    # (a node at the reach itself counts either way: the two computations differ in the last bit, as
    # seed 130 at (0.55, 0.0625, 0) with a node 0.4 m away showed)
    near_edge = np.abs(d - (0.4 + r)) <= 1e-12
    assert (within & ~near_edge).sum() <= res.obstacle_pixels[0] <= (within | near_edge).sum()
    assert np.linalg.norm(res.direction[0]) == pytest.approx(1.0)
    # the nearest point lies on an occupied node box and at the reported distance
    assert np.linalg.norm(P - res.nearest[0]) == pytest.approx(d.min(), abs=1e-12)


def test_sphere_direction_points_away_from_the_obstacle():
    occ = np.zeros(BOX.shape, bool)
    occ[10, 10, 5] = True  # node [0, 0.05] x [0, 0.05] x [0.25, 0.3]
    res = sphere_distances(occ, BOX, np.array([[0.025, 0.025, 0.5]]), 0.05, rho=0.4)
    assert res.distance[0] == pytest.approx(0.5 - 0.3 - 0.05)
    np.testing.assert_allclose(res.direction[0], [0, 0, 1], atol=1e-12)
    for mode in ("all", "hybrid"):
        r2 = sphere_distances(occ, BOX, np.array([[0.025, 0.025, 0.5]]), 0.05, rho=0.4, mode=mode)
        np.testing.assert_allclose(r2.direction[0], [0, 0, 1], atol=1e-12)


@settings(deadline=None, max_examples=25)
@given(seed=st.integers(0, 10_000), pts=st.lists(st.floats(-0.6, 0.9), min_size=6, max_size=6),
       r=st.floats(0.0, 0.1))  # fmt: skip
def test_capsule_distance_is_a_tight_lower_bound_of_brute_force(seed, pts, r):
    occ = random_occupancy(seed, 0.005)
    a, b = np.array(pts[:3]), np.array(pts[3:])
    res = capsule_distances(occ, BOX, a[None], b[None], np.array([r]), rho=0.4)
    ref = brute_segment(occ, a, b)  # >= the true distance, by at most half a sample step
    step = np.linalg.norm(b - a) / 1600
    if ref - r >= 0.4 + step:
        assert res.distance[0] == np.inf
        return
    if res.distance[0] == np.inf:
        assert ref - r >= 0.4 - step
        return
    assert res.distance[0] <= max(ref - r, 0.0) + 1e-9
    assert res.distance[0] >= max(ref - r, 0.0) - step - 1e-9


def test_capsule_distance_matches_coal_box_by_box():
    """Regression test against FCL's successor: capsule vs every occupied node box (exact GJK)."""
    coal = pytest.importorskip("coal")
    occ = random_occupancy(7, 0.004)
    rng = np.random.default_rng(1)
    for _ in range(5):
        a = rng.uniform([-0.3, -0.3, 0.2], [0.3, 0.3, 0.6])
        b = a + rng.normal(size=3) * 0.2
        r = 0.05
        res = capsule_distances(occ, BOX, a[None], b[None], np.array([r]), rho=0.4)
        # coal's capsule is along z, centred: rotate z onto b - a
        axis = (b - a) / np.linalg.norm(b - a)
        z = np.array([0.0, 0.0, 1.0])
        v = np.cross(z, axis)
        c = float(z @ axis)
        K = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
        Rm = np.eye(3) + K + K @ K / (1 + c)
        cap = coal.Capsule(r, float(np.linalg.norm(b - a)))
        Tc = coal.Transform3s(Rm, 0.5 * (a + b))
        best = np.inf
        for lo in BOX.corner_lo(np.argwhere(occ)):
            box = coal.Box(BOX.res, BOX.res, BOX.res)
            Tb = coal.Transform3s(np.eye(3), lo + 0.5 * BOX.res)
            d = coal.distance(cap, Tc, box, Tb, coal.DistanceRequest(), coal.DistanceResult())
            best = min(best, max(d, 0.0))
        if best >= 0.4:
            assert res.distance[0] == np.inf or res.distance[0] >= 0.4 - 1e-6
        else:
            assert res.distance[0] == pytest.approx(best, abs=1e-6)


def test_bad_input_names_the_field():
    occ = np.zeros(BOX.shape, bool)
    with pytest.raises(ValueError, match="occupied grid"):
        sphere_distances(np.zeros((2, 2, 2), bool), BOX, np.zeros((1, 3)))
    with pytest.raises(ValueError, match="centres"):
        sphere_distances(occ, BOX, np.full((1, 3), np.nan))
    with pytest.raises(ValueError, match="rho"):
        sphere_distances(occ, BOX, np.zeros((1, 3)), rho=-1)
    with pytest.raises(ValueError, match="mode"):
        sphere_distances(occ, BOX, np.zeros((1, 3)), mode="max")
    with pytest.raises(ValueError, match="capsule b"):
        capsule_distances(occ, BOX, np.zeros((2, 3)), np.zeros((1, 3)), np.zeros(2))
