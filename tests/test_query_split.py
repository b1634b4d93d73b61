"""The depth grid's query shared with a side thread (``DepthGridFusion.query(side=...)``): the image's tile
rows dealt into parts, merged (``kernels.hits.merge_hits``), against the query on one thread.

The distances and counts must be bit for bit those of the one-thread query (each piece is visited once,
by one part; the unseen space by part 0), whatever the number of parts, the mode, the direction lattice
and the column cache; the directions agree to rounding (the sums are added in another order).
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from depthguard.depthgrid import DepthGridFusion
from depthguard.depthgrid import fusion as fusion_module
from depthguard.kernels.hits import merge_hits
from test_depthgrid_properties import RHO, WORKSPACE, setup


@pytest.fixture(scope="module")
def side():
    with ThreadPoolExecutor(1) as ex:
        yield ex


@settings(
    max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture]
)
@given(
    seed=st.integers(0, 2**32 - 1),
    parts=st.sampled_from([2, 3, 4, 7]),
    stride=st.sampled_from([1, 2, 3]),
    cached=st.booleans(),
)
def test_split_query_answers_as_the_one_thread_query(seed, parts, stride, cached, side, monkeypatch):
    cams, _, depths, P, radii = setup(seed)
    rng = np.random.default_rng(seed)
    masks = [rng.random(c.shape) < 0.05 for c in cams]
    P = np.vstack([P, cams[0].camera_to_world(np.array([[0.0, 0.0, 0.1]]))])  # (one in the unseen space)
    radii = np.append(radii, 0.05)
    one = DepthGridFusion(cams, dd=0.01, workspace=WORKSPACE)
    one.update(depths, masks)
    one.column_cache = False
    split = DepthGridFusion(cams, dd=0.01, workspace=WORKSPACE)
    split.update(depths, masks)
    split.column_cache = cached
    monkeypatch.setattr(fusion_module, "QUERY_PARTS", parts)
    for mode in ("min", "all", "hybrid"):
        for _ in range(2):  # (the second time on the column cache that the first filled)
            a = one.query(P, radii, rho=RHO, mode=mode, direction_stride=stride)
            b = split.query(P, radii, rho=RHO, mode=mode, direction_stride=stride, side=side)
            np.testing.assert_array_equal(a.distance, b.distance)
            if mode == "min":  # (the count of min mode depends on the pruning, and the nearest piece on the
                # order of visit where several lie at the same distance: 0 inside an obstacle)
                apart = a.distance > 0
                np.testing.assert_allclose(a.direction[apart], b.direction[apart], atol=1e-9)
                np.testing.assert_allclose(a.nearest[apart], b.nearest[apart], atol=1e-9)
            else:
                np.testing.assert_array_equal(a.obstacle_pixels, b.obstacle_pixels)
                np.testing.assert_allclose(a.direction, b.direction, atol=1e-9)


def test_merge_takes_the_nearest_part_and_adds_the_sums():
    """Two parts of one sphere by hand: part 1 holds the nearer piece, part 0 ties part 1 on a second sphere."""
    rows = np.zeros((2, 2, 13))
    rows[0, 0] = [0.5, 1, 0, 0, 1, 1, 1, 2, 1.0, 0.0, 0.0, 3, 4]
    rows[1, 0] = [0.2, 0, 1, 0, 2, 2, 2, 1, 0.0, 3.0, 0.0, 5, 6]
    rows[0, 1] = [0.3, 1, 0, 0, 7, 7, 7, 1, 0.0, 0.0, 2.0, 0, 0]
    rows[1, 1] = [0.3, 0, 1, 0, 8, 8, 8, 1, 0.0, 0.0, 2.0, 0, 0]
    out = merge_hits(rows, 2, 2)  # hybrid, lattice stride 2
    np.testing.assert_allclose(out[0], [0.2, 1 / 10**0.5, 3 / 10**0.5, 0, 2, 2, 2, 3 * 4, 8, 10])
    np.testing.assert_allclose(out[1, :7], [0.3, 0, 0, 1, 7, 7, 7])  # (the tie: part 0's piece)
    out = merge_hits(rows, 0, 2)  # min: the nearest piece's direction, the count unscaled
    np.testing.assert_allclose(out[0, :8], [0.2, 0, 1, 0, 2, 2, 2, 3])


def test_split_query_of_no_sphere_and_of_a_bad_sphere(side):
    """No sphere: an empty answer, as on one thread; a bad centre: the same error as on one thread."""
    cams, _, depths, _, _ = setup(7)
    fusion = DepthGridFusion(cams, dd=0.01, workspace=WORKSPACE)
    fusion.update(depths)
    empty = fusion.query(np.zeros((0, 3)), np.zeros(0), rho=RHO, mode="hybrid", side=side)
    assert empty.distance.shape == (0,)
    for bad in (np.array([[0.1, np.nan, 0.5]]), np.array([[0.1, 0.2]])):
        with pytest.raises(ValueError) as one:
            fusion.query(bad, 0.05, rho=RHO)
        with pytest.raises(ValueError) as shared:
            fusion.query(bad, 0.05, rho=RHO, side=side)
        assert str(one.value) == str(shared.value)


@pytest.mark.skipif(
    not hasattr(os, "sched_setaffinity") or len(os.sched_getaffinity(0)) < 2,
    reason="needs Linux CPU affinity and at least two allowed CPUs",
)
def test_the_distance_stage_shares_its_query_on_two_cpus_and_big_images_only(monkeypatch):
    """``DistanceStage.query`` hands the fusion a side executor where this thread may use two CPUs and the
    principal image is big enough; none on one allowed CPU (``taskset``: the two threads would only take
    turns) or for a small image; and answers the same either way."""
    from depthguard.sim import pipeline
    from depthguard.sim.pipeline import DistanceStage

    cams, _, depths, P, radii = setup(11)
    stage = DistanceStage(cams[:2], rho=RHO, mode="hybrid", workspace=WORKSPACE)
    stage.update(depths[:2], [None, None])
    sides = []
    query = stage.fusion.query

    def spy(*args, side=None, **kw):
        sides.append(side)
        return query(*args, side=side, **kw)

    monkeypatch.setattr(stage.fusion, "query", spy)
    small = stage.query(P, radii)  # (120x90: below SHARED_QUERY_MIN_PIXELS)
    monkeypatch.setattr(pipeline, "SHARED_QUERY_MIN_PIXELS", 120 * 90)
    shared = stage.query(P, radii)
    before = os.sched_getaffinity(0)
    try:
        os.sched_setaffinity(0, {min(before)})
        alone = stage.query(P, radii)
    finally:
        os.sched_setaffinity(0, before)
    assert sides[0] is None and sides[1] is not None and sides[2] is None
    np.testing.assert_array_equal(shared.distance, alone.distance)
    np.testing.assert_array_equal(shared.distance, small.distance)


@settings(max_examples=60, deadline=None)
@given(
    k=st.integers(1, 5),
    n=st.integers(0, 6),
    mode=st.sampled_from([0, 1, 2]),
    stride=st.integers(1, 3),
    seed=st.integers(0, 2**32 - 1),
)
def test_merge_against_a_plain_reference(k, n, mode, stride, seed):
    """``merge_hits`` on random parts (distances from a few values, so that parts tie) against numpy: the
    first part with the smallest distance gives the direction and nearest point, the rest adds up."""
    rng = np.random.default_rng(seed)
    rows = rng.normal(size=(k, n, 13))
    rows[:, :, 0] = rng.choice([0.0, 0.1, 0.25, 0.5], size=(k, n))
    rows[:, :, 7] = rng.integers(0, 50, size=(k, n))
    rows[:, :, 11:] = rng.integers(0, 1000, size=(k, n, 2))
    out = merge_hits(rows, mode, stride)
    assert out.shape == (n, 10)
    for i in range(n):
        j = int(np.argmin(rows[:, i, 0]))  # (numpy's argmin: the first of equal minima)
        s = rows[:, i, 8:11].sum(axis=0)
        nrm = np.linalg.norm(s)
        direction = rows[j, i, 1:4] if mode == 0 or nrm <= 1e-9 else s / nrm
        count = rows[:, i, 7].sum() * (stride * stride if mode != 0 else 1)
        expected = [rows[j, i, 0], *direction, *rows[j, i, 4:7], count, *rows[:, i, 11:13].sum(axis=0)]
        np.testing.assert_allclose(out[i], expected, rtol=1e-12, atol=1e-12)
