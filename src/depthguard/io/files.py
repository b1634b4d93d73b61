"""Readers and writers for DepthGuard's file formats (DESIGN.md §3).

* camera JSON: ``{"width", "height", "fx", "fy", "cx", "cy", "R": 3x3, "t": 3}`` plus optional
  ``"min_depth"``, ``"max_depth"``, ``"depth_scale"``;
* points JSON: ``[{"name": str, "position": [x, y, z], "radius": r}, ...]`` in the world frame;
* depth: 16-bit PNG in units of ``depth_scale`` (default mm), 0 = no reading; or ``.npy`` float32 metres,
  where 0, NaN and inf mean no reading. Readers return float32 metres with NaN for "no reading".
* mask: 8- or 16-bit PNG (or ``.npy``), nonzero = robot pixel.

PNG I/O uses ``pypng`` (pure Python, no system libraries).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import png

from depthguard.camera import Camera

__all__ = [
    "ControlPoint",
    "read_camera",
    "write_camera",
    "read_points",
    "write_points",
    "read_depth",
    "write_depth",
    "read_mask",
    "write_mask",
]


class ControlPoint(NamedTuple):
    """A named sphere on the robot: ``position`` (3,) world metres and ``radius`` metres."""

    name: str
    position: np.ndarray
    radius: float


def _load_json(path: str | Path, what: str) -> Any:
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"{what} file '{p}' does not exist")
    try:
        return json.loads(p.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{what} file '{p}' is not valid JSON: {exc}") from None


def read_camera(path: str | Path) -> Camera:
    """Read a camera JSON file; errors name the file and the field."""
    try:
        return Camera.from_dict(_load_json(path, "camera"))
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None


def write_camera(path: str | Path, camera: Camera) -> None:
    """Write ``camera`` as camera JSON."""
    Path(path).write_text(json.dumps(camera.to_dict(), indent=2))


def read_points(path: str | Path) -> list[ControlPoint]:
    """Read a points JSON file into a list of :class:`ControlPoint`."""
    data = _load_json(path, "points")
    if not isinstance(data, list):
        raise ValueError(f"{path}: points JSON must be a list of objects, got {type(data).__name__}")
    out: list[ControlPoint] = []
    for i, item in enumerate(data):
        where = f"{path}: points[{i}]"
        if not isinstance(item, dict):
            raise ValueError(f"{where} must be an object with 'name', 'position', 'radius'")
        for key in ("position", "radius"):
            if key not in item:
                raise ValueError(f"{where} is missing field '{key}'")
        name = item.get("name", f"p{i}")
        if not isinstance(name, str):
            raise ValueError(f"{where}.name must be a string, got {name!r}")
        try:
            pos = np.array(item["position"], dtype=float)
        except (TypeError, ValueError):
            raise ValueError(f"{where}.position must be [x, y, z] numbers, got {item['position']!r}") from None
        if pos.shape != (3,) or not np.all(np.isfinite(pos)):
            raise ValueError(f"{where}.position must be [x, y, z] finite numbers, got {item['position']!r}")
        r = item["radius"]
        if isinstance(r, bool) or not isinstance(r, int | float) or not np.isfinite(r) or r < 0:
            raise ValueError(f"{where}.radius must be a number >= 0, got {r!r}")
        out.append(ControlPoint(name, pos, float(r)))
    return out


def write_points(path: str | Path, points: list[ControlPoint]) -> None:
    """Write control points as points JSON."""
    data = [{"name": p.name, "position": [float(x) for x in p.position], "radius": float(p.radius)} for p in points]
    Path(path).write_text(json.dumps(data, indent=2))


def _read_png(path: Path) -> tuple[np.ndarray, int]:
    try:
        width, height, rows, info = png.Reader(filename=str(path)).asDirect()
    except (png.Error, OSError) as exc:
        raise ValueError(f"{path}: cannot read PNG: {exc}") from None
    planes = info["planes"]
    arr = np.vstack([np.asarray(r, dtype=np.uint16) for r in rows]).reshape(height, width, planes)
    return arr, info["bitdepth"]


def read_depth(path: str | Path, camera: Camera | None = None) -> np.ndarray:
    """Read a depth image as (H, W) float32 metres with NaN where there is no reading.

    ``.png`` must be single-channel 16-bit; its values are multiplied by ``camera.depth_scale``
    (default 0.001, millimetres). ``.npy`` must be a 2-D float array in metres. If ``camera`` is given,
    the shape is checked against it.
    """
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"depth file '{p}' does not exist")
    suffix = p.suffix.lower()
    if suffix == ".png":
        arr, bitdepth = _read_png(p)
        if arr.shape[2] != 1 or bitdepth != 16:
            raise ValueError(
                f"{p}: depth PNG must be single-channel 16-bit (mm, 0 = no reading), "
                f"got {arr.shape[2]} channel(s) of {bitdepth} bits"
            )
        scale = camera.depth_scale if camera is not None else 0.001
        raw = arr[..., 0].astype(np.float32)
        depth = raw * np.float32(scale)
        depth[raw == 0] = np.nan
    elif suffix == ".npy":
        try:
            depth = np.load(p, allow_pickle=False)
        except (ValueError, OSError) as exc:
            raise ValueError(f"{p}: cannot read .npy: {exc}") from None
        if depth.ndim != 2 or not np.issubdtype(depth.dtype, np.floating):
            raise ValueError(f"{p}: depth .npy must be a 2-D float array in metres, got {depth.dtype} {depth.shape}")
        depth = depth.astype(np.float32)
        depth[~np.isfinite(depth) | (depth <= 0)] = np.nan
    else:
        raise ValueError(f"{p}: depth file must be .png (16-bit mm) or .npy (float32 m), got '{suffix}'")
    if camera is not None:
        camera.check_image(depth, f"depth '{p}'")
    return depth


def write_depth(path: str | Path, depth: np.ndarray, depth_scale: float = 0.001) -> None:
    """Write (H, W) metres (NaN/inf/<=0 = no reading) to ``.png`` (uint16, 0 = none) or ``.npy`` (float32)."""
    p = Path(path)
    d = np.asarray(depth, dtype=np.float64)
    if d.ndim != 2:
        raise ValueError(f"depth must be a 2-D array, got shape {d.shape}")
    if p.suffix.lower() == ".png":
        valid = np.isfinite(d) & (d > 0)
        units = np.zeros(d.shape, dtype=np.uint16)
        units[valid] = np.clip(np.rint(d[valid] / depth_scale), 1, 65535).astype(np.uint16)
        with p.open("wb") as fh:
            png.Writer(width=d.shape[1], height=d.shape[0], greyscale=True, bitdepth=16).write(fh, units.tolist())
    elif p.suffix.lower() == ".npy":
        np.save(p, d.astype(np.float32))
    else:
        raise ValueError(f"{p}: depth file must end in .png or .npy")


def read_mask(path: str | Path, camera: Camera | None = None) -> np.ndarray:
    """Read a robot mask (PNG of any bit depth or ``.npy``) as an (H, W) bool array, nonzero = robot."""
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"mask file '{p}' does not exist")
    if p.suffix.lower() == ".png":
        arr, _ = _read_png(p)
        mask = arr[..., 0] != 0
    elif p.suffix.lower() == ".npy":
        arr = np.load(p, allow_pickle=False)
        if arr.ndim != 2:
            raise ValueError(f"{p}: mask .npy must be 2-D, got shape {arr.shape}")
        mask = arr != 0
    else:
        raise ValueError(f"{p}: mask file must be .png or .npy")
    if camera is not None:
        camera.check_image(mask, f"mask '{p}'")
    return mask


def write_mask(path: str | Path, mask: np.ndarray) -> None:
    """Write an (H, W) bool mask as an 8-bit PNG (255 = robot)."""
    m = np.asarray(mask).astype(bool)
    with Path(path).open("wb") as fh:
        png.Writer(width=m.shape[1], height=m.shape[0], greyscale=True, bitdepth=8).write(
            fh, (m.astype(np.uint8) * 255).tolist()
        )
