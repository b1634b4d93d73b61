"""The fields of a scenario TOML file and their checks (``data/scenarios/README.md`` describes them).

:func:`validate_scenario` runs before any simulation starts: a missing, mistyped or unknown field (a typo
such as ``rho_bdy`` must not fall back to a default) raises :class:`~depthguard.errors.InputError` with one
line naming the file, the field and the expected form (unknown fields list the known ones).

A new scenario field is added to :data:`TOP_LEVEL` (or to the table it belongs to) with its check.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from depthguard.errors import InputError

__all__ = ["validate_scenario", "TOP_LEVEL"]

Check = Callable[[Any], str | None]  # returns None when the value is fine, else the expected form


def _is_num(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)


def _num(x: Any) -> str | None:
    return None if _is_num(x) else "a finite number"


def _pos(x: Any) -> str | None:
    return None if _is_num(x) and x > 0 else "a number > 0"


def _nonneg(x: Any) -> str | None:
    return None if _is_num(x) and x >= 0 else "a number >= 0"


def _bool(x: Any) -> str | None:
    return None if isinstance(x, bool) else "true or false"


def _str(x: Any) -> str | None:
    return None if isinstance(x, str) and x else "a non-empty string"


def _int_range(lo: int, hi: int) -> Check:
    def check(x: Any) -> str | None:
        ok = isinstance(x, int) and not isinstance(x, bool) and lo <= x <= hi
        return None if ok else f"an integer in {lo}..{hi}"

    return check


def _choice(*values: str) -> Check:
    def check(x: Any) -> str | None:
        return None if x in values else f"one of {list(values)}"

    return check


def _vec(n: int, positive: bool = False) -> Check:
    def check(x: Any) -> str | None:
        ok = isinstance(x, list) and len(x) == n and all(_is_num(v) and (not positive or v > 0) for v in x)
        return None if ok else f"a list of {n} finite numbers" + (" > 0" if positive else "")

    return check


def _vecs(n: int) -> Check:
    inner = _vec(n)

    def check(x: Any) -> str | None:
        ok = isinstance(x, list) and len(x) > 0 and all(inner(v) is None for v in x)
        return None if ok else f"a non-empty list of [{', '.join('xyzw'[:n])}] lists of finite numbers"

    return check


def _size(x: Any) -> str | None:
    ok = isinstance(x, list) and len(x) == 2 and all(_int_range(8, 4096)(v) is None for v in x)
    return None if ok else "[width, height], integers in 8..4096"


# A table: {field: (check or nested table spec, required)}; a list of tables: ("tables", spec, required).
AVOIDANCE: dict[str, Any] = {
    "rho": (_pos, False),
    "rho_body": (_pos, False),
    "ssm_range": (_pos, False),
    "vmax": (_pos, False),
    "alpha": (_pos, False),
    "pivot": (_bool, False),
    "dv_max": (_pos, False),
    "c": (_pos, False),
}
TASK: dict[str, Any] = {
    "kind": (_choice("points", "cycle", "hold"), False),
    "speed": (_pos, False),
    "tol": (_pos, False),
    "kp": (_pos, False),
    "relative": (_bool, False),
    "waypoints": (_vecs(3), False),  # required unless kind = "hold" (checked below)
}
BOX: dict[str, Any] = {
    "name": (_str, True),
    "center": (_vec(3), True),
    "half": (_vec(3, positive=True), True),
    "movable": (_bool, False),
}
KEYFRAME: dict[str, Any] = {
    "t": (_nonneg, True),
    "base": (_vec(2), True),
    "yaw": (_num, False),
    "left_hand": (_vec(3), False),
    "right_hand": (_vec(3), False),
    "left_hand_rel_ee": (_vec(3), False),
    "right_hand_rel_ee": (_vec(3), False),
    "carry": (_str, False),
    "carry_hand": (_choice("left", "right"), False),
}
PERSON: dict[str, Any] = {"name": (_str, True), "keyframes": (("tables", KEYFRAME), True)}
VARIANT: dict[str, Any] = {
    "name": (_str, True),
    "set": (("any-table",), False),
    "remove_people": (_bool, False),
    "remove_boxes": (_bool, False),
}
TOP_LEVEL: dict[str, Any] = {
    "name": (_str, True),
    "description": (lambda x: None if isinstance(x, str) else "a string", False),
    "paper": (lambda x: None if isinstance(x, str) else "a string", False),
    "cameras": (_choice("icra", "ral", "ral3", "ral-rolled", "ral-rolled-far", "platform"), True),
    "camera_count": (_int_range(1, 8), False),
    "ssm_camera_count": (_int_range(1, 8), False),
    "ssm_cameras": (_choice("icra-ssm", "ral"), False),
    "resolution": (_size, False),
    "quick_resolution": (_size, False),
    "demo_resolution": (_size, False),
    "duration": (_pos, False),
    "quick_duration": (_pos, False),
    "demo_duration": (_pos, False),
    "q0": (lambda x: None if isinstance(x, list) and x and all(_is_num(v) for v in x) else "a list of numbers", False),
    "robot": (_str, False),
    "frame_period": (_pos, False),
    "quick_frame_period": (_pos, False),
    "octree_res": (_pos, False),
    "reach_res": (_pos, False),
    "horizon": (_pos, False),
    "auto_spheres": (_int_range(1, 16), False),
    "ee_start": (_vec(3), False),
    "control_points": (_str, False),
    "ee_radius": (_pos, False),
    "mode": (_choice("min", "all", "hybrid"), False),
    "task_feasible": (_bool, False),
    "floor_z": (_num, False),
    "room": (_vec(4), False),
    "workspace": (_vec(6), False),
    "distance_period": (_pos, False),
    "avoidance": (AVOIDANCE, False),
    "task": (TASK, True),
    "boxes": (("tables", BOX), False),
    "people": (("tables", PERSON), False),
    "variants": (("tables", VARIANT), False),
}


def _fail(source: str, where: str, problem: str) -> InputError:
    return InputError(f"{source}: {where} {problem}")


def _check_table(data: Any, spec: dict[str, Any], source: str, where: str) -> None:
    if not isinstance(data, dict):
        raise _fail(source, where or "the file", "must be a table")
    unknown = [k for k in data if k not in spec]
    if unknown:
        at = f" in '{where}'" if where else ""
        raise InputError(f"{source}: unknown field {unknown[0]!r}{at}; known fields: {sorted(spec)}")
    for key, (check, required) in spec.items():
        name = f"{where}.{key}" if where else key
        if key not in data:
            if required:
                raise _fail(source, f"field '{name}'", "is missing")
            continue
        value = data[key]
        if isinstance(check, dict):
            _check_table(value, check, source, name)
        elif isinstance(check, tuple) and check[0] == "tables":
            if not isinstance(value, list) or not value:
                raise _fail(source, f"field '{name}'", "must be a non-empty list of tables")
            for i, item in enumerate(value):
                _check_table(item, check[1], source, f"{name}[{i}]")
        elif isinstance(check, tuple) and check[0] == "any-table":
            if not isinstance(value, dict):
                raise _fail(source, f"field '{name}'", "must be a table")
        else:
            expected = check(value)
            if expected is not None:
                raise _fail(source, f"field '{name}'", f"must be {expected}, got {value!r}"[:300])


def _check_cross(data: dict[str, Any], source: str) -> None:
    task = data["task"]
    if task.get("kind", "points") != "hold" and "waypoints" not in task:
        raise _fail(source, "field 'task.waypoints'", 'is missing (needed unless task.kind = "hold")')
    placed = {"icra": 1, "icra-ssm": 1, "ral": 2, "ral3": 3, "ral-rolled": 2, "ral-rolled-far": 2, "platform": 2}
    n_placed = placed[data["cameras"]]
    if data.get("camera_count", 1) > n_placed:
        raise _fail(source, "field 'camera_count'", f"must be 1..{n_placed} for cameras = {data['cameras']!r}")
    ssm_placed = data.get("ssm_cameras", data["cameras"])  # (two-camera "ral" cells have an optional third one)
    from depthguard.sim.depthcam import RAL_TWO

    n_ssm = placed[ssm_placed] + (ssm_placed in RAL_TWO)
    if data.get("ssm_camera_count", 1) > n_ssm:
        raise _fail(source, "field 'ssm_camera_count'", f"must be 1..{n_ssm} for cameras = {data['cameras']!r}")
    movable = {b["name"] for b in data.get("boxes", []) if b.get("movable", False)}
    for i, p in enumerate(data.get("people", [])):
        for j, k in enumerate(p["keyframes"]):
            if "carry" in k and k["carry"] not in movable:
                raise _fail(
                    source,
                    f"field 'people[{i}].keyframes[{j}].carry'",
                    f"must name a movable box (boxes with movable = true: {sorted(movable)}), got {k['carry']!r}",
                )
            if j and k["t"] <= p["keyframes"][j - 1]["t"]:
                raise _fail(source, f"field 'people[{i}].keyframes[{j}].t'", "must be larger than the previous t")


def _apply(data: dict[str, Any], dotted: str, value: Any) -> None:
    keys = dotted.split(".")
    for k in keys[:-1]:
        data = data.setdefault(k, {})
        if not isinstance(data, dict):
            raise KeyError(dotted)
    data[keys[-1]] = value


def validate_scenario(data: dict[str, Any], source: str) -> None:
    """Check a parsed scenario file; raise :class:`InputError` naming ``source`` and the first bad field.

    Each ``[[variants]]`` entry's ``set`` is applied to a copy and the result is checked too, so a variant
    cannot introduce a typo either.
    """
    import copy

    _check_table(data, TOP_LEVEL, source, "")
    _check_cross(data, source)
    for i, v in enumerate(data.get("variants", [])):
        varied = copy.deepcopy(data)
        for key, value in v.get("set", {}).items():
            try:
                _apply(varied, key, value)
            except KeyError:
                raise _fail(source, f"field 'variants[{i}].set.{key}'", "names no table of the scenario") from None
        if v.get("remove_people"):
            varied.pop("people", None)
        if v.get("remove_boxes"):
            varied.pop("boxes", None)
        where = f"{source}: variants[{i}] ({v['name']!r})"
        _check_table(varied, TOP_LEVEL, where, "")
        _check_cross(varied, where)
