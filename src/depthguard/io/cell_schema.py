"""The cell file's schema: known keys, their types, defaults and choices, and the checks that name the key
(used by :mod:`depthguard.io.cellfile`)."""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import numpy as np

from depthguard.control.ssm import SSM_RANGE
from depthguard.errors import InputError
from depthguard.kernels.records import direction_stride
from depthguard.validation import is_numeric_nest

__all__ = ["CellError", "NODE_ROLES", "apply_calibration", "check_background", "check_names", "distance_section"]

_SHAPES = ("box", "cylinder", "sphere", "mesh")


class CellError(InputError):
    """A cell file problem (an :class:`~depthguard.errors.InputError`, a ``ValueError``); the message names the
    file and the key."""


#: The nodes of a cell besides its cameras (``depthguard.io.cellfile.node_names``): a camera may not take one of
#: these names (its node would take that node's port, and with one certificate per node its certificate)
NODE_ROLES = ("sim", "distance", "controller", "monitor", "run", "view")
#: A ROS 2 topic name: tokens of letters, digits and underscores, not starting with a digit, joined by "/"
_TOPIC = re.compile(r"/?[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*")
_INT_LIMIT = 2**31  # (integer keys: image sizes, pixels, ids; a larger one is a typo, not a setting)


# ------------------------------------------------------------------------------------------- the schema
# key -> (type(s), default); a default of ... means required.
_NUM = (int, float)
_SCHEMA: dict[str, dict[str, tuple[Any, Any]]] = {
    "cell": {"name": (str, "cell"), "description": (str, "")},
    "robot": {
        "model": (str, None),
        "urdf": (str, None),
        "ee_frame": (str, None),
        "joint_names": (list, None),
        "control_points": (str, "ral-9"),
        "ee_radius": (_NUM, 0.06),
        "spheres": (list, []),
        "attachments": (list, []),
    },
    "sphere": {"link": (str, ...), "position": (list, ...), "radius": (_NUM, ...)},
    "attachment": {
        "name": (str, ...),
        "link": (str, ...),
        "shape": (str, ...),
        "size": (list, []),
        "mesh": (str, None),
        "xyz": (list, [0.0, 0.0, 0.0]),
        "rpy": (list, [0.0, 0.0, 0.0]),
    },
    "camera": {
        "name": (str, ...),
        "topic": (str, ""),
        "info_topic": (str, ""),
        "frame_id": (str, ""),
        "intrinsics": (str, "file"),
        "width": (int, None),
        "height": (int, None),
        "fx": (_NUM, None),
        "fy": (_NUM, None),
        "cx": (_NUM, None),
        "cy": (_NUM, None),
        "min_depth": (_NUM, 0.3),
        "max_depth": (_NUM, 8.0),
        "depth_scale": (_NUM, 0.001),
        "rate": (_NUM, 30.0),
        "extrinsics": (str, "file"),
        "R": (list, None),
        "t": (list, None),
        "matrix": (list, None),
        "eye": (list, None),
        "target": (list, None),
        "up": (list, [0.0, 0.0, 1.0]),
        "parent": (str, "world"),
        "align": (str, "none"),
        "noise_coeff": (_NUM, 0.0),
    },
    "distance": {
        "backend": (str, "depthspace"),
        "rho": (_NUM, 0.4),
        "mode": (str, "hybrid"),
        "invalid": (str, "conservative"),
        "fill_radius": (int, 4),
        "grid_dd": (_NUM, 0.01),
        "workspace": (list, [-1.2, 1.2, -1.2, 1.2, -0.3, 1.5]),
        "octree_res": (_NUM, 0.05),
        "period": (_NUM, 0.003),
        "direction_stride": ((str, int), "auto"),
    },
    "controller": {
        "rate": (_NUM, 1000.0),
        "distance_timeout": (_NUM, 0.1),
        "joint_timeout": (_NUM, 0.005),
        "resume_time": (_NUM, 0.1),
        "velocity_scale": (_NUM, 1.0),
        "a_max": (_NUM, 10.0),
        "j_max": (_NUM, 500.0),
        "rho_ee": (_NUM, 0.4),
        "rho_body": (_NUM, 0.4),
        "alpha": (_NUM, 6.0),
        "v_rep_max": (_NUM, 2.0),
        "ssm": (bool, False),
        "ssm_range": (_NUM, SSM_RANGE),
        "background": (str, None),
    },
    "topics": {
        "joint_states": (str, "/joint_states"),
        "tf": (str, "/tf"),
        "tf_static": (str, "/tf_static"),
        "command": (str, "/depthguard/joint_trajectory"),
        "command_array": (str, "/depthguard/joint_velocity_command"),
        "distances": (str, "/depthguard/distances"),
        "monitor_distances": (str, "/depthguard/monitor_distances"),
        "status": (str, "/depthguard/status"),
        "markers": (str, "/depthguard/markers"),
    },
    "network": {
        "domain": (int, 0),
        "host": (str, "127.0.0.1"),
        "base_port": (int, 7460),
        "connect": (list, ["tcp/127.0.0.1:7447"]),
        "publishers": (list, ["distance", "controller"]),
        "tls_root_ca": (str, ""),
        "tls_certificate": (str, ""),
        "tls_private_key": (str, ""),
    },
}
_TOP = {"cell", "robot", "cameras", "distance", "controller", "topics", "calibration", "network"}
_CHOICES = {
    ("distance", "backend"): ("depthspace", "octree"),
    ("distance", "mode"): ("min", "all", "hybrid"),
    ("distance", "invalid"): ("conservative", "ignore"),
    ("camera", "intrinsics"): ("file", "camera_info", "device"),
    ("camera", "extrinsics"): ("file", "tf"),
    ("camera", "align"): ("none", "color"),
    ("attachment", "shape"): _SHAPES,
}
_POSITIVE = {
    *("rho", "grid_dd", "octree_res", "period", "rate", "distance_timeout", "joint_timeout", "a_max", "j_max"),
    *("rho_ee", "rho_body", "alpha", "v_rep_max"),  # (eq. 7 divides by rho; alpha, v_rep_max <= 0 never repel)
}
#: keys that must be >= 0 (a negative value would be taken for another setting, or fail mid-run)
_NON_NEGATIVE = {"ee_radius", "resume_time", "fill_radius"}


def _section(src: Path, where: str, kind: str, table: Any) -> dict[str, Any]:
    """Validate one table against ``_SCHEMA[kind]``: unknown keys, types, choices, required keys."""
    if not isinstance(table, dict):
        raise CellError(f"{src}: [{where}] must be a table, got {type(table).__name__}")
    schema = _SCHEMA[kind]
    unknown = sorted(set(table) - set(schema))
    if unknown:
        raise CellError(f"{src}: unknown key(s) {unknown} in [{where}]; known keys: {sorted(schema)}")
    out: dict[str, Any] = {}
    for key, (typ, default) in schema.items():
        if key not in table:
            if default is ...:
                raise CellError(f"{src}: [{where}] needs the key '{key}'")
            out[key] = default
            continue
        val = table[key]
        if isinstance(val, bool) and typ is not bool:
            raise CellError(f"{src}: {where}.{key} must be {_type_name(typ)}, got {val!r}")
        if not isinstance(val, typ):
            raise CellError(f"{src}: {where}.{key} must be {_type_name(typ)}, got {val!r}")
        if typ is _NUM and not _finite(val):  # (an integer past the float range too: 1e400 written out)
            raise CellError(f"{src}: {where}.{key} must be a finite number, got {val!r}")
        if isinstance(val, int) and typ is not _NUM and not -_INT_LIMIT < val < _INT_LIMIT:
            raise CellError(f"{src}: {where}.{key} must be an integer below 2**31 in size, got {val!r}")
        if key in _POSITIVE and val <= 0:
            raise CellError(f"{src}: {where}.{key} must be > 0, got {val!r}")
        if key in _NON_NEGATIVE and val < 0:
            raise CellError(f"{src}: {where}.{key} must be >= 0, got {val!r}")
        choices = _CHOICES.get((kind, key))
        if choices and val not in choices:
            raise CellError(f"{src}: {where}.{key} must be one of {list(choices)}, got {val!r}")
        out[key] = val
    return out


def _finite(val: Any) -> bool:
    """Whether the number ``val`` is finite as a float (a Python int may be too large for one)."""
    try:
        return math.isfinite(float(val))
    except OverflowError:
        return False


def _type_name(typ: Any) -> str:
    if typ is _NUM:
        return "a number"
    return {str: "a string", int: "an integer", list: "an array", bool: "true or false"}.get(typ, str(typ))


def _vector(src: Path, where: str, value: Any, n: int) -> tuple[float, ...]:
    if not is_numeric_nest(value):  # (numpy would take "1" and true for numbers)
        raise CellError(f"{src}: {where} must be {n} numbers, got {value!r}")
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError, OverflowError):  # (OverflowError: an integer past the float range)
        raise CellError(f"{src}: {where} must be {n} numbers, got {value!r}") from None
    if arr.shape != (n,) or not np.all(np.isfinite(arr)):
        raise CellError(f"{src}: {where} must be {n} finite numbers, got {value!r}")
    return tuple(float(x) for x in arr)


def _is_matrix(value: Any, rows: int, cols: int) -> bool:
    if not is_numeric_nest(value):
        return False
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError, OverflowError):
        return False
    return arr.shape == (rows, cols) and bool(np.all(np.isfinite(arr)))


def distance_section(src: Path, table: Any) -> dict[str, Any]:
    """The ``[distance]`` table: :func:`_section`, then the workspace (6 numbers, min < max per axis)
    and the direction lattice (``"auto"`` or an integer >= 1), each error naming its key."""
    dist = _section(src, "distance", "distance", table)
    ws = _vector(src, "distance.workspace", dist["workspace"], 6)
    if any(ws[2 * i] >= ws[2 * i + 1] for i in range(3)):
        raise CellError(f"{src}: distance.workspace must be xmin, xmax, ymin, ymax, zmin, zmax with min < max")
    dist["workspace"] = ws
    try:
        direction_stride(dist["direction_stride"], 640)
    except ValueError:
        raise CellError(
            f'{src}: distance.direction_stride must be "auto" or an integer >= 1, got {dist["direction_stride"]!r}'
        ) from None
    return dist


def apply_calibration(src: Path, ref: Any, cams: tuple) -> tuple:
    """Replace the extrinsics of the cameras (:class:`depthguard.io.cellfile.CellCamera`) named in the
    calibration file ``ref`` (``depthguard calibrate``), relative to the cell file ``src``; each entry's
    ``parent``, when given, must be the camera's."""
    import dataclasses
    import tomllib

    from depthguard.validation import check_rotation

    if not isinstance(ref, str):
        raise CellError(f"{src}: calibration must be a path (string) to a calibration file")
    path = (src.parent / ref).resolve()
    if not path.is_file():
        raise CellError(f"{src}: calibration file '{ref}' is not a file (looked at {path})")
    try:
        cal = tomllib.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise CellError(f"{path}: not a valid calibration file ({exc})") from None
    by_name = {c.name: c for c in cams}
    if sorted(cal) != ["cameras"]:  # (a typo such as [[camera]] must not leave the cell's extrinsics in use)
        raise CellError(f"{path}: a calibration file holds [[cameras]] tables only, got the key(s) {sorted(cal)}")
    if not isinstance(cal["cameras"], list) or not all(isinstance(e, dict) for e in cal["cameras"]):
        raise CellError(f"{path}: cameras must be an array of tables ([[cameras]]), got {cal['cameras']!r}")
    seen: set[str] = set()
    for i, entry in enumerate(cal["cameras"]):
        unknown = sorted(set(entry) - {"name", "parent", "R", "t", "date", "rmse", "inlier_fraction"})
        if unknown:
            raise CellError(f"{path}: unknown key(s) {unknown} in cameras[{i}]")
        name = entry.get("name")
        if not isinstance(name, str) or name not in by_name:
            raise CellError(f"{path}: cameras[{i}] names camera {name!r}, which the cell file does not have")
        if name in seen:  # (which of the two would place it?)
            raise CellError(f"{path}: cameras[{i}] places camera {name!r} a second time: one entry per camera")
        seen.add(name)
        _calibration_quality(path, i, entry)
        if entry.get("parent", by_name[name].parent) != by_name[name].parent:
            raise CellError(
                f"{path}: cameras[{i}].parent = {entry['parent']!r}, but camera {name!r} of the cell file has parent"
                f" {by_name[name].parent!r}: this calibration was made for another mounting"
            )
        try:
            R = check_rotation(entry.get("R"), f"{path.name} cameras[{i}].R")
        except (ValueError, OverflowError) as exc:
            raise CellError(f"{path}: {exc}") from None
        t = np.asarray(_vector(path, f"cameras[{i}].t", entry.get("t"), 3))
        by_name[name] = dataclasses.replace(by_name[name], R=R, t=t, extrinsics="file")
    return tuple(by_name[c.name] for c in cams)


def _calibration_quality(path: Path, i: int, entry: dict[str, Any]) -> None:
    """A calibration entry's record of its quality (``cell check`` prints it): ``rmse`` a finite number of
    metres >= 0, ``inlier_fraction`` one in [0, 1], ``date`` a string or a TOML date."""
    import datetime

    for key, hi in (("rmse", math.inf), ("inlier_fraction", 1.0)):
        v = entry.get(key, 0.0)
        if isinstance(v, bool) or not isinstance(v, _NUM) or not _finite(v) or not 0 <= v <= hi:
            form = "a finite number of metres >= 0" if key == "rmse" else "a number in [0, 1]"
            raise CellError(f"{path}: cameras[{i}].{key} must be {form}, got {v!r}")
    if not isinstance(entry.get("date", ""), str | datetime.date | datetime.datetime):
        raise CellError(f"{path}: cameras[{i}].date must be a string or a TOML date, got {entry['date']!r}")


def check_names(src: Path, cams: tuple, topics: dict[str, str]) -> None:
    """The cameras' names (non-empty, none of :data:`NODE_ROLES`) and the topics: ``[topics]`` holds ROS topic
    names, and no two topics are the same (the cameras' ``topic`` and ``info_topic`` and the ``[topics]``):
    two cameras on one topic would each take the other's images with their own pose."""
    for i, c in enumerate(cams):
        if not c.name:
            raise CellError(f"{src}: cameras[{i}].name must be a name (its node's, its topics'), got {c.name!r}")
        if c.name in NODE_ROLES:
            raise CellError(
                f"{src}: cameras[{i}].name {c.name!r} is the name of one of the cell's nodes {list(NODE_ROLES)}:"
                " the camera's node would take its port and certificate; choose another name"
            )
    for key, topic in topics.items():
        if not _TOPIC.fullmatch(topic):
            raise CellError(
                f"{src}: topics.{key} must be a ROS topic name such as \"/ns/name\" (letters, digits and '_'"
                f" between slashes, no token starting with a digit), got {topic!r}"
            )
    keys = [(f"cameras[{i}].{k}", getattr(c, k)) for i, c in enumerate(cams) for k in ("topic", "info_topic")]
    seen: dict[str, str] = {}
    for key, topic in keys + [(f"topics.{k}", v) for k, v in topics.items()]:
        other = seen.setdefault(topic.strip("/"), key)
        if other != key:
            raise CellError(f"{src}: {key} and {other} are the same topic {topic!r}: each needs its own")


def check_background(src: Path, ctrl: dict[str, Any], cams: tuple) -> None:
    """``[controller] background``: the background file of ``depthguard commission`` (a path relative to the
    cell file ``src``) must be one, for the cell's cameras (names; cameras fixed in the world); the key becomes
    the resolved path. The image sizes are checked when a run starts, against the cameras of its source (a
    simulated ``--quick`` run is 160x120 whatever the cell file says)."""
    ref = ctrl.get("background")
    if ref is None:
        return
    from depthguard.io.background import read_background

    if not ref.strip():
        raise CellError(f"{src}: controller.background must be the path of a background file (depthguard commission)")
    path = (src.parent / ref).resolve()
    if not path.is_file():
        raise CellError(
            f"{src}: controller.background '{ref}' is not a file (looked at {path}; `depthguard commission` writes it)"
        )
    try:
        bg = read_background(path)
    except ValueError as exc:
        raise CellError(f"{src}: controller.background '{ref}': {exc}") from None
    names = [c.name for c in cams]
    if sorted(bg.names) != sorted(names):
        raise CellError(
            f"{src}: controller.background '{ref}' holds the cameras {list(bg.names)}, the cell file has {names}:"
            " commission this cell again"
        )
    carried = [f"cameras[{i}].parent = {c.parent!r}" for i, c in enumerate(cams) if c.parent != "world"]
    if carried:
        raise CellError(
            f"{src}: controller.background with {', '.join(carried)}: a background needs cameras fixed in the world"
        )
    ctrl["background"] = str(path)
