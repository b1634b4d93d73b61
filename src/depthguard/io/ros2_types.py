"""The ROS 2 type store of DepthGuard (``rosbags``' Jazzy store plus :data:`DEPTHGUARD_MSGS`), time stamps,
headers and CDR (de)serialisation: what every message builder of :mod:`depthguard.io.ros2` stands on.
:mod:`depthguard.io.ros2` re-exports all of it."""

from __future__ import annotations

import math
from fractions import Fraction
from functools import cache
from typing import Any

__all__ = [
    "DEPTHGUARD_MSGS",
    "typestore",
    "stamp",
    "stamp_parts",
    "to_seconds",
    "header",
    "serialize",
    "deserialize",
    "msgdef",
]

#: DepthGuard's own ROS 2 message definitions (package ``depthguard_msgs``).
DEPTHGUARD_MSGS: dict[str, str] = {
    "depthguard_msgs/msg/ControlPointDistance": """\
# One control sphere and its distance to the nearest obstacle (people and unseen space included).
string name
geometry_msgs/Point centre          # sphere centre, world frame, m
float64 radius                      # m
float64 distance                    # from the sphere surface, m; +inf = nothing within rho; NaN = unknown
geometry_msgs/Vector3 direction     # unit repulsive direction (from the obstacle towards the point)
geometry_msgs/Point nearest         # nearest obstacle point, world frame, m (NaN if none)
""",
    "depthguard_msgs/msg/ControlPointDistances": """\
# All control points of one distance query.
std_msgs/Header header
float64 rho                         # radius of surveillance, m
depthguard_msgs/ControlPointDistance[] points
""",
    "depthguard_msgs/msg/ControllerStatus": """\
# One control cycle's outcome.
std_msgs/Header header
string status                       # CycleStatus name (OK, SCALED, STOP_STALE_DISTANCES, ...)
float64 scale                       # SNS task scale in [0, 1]
string monitor_state                # SSM state, empty when SSM is off
float64 ssm_scale                   # SSM speed scale in [0, 1] (1 when off)
""",
}


@cache
def typestore():
    """The ROS 2 Jazzy type store with :data:`DEPTHGUARD_MSGS` registered (built once)."""
    try:
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    except ImportError as exc:  # pragma: no cover - depends on the installation
        raise ImportError(f"ROS 2 messages need the 'cell' extra: pip install 'depthguard[cell]' ({exc})") from None
    ts = get_typestore(Stores.ROS2_JAZZY)
    types: dict[str, Any] = {}
    for name, text in DEPTHGUARD_MSGS.items():
        types.update(get_types_from_msg(text, name))
    ts.register(types)
    return ts


def _t(name: str):
    return typestore().types[name]


#: ``builtin_interfaces/msg/Time.sec`` is an int32: stamps end at 2**31 s (2038-01-19)
MAX_STAMP_SECONDS = 2**31


def stamp_parts(t: float) -> tuple[int, int]:
    """``(sec, nanosec)`` of ``t`` seconds (negative times, -inf included, clamp to 0), as every stamp
    DepthGuard writes: the nanosecond nearest to the float's exact value (its whole seconds split off first,
    so that epoch-scale times are not rounded twice). NaN, +inf or ``t >= 2**31`` (beyond ``Time.sec``'s
    int32): ``ValueError``."""
    x = float(t)
    if x != x or x >= MAX_STAMP_SECONDS:
        raise ValueError(f"stamp: t must be a number of seconds below 2**31 (int32 Time.sec), got {t!r}")
    x = max(x, 0.0)
    sec = int(x)  # (x - sec is exact in floating point)
    f = (x - sec) * 1e9
    if abs(f - math.floor(f) - 0.5) < 1e-6:  # near a tie: the product's rounding could decide it, so exactly
        ns = round(Fraction(x - sec) * 1_000_000_000)
    else:
        ns = int(round(f))
    return (sec + 1, 0) if ns >= 1_000_000_000 else (sec, ns)


def stamp(t: float):
    """``builtin_interfaces/msg/Time`` for ``t`` seconds (t >= 0)."""
    sec, nanosec = stamp_parts(t)
    return _t("builtin_interfaces/msg/Time")(sec=sec, nanosec=nanosec)


def to_seconds(st) -> float:
    """Seconds of a ``builtin_interfaces/msg/Time``."""
    return float(st.sec) + 1e-9 * float(st.nanosec)


def header(t: float, frame_id: str):
    """``std_msgs/msg/Header``."""
    return _t("std_msgs/msg/Header")(stamp=stamp(t), frame_id=str(frame_id))


def serialize(msg, typename: str) -> bytes:
    """CDR bytes (with the 4-byte encapsulation header) of ``msg``."""
    return bytes(typestore().serialize_cdr(msg, typename))


def deserialize(data: bytes | memoryview, typename: str):
    """Message from CDR bytes (the generic decoder; :func:`depthguard.io.ros2.deserialize` adds the fast path
    of ``sensor_msgs/msg/JointState``)."""
    return typestore().deserialize_cdr(data, typename)


def msgdef(typename: str) -> str:
    """The ROS 2 message definition text of ``typename`` with its dependencies (MCAP ``ros2msg`` schema)."""
    return typestore().generate_msgdef(typename, ros_version=2)[0]
