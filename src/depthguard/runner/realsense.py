"""A live Intel RealSense depth camera as a source (``depthguard run --source realsense``).

The depth stream comes through ``pyrealsense2`` (``pip install 'depthguard[realsense]'``; the wheel also needs
the system's libusb: ``apt install libusb-1.0-0``) with the device's own intrinsics and depth scale (cell file
``intrinsics = "device"``) and the cell file's extrinsics. The source ticks at the controller's rate in real
time; a new depth frame is handed over at the first tick after it arrives.

Faults never crash the run: no frame for ``frame_timeout`` seconds (a dropped stream, a pulled cable) or an
SDK error gives ticks without frames and a ``faults`` entry naming the camera, so the distances go stale and
the controller stops (``STOP_STALE_DISTANCES``); frames coming back resume the run (after the resume latch).

Optional alignment (cell file ``align = "color"`` on the camera; default ``"none"``): the colour stream is
enabled beside the depth stream (both at the cell file's ``width`` x ``height`` when given, the device's
defaults otherwise, ``rate`` fps; colour as rgb8) and every frame set goes through ``pyrealsense2``'s own
``rs.align(rs.stream.color)`` processing block, so that depth pixel (u, v) is colour pixel (u, v) (for a
colour-based person detector beside DepthGuard). The camera model is then the colour stream's intrinsics at
the colour resolution and the cell file's extrinsics are those of the colour camera's optical frame
(``depthguard cell check`` says so). ``rs.align`` moves each depth pixel to the colour pixels that it covers
but keeps its value, the depth along the *depth* camera's optical axis; the source turns that value into
the depth along the colour camera's axis with the device's depth-to-colour extrinsics (per colour pixel
``z_color = (z_depth + (R^T t)_z) / (R^T r)_z``, ``r`` the pixel's ray, ``P_color = R P_depth + t``: no
reprojection, an exact change of the value; the identity when the two axes are parallel and not offset
along them, as nearly on a D4xx). A frame set without its depth or its colour frame gives no frame (the
syncer drops one of them): a stream that stays away becomes the same named fault and stale distances as a
silent depth stream. Lens distortion of the colour stream is ignored, as the depth stream's is (the
model is a pinhole camera; D435 streams report none). librealsense's ``ppx, ppy`` put pixel centres at
integers: the camera gets half a pixel added (:func:`depthguard.camera.principal_point_from_opencv`).

Joint states are not in the camera's stream: pass ``joints``, an object whose ``latest()`` returns
``(t, q, qdot)`` (time on ``time.monotonic()``'s clock) or None, fed by your robot driver. Without it every tick
carries no joint state and the controller stops (``STOP_INVALID_INPUT``): a camera alone never moves a robot.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

import numpy as np

from depthguard.camera import Camera, principal_point_from_opencv
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
            pipeline; with ``align = "color"``: ``(depth sensor, syncer, depth profile, colour profile)``,
            the depth profile's extrinsics to the colour profile registered.
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
        self.align = self.cc.align  # "none" | "color"
        aligned = self.align == "color"
        color_vsp = None
        if device is None:
            p = self.cc.params
            w, h = int(p.get("width", 0) or 0), int(p.get("height", 0) or 0)
            fps = int(round(self.cc.rate))
            cfg = rs.config()
            cfg.enable_stream(rs.stream.depth, w, h, rs.format.z16, fps)
            if aligned:
                cfg.enable_stream(rs.stream.color, w, h, rs.format.rgb8, fps)
            self._pipeline = rs.pipeline()
            try:
                profile = self._pipeline.start(cfg)
            except RuntimeError as exc:
                what = 'the depth and colour streams (align = "color")' if aligned else "the depth stream"
                raise ValueError(f"RealSense camera '{self.cc.name}': cannot start {what} ({exc})") from None
            try:
                sensor = profile.get_device().first_depth_sensor()
                self.depth_scale = float(sensor.get_depth_scale())
                vsp = profile.get_stream(rs.stream.depth).as_video_stream_profile()
                if aligned:
                    color_vsp = profile.get_stream(rs.stream.color).as_video_stream_profile()
            except RuntimeError as exc:
                self.close()
                raise ValueError(f"RealSense camera '{self.cc.name}': the streams are unusable ({exc})") from None
            self._poll = self._pipeline.poll_for_frames
        else:
            sensor, syncer, vsp, *more = device
            color_vsp = more[0].as_video_stream_profile() if more else None
            self.depth_scale = float(sensor.get_option(rs.option.depth_units))
            self._poll = syncer.poll_for_frames
        self._align = None
        self._zfix: tuple[np.ndarray, np.float32] | None = None
        self._why = ""  # with alignment: why the last frame set gave no frame
        if aligned:
            ext = self._extrinsics(vsp, color_vsp)
            self._align = rs.align(rs.stream.color)
            intr = color_vsp.get_intrinsics()
            R = np.asarray(ext.rotation, float).reshape(3, 3).T  # librealsense stores it column-major
            t = np.asarray(ext.translation, float)
            self.depth_to_color = (R, t)  # P_color = R P_depth + t, m
            self._zfix = _colour_z(intr, R, t)
        else:
            intr = vsp.get_intrinsics()
        self.stream = self.align if aligned else "depth"  # the stream whose camera model and pixels the frames have
        self.distortion = (str(intr.model), tuple(float(c) for c in intr.coeffs))
        self._size = (int(intr.width), int(intr.height))
        cx, cy = principal_point_from_opencv(intr.ppx, intr.ppy)  # (librealsense: pixel centres at integers)
        intrinsics = dict(width=intr.width, height=intr.height, fx=intr.fx, fy=intr.fy, cx=cx, cy=cy)
        self.cameras: list[Camera] = [self.cc.build(**intrinsics)]

    def _extrinsics(self, vsp: Any, color_vsp: Any) -> Any:
        """The device's depth-to-colour extrinsics (``rs.align`` needs them), or ``ValueError`` naming the camera."""
        why = "no colour stream was given"
        if color_vsp is not None:
            try:
                return vsp.get_extrinsics_to(color_vsp)
            except RuntimeError as exc:
                why = f"the device has no extrinsics from its depth to its colour stream ({exc})"
        self.close()
        raise ValueError(f"RealSense camera '{self.cc.name}': align = \"color\" needs the colour stream: {why}")

    def _frame(self) -> np.ndarray | None:
        """The newest depth frame as (H, W) float32 m (NaN = no reading), or None if none arrived; aligned to
        the colour stream (its pixels, depth along its axis) with ``align = "color"``."""
        got = self._poll()
        if not got:
            return None
        if self._align is not None:
            has_depth, has_colour = bool(got.get_depth_frame()), bool(got.get_color_frame())
            if not (has_depth and has_colour):  # rs.align would hand the frame set back unaligned
                self._why = "depth frames without colour" if has_depth else "colour frames without depth"
                return None
            depth = self._align.process(got).get_depth_frame()
            if not depth or (depth.get_width(), depth.get_height()) != self._size:
                self._why = "rs.align gave no depth at the colour resolution"
                return None
        else:
            depth = got.get_depth_frame() if hasattr(got, "get_depth_frame") else got
            if not depth:
                return None
        raw = np.asanyarray(depth.get_data()).astype(np.float32) * np.float32(self.depth_scale)
        raw[raw <= 0] = np.nan
        if self._zfix is not None:  # the depth camera's z -> the colour camera's z (module docstring)
            a, b = self._zfix
            raw = (raw + b) / a
        self._why = ""
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
                why = f" ({self._why})" if self._why else ""
                faults.setdefault(self.cc.name, f"no frame for {t - last_frame:.2f} s{why}")
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


def _colour_z(intr: Any, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.float32] | None:
    """Per colour pixel ``(a, b)`` with ``z_color = (z_depth + b) / a``: for the point ``P_c = z_color r`` seen
    at colour pixel (u, v) (``r = ((u - cx)/fx, (v - cy)/fy, 1)``), ``z_depth = e3 . R^T (P_c - t)``, so
    ``a = R[:, 2] . r`` and ``b = R[:, 2] . t`` (``P_color = R P_depth + t``). None when it is the identity."""
    u = (np.arange(intr.width) - intr.ppx) / intr.fx
    v = (np.arange(intr.height) - intr.ppy) / intr.fy
    a = R[0, 2] * u[None, :] + R[1, 2] * v[:, None] + R[2, 2]
    b = float(R[:, 2] @ t)
    if np.all(np.abs(a - 1.0) < 1e-9) and abs(b) < 1e-9:
        return None
    a = np.where(a > 0, a, np.nan)  # a colour ray at right angles to the depth axis: no depth
    return a.astype(np.float32), np.float32(b)
