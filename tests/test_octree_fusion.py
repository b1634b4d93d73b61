"""Obstacle octree sets and fusion against an independent numpy ray caster on analytic scenes."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from depthguard.camera import Camera, look_at
from depthguard.octree.fusion import CameraObservation, ScanObservation, fuse
from depthguard.octree.grid import VoxelBox
from depthguard.octree.scanner import LaserScanner
from depthguard.octree.sets import F, O, P

RES = 0.05
BOX = VoxelBox.around([-1.0, -1.0, 0.0], [1.0, 1.0, 1.5], RES)
OBSTACLE = (np.array([-0.15, -0.15, 0.2]), np.array([0.15, 0.15, 0.8]))  # a box, world frame
ROOM = [  # floor and four walls, so that every ray returns a reading
    (np.array([-5.0, -5.0, -0.2]), np.array([5.0, 5.0, -0.05])),
    (np.array([-5.0, 3.0, -0.2]), np.array([5.0, 3.2, 4.0])),
    (np.array([-5.0, -3.2, -0.2]), np.array([5.0, -3.0, 4.0])),
    (np.array([3.0, -5.0, -0.2]), np.array([3.2, 5.0, 4.0])),
    (np.array([-3.2, -5.0, -0.2]), np.array([-3.0, 5.0, 4.0])),
]
HIDDEN = (np.array([-0.1, 0.45, 0.3]), np.array([0.1, 0.6, 0.6]))  # behind OBSTACLE for camera 1


def small_camera(eye, target) -> Camera:
    R, t = look_at(np.array(eye, float), np.array(target, float))
    return Camera.kinect_v1(R, t, width=160, height=120, fx=131.25, fy=131.25, cx=79.5, cy=59.5, min_depth=0.3)


def ray_box_hits(origins, dirs, lo, hi):
    """Ray parameter of the first hit of rays o + s d (s >= 0) with the box [lo, hi]; inf when missed."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (lo - origins) / dirs
        t2 = (hi - origins) / dirs
    tmin = np.nanmax(np.minimum(t1, t2), axis=-1)
    tmax = np.nanmin(np.maximum(t1, t2), axis=-1)
    hit = (tmax >= np.maximum(tmin, 0.0)) & (tmin > 0)
    return np.where(hit, tmin, np.inf)


def render(camera, boxes):
    """Depth z_C (H, W) of the first box along each pixel-centre ray (rays scaled to z_C = 1); 0 = none."""
    d_c = camera.pixel_ray_directions().reshape(-1, 3)
    d_w = d_c @ camera.R
    o = np.broadcast_to(camera.position, d_w.shape)
    s = np.min([ray_box_hits(o, d_w, lo, hi) for lo, hi in boxes], axis=0)
    s[s > camera.max_depth] = np.inf
    return np.where(np.isfinite(s), s, 0.0).reshape(camera.shape).astype(np.float32), d_w


def reference_sets(camera, depth, d_w, step=RES / 5):
    """Independent ray caster: per node, whether a pixel-centre ray has a free / occupied-or-occluded sample."""
    hit = depth.reshape(-1).astype(float)
    hit[hit == 0] = np.inf
    free = np.zeros(BOX.shape, bool)
    blocked = np.zeros(BOX.shape, bool)
    zs = np.arange(camera.min_depth, 4.0, step)
    for z in zs:
        pts = camera.position + d_w * z
        idx = BOX.index(pts)
        ok = BOX.inside(idx)
        b = ok & (z >= hit - 1e-9)
        f = ok & (z < hit - 1e-9)
        blocked[tuple(idx[b].T)] = True
        free[tuple(idx[f].T)] = True
    return free, blocked


CAMS = [small_camera([0.0, -2.5, 1.2], [0.0, 0.0, 0.5]), small_camera([2.2, 1.2, 1.4], [0.0, 0.3, 0.5])]


@pytest.fixture(scope="module")
def scene():
    depths, rays = zip(*(render(c, [OBSTACLE, HIDDEN, *ROOM]) for c in CAMS), strict=True)
    obs = [CameraObservation(c, d) for c, d in zip(CAMS, depths, strict=True)]
    refs = [reference_sets(c, d, r) for c, d, r in zip(CAMS, depths, rays, strict=True)]
    return depths, obs, refs


def node_flags(frame, i):
    return frame.flags[i]


@pytest.mark.parametrize("mode", ["saphari", "conservative"])
def test_every_reference_blocked_node_is_in_its_sensor_set_and_in_the_fusion(scene, mode):
    _, obs, refs = scene
    frame = fuse(BOX, obs, mode=mode)
    for i, (_, blocked) in enumerate(refs):
        fl = node_flags(frame, i)
        missing = blocked & ((fl & O) == 0)
        assert not missing.any(), f"camera {i}: {missing.sum()} nodes blocked for the reference but not in O_i"
    # fused: a node blocked for camera i that no other camera's ray crosses free must be an obstacle
    free0, blocked0 = refs[0]
    free1, blocked1 = refs[1]
    must = (blocked0 & ~free1) | (blocked1 & ~free0)
    assert not (must & ~frame.occupied).any()


def test_measured_points_always_stay_and_free_space_is_free_in_saphari_mode(scene):
    depths, obs, _ = scene
    frame = fuse(BOX, obs, mode="saphari")
    for cam, d in zip(CAMS, depths, strict=True):
        pts = cam.unproject_image(d)[d > 0]
        idx = BOX.index(pts)
        idx = idx[BOX.inside(idx)]
        assert frame.occupied[tuple(idx.T)].all()
        assert (frame.kind[tuple(idx.T)] == 1).all()
    # the space between camera 0 and the obstacle's front face, inside the box: free
    ray = np.linspace([0.0, -0.95, 0.5], [0.0, -0.35, 0.5], 20)
    assert not frame.occupied[tuple(BOX.index(ray).T)].any()
    # a node that some sensor sees free holds no obstacle unless it holds a measured point
    for i in range(len(obs)):
        fl = node_flags(frame, i)
        any_p = np.zeros(BOX.shape, bool)
        for k in range(len(obs)):
            any_p |= (node_flags(frame, k) & P) != 0
        assert not (((fl & F) != 0) & frame.occupied & ~any_p).any()


def test_hidden_obstacle_is_found_by_the_second_camera(scene):
    """RA-L'16 Figs. 8-13: an obstacle in the first camera's shadow, seen by the second one."""
    _, obs, _ = scene
    for mode in ("saphari", "conservative"):
        frame = fuse(BOX, obs, mode=mode)
        centre = 0.5 * (HIDDEN[0] + HIDDEN[1])
        assert frame.occupied[tuple(BOX.index(centre[None])[0])]
        # one camera alone: the hidden box lies in the shadow of the first obstacle -> occluded, not occupied
        solo = fuse(BOX, obs[:1], mode=mode)
        assert solo.kind[tuple(BOX.index(centre[None])[0])] == 2


def test_conservative_mode_marks_unseen_space_and_saphari_mode_frees_it(scene):
    _, obs, _ = scene
    behind_cam0 = np.array([[0.0, -2.9, 1.2]])  # outside BOX anyway; take a node beside both frusta
    corner = np.array([[-0.97, 0.97, 1.45]])
    del behind_cam0
    cons = fuse(BOX, obs, mode="conservative")
    sap = fuse(BOX, obs, mode="saphari")
    ijk = tuple(BOX.index(corner)[0])
    if not (node_flags(cons, 0)[ijk] & 1 or node_flags(cons, 1)[ijk] & 1):
        assert cons.kind[ijk] == 3 and not sap.occupied[ijk]
    assert cons.occupied.sum() > sap.occupied.sum()
    assert (cons.occupied | ~sap.occupied).all()  # conservative ⊇ saphari


def test_missing_pixels_never_free_a_node(scene):
    depths, obs, _ = scene
    rng = np.random.default_rng(0)
    holes = [np.where(rng.random(d.shape) < 0.3, 0.0, d).astype(np.float32) for d in depths]
    # hole filling (nearest valid depth within 4 px) may fill a removed reading with a farther neighbour
    # (the documented limit of the missing-depth policy); without it, holes are unknown space: monotone
    with_holes = fuse(
        BOX, [CameraObservation(c, h) for c, h in zip(CAMS, holes, strict=True)], mode="saphari", fill_radius=0
    )
    full = fuse(BOX, obs, mode="saphari", fill_radius=0)
    for i in range(len(CAMS)):  # per sensor: holes only add blocked nodes and only remove free ones
        fh, ff = node_flags(with_holes, i), node_flags(full, i)
        assert not (((ff & O) != 0) & ((fh & O) == 0)).any()
        assert not (((fh & F) != 0) & ((ff & F) == 0)).any()
    nothing = fuse(BOX, [CameraObservation(c, np.zeros(c.shape, np.float32)) for c in CAMS], mode="saphari")
    fl = node_flags(nothing, 0)
    assert not (fl & F).any()  # no reading at all: nothing is seen free


def test_robot_pixels_hide_space_without_making_it_an_obstacle():
    cam = CAMS[0]
    d, _ = render(cam, [OBSTACLE, *ROOM])
    mask = render(cam, [OBSTACLE])[0] > 0  # pretend the whole box is the robot
    frame = fuse(BOX, [CameraObservation(cam, d, mask)], mode="conservative")
    centre = 0.5 * (OBSTACLE[0] + OBSTACLE[1])
    assert not frame.occupied[tuple(BOX.index(centre[None])[0])]


def scanner_at(pos, yaw=0.0):
    c, s = math.cos(yaw), math.sin(yaw)
    R_ws = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])  # scanner axes in the world
    R = R_ws.T
    return LaserScanner(R, -R @ np.asarray(pos, float), n_rays=541)


def scan_cylinder(sc, centre_xy, radius):
    """Analytic ranges of a vertical cylinder; +inf where the ray misses it (REP 117 'no return')."""
    o = sc.position[:2]
    d = sc.directions()[:, :2]
    oc = o - centre_xy
    b = d @ oc
    c = oc @ oc - radius**2
    disc = b * b - c
    s = -b - np.sqrt(np.maximum(disc, 0.0))
    return np.where((disc >= 0) & (s > 0), s, np.inf)


def test_scanner_sets_shadow_behind_a_leg():
    sc = scanner_at([-0.9, 0.0, 0.2])
    ranges = scan_cylinder(sc, np.array([0.0, 0.0]), 0.08)
    frame = fuse(BOX, [ScanObservation(sc, ranges)], mode="saphari")
    plane = lambda x, y: tuple(BOX.index(np.array([[x, y, 0.2]]))[0])  # noqa: E731
    assert frame.kind[plane(-0.08, 0.0)] == 1  # the leg's front surface
    assert frame.occupied[plane(0.5, 0.0)]  # in its shadow
    assert not frame.occupied[plane(-0.5, 0.0)]  # in front of it
    assert not frame.occupied[plane(0.5, 0.6)]  # beside the shadow
    assert not frame.occupied[tuple(BOX.index(np.array([[0.5, 0.0, 0.8]]))[0])]  # off the scan plane
    # conservative mode: the scanner frees nothing, the shadow and the leg stay
    cons = fuse(BOX, [ScanObservation(sc, ranges)], mode="conservative")
    assert cons.occupied[plane(0.5, 0.0)] and cons.occupied[plane(-0.5, 0.0)]
    # missing readings are not free, +inf readings are
    holes = ranges.copy()
    holes[:] = np.nan
    fr = fuse(BOX, [ScanObservation(sc, holes)], mode="saphari")
    assert fr.occupied[plane(-0.5, 0.0)]


def test_bad_input():
    with pytest.raises(ValueError, match="mode"):
        fuse(BOX, [CameraObservation(CAMS[0], np.zeros(CAMS[0].shape))], mode="optimistic")
    with pytest.raises(ValueError, match="depth image has shape"):
        fuse(BOX, [CameraObservation(CAMS[0], np.zeros((3, 3)))])
    with pytest.raises(ValueError, match="scan ranges"):
        fuse(BOX, [ScanObservation(scanner_at([0, 0, 0.2]), np.zeros(3))])
    with pytest.raises(ValueError, match="reach mask"):
        fuse(BOX, [ScanObservation(scanner_at([0, 0, 0.2]), np.zeros(541))], reach=np.ones((2, 2, 2), bool))
    with pytest.raises(ValueError, match="n_rays"):
        LaserScanner(n_rays=0)


@pytest.mark.slow
@settings(deadline=None, max_examples=8)
@given(
    centre=st.tuples(st.floats(-0.6, 0.6), st.floats(-0.6, 0.6), st.floats(0.3, 1.2)),
    half=st.tuples(st.floats(0.03, 0.3), st.floats(0.03, 0.3), st.floats(0.03, 0.3)),
    holes=st.floats(0.0, 0.3),
    seed=st.integers(0, 1000),
)
def test_random_box_scenes_are_conservative(centre, half, holes, seed):
    """Hypothesis: any box, any hole fraction: every node the reference ray caster finds blocked is in O_1,
    and the fused obstacle set (conservative mode) holds it unless the other camera's rays cross it free."""
    box = (np.array(centre) - half, np.array(centre) + half)
    cams = [small_camera([0.0, -2.5, 1.2], [0.0, 0.0, 0.5]), small_camera([2.2, 1.2, 1.4], [0.0, 0.3, 0.5])]
    rng = np.random.default_rng(seed)
    obs, refs = [], []
    for cam in cams:
        d, rays = render(cam, [box, *ROOM])
        d = np.where(rng.random(d.shape) < holes, 0.0, d).astype(np.float32)
        obs.append(CameraObservation(cam, d))
        refs.append(reference_sets(cam, d, rays, step=RES / 3))
    frame = fuse(BOX, obs, mode="conservative", fill_radius=0)
    for i, (_, blocked) in enumerate(refs):
        assert not (blocked & ((frame.flags[i] & O) == 0)).any()
    must = (refs[0][1] & ~refs[1][0]) | (refs[1][1] & ~refs[0][0])
    assert not (must & ~frame.occupied).any()


@settings(max_examples=30, deadline=None)
@given(st.integers(1, 70), st.integers(1, 70), st.integers(0, 2**31))
def test_min_pyramid_levels_are_the_minima_of_their_pixel_blocks(h, w, seed):
    """Level l holds, per 2^l x 2^l block of pixels (clipped at odd sizes), the minimum: compared with
    numpy's reshape-and-min of the inf-padded image, level by level."""
    from depthguard.octree.sets import min_pyramid

    rng = np.random.default_rng(seed)
    img = rng.random((h, w)).astype(np.float32)
    img[rng.random((h, w)) < 0.2] = np.inf
    data, offs, hs, ws = min_pyramid(img)
    level = img
    for lv in range(len(offs)):
        assert (hs[lv], ws[lv]) == level.shape
        got = data[offs[lv] : offs[lv] + hs[lv] * ws[lv]].reshape(level.shape)
        assert np.array_equal(got, level)
        a, b = level.shape
        padded = np.full(((a + 1) // 2 * 2, (b + 1) // 2 * 2), np.inf, np.float32)
        padded[:a, :b] = level
        level = padded.reshape((a + 1) // 2, 2, (b + 1) // 2, 2).min(axis=(1, 3))
    assert hs[-1] == 1 and ws[-1] == 1


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 5), st.integers(0, 2**31), st.booleans())
def test_combine_is_the_set_formula_node_by_node(n_sensors, seed, conservative):
    """``combine`` against SAPHARI §3.2 written out per node with Python sets: occupied where some sensor
    holds a measured point (P); occluded where some Oi is seen free by no other sensor j != i; in the
    conservative mode unseen where no sensor sees the node free, occupied, occluded or robot-hidden."""
    from depthguard.octree.sets import R, combine

    rng = np.random.default_rng(seed)
    shape = (4, 5, 3)
    flags = np.zeros((n_sensors,) + shape, np.uint8)
    for bit, p in ((1, 0.5), (P, 0.1), (O, 0.35), (R, 0.2), (F, 0.4)):
        flags |= (rng.random(flags.shape) < p).astype(np.uint8) * np.uint8(bit)
    # any bits, even Oi with Fi (the kernels never set both; the formula must hold regardless)
    mask = rng.random(shape) < 0.85
    kind = np.full(shape, 255, np.uint8)
    combine(flags, mask, conservative, kind)
    for idx in np.ndindex(shape):
        f = [int(flags[(s,) + idx]) for s in range(n_sensors)]
        free_by = {s for s in range(n_sensors) if f[s] & F}
        if not mask[idx]:
            want = 0
        elif any(x & P for x in f):
            want = 1
        elif any(f[s] & O and not (free_by - {s}) for s in range(n_sensors)):
            want = 2
        elif conservative and not free_by and not any(x & (O | R) for x in f):
            want = 3
        else:
            want = 0
        assert kind[idx] == want, (idx, f, bool(mask[idx]))


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31), st.sampled_from([0.02, 0.05, 0.09]), st.sampled_from([0.05, 0.09, 0.13]))
def test_reach_mask_marks_exactly_the_nodes_whose_boxes_overlap_a_reachable_cell(seed, res, src_res):
    """``mark_overlaps`` against the definition, cell by cell and node by node: a node is marked when, on
    every axis, its index lies in the cell's node range widened by 1e-9 of a node (a node that only touches
    a cell's face counts: C(t) is never cut by rounding)."""
    from depthguard.octree.sets import mark_overlaps

    rng = np.random.default_rng(seed)
    src = rng.random(tuple(rng.integers(1, 7, 3))) < rng.uniform(0.05, 0.6)
    src_origin = rng.uniform(-0.3, 0.3, 3)
    origin = rng.uniform(-0.4, 0.0, 3)
    shape = np.array(rng.integers(1, 14, 3), np.int64)
    out = np.zeros(tuple(shape), bool)
    mark_overlaps(src, src_origin, src_res, origin, res, shape, out)
    want = np.zeros_like(out)
    for a, b, c in np.argwhere(src):
        s_lo = src_origin + np.array([a, b, c]) * src_res
        for idx in np.ndindex(*shape):
            # the kernel's rule: node index range floor((s_lo - o)/res - eps) .. ceil((s_hi - o)/res + eps) - 1
            lo_i = np.floor((s_lo - origin) / res - 1e-9)
            hi_i = np.ceil((s_lo + src_res - origin) / res + 1e-9) - 1
            if np.all((np.array(idx) >= lo_i) & (np.array(idx) <= hi_i)):
                want[idx] = True
    assert np.array_equal(out, want)


@pytest.mark.parametrize("mode", ["saphari", "conservative"])
def test_observations_and_reach_given_later_give_the_same_frame(scene, mode):
    """Observations given as tasks (called on the sensors' threads) and C(t) given as a callable (called
    once the sets are done, which are then computed over the whole box) or as a Future of the backend:
    the same nodes, flags and kinds as when everything is given at once."""
    from concurrent.futures import ThreadPoolExecutor

    from depthguard.octree.backend import OctreeBackend

    _, obs, _ = scene
    sc = scanner_at([-0.9, 0.0, 0.2], yaw=0.3)
    scan = ScanObservation(sc, scan_cylinder(sc, np.array([0.0, 0.0]), 0.08))
    every = [*obs, scan]
    rng = np.random.default_rng(3)
    reach = rng.random(BOX.shape) < 0.7
    ref = fuse(BOX, every, reach, mode=mode)
    tasks = [lambda o=o: o for o in every]
    for got in (
        fuse(BOX, tasks, lambda: reach, mode=mode),
        fuse(BOX, every, lambda: reach, mode=mode, workers=1),
    ):
        assert np.array_equal(got.kind, ref.kind) and np.array_equal(got.flags, ref.flags)
        assert np.array_equal(got.mask, reach)
        assert not got.flags[:, ~reach].any()  # 0 outside C(t), as documented
    whole = fuse(BOX, every, None, mode=mode)
    later_none = fuse(BOX, tasks, lambda: None, mode=mode)
    assert np.array_equal(later_none.kind, whole.kind) and np.array_equal(later_none.flags, whole.flags)
    be = OctreeBackend(BOX, mode=mode)
    with ThreadPoolExecutor(1) as pool:
        frame = be.update(tasks, pool.submit(lambda: reach))
    assert np.array_equal(frame.kind, ref.kind)
    with pytest.raises(ValueError, match="reach mask has shape"):
        fuse(BOX, tasks, lambda: np.ones((2, 2, 2), bool), mode=mode)
    with pytest.raises(ValueError, match="reach mask has shape"):
        be.update(every, np.ones((2, 2, 2), bool))
    with pytest.raises(ValueError, match="call update"):
        be.query(np.zeros((1, 3)))  # a failed update leaves no answer


def _scanner_sets_by_definition(box, sc, obstacle, robot):
    """Per node, with numpy: the scan plane cuts the node (its centre within the node's half extent along
    the plane's normal); the beam sectors that meet the angular range of its 8 corners (``arctan2`` of
    each, as seen from the scanner); its planar range from its centre's distance less half its diagonal
    to its farthest corner; O / R: some ray of those blocked within that range; V: all in the fan and range."""
    idx = np.indices(box.shape).reshape(3, -1).T
    c_w = box.origin + (idx + 0.5) * box.res
    c_s = c_w @ sc.R.T + sc.t
    n = sc.R[2]
    ez = 0.5 * box.res * np.abs(n).sum()
    cut = np.abs(c_s[:, 2]) <= ez
    offs = (np.indices((2, 2, 2)).reshape(3, -1).T - 0.5) * box.res
    corners = c_s[:, None, :2] + (offs @ sc.R.T)[None, :, :2]
    phic = np.arctan2(c_s[:, 1], c_s[:, 0])
    rel = np.arctan2(corners[..., 1], corners[..., 0]) - phic[:, None]
    rel = (rel + np.pi) % (2 * np.pi) - np.pi
    lo, hi = np.minimum(rel.min(axis=1), 0.0), np.maximum(rel.max(axis=1), 0.0)
    rc = np.hypot(c_s[:, 0], c_s[:, 1])
    h = 0.5 * math.sqrt(3.0) * box.res
    rhi = np.hypot(corners[..., 0], corners[..., 1]).max(axis=1)
    inc, a0, nr = sc.angle_increment, sc.angle_min, sc.n_rays
    flags = np.zeros(len(idx), np.uint8)
    for m in np.flatnonzero(cut):
        hit, in_fov = np.ones(nr, bool), False  # (a node holding the scanner: every ray may meet it)
        if rc[m] > h:  # the rays whose sector meets the node's angles, modulo a turn (the fan may cross +-pi)
            hit[:] = False
            for turn in (-2 * math.pi, 0.0, 2 * math.pi):
                j0 = math.ceil((phic[m] + turn + lo[m] - a0 - 0.5 * inc) / inc)
                j1 = math.floor((phic[m] + turn + hi[m] - a0 + 0.5 * inc) / inc)
                in_fov = in_fov or (j0 >= 0 and j1 < nr)
                if max(j0, 0) <= min(j1, nr - 1):
                    hit[max(j0, 0) : min(j1, nr - 1) + 1] = True
            in_fov = in_fov and rc[m] - h >= sc.range_min and rhi[m] <= sc.range_max
            if not hit.any():
                continue
        fl = (4 if (obstacle[hit] <= rhi[m]).any() else 0) | (8 if (robot[hit] <= rhi[m]).any() else 0)
        if in_fov:
            fl |= 1 | (16 if fl == 0 else 0)
        flags[m] = fl
    return flags.reshape(box.shape)


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 2**31), tilt=st.floats(0.0, 0.4), res=st.sampled_from([0.05, 0.1]))
@example(seed=58414952, tilt=0.25, res=0.1)  # (a node across +-pi, behind the scanner: fresh seeds)
def test_scanner_sets_follow_their_definition(seed, tilt, res):
    """The scanner's sets (which compare the corners' angles through their tangents from the node's
    direction) against the definition written with ``arctan2`` of every corner, on random poses (the scan
    plane tilted too), ranges and robot rays."""
    from depthguard.octree.sets import scanner_sets

    rng = np.random.default_rng(seed)
    box = VoxelBox.around([-0.8, -0.8, -0.4], [0.8, 0.8, 0.6], res)
    yaw, roll = rng.uniform(-np.pi, np.pi), rng.uniform(-tilt, tilt)
    cy, sy, cr, sr = math.cos(yaw), math.sin(yaw), math.cos(roll), math.sin(roll)
    R_ws = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]]) @ np.array(
        [[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]]
    )
    pos = rng.uniform(-0.4, 0.4, 3)
    sc = LaserScanner(R_ws.T, -R_ws.T @ pos, n_rays=541)
    obstacle = np.where(rng.random(541) < 0.3, np.inf, rng.uniform(0.05, 1.5, 541))
    robot = np.where(rng.random(541) < 0.1, rng.uniform(0.1, 0.8, 541), np.inf)
    mask = np.ones(box.shape, bool)
    got = scanner_sets(mask, box, sc, obstacle, robot)
    assert np.array_equal(got, _scanner_sets_by_definition(box, sc, obstacle, robot))


@settings(max_examples=20, deadline=None)
@given(st.integers(1, 70), st.integers(1, 70), st.integers(0, 2**31))
def test_min_and_negated_max_pyramids_in_one_pass(h, w, seed):
    from depthguard.octree.pyramids import min_negmax_pyramids, min_pyramid

    rng = np.random.default_rng(seed)
    img = rng.random((h, w)).astype(np.float32)
    img[rng.random((h, w)) < 0.2] = np.inf
    lo, neg, offs, hs, ws = min_negmax_pyramids(img)
    for got, ref in ((lo, min_pyramid(img)), (neg, min_pyramid(-img))):
        assert np.array_equal(got, ref[0])
        assert np.array_equal(offs, ref[1]) and np.array_equal(hs, ref[2]) and np.array_equal(ws, ref[3])


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**31), res=st.sampled_from([0.02, 0.05, 0.1]))
def test_measured_points_mark_the_nodes_that_hold_them(seed, res):
    """P of a camera against numpy: every measured, non-robot pixel within the depth limits unprojected to
    the world and binned into the box's nodes (inside the mask); nothing else."""
    from depthguard.octree.sets import bin_depth_points

    rng = np.random.default_rng(seed)
    cam = CAMS[seed % 2]
    box = VoxelBox.around([-1.0, -1.0, 0.0], [1.0, 1.0, 1.5], res)
    depth = rng.uniform(0.1, 5.0, cam.shape).astype(np.float32)
    depth[rng.random(cam.shape) < 0.1] = np.nan
    depth[rng.random(cam.shape) < 0.05] = 0.0
    robot = rng.random(cam.shape) < 0.2
    mask = rng.random(box.shape) < 0.8
    got = np.zeros(box.shape, np.uint8)
    bin_depth_points(cam, depth, robot, box, mask, got)
    ok = ~robot & (depth >= cam.min_depth) & (depth <= cam.max_depth)
    pts = cam.unproject_image(np.where(ok, depth, 0.0).astype(float))[ok]
    f = (pts - box.origin) / box.res
    # a point within 1e-9 of a node face may land on either side of it (rounding)
    edge = np.abs(f - np.round(f)) < 1e-9
    idx = np.floor(f).astype(int)
    inside = np.all((idx >= 0) & (idx < np.array(box.shape)), axis=1) & ~edge.any(axis=1)
    ref = np.zeros(box.shape, bool)
    ref[tuple(idx[inside].T)] = True
    ref &= mask
    assert np.array_equal((got & P) != 0, ref | ((got & P) != 0) & ~ref & _near_faces(pts, edge, box, mask))


def _near_faces(pts, edge, box, mask):
    """Nodes that a point within 1e-9 of a node face may be binned into (either side)."""
    out = np.zeros(box.shape, bool)
    for p in pts[edge.any(axis=1)]:
        for d in np.indices((2, 2, 2)).reshape(3, -1).T:
            i = np.floor((p - box.origin) / box.res + (d - 0.5) * 2e-9).astype(int)
            if np.all((i >= 0) & (i < np.array(box.shape))):
                out[tuple(i)] = True
    return out & mask


@settings(max_examples=25, deadline=None)
@given(
    h=st.integers(1, 40),
    w=st.integers(1, 40),
    seed=st.integers(0, 2**31),
    holes=st.sampled_from([0.0, 0.02, 0.3, 0.9]),
    radius=st.integers(0, 5),
    conservative=st.booleans(),
)
def test_camera_pyramids_equal_the_filled_depths_pyramids(h, w, seed, holes, radius, conservative):
    """The one-pass camera pyramids against their definition: the depth space's missing-depth policy
    (``fill_missing_depth``: sparse and dense holes, radius 0, both policies), the robot's blocking depth,
    and the min / negated-max pyramids of those images."""
    from depthguard.depthspace import fill_missing_depth
    from depthguard.octree.fusion import robot_blocking_depth
    from depthguard.octree.pyramids import camera_pyramids, min_negmax_pyramids, min_pyramid

    rng = np.random.default_rng(seed)
    cam = Camera.kinect_v1(np.eye(3), np.zeros(3), width=w, height=h, fx=50.0, fy=50.0, cx=w / 2, cy=h / 2)
    depth = rng.uniform(0.2, 5.0, (h, w)).astype(np.float32)
    bad = rng.random((h, w)) < holes
    depth[bad] = rng.choice(np.array([0.0, np.nan, np.inf, -np.inf, -1.0], np.float32), int(bad.sum()))
    robot = rng.random((h, w)) < 0.2
    policy = "conservative" if conservative else "ignore"
    f = fill_missing_depth(cam, depth, robot, invalid=policy, fill_radius=radius)
    near = np.float32(cam.min_depth)
    lo, neg, rob, offs, hs, ws = camera_pyramids(depth, robot, radius, near, conservative)
    ref_lo, ref_neg, *layout = min_negmax_pyramids(f.obstacle_depth)
    ref_rob = min_pyramid(robot_blocking_depth(f.robot, f.missing, f.depth, near))[0]
    for got, ref in ((lo, ref_lo), (neg, ref_neg), (rob, ref_rob)):
        assert np.array_equal(got, ref)
    for got, ref in zip((offs, hs, ws), layout, strict=True):
        assert np.array_equal(got, ref)


@settings(max_examples=30, deadline=None)
@given(h=st.integers(1, 90), w=st.integers(1, 90), seed=st.integers(0, 2**31))
def test_any_le_is_the_rectangle_minimum_test(h, w, seed):
    """``any_le`` (the camera sets' pyramid search) against the brute-force minimum of random rectangles, with
    thresholds just below, at and above the rectangle's minimum and the minimum of its surroundings."""
    from depthguard.octree.pyramids import any_le, min_pyramid

    rng = np.random.default_rng(seed)
    img = rng.uniform(0.5, 4.0, (h, w)).astype(np.float32)
    img[rng.random((h, w)) < 0.3] = np.inf
    data, offs, hs, ws = min_pyramid(img)
    work = np.empty((4 * 64 + 64, 3), np.int64)
    for _ in range(40):
        v0, v1 = np.sort(rng.integers(0, h, 2))
        u0, u1 = np.sort(rng.integers(0, w, 2))
        m = float(img[v0 : v1 + 1, u0 : u1 + 1].min())
        finite = img[np.isfinite(img)]
        near = [float(finite.min())] if finite.size else []
        for thr in [m, np.nextafter(np.float32(m), np.float32(-np.inf)), m + 1e-3, *near, 0.0, 5.0]:
            thr = float(thr)
            assert any_le(img, data, offs, hs, ws, u0, v0, u1, v1, thr, work) == (m <= thr)


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**31), res=st.sampled_from([0.0625, 0.125]))
def test_level_scanner_on_a_node_face_cuts_two_layers_by_definition(seed, res):
    """A level scan plane on a face between two node layers cuts both alike (the kernel computes each
    centre in the plane once per column): the sets against their ``arctan2`` definition. The lattice is
    binary (exact), so that the face is one in floating point too."""
    from depthguard.octree.sets import scanner_sets

    rng = np.random.default_rng(seed)
    n = int(round(1.5 / res))
    box = VoxelBox(np.array([-0.75, -0.75, -0.5]), res, (n, n, n))
    yaw = rng.uniform(-np.pi, np.pi)
    cy, sy = math.cos(yaw), math.sin(yaw)
    R_ws = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    pos = np.array([*rng.uniform(-0.4, 0.4, 2), box.origin[2] + 6 * res])  # on the face of layers 5 and 6
    sc = LaserScanner(R_ws.T, -R_ws.T @ pos, n_rays=541)
    obstacle = np.where(rng.random(541) < 0.3, np.inf, rng.uniform(0.05, 1.5, 541))
    robot = np.where(rng.random(541) < 0.1, rng.uniform(0.1, 0.8, 541), np.inf)
    got = scanner_sets(np.ones(box.shape, bool), box, sc, obstacle, robot)
    assert got[:, :, 5].any() and np.array_equal(got[:, :, 5], got[:, :, 6])
    assert np.array_equal(got, _scanner_sets_by_definition(box, sc, obstacle, robot))


def test_a_future_of_a_reachability_grid_is_taken_as_its_mask(scene):
    """``OctreeBackend.update`` with a Future of a reachability grid (its node mask made on the thread that
    completes it): the same frame as with the grid given at once, done or not yet done when the update
    starts; the future's exception reaches the caller."""
    import threading
    from concurrent.futures import ThreadPoolExecutor

    from depthguard.octree.backend import OctreeBackend
    from depthguard.octree.reach import ReachabilityGrid

    _, obs, _ = scene
    coarse = VoxelBox(BOX.origin - 0.03, 0.09, (24, 24, 18))
    t = np.where(np.random.default_rng(3).random(coarse.shape) < 0.6, 0.2, np.inf).astype(np.float32)
    grid = ReachabilityGrid(coarse, t, 0.5, 0.0)
    be = OctreeBackend(BOX, mode="conservative")
    ref = be.update(obs, grid)
    assert 0 < ref.mask.sum() < ref.mask.size
    gate = threading.Event()
    with ThreadPoolExecutor(1) as pool:
        done = pool.submit(lambda: grid)
        done.result()
        slow = pool.submit(lambda: (gate.wait(), grid)[1])
        threading.Timer(0.05, gate.set).start()
        for pending in (done, slow):
            got = be.update(obs, pending)
            assert np.array_equal(got.mask, ref.mask) and np.array_equal(got.kind, ref.kind)
            assert np.array_equal(got.flags, ref.flags)
        with pytest.raises(ZeroDivisionError):
            be.update(obs, pool.submit(lambda: 1 / 0))
    assert not be.ready


def test_measured_points_into_arrays_of_any_layout():
    """The P bits are the same when the flags and the mask are not C-contiguous (the kernel marks flat
    node indices, so it works on contiguous copies then)."""
    from depthguard.octree.sets import bin_depth_points

    rng = np.random.default_rng(5)
    cam = CAMS[0]
    depth = rng.uniform(0.3, 3.0, cam.shape).astype(np.float32)
    robot = rng.random(cam.shape) < 0.2
    mask = rng.random(BOX.shape) < 0.8
    ref = np.zeros(BOX.shape, np.uint8)
    bin_depth_points(cam, depth, robot, BOX, mask, ref)
    assert (ref & P).any()
    got = np.zeros(BOX.shape, np.uint8, order="F")
    bin_depth_points(cam, depth, robot, BOX, np.asfortranarray(mask), got)
    assert np.array_equal(got, ref)
    both = np.zeros((2, *BOX.shape), np.uint8)
    bin_depth_points(cam, depth, robot, BOX, mask, both[1])
    assert np.array_equal(both[1], ref) and not both[0].any()


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31), n_sensors=st.integers(1, 5), conservative=st.booleans(), clear=st.booleans())
def test_combine_cleared_is_the_edits_then_combine(seed, n_sensors, conservative, clear):
    """``combine_cleared`` (the fusion's last pass) against its definition: the flags zeroed outside the
    mask (``clear``) and the chosen sensors' F bits dropped, then ``combine``; the same flags and kinds."""
    from depthguard.octree.fusion import clear_outside
    from depthguard.octree.sets import combine, combine_cleared

    rng = np.random.default_rng(seed)
    shape = tuple(int(x) for x in rng.integers(1, 9, 3))
    flags = rng.integers(0, 32, (n_sensors, *shape)).astype(np.uint8)
    mask = rng.random(shape) < 0.7
    drop_f = rng.random(n_sensors) < 0.5
    ref = flags.copy()
    if clear:
        clear_outside(ref, mask)
    ref[drop_f] &= np.uint8(~F & 0xFF)
    want = np.empty(shape, np.uint8)
    combine(ref, mask, conservative, want)
    got = np.empty(shape, np.uint8)
    combine_cleared(flags, mask, conservative, got, clear, drop_f)
    assert np.array_equal(flags, ref) and np.array_equal(got, want)
