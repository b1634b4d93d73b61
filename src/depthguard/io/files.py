"""Readers and writers for DepthGuard's file formats (``docs/conventions.md``, "File formats").

* camera JSON: ``{"width", "height", "fx", "fy", "cx", "cy", "R": 3x3, "t": 3}`` plus optional
  ``"min_depth"``, ``"max_depth"``, ``"depth_scale"``;
* points JSON: ``[{"name": str, "position": [x, y, z], "radius": r}, ...]`` in the world frame;
* depth: 16-bit PNG in units of ``depth_scale`` (default mm), 0 = no reading; or ``.npy`` float32 metres,
  where 0, NaN and inf mean no reading. Readers return float32 metres with NaN for "no reading".
* mask: 8- or 16-bit PNG (or ``.npy``), nonzero = robot pixel.

Every reader raises :class:`~depthguard.errors.InputError` (a ``ValueError``) with one line naming the file
and the problem for anything it cannot use: a missing file or a directory, bytes that are not UTF-8 JSON, a
truncated or corrupt PNG or ``.npy``, wrong shapes or types, unknown fields (a typo such as ``min_Depth``
is an error, never a silent default). PNG I/O uses ``pypng`` (pure Python, no system libraries).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import png

from depthguard.camera import Camera
from depthguard.errors import InputError, check_known_keys
from depthguard.validation import is_numeric_nest

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
    "check_input_file",
    "prepare_out_dir",
]

#: The largest image a reader accepts when no camera gives the expected size (pixels).
MAX_PIXELS = 1 << 26

POINT_FIELDS = ("name", "position", "radius")


class ControlPoint(NamedTuple):
    """A named sphere on the robot: ``position`` (3,) world metres and ``radius`` metres."""

    name: str
    position: np.ndarray
    radius: float


def check_input_file(path: str | Path, what: str) -> Path:
    """Return ``path`` as a :class:`Path` if it is a readable file, else raise :class:`InputError` saying why."""
    p = Path(path)
    if p.is_dir():
        raise InputError(f"{what} file '{p}' is a directory, expected a file")
    if not p.exists():
        raise InputError(f"{what} file '{p}' does not exist")
    if not p.is_file():
        raise InputError(f"{what} file '{p}' is not a regular file")
    if not os.access(p, os.R_OK):
        raise InputError(f"{what} file '{p}' is not readable (permission denied)")
    return p


def prepare_out_dir(path: str | Path, what: str = "output folder") -> Path:
    """Create the output folder ``path`` (with parents) and check that it is writable, before any work starts.

    Raises:
        InputError: naming the path when it is a file, lies under a file, or cannot be created or written.
    """
    p = Path(path)
    for parent in (p, *p.parents):
        if parent.exists() and not parent.is_dir():
            raise InputError(f"{what} '{p}': '{parent}' is a file, not a folder")
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{what} '{p}' cannot be created: {exc.strerror or exc}") from None
    if not os.access(p, os.W_OK | os.X_OK):
        raise InputError(f"{what} '{p}' is not writable (permission denied)")
    return p


def _load_json(path: str | Path, what: str) -> Any:
    p = check_input_file(path, what)
    try:
        text = p.read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(f"{what} file '{p}' is not UTF-8 text (byte {exc.start}): expected JSON") from None
    except OSError as exc:
        raise InputError(f"{what} file '{p}' cannot be read: {exc.strerror or exc}") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"{what} file '{p}' is not valid JSON: {exc}") from None
    except RecursionError:
        raise InputError(f"{what} file '{p}' is not valid JSON: nested too deeply") from None


def read_camera(path: str | Path) -> Camera:
    """Read a camera JSON file; errors (:class:`InputError`) name the file and the field."""
    data = _load_json(path, "camera")
    try:
        return Camera.from_dict(data)
    except (ValueError, TypeError, OverflowError) as exc:
        raise InputError(str(exc), path) from None


def write_camera(path: str | Path, camera: Camera) -> None:
    """Write ``camera`` as camera JSON."""
    Path(path).write_text(json.dumps(camera.to_dict(), indent=2))


def read_points(path: str | Path) -> list[ControlPoint]:
    """Read a points JSON file into a list of :class:`ControlPoint`; errors name the file and the entry."""
    data = _load_json(path, "points")
    if not isinstance(data, list):
        raise InputError(f"{path}: points JSON must be a list of objects, got {type(data).__name__}")
    out: list[ControlPoint] = []
    for i, item in enumerate(data):
        where = f"{path}: points[{i}]"
        if not isinstance(item, dict):
            raise InputError(f"{where} must be an object with 'name', 'position', 'radius'")
        check_known_keys(item, POINT_FIELDS, where)
        for key in ("position", "radius"):
            if key not in item:
                raise InputError(f"{where} is missing field '{key}'")
        name = item.get("name", f"p{i}")
        if not isinstance(name, str):
            raise InputError(f"{where}.name must be a string, got {name!r}")
        if not isinstance(item["position"], list) or not is_numeric_nest(item["position"]):
            raise InputError(f"{where}.position must be [x, y, z] numbers, got {item['position']!r}")
        try:
            pos = np.array(item["position"], dtype=float)
        except (TypeError, ValueError, OverflowError):
            raise InputError(f"{where}.position must be [x, y, z] numbers, got {item['position']!r}") from None
        if pos.shape != (3,) or not np.all(np.isfinite(pos)):
            raise InputError(f"{where}.position must be [x, y, z] finite numbers, got {item['position']!r}")
        r = item["radius"]
        try:
            ok = not isinstance(r, bool) and isinstance(r, int | float) and bool(np.isfinite(float(r))) and r >= 0
        except OverflowError:
            ok = False
        if not ok:
            raise InputError(f"{where}.radius must be a finite number >= 0, got {r!r}")
        out.append(ControlPoint(name, pos, float(r)))
    return out


def write_points(path: str | Path, points: list[ControlPoint]) -> None:
    """Write control points as points JSON."""
    data = [{"name": p.name, "position": [float(x) for x in p.position], "radius": float(p.radius)} for p in points]
    Path(path).write_text(json.dumps(data, indent=2))


def _shape_error(
    path: Path, what: str, got: tuple, shape: tuple[int, int], camera_file: str | Path | None
) -> InputError:
    """The error for an image whose size is not the camera's; it names the camera file too where there is one
    (the wrong number may be in either file)."""
    source = f"the camera file {camera_file}" if camera_file is not None else "the camera"
    return InputError(f"{path}: {what} has shape {tuple(got)}, expected (height, width) = {shape} from {source}")


def _read_png(
    path: Path, shape: tuple[int, int] | None, camera_file: str | Path | None = None
) -> tuple[np.ndarray, int]:
    """Decode a PNG to ``(H, W, planes)`` uint16 and its bit depth; the size is checked before the pixels."""
    try:
        width, height, rows, info = png.Reader(filename=str(path)).asDirect()
        if shape is not None and (height, width) != shape:
            raise _shape_error(path, "image", (height, width), shape, camera_file)
        if width * height > MAX_PIXELS:
            raise InputError(f"{path}: image of {width}x{height} pixels is larger than {MAX_PIXELS} pixels")
        planes = info["planes"]
        arr = np.vstack([np.asarray(r, dtype=np.uint16) for r in rows]).reshape(height, width, planes)
    except InputError:
        raise
    except Exception as exc:  # noqa: BLE001  pypng raises many kinds (ChunkError, AttributeError, zlib.error ...)
        raise InputError(f"{path}: cannot read PNG (truncated or corrupt?): {type(exc).__name__}: {exc}") from None
    return arr, info["bitdepth"]


def _read_npy(path: Path, what: str) -> np.ndarray:
    """Load a ``.npy`` array without pickles; a short, empty or corrupt file is an :class:`InputError`."""
    try:
        arr = np.load(path, allow_pickle=False, mmap_mode="r")
        if not isinstance(arr, np.ndarray):
            raise ValueError("not a single array")
        if arr.size > MAX_PIXELS:
            raise ValueError(f"{arr.shape} is larger than {MAX_PIXELS} pixels")
        return np.array(arr)
    except Exception as exc:  # noqa: BLE001  numpy's header parser raises many kinds (EOFError, TokenError ...)
        problem = f"{type(exc).__name__}: {exc}"
        raise InputError(f"{path}: cannot read {what} .npy (empty, truncated or corrupt?): {problem}") from None


def read_depth(path: str | Path, camera: Camera | None = None, camera_file: str | Path | None = None) -> np.ndarray:
    """Read a depth image as (H, W) float32 metres with NaN where there is no reading.

    ``.png`` must be single-channel 16-bit; its values are multiplied by ``camera.depth_scale``
    (default 0.001, millimetres). ``.npy`` must be a 2-D float array in metres. If ``camera`` is given,
    the shape is checked against it. Raises :class:`InputError` naming the file (and ``camera_file``, where
    given, on a size that is not the camera's).
    """
    p = check_input_file(path, "depth")
    suffix = p.suffix.lower()
    shape = camera.shape if camera is not None else None
    if suffix == ".png":
        arr, bitdepth = _read_png(p, shape, camera_file)
        if arr.shape[2] != 1 or bitdepth != 16:
            raise InputError(
                f"{p}: depth PNG must be single-channel 16-bit (mm, 0 = no reading), "
                f"got {arr.shape[2]} channel(s) of {bitdepth} bits"
            )
        scale = camera.depth_scale if camera is not None else 0.001
        raw = arr[..., 0].astype(np.float32)
        with np.errstate(over="ignore"):
            out_of_range = not np.isfinite(np.float32(scale * 65535)) or np.float32(scale) == 0
        if out_of_range:
            source = f"the camera file {camera_file}" if camera_file is not None else "the camera"
            raise InputError(
                f"{p}: depth_scale {scale!r} of {source} takes 16-bit depth values out of the float32 range of metres"
            )
        depth = raw * np.float32(scale)
        depth[raw == 0] = np.nan
    elif suffix == ".npy":
        depth = _read_npy(p, "depth")
        if depth.ndim != 2 or not np.issubdtype(depth.dtype, np.floating):
            raise InputError(f"{p}: depth .npy must be a 2-D float array in metres, got {depth.dtype} {depth.shape}")
        with np.errstate(over="ignore", invalid="ignore"):
            depth = depth.astype(np.float32)
        depth[~np.isfinite(depth) | (depth <= 0)] = np.nan
    else:
        raise InputError(f"{p}: depth file must be .png (16-bit mm) or .npy (float32 m), got '{suffix}'")
    if shape is not None and depth.shape != shape:
        raise _shape_error(p, "depth image", depth.shape, shape, camera_file)
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


def read_mask(path: str | Path, camera: Camera | None = None, camera_file: str | Path | None = None) -> np.ndarray:
    """Read a robot mask (PNG of any bit depth or ``.npy``) as an (H, W) bool array, nonzero = robot.

    Raises :class:`InputError` naming the file (and ``camera_file``, where given, on a size that is not the
    camera's).
    """
    p = check_input_file(path, "mask")
    suffix = p.suffix.lower()
    shape = camera.shape if camera is not None else None
    if suffix == ".png":
        arr, _ = _read_png(p, shape, camera_file)
        colour = 3 if arr.shape[2] >= 3 else 1  # (an alpha plane, last, is not the pixel's value)
        mask = np.any(arr[..., :colour] != 0, axis=-1)
    elif suffix == ".npy":
        arr = _read_npy(p, "mask")
        if arr.ndim != 2 or not (arr.dtype == bool or np.issubdtype(arr.dtype, np.number)):
            raise InputError(f"{p}: mask .npy must be a 2-D array of numbers or booleans, got {arr.dtype} {arr.shape}")
        mask = arr != 0
    else:
        raise InputError(f"{p}: mask file must be .png or .npy, got '{suffix}'")
    if shape is not None and mask.shape != shape:
        raise _shape_error(p, "mask image", mask.shape, shape, camera_file)
    return mask


def write_mask(path: str | Path, mask: np.ndarray) -> None:
    """Write an (H, W) bool mask as an 8-bit PNG (255 = robot)."""
    m = np.asarray(mask).astype(bool)
    with Path(path).open("wb") as fh:
        png.Writer(width=m.shape[1], height=m.shape[0], greyscale=True, bitdepth=8).write(
            fh, (m.astype(np.uint8) * 255).tolist()
        )
