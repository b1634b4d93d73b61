"""Property tests of the fusion over random scenes and camera placements (ground truth: exact distances).

* fused >= single-camera - tolerance (fusion only removes gray area);
* fused <= truth + tolerance (no obstacle is lost; a distance is a lower bound);
* adding a camera never raises a distance beyond the truth, and lowers it at most by the declared
  per-point frustum slack (it can only clear cells); the modes give identical distances;
* the stored and the on-the-fly map give identical answers.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from depthguard.camera import Camera, look_at
from depthguard.depthgrid import DepthGridFusion
from depthguard.depthspace import prepare_frame, query_distances
from depthguard.scene import Box, Capsule, HalfSpace, Scene, Sphere, render_depth

RHO = 0.4
WORKSPACE = (-1.0, 1.0, -1.0, 1.0, -0.2, 1.6)
ROOM = (
    HalfSpace(np.array([0.0, 0.0, -0.5]), np.array([0.0, 0.0, 1.0])),
    HalfSpace(np.array([-3.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0])),
    HalfSpace(np.array([3.0, 0.0, 0.0]), np.array([-1.0, 0.0, 0.0])),
    HalfSpace(np.array([0.0, -3.0, 0.0]), np.array([0.0, 1.0, 0.0])),
    HalfSpace(np.array([0.0, 3.0, 0.0]), np.array([0.0, -1.0, 0.0])),
)


def random_camera(rng: np.random.Generator, azimuth: float, w=120, h=90, f=100.0) -> Camera:
    dist = rng.uniform(1.8, 2.5)
    eye = np.array([dist * np.cos(azimuth), dist * np.sin(azimuth), rng.uniform(0.6, 2.2)])
    target = np.array([rng.uniform(-0.2, 0.2), rng.uniform(-0.2, 0.2), rng.uniform(0.4, 1.0)])
    R, t = look_at(eye, target)
    return Camera(
        width=w,
        height=h,
        fx=f,
        fy=f * rng.uniform(0.95, 1.05),
        cx=w / 2 + rng.uniform(-3, 3),
        cy=h / 2 + rng.uniform(-3, 3),
        R=R,
        t=t,
        min_depth=0.3,
        max_depth=6.0,
    )


def random_scene(rng: np.random.Generator) -> Scene:
    prims = []
    for _ in range(rng.integers(1, 4)):
        c = rng.uniform([-0.6, -0.6, 0.2], [0.6, 0.6, 1.4])
        kind = rng.integers(0, 3)
        if kind == 0:
            prims.append(Sphere(c, rng.uniform(0.08, 0.25)))
        elif kind == 1:
            prims.append(Capsule(c, c + rng.uniform(-0.4, 0.4, 3), rng.uniform(0.06, 0.15)))
        else:
            q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
            q *= np.sign(np.linalg.det(q))
            prims.append(Box(c, rng.uniform(0.06, 0.25, 3), q))
    return Scene((*prims, *ROOM))


def setup(seed: int):
    rng = np.random.default_rng(seed)
    az0 = rng.uniform(0, 2 * np.pi)
    cams = [
        random_camera(rng, az0),
        random_camera(rng, az0 + rng.uniform(1.2, 2.2)),
        random_camera(rng, az0 + rng.uniform(-2.6, -1.4), w=100, h=80, f=85.0),
    ]
    scene = random_scene(rng)
    depths = [render_depth(c, scene) for c in cams]
    if rng.random() < 0.5:  # dropouts: filled or unknown, never free
        for d in depths:
            d[rng.random(d.shape) < 0.05] = np.nan
    P = rng.uniform([-0.7, -0.7, 0.1], [0.7, 0.7, 1.5], size=(12, 3))
    radii = rng.uniform(0.0, 0.1, 12)
    return cams, scene, depths, P, radii


def check_upper(fused, truth, tol):
    """fused <= truth + tol, where inf means 'nothing within ρ'."""
    found = np.isfinite(fused)
    assert np.all(fused[found] <= truth[found] + tol[found]), (fused, truth, tol)
    assert np.all(truth[~found] + tol[~found] >= RHO), (fused, truth, tol)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), mode=st.sampled_from(["min", "all"]))
def test_fusion_bounds(seed, mode):
    cams, scene, depths, P, radii = setup(seed)
    truth = np.maximum(scene.distance(P) - radii, 0.0)
    single = query_distances(prepare_frame(cams[0], depths[0]), P, radii, rho=RHO, mode=mode).distance

    f2 = DepthGridFusion(cams[:2], dd=0.01, workspace=WORKSPACE)
    f2.update(depths[:2])
    d2 = f2.query(P, radii, rho=RHO, mode=mode).distance
    tol2 = f2.tolerance(P, RHO)

    f3 = DepthGridFusion(cams, dd=0.01, workspace=WORKSPACE)
    f3.update(depths)
    d3 = f3.query(P, radii, rho=RHO, mode=mode).distance
    tol3 = f3.tolerance(P, RHO)

    assert np.all(d2 >= single - tol2)
    check_upper(d2, truth, tol2)
    check_upper(d3, truth, tol3)
    # a third camera can only clear cells, so each column's nearest occupied segment can only move away
    # from P; the reported bound D = d_ray - h min(hi, d_p + d_ray) of that segment may still drop by up to
    # the frustum slack h (d_p + d_ray) of the point, d_ray <= (ρ + r + h d_p) / (1 - h) for any segment
    # within reach (the same slack as depthspace.lower_bound_slack, per point)
    pz = np.maximum(cams[0].world_to_camera(P)[:, 2], 0.0)
    h = 0.5 * np.sqrt(cams[0].fx ** -2 + cams[0].fy ** -2)
    slack = h * (pz + (RHO + radii + h * pz) / (1.0 - h)) + 1e-12
    both = np.isfinite(d2)
    assert np.all(~np.isfinite(d3) | both | (d3 >= RHO - slack))
    assert np.all(d3[both] >= d2[both] - slack[both])
    # the distance does not depend on the aggregation mode: exactly (min mode prunes only tiles and
    # segments whose bound is at least the best distance so far)
    other = f3.query(P, radii, rho=RHO, mode="min" if mode == "all" else "all").distance
    np.testing.assert_array_equal(other, d3)
    np.testing.assert_array_equal(f3.query(P, radii, rho=RHO, mode="hybrid").distance, d3)


@settings(max_examples=4, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1))
def test_stored_and_on_the_fly_maps_agree(seed, tmp_path_factory):
    cams, scene, depths, P, radii = setup(seed)
    cache = tmp_path_factory.mktemp("gridmap")
    fly = DepthGridFusion(cams, dd=0.02, workspace=WORKSPACE, map_mode="onthefly")
    stored = DepthGridFusion(cams, dd=0.02, workspace=WORKSPACE, map_mode="stored", cache_dir=cache)
    for f in (fly, stored):
        f.update(depths)
    for mode in ("min", "all", "hybrid"):
        a = fly.query(P, radii, rho=RHO, mode=mode)
        b = stored.query(P, radii, rho=RHO, mode=mode)
        for x, y in zip(a, b, strict=True):
            assert np.array_equal(x, y, equal_nan=True)
        assert np.array_equal(fly.last_cells, stored.last_cells)


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1))
def test_fusion_never_claims_free_what_no_camera_saw_free(seed):
    """fused <= measured bound + tolerance, with two and three cameras: the measured bound
    (depthguard.sim.measured_bound, an independent lattice search) is the distance to the space that no
    camera sees free or that some camera measures. Stronger than the truth check where space is unseen:
    there the truth may be far while the bound is near."""
    from depthguard.sim.measured_bound import measured_bound, measured_views

    cams, _, depths, P, radii = setup(seed)
    # one camera, the depth space (RA-L'16 §II-IV): its tolerance is one pixel footprint at d_p + rho
    single = np.minimum(query_distances(prepare_frame(cams[0], depths[0]), P, radii, rho=RHO, mode="min").distance, RHO)
    tol1 = (np.maximum(cams[0].world_to_camera(P)[:, 2], 0.0) + RHO) / min(cams[0].fx, cams[0].fy)
    bound1 = measured_bound(measured_views(cams[:1], depths[:1], [np.zeros(cams[0].shape, bool)]), P, radii, RHO)
    assert np.all(single <= bound1 + tol1), (single, bound1, tol1)
    for n in (2, 3):
        f = DepthGridFusion(cams[:n], dd=0.01, workspace=WORKSPACE)
        f.update(depths[:n])
        fused = np.minimum(f.query(P, radii, rho=RHO, mode="min").distance, RHO)
        tol = f.tolerance(P, RHO)
        views = measured_views(cams[:n], depths[:n], [np.zeros(c.shape, bool) for c in cams[:n]])
        bound = measured_bound(views, P, radii, RHO)
        assert np.all(fused <= bound + tol), (n, fused, bound, tol)


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1))
def test_update_beside_a_side_thread_gives_the_same_answers(seed):
    """``update(side=...)`` (the secondary part on a worker thread, a principal correction on this one)
    answers bit for bit as the plain update; an error in the secondary part raises and leaves no answer."""
    from concurrent.futures import ThreadPoolExecutor

    cams, _, depths, P, radii = setup(seed)
    rng = np.random.default_rng(seed)
    masks = [rng.random(c.shape) < 0.05 for c in cams]
    windows = [None] + [
        (np.full(c.shape, 1.0, np.float32), np.full(c.shape, 1.0 + rng.uniform(0, 1), np.float32)) for c in cams[1:]
    ]

    def principal(d, m):  # some correction of the principal frame (here: drop the mask's first rows)
        m = m.copy()
        m[:5] = False
        return d, m

    plain = DepthGridFusion(cams, dd=0.01, workspace=WORKSPACE)
    d0, m0 = principal(depths[0], masks[0])
    plain.update([d0, *depths[1:]], [m0, *masks[1:]], windows=windows)
    side = DepthGridFusion(cams, dd=0.01, workspace=WORKSPACE)
    with ThreadPoolExecutor(max_workers=1) as ex:
        side.update(depths, masks, windows=lambda: windows, side=ex, principal=principal)
        for mode in ("min", "hybrid"):
            a, b = plain.query(P, radii, rho=RHO, mode=mode), side.query(P, radii, rho=RHO, mode=mode)
            np.testing.assert_array_equal(a.distance, b.distance)
            np.testing.assert_array_equal(a.direction, b.direction)
        bad = [None, (np.zeros((3, 3), np.float32), np.zeros((3, 3), np.float32)), None]
        with pytest.raises(ValueError, match="windows"):
            side.update(depths, masks, windows=lambda: bad, side=ex, principal=principal)
        with pytest.raises(RuntimeError, match="update"):
            side.query(P, radii, rho=RHO)
