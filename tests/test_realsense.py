"""The RealSense source on the SDK's own software device (no hardware here): intrinsics and depth scale from
the device, frames in metres with 0 -> NaN, a stopped feed becomes a fault naming the camera, never a crash."""

import threading
import time
from pathlib import Path

import numpy as np
import pytest

try:
    import pyrealsense2 as rs
except ImportError as exc:  # the wheel needs the system's libusb
    pytest.skip(f"pyrealsense2 does not import here ({exc})", allow_module_level=True)

from depthguard.io.cellfile import read_cell  # noqa: E402
from depthguard.runner.realsense import RealSenseSource  # noqa: E402

CELL = """
[robot]
model = "lwr4"
[[cameras]]
name = "d435"
intrinsics = "device"
R = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
t = [0.0, 0.0, 2.0]
min_depth = 0.2
max_depth = 4.0
[controller]
rate = 200.0
"""
W, H = 64, 48


def _device():
    intr = rs.intrinsics()
    intr.width, intr.height, intr.ppx, intr.ppy, intr.fx, intr.fy = W, H, 31.5, 23.5, 50.0, 51.0
    intr.model = rs.distortion.brown_conrady
    intr.coeffs = [0.0] * 5
    sd = rs.software_device()
    sensor = sd.add_sensor("Depth")
    sensor.add_read_only_option(rs.option.depth_units, 0.00025)
    vs = rs.video_stream()
    vs.type, vs.index, vs.uid, vs.width, vs.height, vs.fps, vs.bpp, vs.fmt = (
        rs.stream.depth,
        0,
        0,
        W,
        H,
        30,
        2,
        rs.format.z16,
    )
    vs.intrinsics = intr
    profile = sensor.add_video_stream(vs).as_video_stream_profile()
    syncer = rs.syncer()
    sensor.open(profile)
    sensor.start(syncer)
    return sd, sensor, syncer, profile


def _push(sensor, profile, n, period, keep):
    for i in range(n):
        px = np.full((H, W), 8000, dtype=np.uint16)  # 8000 * 0.25 mm = 2.0 m
        px[0, 0] = 0
        keep.append(px)
        f = rs.software_video_frame()
        f.pixels, f.bpp, f.stride = px, 2, 2 * W
        f.timestamp, f.frame_number = 1000.0 * i * period, i
        f.domain = rs.timestamp_domain.hardware_clock
        f.profile = profile
        sensor.on_video_frame(f)
        time.sleep(period)


def test_software_device_frames_intrinsics_and_dropout(tmp_path):
    p = Path(tmp_path) / "cell.toml"
    p.write_text(CELL)
    cell = read_cell(p)
    sd, sensor, syncer, profile = _device()
    src = RealSenseSource(cell, ("a",), device=(sensor, syncer, profile), duration=0.8, frame_timeout=0.15)
    cam = src.cameras[0]
    # librealsense's ppx, ppy put pixel centres at integers, DepthGuard's at u + 0.5 (tests/test_pixel_convention.py)
    assert (cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy) == (W, H, 50.0, 51.0, 32.0, 24.0)
    assert src.depth_scale == pytest.approx(0.00025)
    keep: list = []
    feeder = threading.Thread(target=_push, args=(sensor, profile, 6, 1 / 30, keep))  # 0.2 s, then silence
    feeder.start()
    ticks = list(src.ticks())
    feeder.join()
    src.close()
    frames = [tk for tk in ticks if tk.frames is not None]
    assert len(frames) >= 3
    d = frames[0].frames[0]
    assert d.shape == (H, W) and np.isnan(d[0, 0]) and d[1, 1] == pytest.approx(2.0)
    faults = [tk.faults for tk in ticks if tk.faults]
    assert faults and all("d435" in f for f in faults)  # the silence after 0.2 s is named
    assert all(tk.q is None for tk in ticks)  # no joint provider: the controller would stop


def _feed_from_second_tick(src, feeder, tail):
    """Start ``feeder`` at the source's second tick (the first control cycle may compile for seconds on a
    loaded machine, longer than the feed) and end the ticks ``tail`` s after the feeder has finished."""
    ticks = src.ticks

    def started():
        done = None
        for k, tick in enumerate(ticks()):
            if k == 1:
                feeder.start()
            elif k > 1 and not feeder.is_alive():
                done = time.monotonic() if done is None else done
                if time.monotonic() - done > tail:
                    return
            yield tick

    src.ticks = started


def test_runner_keeps_going_and_stops_the_controller_without_frames(tmp_path):
    from depthguard.runner.chain import Chain
    from depthguard.runner.run import RunLog, run_chain

    p = Path(tmp_path) / "cell.toml"
    p.write_text(CELL)
    cell = read_cell(p)
    sd, sensor, syncer, profile = _device()

    class Joints:
        def latest(self):
            return time.monotonic(), np.zeros(7), np.zeros(7)

    from depthguard.robot.model import load_lwr4

    model = load_lwr4()
    src = RealSenseSource(cell, model.joint_names, joints=Joints(), device=(sensor, syncer, profile), duration=60.0)
    keep: list = []
    feeder = threading.Thread(target=_push, args=(sensor, profile, 45, 1 / 30, keep))  # 1.5 s, then silence
    _feed_from_second_tick(src, feeder, tail=1.0)
    chain = Chain(cell, src.cameras, model)
    chain.on_frames([np.full((H, W), 2.0, np.float32)], np.zeros(7))  # compile the kernels before the clock runs
    chain.query(0.0, np.zeros(7))
    chain = Chain(cell, src.cameras, model)
    log = RunLog()
    summary = run_chain(cell, src, chain, log=log)
    feeder.join()
    assert summary["commands"] > 20 and summary["frames"] >= 1
    assert log.status[-1].startswith("STOP_")  # frames stopped: the distances went stale
    assert all(np.all(np.isfinite(q)) for q in log.q_cmd)


# ------------------------------------------------------------------ align = "color": rs.align on a software device
ALIGNED_CELL = CELL.replace('intrinsics = "device"', 'intrinsics = "device"\nalign = "color"')
UNITS = 0.00025  # m per z16 step
CW, CH = 80, 60  # the colour stream: another size, focal length and principal point than the depth stream
C_INTR = (CW, CH, 39.0, 30.5, 70.0, 72.0)  # width, height, ppx, ppy, fx, fy
D_INTR = (W, H, 31.5, 23.5, 50.0, 51.0)
BOX_Z, BACK_Z = 1.23456, 1.98765  # the scene in the depth camera's frame: a box face, a wall (m, off the z16 grid)
BOX_X, BOX_Y = (-0.25, 0.15), (-0.1, 0.2)


def _rot(ax, ay):
    cx, sx, cy, sy = np.cos(ax), np.sin(ax), np.cos(ay), np.sin(ay)
    return np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]]) @ np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])


def _depthguard(intr):
    """(w, h, cx, cy, fx, fy) of DepthGuard's camera for librealsense's (w, h, ppx, ppy, fx, fy): pixel centres at
    u + 0.5, not at u (tests/test_pixel_convention.py)."""
    w, h, ppx, ppy, fx, fy = intr
    return (w, h, ppx + 0.5, ppy + 0.5, fx, fy)


def _rs_intr(w, h, ppx, ppy, fx, fy):
    intr = rs.intrinsics()
    intr.width, intr.height, intr.ppx, intr.ppy, intr.fx, intr.fy = w, h, ppx, ppy, fx, fy
    intr.model, intr.coeffs = rs.distortion.brown_conrady, [0.0] * 5
    return intr


def _aligned_device(R, t):
    """Depth (64x48) and colour (80x60) sensors of one software device; depth-to-colour extrinsics
    ``P_color = R P_depth + t`` registered (column-major, as librealsense stores them)."""
    sd = rs.software_device()
    dsensor, csensor = sd.add_sensor("Depth"), sd.add_sensor("Color")
    dsensor.add_read_only_option(rs.option.depth_units, UNITS)
    profiles = []
    for sensor, kind, uid, intr, bpp, fmt in (
        (dsensor, rs.stream.depth, 0, D_INTR, 2, rs.format.z16),
        (csensor, rs.stream.color, 1, C_INTR, 3, rs.format.rgb8),
    ):
        vs = rs.video_stream()
        vs.type, vs.index, vs.uid, vs.width, vs.height, vs.fps, vs.bpp, vs.fmt = (
            kind,
            0,
            uid,
            intr[0],
            intr[1],
            30,
            bpp,
            fmt,
        )
        vs.intrinsics = _rs_intr(*intr)
        profiles.append(sensor.add_video_stream(vs).as_video_stream_profile())
    dp, cp = profiles
    ext = rs.extrinsics()
    ext.rotation = [float(x) for x in np.asarray(R).T.ravel()]
    ext.translation = [float(x) for x in t]
    dp.register_extrinsics_to(cp, ext)
    syncer = rs.syncer()
    dsensor.open(dp)
    csensor.open(cp)
    dsensor.start(syncer)
    csensor.start(syncer)
    return sd, dsensor, csensor, syncer, dp, cp


def _render_depth():
    """The z16 depth image of the scene (box face and wall, fronto-parallel in the depth camera's frame)."""
    w, h, ppx, ppy, fx, fy = D_INTR
    x = (np.arange(w) - ppx) / fx
    y = (np.arange(h) - ppy) / fy
    X, Y = np.meshgrid(x * BOX_Z, y * BOX_Z)
    box = (X >= BOX_X[0]) & (X <= BOX_X[1]) & (Y >= BOX_Y[0]) & (Y <= BOX_Y[1])
    return np.round(np.where(box, BOX_Z, BACK_Z) / UNITS).astype(np.uint16), box


def _truth_colour(R, t):
    """Per colour pixel: the depth (z in the colour camera's frame) of the box face's plane and of the wall on
    its ray, and whether the ray meets the box."""
    w, h, ppx, ppy, fx, fy = C_INTR
    u, v = np.meshgrid((np.arange(w) - ppx) / fx, (np.arange(h) - ppy) / fy)
    ray = np.stack([u, v, np.ones_like(u)], -1)  # colour frame, z = 1: the point at s * ray has z_color = s
    o = -R.T @ t  # the colour camera's centre in the depth frame
    d = ray @ R  # rows: R^T ray
    z_box, z_wall = (BOX_Z - o[2]) / d[..., 2], (BACK_Z - o[2]) / d[..., 2]
    pb = o + z_box[..., None] * d
    on_box = (pb[..., 0] >= BOX_X[0]) & (pb[..., 0] <= BOX_X[1]) & (pb[..., 1] >= BOX_Y[0]) & (pb[..., 1] <= BOX_Y[1])
    return z_box, z_wall, on_box


def _neighbours(a):
    """The 3x3 neighbourhood of each pixel of ``a`` (9, H, W), the border repeated."""
    pad = np.pad(a, 1, mode="edge")
    h, w = a.shape
    return np.array([pad[1 + dy : 1 + dy + h, 1 + dx : 1 + dx + w] for dy in (-1, 0, 1) for dx in (-1, 0, 1)])


def _push_pair(dsensor, csensor, dp, cp, depth, n, period, keep, colour_until=None, noise=False):
    """``n`` depth frames (and colour frames up to frame ``colour_until``) at ``period`` s, stamps in step;
    ``noise``: one pixel a z16 step off per frame (identical frames are a frozen sensor)."""
    for i in range(n):
        px, rgb = depth.copy(), np.zeros((CH, CW, 3), np.uint8)
        px[(7 * i) % H, (11 * i) % W] += np.uint16(noise)
        keep += [px, rgb]
        for sensor, prof, pix, bpp, width in ((dsensor, dp, px, 2, W), (csensor, cp, rgb, 3, CW)):
            if sensor is csensor and colour_until is not None and i >= colour_until:
                continue
            f = rs.software_video_frame()
            f.pixels, f.bpp, f.stride = pix, bpp, bpp * width
            f.timestamp, f.frame_number = 1000.0 * i * period, i
            f.domain = rs.timestamp_domain.hardware_clock
            f.profile = prof
            if sensor is dsensor:
                f.depth_units = UNITS
            sensor.on_video_frame(f)
        time.sleep(period)


EXTRINSICS = {  # depth -> colour: an offset along the optical axis that rs.align alone gets wrong, and a rotation
    "translation": (np.eye(3), np.array([0.05, -0.01, 0.03])),
    "rotation": (_rot(np.radians(2.0), np.radians(-4.0)), np.array([0.03, 0.005, 0.02])),
}


def _aligned_frames(tmp_path, R, t, n=8, colour_until=None, duration=0.6):
    p = Path(tmp_path) / "cell.toml"
    p.write_text(ALIGNED_CELL)
    cell = read_cell(p)
    sd, dsensor, csensor, syncer, dp, cp = _aligned_device(R, t)
    src = RealSenseSource(cell, ("a",), device=(dsensor, syncer, dp, cp), duration=duration, frame_timeout=0.15)
    depth, _ = _render_depth()
    keep: list = []
    feeder = threading.Thread(target=_push_pair, args=(dsensor, csensor, dp, cp, depth, n, 1 / 30, keep, colour_until))
    feeder.start()
    ticks = list(src.ticks())
    feeder.join()
    src.close()
    return src, ticks


@pytest.mark.parametrize("which", sorted(EXTRINSICS))
def test_aligned_depth_is_the_colour_cameras_depth(tmp_path, which):
    """A box before a wall in the depth stream; after rs.align, the depth at each colour pixel is the z, in the
    colour camera's frame, of the scene point on that pixel's ray: to the z16 rounding (0.125 mm) on the surfaces,
    to a colour pixel at the box's edges. The camera is the colour stream's (80x60, its focal lengths)."""
    R, t = EXTRINSICS[which]
    src, ticks = _aligned_frames(tmp_path, R, t)
    cam = src.cameras[0]
    assert (cam.width, cam.height, cam.cx, cam.cy, cam.fx, cam.fy) == pytest.approx(_depthguard(C_INTR))
    assert src.stream == "color" and src.align == "color"
    np.testing.assert_allclose(src.depth_to_color[0], R, atol=1e-6)
    np.testing.assert_allclose(src.depth_to_color[1], t, atol=1e-6)
    frames = [tk.frames[0] for tk in ticks if tk.frames is not None]
    assert len(frames) >= 3
    d = frames[-1]
    assert d.shape == (CH, CW) and d.dtype == np.float32
    z_box, z_wall, on_box = _truth_colour(R, t)
    truth = np.where(on_box, z_box, z_wall)
    valid = np.isfinite(d)
    tol = UNITS / 2 + 2e-6  # the z16 rounding (half a step: 0.125 mm) and float32
    nb = _neighbours(on_box)
    interior = np.all(nb == on_box, axis=0)  # the pixel and its 8 neighbours see one surface
    interior[[0, -1], :] = interior[:, [0, -1]] = False  # rs.align skips depth pixels that cross the border
    assert valid[interior].mean() > 0.97, valid[interior].mean()  # rs.align filled the colour image
    err = np.abs(d - truth)
    assert np.max(err[interior & valid]) <= tol, np.max(err[interior & valid])
    # every depth is that of a surface seen at this colour pixel or a neighbour (one pixel of the colour grid),
    # taken on this pixel's ray
    box_ok = nb.any(axis=0) & (np.abs(d - z_box) <= tol)
    wall_ok = (~nb).any(axis=0) & (np.abs(d - z_wall) <= tol)
    assert np.all((box_ok | wall_ok)[valid]), np.argwhere(valid & ~(box_ok | wall_ok))[:5]
    # the box is where the colour camera sees it
    assert np.all(np.abs(d - z_box)[on_box & interior] <= tol)
    assert np.all(np.abs(d - z_wall)[~on_box & interior & valid] <= tol)
    assert not np.allclose(z_box[on_box], BOX_Z, atol=1e-3)  # (rs.align's own value, the depth camera's z, is not it)


def test_aligned_colour_dropout_and_disconnect_become_named_faults(tmp_path):
    """Colour frames stop (depth goes on): no aligned frame, a fault naming the camera and the missing colour,
    never a crash; a poll that raises (a pulled cable) is a 'disconnected' fault."""
    R, t = EXTRINSICS["translation"]
    src, ticks = _aligned_frames(tmp_path, R, t, n=24, colour_until=6, duration=0.7)  # colour for 0.2 s of 0.8 s
    frames = [tk for tk in ticks if tk.frames is not None]
    assert frames and all(tk.frames[0].shape == (CH, CW) for tk in frames)
    assert max(tk.t for tk in frames) < 0.45  # nothing after the colour stopped (the syncer's wait aside)
    faults = [tk.faults["d435"] for tk in ticks if tk.faults]
    assert faults and any("depth frames without colour" in f for f in faults), faults[-3:]
    assert all(tk.q is None for tk in ticks)

    p = Path(tmp_path) / "cell.toml"
    sd, dsensor, csensor, syncer, dp, cp = _aligned_device(R, t)

    class Unplugged:
        def poll_for_frames(self):
            raise RuntimeError("Device disconnected")

    src = RealSenseSource(read_cell(p), ("a",), device=(dsensor, Unplugged(), dp, cp), duration=0.05)
    ticks = list(src.ticks())
    assert ticks and all(tk.frames is None and "disconnected" in tk.faults["d435"] for tk in ticks)


def test_aligned_needs_the_colour_stream_and_its_extrinsics(tmp_path):
    p = Path(tmp_path) / "cell.toml"
    p.write_text(ALIGNED_CELL)
    cell = read_cell(p)
    sd, dsensor, csensor, syncer, dp, cp = _aligned_device(*EXTRINSICS["translation"])
    with pytest.raises(ValueError, match='align = "color" needs the colour stream: no colour stream'):
        RealSenseSource(cell, ("a",), device=(dsensor, syncer, dp))
    sd2 = rs.software_device()  # a colour profile that has no extrinsics to the depth profile
    s2 = sd2.add_sensor("Color")
    vs = rs.video_stream()
    vs.type, vs.index, vs.uid, vs.width, vs.height, vs.fps, vs.bpp = (rs.stream.color, 0, 7, CW, CH, 30, 3)
    vs.fmt, vs.intrinsics = rs.format.rgb8, _rs_intr(*C_INTR)
    lone = s2.add_video_stream(vs)
    with pytest.raises(ValueError, match="no extrinsics from its depth to its colour stream"):
        RealSenseSource(cell, ("a",), device=(dsensor, syncer, dp, lone))


class _LivePyrealsense2:
    """pyrealsense2 whose ``config`` records ``enable_stream`` and whose ``pipeline`` runs on a software device
    (``software_device.add_to(context)`` lists no device in pyrealsense2 2.59, so the real pipeline cannot start on
    one): the live branch of the source, its stream configuration included, runs on the SDK's own frames."""

    def __init__(self, dsensor, syncer, dp, cp, fail=False):
        self.enabled: list[tuple] = []
        self.stopped = 0
        outer = self

        class Config:
            def enable_stream(self, *args):
                outer.enabled.append(args)

        class Profile:
            def get_device(self):
                class Dev:
                    def first_depth_sensor(self):
                        return type("S", (), {"get_depth_scale": lambda s: dsensor.get_option(rs.option.depth_units)})()

                return Dev()

            def get_stream(self, kind):
                return {rs.stream.depth: dp, rs.stream.color: cp}[kind]

        class Pipeline:
            def start(self, cfg):
                if fail:
                    raise RuntimeError("Couldn't resolve requests")
                return Profile()

            def poll_for_frames(self):
                return syncer.poll_for_frames()

            def stop(self):
                outer.stopped += 1

        self.config, self.pipeline = Config, Pipeline

    def __getattr__(self, name):
        return getattr(rs, name)


@pytest.mark.parametrize("aligned", [False, True])
def test_live_pipeline_enables_the_colour_stream_when_aligned(tmp_path, monkeypatch, aligned):
    import depthguard.runner.realsense as rsmod

    p = Path(tmp_path) / "cell.toml"
    text = ALIGNED_CELL if aligned else CELL
    p.write_text(text.replace("max_depth = 4.0", "max_depth = 4.0\nwidth = 80\nheight = 60\nrate = 15.0"))
    cell = read_cell(p)
    R, t = EXTRINSICS["rotation"]
    sd, dsensor, csensor, syncer, dp, cp = _aligned_device(R, t)
    fake = _LivePyrealsense2(dsensor, syncer, dp, cp)
    monkeypatch.setattr(rsmod, "import_pyrealsense2", lambda: fake)
    src = RealSenseSource(cell, ("a",), duration=0.4)
    want = [(rs.stream.depth, 80, 60, rs.format.z16, 15)]
    if aligned:
        want.append((rs.stream.color, 80, 60, rs.format.rgb8, 15))
    assert fake.enabled == want
    cam = src.cameras[0]
    got = (cam.width, cam.height, cam.cx, cam.cy, cam.fx, cam.fy)
    assert got == pytest.approx(_depthguard(C_INTR if aligned else D_INTR))
    depth, _ = _render_depth()
    keep: list = []
    feeder = threading.Thread(target=_push_pair, args=(dsensor, csensor, dp, cp, depth, 8, 1 / 30, keep))
    feeder.start()
    frames = [tk.frames[0] for tk in src.ticks() if tk.frames is not None]
    feeder.join()
    src.close()
    assert fake.stopped == 1 and frames
    assert frames[-1].shape == ((CH, CW) if aligned else (H, W))
    if aligned:
        z_box, z_wall, on_box = _truth_colour(R, t)
        ok = np.isfinite(frames[-1])
        assert ok.mean() > 0.95
        assert np.median(np.abs(frames[-1] - np.where(on_box, z_box, z_wall))[ok]) <= UNITS / 2

    fake = _LivePyrealsense2(dsensor, syncer, dp, cp, fail=True)
    monkeypatch.setattr(rsmod, "import_pyrealsense2", lambda: fake)
    what = 'the depth and colour streams \\(align = "color"\\)' if aligned else "the depth stream"
    with pytest.raises(ValueError, match=f"'d435': cannot start {what}"):
        RealSenseSource(cell, ("a",))


def test_aligned_runner_stops_the_controller_when_the_colour_stream_stops(tmp_path):
    """The run goes on after the colour stream stops (depth still arriving): the distances go stale and the
    controller stops, as for a silent depth stream."""
    from depthguard.robot.model import load_lwr4
    from depthguard.runner.chain import Chain
    from depthguard.runner.run import RunLog, run_chain

    p = Path(tmp_path) / "cell.toml"
    p.write_text(ALIGNED_CELL)
    cell = read_cell(p)
    R, t = EXTRINSICS["rotation"]
    sd, dsensor, csensor, syncer, dp, cp = _aligned_device(R, t)

    class Joints:
        def latest(self):
            return time.monotonic(), np.zeros(7), np.zeros(7)

    model = load_lwr4()
    src = RealSenseSource(cell, model.joint_names, joints=Joints(), device=(dsensor, syncer, dp, cp), duration=60.0)
    chain = Chain(cell, src.cameras, model)
    chain.on_frames([np.full((CH, CW), 2.0, np.float32)], np.zeros(7))  # compile the kernels before the clock runs
    chain.query(0.0, np.zeros(7))
    chain = Chain(cell, src.cameras, model)
    depth, _ = _render_depth()
    keep: list = []
    feeder = threading.Thread(target=_push_pair, args=(dsensor, csensor, dp, cp, depth, 75, 1 / 30, keep, 30, True))
    _feed_from_second_tick(src, feeder, tail=0.5)  # 2.5 s of depth, colour for its first 1 s
    log = RunLog()
    summary = run_chain(cell, src, chain, log=log)
    feeder.join()
    assert summary["commands"] > 20 and summary["frames"] >= 1
    assert summary["statuses"].get("OK", 0) > 0  # it ran on aligned frames (past the resume latch)
    assert log.status[-1].startswith("STOP_")  # the colour stopped: the distances went stale
    assert any("depth frames without colour" in k for k in summary["sensor_faults"])
    assert all(np.all(np.isfinite(q)) for q in log.q_cmd)
