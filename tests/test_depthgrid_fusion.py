"""On-line fusion (RA-L'16 §VI-VII): shadow and hidden obstacles, the vote, one-camera reduction.

Ground truth comes from the exact distances of :mod:`depthguard.scene`, never from this code.
"""

from __future__ import annotations

import numpy as np
import pytest

from depthguard.camera import Camera, look_at
from depthguard.depthgrid import DepthGridFusion, fused_distances
from depthguard.depthspace import prepare_frame, query_distances
from depthguard.scene import Box, HalfSpace, Scene, Sphere, render_depth

WORKSPACE = (-1.5, 1.5, -1.5, 1.5, -0.5, 1.5)
WALLS = (
    HalfSpace(np.array([-2.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0])),  # faces the principal camera
    HalfSpace(np.array([0.0, -2.0, 0.0]), np.array([0.0, 1.0, 0.0])),  # faces the second camera
    HalfSpace(np.array([0.0, 0.0, -0.5]), np.array([0.0, 0.0, 1.0])),  # floor
)


def camera(eye, target, w=160, h=120, f=131.25) -> Camera:
    R, t = look_at(eye, target)
    return Camera(width=w, height=h, fx=f, fy=f, cx=w / 2 - 0.5, cy=h / 2 - 0.5, R=R, t=t, min_depth=0.3, max_depth=6.0)


def two_cameras():
    return [camera([2.0, 0.0, 1.0], [0.0, 0.0, 1.0]), camera([0.0, 2.0, 1.2], [0.0, 0.0, 0.9])]


def robot_mask(cam: Camera, robot: Scene, full: Scene) -> tuple[np.ndarray, np.ndarray]:
    """Depth of the full scene and the mask of the pixels where the robot is what the camera sees."""
    d_all = render_depth(cam, full)
    d_robot = render_depth(cam, robot)
    mask = np.isfinite(d_robot) & (d_robot <= d_all + 1e-9)
    return d_all, mask


# ----------------------------------------------------------------------------------- Figs. 8 and 12
def test_shadow_obstacle_is_cleared_by_the_second_camera():
    """An obstacle 0.3 m in front of P (seen from the principal camera) puts P in its shadow."""
    cams = two_cameras()
    P = np.array([[0.0, 0.0, 1.0]])
    obstacle = Sphere(np.array([0.4, 0.0, 1.0]), 0.1)  # between the principal camera and P, 0.3 m from P
    scene = Scene((obstacle, *WALLS))
    truth = scene.distance(P)[0]
    assert truth == pytest.approx(0.3)
    depths = [render_depth(c, scene) for c in cams]

    single = query_distances(prepare_frame(cams[0], depths[0]), P, 0.0, rho=0.4, mode="min")
    assert single.distance[0] < 0.02  # one camera: P sits in the gray area

    for mode in ("min", "all", "hybrid"):
        fusion = DepthGridFusion(cams, dd=0.01, workspace=WORKSPACE)
        fusion.update(depths)
        res = fusion.query(P, 0.0, rho=0.4, mode=mode)
        tol = fusion.tolerance(P)[0]
        assert truth - tol <= res.distance[0] <= truth + 1e-9, mode
        # the repulsion points away from the obstacle, i.e. mostly along -x
        assert res.direction[0, 0] < -0.8, mode
        assert np.linalg.norm(res.nearest[0] - np.array([0.3, 0.0, 1.0])) < 0.03, mode


def test_shadow_stays_when_the_second_camera_is_blind():
    """Missing pixels in the secondary camera never clear a cell (DESIGN.md §5.2)."""
    cams = two_cameras()
    P = np.array([[0.0, 0.0, 1.0]])
    scene = Scene((Sphere(np.array([0.4, 0.0, 1.0]), 0.1), *WALLS))
    depths = [render_depth(c, scene) for c in cams]
    depths[1][:] = np.nan
    fusion = DepthGridFusion(cams, dd=0.01, workspace=WORKSPACE)
    fusion.update(depths)
    assert fusion.query(P, 0.0, mode="min").distance[0] < 0.02
    # with the "ignore" policy a missing pixel is free space, as the caller asked
    fusion.update(depths, invalid="ignore")
    assert fusion.query(P, 0.0, mode="min").distance[0] > 0.25


# ----------------------------------------------------------------------------------- Figs. 9 and 13
def hidden_obstacle_setup():
    cams = two_cameras()
    robot = Scene((Box(np.array([0.5, 0.0, 1.0]), np.array([0.1, 0.3, 0.3])),))
    hand = Sphere(np.array([0.0, 0.0, 1.0]), 0.1)  # behind the robot link, seen from the principal camera
    full = Scene((*robot.primitives, hand, *WALLS))
    P = np.array([[0.3, 0.0, 1.0]])  # a control point on the back of the link
    depths, masks = zip(*(robot_mask(c, robot, full) for c in cams), strict=True)
    return cams, list(depths), list(masks), Scene((hand, *WALLS)), P


def test_hidden_obstacle_behind_the_robot_is_found():
    cams, depths, masks, obstacles, P = hidden_obstacle_setup()
    truth = obstacles.distance(P)[0]
    assert truth == pytest.approx(0.2)
    single = query_distances(prepare_frame(cams[0], depths[0], masks[0]), P, 0.0, rho=0.4, mode="min")
    assert single.distance[0] > truth + 0.1  # the principal camera alone misses the hand
    for mode in ("min", "all"):
        fusion = DepthGridFusion(cams, dd=0.01, workspace=WORKSPACE)
        fusion.update(depths, masks)
        res = fusion.query(P, 0.0, rho=0.4, mode=mode)
        tol = fusion.tolerance(P)[0]
        assert truth - tol <= res.distance[0] <= truth + 1e-9, mode
        assert res.direction[0, 0] > 0.8, mode  # away from the hand, along +x
    # without a second camera nothing confirms an obstacle behind the robot (case iv), as for one camera
    blind = DepthGridFusion(cams[:1], dd=0.01, workspace=WORKSPACE)
    blind.update(depths[:1], masks[:1])
    assert blind.query(P, 0.0, mode="min").distance[0] > truth + 0.1
    # a second camera that cannot see there (missing pixels = unknown) keeps it occupied: safe
    blind2 = DepthGridFusion(cams, dd=0.01, workspace=WORKSPACE)
    blind2.update([depths[0], np.full_like(depths[1], np.nan)], masks)
    assert blind2.query(P, 0.0, mode="min").distance[0] < 0.02


def test_robot_pixel_without_depth_is_checked_from_the_near_limit():
    cams, depths, masks, obstacles, P = hidden_obstacle_setup()
    depths[0] = np.where(masks[0], np.nan, depths[0])  # the robot is masked but has no reading
    fusion = DepthGridFusion(cams, dd=0.01, workspace=WORKSPACE)
    fusion.update(depths, masks)
    res = fusion.query(P, 0.0, rho=0.4, mode="min")
    tol = fusion.tolerance(P)[0]
    assert 0.2 - tol <= res.distance[0] <= 0.2 + 1e-9


def test_robot_in_the_secondary_camera_sees_past_unless_robot_occludes():
    """DESIGN.md §4: a secondary robot pixel never confirms an obstacle. So space hidden by an obstacle
    from the principal camera and by the robot from the other camera is free by default (the documented
    limit), and an obstacle (gray area) with ``robot_occludes=True``."""
    cams = two_cameras()
    P = np.array([[0.0, 0.0, 1.0]])
    obstacle = Sphere(np.array([0.4, 0.0, 1.0]), 0.1)  # shadows P from the principal camera
    robot = Scene((Box(np.array([0.0, 0.5, 1.0]), np.array([0.3, 0.05, 0.3])),))  # hides P from camera 2
    full = Scene((obstacle, *robot.primitives, *WALLS))
    depths, masks = zip(*(robot_mask(c, robot, full) for c in cams), strict=True)
    masks = [np.zeros_like(masks[0]), masks[1]]  # the robot is not in the principal camera's way
    free = DepthGridFusion(cams, dd=0.01, workspace=WORKSPACE)
    free.update(list(depths), masks)
    assert free.query(P, 0.0, mode="min").distance[0] > 0.25
    occl = DepthGridFusion(cams, dd=0.01, workspace=WORKSPACE, robot_occludes=True)
    occl.update(list(depths), masks)
    assert occl.query(P, 0.0, mode="min").distance[0] < 0.02


def test_vote_margin_only_lowers_distances():
    cams, depths, masks, obstacles, P = hidden_obstacle_setup()
    rng = np.random.default_rng(7)
    Q = np.concatenate([P, rng.uniform([-0.3, -0.5, 0.5], [0.8, 0.5, 1.5], size=(20, 3))])
    plain = DepthGridFusion(cams, dd=0.01, workspace=WORKSPACE)
    careful = DepthGridFusion(cams, dd=0.01, workspace=WORKSPACE, vote_margin=0.03)
    for f in (plain, careful):
        f.update(depths, masks)
    a = plain.query(Q, 0.0, mode="min").distance
    b = careful.query(Q, 0.0, mode="min").distance
    assert np.all(b <= a + 1e-3)
    assert np.any(b < a - 0.005)
    with pytest.raises(ValueError, match="vote_margin"):
        DepthGridFusion(cams, vote_margin=-0.01)


@pytest.mark.slow  # compiles the parallel kernel (about 10 s the first time)
def test_parallel_query_gives_the_same_answers():
    cams, depths, masks, _, _ = hidden_obstacle_setup()
    rng = np.random.default_rng(6)
    P = rng.uniform([-0.3, -0.5, 0.5], [0.8, 0.5, 1.5], size=(16, 3))
    serial = DepthGridFusion(cams, dd=0.01, workspace=WORKSPACE)
    par = DepthGridFusion(cams, dd=0.01, workspace=WORKSPACE, parallel=True)
    for f in (serial, par):
        f.update(depths, masks)
    for mode in ("min", "all", "hybrid"):
        for a, b in zip(serial.query(P, 0.05, mode=mode), par.query(P, 0.05, mode=mode), strict=True):
            assert np.array_equal(a, b, equal_nan=True)


def test_vote_needs_d_end_not_d_start():
    """The paper's confirmation test d_o^k < d_start^k would clear the cell holding the hand's surface.

    Take the cell of the principal grid, behind the masked robot, that contains the point of the hand
    nearest to P, and the second camera's pixels that see it: camera 2 measures the hand *inside* the
    cell (d_start <= d_o <= d_end), so the paper's test says "not confirmed" and the cell would be free;
    the d_end test keeps it occupied and fusion finds the hand.
    """
    cams, depths, masks, obstacles, P = hidden_obstacle_setup()
    fusion = DepthGridFusion(cams, dd=0.01, workspace=WORKSPACE)
    fusion.update(depths, masks)
    O = np.array([0.1 / np.sqrt(2.0), 0.1 / np.sqrt(2.0), 1.0])
    assert obstacles.distance(O[None])[0] < 1e-9  # on the hand's surface, facing both P and camera 2
    px, py, d = cams[0].project(O)
    u, v, g = int(px), int(py), int(fusion.grid.r(d))
    fp = fusion.map.footprint(0, u, v, g)
    assert fp is not None
    seen = depths[1][fp["v"][0] : fp["v"][1] + 1, fp["u"][0] : fp["u"][1] + 1]
    inside = (seen >= fp["d_start"]) & (seen <= fp["d_end"])
    assert inside.any()
    paper_confirms = bool(np.all(seen < fp["d_start"]))
    conservative_clears = bool(np.all(seen > fp["d_end"]))
    assert not paper_confirms  # the paper would call the cell free ...
    assert not conservative_clears  # ... the d_end test does not
    from depthguard.depthgrid.records import Grid
    from depthguard.depthgrid.votes import cell_occupied

    g_ = fusion.grid
    grid = Grid(g_.d_min, g_.dd, g_.n_cells)
    occupied = cell_occupied(u, v, g, grid, fusion.map.kernel_args(), fusion._votes, True)
    assert occupied  # and neither does the kernel
    res = fusion.query(P, 0.0, mode="min")
    assert res.distance[0] < 0.21


# ----------------------------------------------------------------------------------- one camera
def test_one_camera_reduces_to_the_single_camera_module():
    cams = two_cameras()
    scene = Scene(
        (Sphere(np.array([0.4, 0.1, 1.0]), 0.12), Box(np.array([-0.3, -0.4, 0.6]), np.array([0.1, 0.2, 0.3])), *WALLS)
    )
    depth = render_depth(cams[0], scene)
    rng = np.random.default_rng(3)
    depth[rng.random(depth.shape) < 0.03] = np.nan  # some holes and unknown pixels
    depth[:10, :10] = np.nan
    P = rng.uniform([-0.8, -0.8, 0.3], [0.8, 0.8, 1.4], size=(40, 3))
    radii = rng.uniform(0.0, 0.1, 40)
    fusion = DepthGridFusion(cams[:1], dd=0.01, workspace=WORKSPACE)
    fusion.update([depth])
    frame = prepare_frame(cams[0], depth)
    for mode in ("min", "all", "hybrid"):
        ref = query_distances(frame, P, radii, rho=0.4, mode=mode)
        res = fusion.query(P, radii, rho=0.4, mode=mode)
        assert np.array_equal(np.isfinite(ref.distance), np.isfinite(res.distance))
        ok = np.isfinite(ref.distance)
        assert ok.sum() > 10
        assert np.all(res.distance[ok] >= ref.distance[ok] - 1e-9)
        # the cell-bounded frustum slack h min(d2, d_p + D) is at most h (ρ + r) below the gray-ray one
        h = 0.5 * np.sqrt(2.0) / cams[0].fx
        assert np.allclose(res.distance[ok], ref.distance[ok], atol=h * 0.5)


def test_one_camera_with_robot_mask_reduces_to_the_single_camera_module():
    cams, depths, masks, _, _ = hidden_obstacle_setup()
    rng = np.random.default_rng(4)
    P = rng.uniform([-0.3, -0.5, 0.5], [0.8, 0.5, 1.5], size=(40, 3))
    fusion = DepthGridFusion(cams[:1], dd=0.01, workspace=WORKSPACE)
    fusion.update(depths[:1], masks[:1])
    ref = query_distances(prepare_frame(cams[0], depths[0], masks[0]), P, 0.02, rho=0.4, mode="min")
    res = fusion.query(P, 0.02, rho=0.4, mode="min")
    assert np.array_equal(np.isfinite(ref.distance), np.isfinite(res.distance))
    ok = np.isfinite(ref.distance)
    assert np.allclose(res.distance[ok], ref.distance[ok], atol=0.5 * 0.5 * np.sqrt(2.0) / cams[0].fx)


def test_missing_pixels_of_a_secondary_camera_never_clear_a_cell():
    """A small dark object (no reading in camera 2) inside the principal camera's shadow stays an obstacle.

    Camera 2 sees a far wall around the object, within the hole-filling radius: filling the hole with the
    wall's depth would let camera 2 clear the cells the object occupies, and report a distance larger
    than the true one.
    """
    cams = two_cameras()
    P = np.array([[0.0, 0.0, 1.0]])
    blocker = Sphere(np.array([0.7, 0.0, 1.0]), 0.1)  # puts P and the dark object in the principal's shadow
    dark = Sphere(np.array([0.15, 0.0, 1.0]), 0.03)  # no reading in camera 2
    full = Scene((blocker, dark, *WALLS))
    true = float(full.distance(P)[0]) - 0.02
    assert 0.09 < true < 0.11
    depths = [render_depth(c, full) for c in cams]
    hole = np.isfinite(render_depth(cams[1], Scene((dark,))))
    assert 4 <= hole.sum() <= 60  # a hole narrower than the fill radius (4 pixels), inside the wall
    depths[1] = depths[1].copy()
    depths[1][hole] = np.nan
    fusion = DepthGridFusion(cams, dd=0.01, workspace=WORKSPACE, fill_radius=4)
    fusion.update(depths)
    for mode in ("min", "all"):
        res = fusion.query(P, 0.02, rho=0.4, mode=mode)
        assert res.distance[0] <= true + 1e-9, mode
    assert np.all(fusion._votes[0, : cams[1].height][hole] == 0.0)


@pytest.mark.parametrize("invalid", ["conservative", "ignore"])
def test_frame_preparation_matches_prepare_frame(invalid):
    """update() prepares each image in one pass; it must agree with depthspace.prepare_frame."""
    from depthguard.depthgrid import records as K

    rng = np.random.default_rng(5)
    cams = two_cameras()
    depths, masks = [], []
    for cam in cams:
        d = rng.uniform(0.6, 4.0, cam.shape).astype(np.float32)
        d[rng.random(cam.shape) < 0.1] = np.nan
        d[rng.random(cam.shape) < 0.02] = 0.0
        d[30:50, 40:70] = np.nan  # a hole too big to fill
        m = rng.random(cam.shape) < 0.05
        m[60:80, 100:120] = True
        depths.append(d)
        masks.append(m)
    fusion = DepthGridFusion(cams, dd=0.05, fill_radius=3)
    fusion.update(depths, masks, invalid=invalid)
    f0 = prepare_frame(cams[0], depths[0], masks[0], invalid=invalid, fill_radius=3)
    f1 = prepare_frame(cams[1], depths[1], masks[1], invalid=invalid, fill_radius=3)
    near = np.float32(cams[0].min_depth)
    missing0 = ~np.isfinite(depths[0]) | (depths[0] <= 0)
    robot_start = np.where(np.isfinite(f0.robot_depth), f0.robot_depth, near if invalid == "conservative" else np.inf)
    start = np.where(f0.robot_mask, robot_start, f0.obstacle_depth)
    kind = np.where(
        f0.robot_mask,
        np.where(np.isfinite(robot_start), K.KIND_ROBOT, K.KIND_NONE),
        # a filled hole is unknown from its fill depth, like an unfillable hole from the near limit
        np.where(np.isinf(f0.obstacle_depth), K.KIND_NONE, np.where(missing0, K.KIND_UNKNOWN, K.KIND_SURFACE)),
    )
    assert np.array_equal(fusion._start, start.astype(np.float32))
    assert np.array_equal(fusion._kind, kind)
    missing1 = ~np.isfinite(depths[1]) | (depths[1] <= 0)
    # a missing secondary pixel is never filled: it clears nothing (votes 0) unless the caller ignores holes
    votes = np.where(missing1 & ~masks[1] & (invalid == "conservative"), 0.0, f1.obstacle_depth)
    assert np.array_equal(fusion._votes[0, : cams[1].height], votes.astype(np.float32))
    assert (kind == K.KIND_UNKNOWN).sum() > 0 if invalid == "conservative" else True


def test_fused_distances_helper_and_errors():
    cams = two_cameras()
    P = np.array([[0.0, 0.0, 1.0]])
    scene = Scene((Sphere(np.array([0.4, 0.0, 1.0]), 0.1), *WALLS))
    depths = [render_depth(c, scene) for c in cams]
    two = fused_distances(cams, depths, None, P, 0.05, rho=0.4, mode="min", dd=0.01, workspace=WORKSPACE)
    assert 0.2 < two.distance[0] <= 0.25 + 1e-9
    one = fused_distances(cams[:1], depths[:1], None, P, 0.05, rho=0.4, mode="min")
    assert one.distance[0] == 0.0
    fusion = DepthGridFusion(cams)
    with pytest.raises(RuntimeError, match="update"):
        fusion.query(P)
    with pytest.raises(ValueError, match="2 cameras"):
        fusion.update(depths[:1])
    with pytest.raises(ValueError, match="masks"):
        fusion.update(depths, [None])
    with pytest.raises(ValueError, match="shape"):
        fusion.update([depths[0], depths[1][:, :10]])
    with pytest.raises(ValueError, match="at least one camera"):
        DepthGridFusion([])
    with pytest.raises(ValueError, match="fill_radius"):
        DepthGridFusion(cams, fill_radius=-1)
    fusion.update(depths)
    with pytest.raises(ValueError, match="mode"):
        fusion.query(P, mode="mean")


def test_voxel_baseline_agrees_on_the_shadow_scene():
    """The voxel baseline (bench) sees the same fused free space: the shadow is cleared there too."""
    from depthguard.bench.voxel import VoxelFusion

    cams = two_cameras()
    P = np.array([[0.0, 0.0, 1.0]])
    scene = Scene((Sphere(np.array([0.4, 0.0, 1.0]), 0.1), *WALLS))
    depths = [render_depth(c, scene) for c in cams]
    voxel = VoxelFusion(cams, (-0.6, 0.6, -0.6, 0.6, 0.5, 1.5), res=0.02)
    voxel.update(depths)
    res = voxel.query(P, 0.0, rho=0.4, mode="all")
    assert 0.3 - 0.04 <= res.distance[0] <= 0.3 + 1e-9
    voxel.update([depths[0], np.full_like(depths[1], np.nan)])  # blind second camera: the shadow stays
    assert voxel.query(P, 0.0, rho=0.4, mode="min").distance[0] < 0.03


def test_write_windows_keeps_only_finite_ordered_windows_and_resets_the_rest():
    """A window is set only where lo and hi are finite and lo <= hi; everywhere else, and for a camera
    without windows (including the rows of a smaller camera's padding), the block reads "no window"."""
    from depthguard.depthgrid.frames import write_windows

    cams = [camera([2.0, 0.0, 1.0], [0.0, 0.0, 1.0], w=4, h=3), camera([0.0, 2.0, 1.2], [0.0, 0.0, 0.9], w=4, h=3)]
    cams.append(camera([0.0, -2.0, 1.2], [0.0, 0.0, 0.9], w=2, h=2))
    hm, wm = 3, 4
    votes = np.full((2, 3 * hm, wm), 7.0, np.float32)  # stale values from an earlier frame everywhere
    lo = np.array([[1.0, np.nan, 2.0, np.inf], [1.0, 1.0, -np.inf, 0.5], [3.0, 3.0, 3.0, 3.0]], np.float32)
    hi = np.array([[1.5, 2.0, 1.0, np.inf], [np.nan, 1.2, 1.0, 0.5], [4.0, 4.0, 4.0, 4.0]], np.float32)
    assert write_windows(votes, hm, cams, [None, (lo, hi), None])
    ok = np.isfinite(lo) & np.isfinite(hi) & (lo <= hi)
    assert np.array_equal(votes[0, hm : 2 * hm], np.where(ok, lo, np.inf))
    assert np.array_equal(votes[0, 2 * hm :], np.where(ok, hi, -np.inf))
    assert np.all(votes[1, hm : 2 * hm] == np.inf) and np.all(votes[1, 2 * hm :] == -np.inf)
    assert np.all(votes[:, :hm] == 7.0)  # the votes themselves are not touched
    small = (np.ones((2, 2), np.float32), np.full((2, 2), 2.0, np.float32))
    votes[:] = 7.0
    write_windows(votes, hm, cams, [None, None, small])
    assert np.all(votes[1, hm : hm + 2, :2] == 1.0) and np.all(votes[1, 2 * hm : 2 * hm + 2, :2] == 2.0)
    assert np.all(votes[1, hm + 2 : 2 * hm] == np.inf) and np.all(votes[1, hm : 2 * hm, 2:] == np.inf)
    assert np.all(votes[1, 2 * hm + 2 :] == -np.inf) and np.all(votes[1, 2 * hm :, 2:] == -np.inf)
