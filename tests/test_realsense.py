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
    assert (cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy) == (W, H, 50.0, 51.0, 31.5, 23.5)
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
    src = RealSenseSource(cell, model.joint_names, joints=Joints(), device=(sensor, syncer, profile), duration=5.0)
    keep: list = []
    feeder = threading.Thread(target=_push, args=(sensor, profile, 45, 1 / 30, keep))  # 1.5 s, then silence
    feeder.start()
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
