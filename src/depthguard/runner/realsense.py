"""A live Intel RealSense depth camera as a source (``depthguard run --source realsense``).

The depth stream comes through ``pyrealsense2`` (``pip install 'depthguard[realsense]'``; the wheel also needs
the system's libusb: ``apt install libusb-1.0-0``) with the device's own intrinsics and depth scale (cell file
``intrinsics = "device"``) and the cell file's extrinsics. The source ticks at the controller's rate in real
time; a new depth frame is handed over at the first tick after it arrives.

Faults never crash the run: no frame for ``frame_timeout`` seconds (a dropped stream, a pulled cable) or an
SDK error gives ticks without frames and a ``faults`` entry naming the camera, so the distances go stale and
the controller stops (``STOP_STALE_DISTANCES``); frames coming back resume the run (after the resume latch).

Joint states are not in the camera's stream: pass ``joints``, an object whose ``latest()`` returns
``(t, q, qdot)`` (time on ``time.monotonic()``'s clock) or None, fed by your robot driver. Without it every tick
carries no joint state and the controller stops (``STOP_INVALID_INPUT``): a camera alone never moves a robot.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

import numpy as np

from depthguard.camera import Camera
from depthguard.io.cellfile import CellFile
from depthguard.runner.sources import Tick

__all__ = ["RealSenseSource", "import_pyrealsense2"]


def import_pyrealsense2():
    """``pyrealsense2``, or ``ValueError`` with the install hint (the wheel, and the system's libusb)."""
    try:
        import pyrealsense2 as rs
    except ImportError as exc:
        raise ValueError(
            f"the RealSense source needs pyrealsense2: pip install 'depthguard[realsense]' and the system's"
            f" libusb (apt install libusb-1.0-0) ({exc})"
        ) from None
    return rs


class RealSenseSource:
    """Live depth from a RealSense (module docstring).

    Args:
        cell: the cell file (its first camera describes the RealSense).
        joint_names: the model's joint order.
        joints: joint-state provider (``latest() -> (t, q, qdot) | None``); None = no joint states.
        device: for tests, ``(sensor, syncer, profile)`` of an ``rs.software_device`` instead of the live
            pipeline.
        duration: stop after this many seconds (None = run until interrupted).
        frame_timeout: no frame for this long is a camera fault, s.
    """

    def __init__(
        self,
        cell: CellFile,
        joint_names: tuple[str, ...],
        *,
        joints: Any = None,
        device: tuple | None = None,
        duration: float | None = None,
        frame_timeout: float = 0.2,
    ) -> None:
        rs = import_pyrealsense2()
        self.rs = rs
        if len(cell.cameras) != 1:
            raise ValueError(
                f"{cell.path}: the RealSense source takes one camera, the cell file has {len(cell.cameras)}"
            )
        self.cc = cell.cameras[0]
        self.joint_names = tuple(joint_names)
        self.joints = joints
        self.duration = float("inf") if duration is None else float(duration)
        self.frame_timeout = float(frame_timeout)
        self.dt = 1.0 / float(cell.controller["rate"])
        self._pipeline = None
        if device is None:
            p = self.cc.params
            cfg = rs.config()
            cfg.enable_stream(rs.stream.depth, int(p.get("width", 0) or 0), int(p.get("height", 0) or 0),
                              rs.format.z16, int(round(self.cc.rate)))  # fmt: skip
            self._pipeline = rs.pipeline()
            try:
                profile = self._pipeline.start(cfg)
            except RuntimeError as exc:
                raise ValueError(f"RealSense camera '{self.cc.name}': cannot start the depth stream ({exc})") from None
            sensor = profile.get_device().first_depth_sensor()
            self.depth_scale = float(sensor.get_depth_scale())
            vsp = profile.get_stream(rs.stream.depth).as_video_stream_profile()
            self._poll = self._pipeline.poll_for_frames
        else:
            sensor, syncer, vsp = device
            self.depth_scale = float(sensor.get_option(rs.option.depth_units))
            self._poll = syncer.poll_for_frames
        intr = vsp.get_intrinsics()
        intrinsics = dict(width=intr.width, height=intr.height, fx=intr.fx, fy=intr.fy, cx=intr.ppx, cy=intr.ppy)
        self.cameras: list[Camera] = [self.cc.build(**intrinsics)]

    def _frame(self) -> np.ndarray | None:
        """The newest depth frame as (H, W) float32 m (NaN = no reading), or None if none arrived."""
        got = self._poll()
        if not got:
            return None
        depth = got.get_depth_frame() if hasattr(got, "get_depth_frame") else got
        if not depth:
            return None
        raw = np.asanyarray(depth.get_data()).astype(np.float32) * np.float32(self.depth_scale)
        raw[raw <= 0] = np.nan
        return raw

    def ticks(self) -> Iterator[Tick]:
        t0 = time.monotonic()
        last_frame = t0
        k = 0
        while True:
            t = time.monotonic()
            if t - t0 > self.duration:
                return
            faults: dict[str, str] = {}
            try:
                frame = self._frame()
            except RuntimeError as exc:  # the SDK reports a lost device this way
                frame, faults = None, {self.cc.name: f"disconnected ({exc})"}
            if frame is not None:
                last_frame = t
            elif t - last_frame > self.frame_timeout:
                faults.setdefault(self.cc.name, f"no frame for {t - last_frame:.2f} s")
            js = self.joints.latest() if self.joints is not None else None
            q = qd = None
            tj = t
            if js is not None:
                tj, q, qd = js
            tt = t - t0
            yield Tick(tt, q, qd, tj - t0, np.zeros(3), None if frame is None else [frame], tt, faults)
            k += 1
            sleep = t0 + k * self.dt - time.monotonic()
            if sleep > 0:
                time.sleep(sleep)

    def command(self, q_cmd: np.ndarray, qdot_cmd: np.ndarray) -> None:
        """Commands go to the robot through the recording/transport topics, not through the camera."""

    def close(self) -> None:
        if self._pipeline is not None:
            try:
                self._pipeline.stop()
            except RuntimeError:
                pass
