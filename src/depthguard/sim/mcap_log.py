"""Recordings of the SAPHARI experiments as ROS 2 messages (:mod:`depthguard.io.mcap_ros2`).

``/joint_states`` messages with a ``position`` become ``sensor_msgs/msg/JointState`` (``name``, else
``joint1``, ``joint2``, ...; ``position``, and ``velocity`` and ``effort`` where given, in the order of the
names); every other topic's messages (dicts of named numbers and arrays) become
``std_msgs/msg/Float64MultiArray`` with one labelled layout dimension per field
(:func:`depthguard.io.ros2.labelled_array_msg`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["write_mcap"]


def write_mcap(path: str | Path, channels: dict[str, list[tuple[float, dict]]]) -> Path:
    """Write ``{topic: [(t_seconds, message_dict), ...]}`` to ``path`` (.mcap, ROS 2). Returns the path.

    Raises ``ValueError`` for a joint state whose ``name``, ``velocity`` or ``effort`` do not have one entry
    per position (naming the topic and the message's index), and as
    :meth:`~depthguard.io.mcap_ros2.Ros2McapWriter.write` does."""
    from depthguard.io import ros2
    from depthguard.io.mcap_ros2 import Ros2McapWriter

    path = Path(path)
    with Ros2McapWriter(path) as w:
        for topic, msgs in channels.items():
            for i, (t, msg) in enumerate(msgs):
                if topic == "/joint_states" and "position" in msg:
                    w.write(topic, "sensor_msgs/msg/JointState", _joint_state(ros2, topic, i, t, msg), t)
                else:
                    fields = {k: v for k, v in msg.items() if not isinstance(v, str)}
                    w.write(topic, "std_msgs/msg/Float64MultiArray", ros2.labelled_array_msg(fields), t)
    return path


def _joint_state(ros2, topic: str, i: int, t: float, msg: dict):
    """The ``sensor_msgs/msg/JointState`` of the dict ``msg`` (message ``i`` on ``topic``, ``t`` seconds)."""
    q = np.asarray(msg["position"], float).ravel()
    names = msg.get("name")
    names = [f"joint{k + 1}" for k in range(q.size)] if names is None or len(names) == 0 else list(names)
    extra = {k: np.asarray(msg[k], float).ravel() for k in ("velocity", "effort") if msg.get(k) is not None}
    for what, n in (("name", len(names)), *((k, v.size) for k, v in extra.items())):
        if n != q.size and (what == "name" or n != 0):  # (an empty velocity or effort means none)
            raise ValueError(f"{topic} message {i}: {n} {what} entries for {q.size} positions")
    js = ros2.joint_state_msg(t, names, q, extra.get("velocity"))
    if "effort" in extra:
        js.effort = extra["effort"]
    return js
