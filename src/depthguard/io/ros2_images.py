"""ROS 2 image messages: depth images (``16UC1`` millimetres, ``32FC1`` metres), robot masks (``mono8``),
camera info and ``rgb8`` pictures, built and read without a ROS installation. :mod:`depthguard.io.ros2`
re-exports all of it."""

from __future__ import annotations

from typing import Any

import numpy as np

from depthguard.io.ros2_types import _t, header
from depthguard.kernels.depthimage import metres_or_nan

__all__ = ["image_msg", "image_to_depth", "mask_msg", "image_to_mask", "camera_info_msg", "rgb_image_msg"]


def image_msg(t: float, frame_id: str, depth: np.ndarray, encoding: str = "16UC1"):
    """Depth image (H, W) as ``sensor_msgs/msg/Image``.

    Args:
        depth: metres (float; 0/NaN/inf = no reading) or, for ``16UC1``, already uint16 millimetres.
        encoding: ``16UC1`` (uint16 mm, 0 = no reading) or ``32FC1`` (float32 m, NaN = no reading).
    """
    d = np.asarray(depth)
    if d.ndim != 2:
        raise ValueError(f"depth image must be (H, W), got shape {d.shape}")
    if encoding == "16UC1":
        if d.dtype != np.uint16:
            m = np.nan_to_num(np.asarray(d, float), nan=0.0, posinf=0.0, neginf=0.0) * 1000.0
            d = np.clip(np.round(m), 0, 65535).astype(np.uint16)
        data = d.astype("<u2")
    elif encoding == "32FC1":
        f = np.asarray(d, dtype=np.float32)
        data = np.where(np.isfinite(f) & (f > 0), f, np.float32(np.nan)).astype("<f4")
    else:
        raise ValueError(f"depth encoding must be '16UC1' or '32FC1', got {encoding!r}")
    return _image(t, frame_id, data, encoding)


def _image(t: float, frame_id: str, data: np.ndarray, encoding: str):
    """``sensor_msgs/Image`` of the (H, W) or (H, W, C) little-endian samples ``data``, rows unpadded."""
    h, w = data.shape[:2]
    return _t("sensor_msgs/msg/Image")(
        header=header(t, frame_id),
        height=h,
        width=w,
        encoding=encoding,
        is_bigendian=0,
        step=w * int(np.prod(data.shape[2:], dtype=int)) * data.itemsize,
        data=np.frombuffer(np.ascontiguousarray(data).tobytes(), dtype=np.uint8),
    )


def mask_msg(t: float, frame_id: str, mask: np.ndarray):
    """``sensor_msgs/Image`` mono8 of a robot mask (H, W) bool: 255 = robot pixel."""
    m = np.asarray(mask, bool)
    if m.ndim != 2:
        raise ValueError(f"robot mask must be (H, W), got shape {m.shape}")
    return _image(t, frame_id, m.astype(np.uint8) * 255, "mono8")


def image_to_mask(msg) -> np.ndarray:
    """(H, W) bool robot mask from a mono8 ``sensor_msgs/msg/Image`` (non-zero = robot pixel; rows may be
    padded to ``step`` bytes). Raises ``ValueError`` for another encoding, a row step shorter than a row or
    fewer bytes than the size says."""
    if str(msg.encoding) != "mono8":
        raise ValueError(f"robot mask must be a mono8 Image, got {msg.encoding!r}")
    h, w = int(msg.height), int(msg.width)
    raw = np.asarray(msg.data, np.uint8).reshape(-1)
    step = int(msg.step) or w
    if step < w or raw.size < step * h:
        raise ValueError(f"robot mask {w}x{h} holds {raw.size} bytes with step {msg.step}: too few")
    return raw[: step * h].reshape(h, step)[:, :w] > 0


def image_to_depth(msg) -> np.ndarray:
    """(H, W) float32 depth in metres from a ``sensor_msgs/msg/Image`` (NaN = no reading).

    Raises ``ValueError`` for encodings other than 16UC1 / 32FC1 or a size that contradicts the data.
    """
    enc = str(msg.encoding).upper()
    h, w = int(msg.height), int(msg.width)
    dtype = {"16UC1": np.uint16, "MONO16": np.uint16, "32FC1": np.float32}.get(enc)
    if dtype is None:
        raise ValueError(f"Image encoding {msg.encoding!r} is not a depth encoding (expected 16UC1 or 32FC1)")
    item = np.dtype(dtype).itemsize
    raw = np.ascontiguousarray(np.asarray(msg.data, dtype=np.uint8)).reshape(-1)
    step = int(msg.step) or w * item
    if step < w * item or raw.size < step * h:
        raise ValueError(f"Image {w}x{h} {msg.encoding} holds {raw.size} bytes with step {msg.step}: too few")
    order = ">" if msg.is_bigendian else "<"
    typ = np.dtype(dtype).newbyteorder(order)
    if step == w * item:  # (the usual layout: read the samples where they lie, one pass to the output)
        img = np.frombuffer(raw, dtype=typ, count=h * w).reshape(h, w)
    else:
        img = np.ascontiguousarray(raw[: step * h].reshape(h, step)[:, : w * item]).view(typ).reshape(h, w)
    return metres_or_nan(img, 1000.0 if dtype == np.uint16 else 1.0)


def camera_info_msg(t: float, frame_id: str, camera) -> Any:
    """``sensor_msgs/msg/CameraInfo`` of a :class:`depthguard.camera.Camera` (no distortion). ``K`` and ``P`` hold
    the principal point in ROS's convention (pixel centres at integers: DepthGuard's ``cx - 0.5``,
    :func:`depthguard.camera.principal_point_to_opencv`), so that ROS tools and DepthGuard's own readers
    (which add the half pixel back) cast the same rays."""
    from depthguard.camera import principal_point_to_opencv

    cx, cy = principal_point_to_opencv(camera.cx, camera.cy)
    K = [camera.fx, 0.0, cx, 0.0, camera.fy, cy, 0.0, 0.0, 1.0]
    P = [camera.fx, 0.0, cx, 0.0, 0.0, camera.fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0]
    roi = _t("sensor_msgs/msg/RegionOfInterest")(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    return _t("sensor_msgs/msg/CameraInfo")(
        header=header(t, frame_id),
        height=int(camera.height),
        width=int(camera.width),
        distortion_model="plumb_bob",
        d=np.zeros(5),
        k=np.array(K, dtype=float),
        r=np.eye(3).ravel(),
        p=np.array(P, dtype=float),
        binning_x=0,
        binning_y=0,
        roi=roi,
    )


def rgb_image_msg(t: float, frame_id: str, rgb: np.ndarray):
    """(H, W, 3) uint8 image as ``sensor_msgs/msg/Image`` (``rgb8``)."""
    img = np.ascontiguousarray(np.asarray(rgb, dtype=np.uint8))
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"an rgb8 image must be (H, W, 3), got shape {img.shape}")
    return _image(t, frame_id, img, "rgb8")
