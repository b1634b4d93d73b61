"""Recordings of the SAPHARI experiments as ROS 2 messages (:mod:`depthguard.io.mcap_ros2`).

``/joint_states`` becomes ``sensor_msgs/msg/JointState``; every other topic's messages (dicts of named
numbers and arrays) become ``std_msgs/msg/Float64MultiArray`` with one labelled layout dimension per field
(:func:`depthguard.io.ros2.labelled_array_msg`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["write_mcap"]


def write_mcap(path: str | Path, channels: dict[str, list[tuple[float, dict]]]) -> Path:
    """Write ``{topic: [(t_seconds, message_dict), ...]}`` to ``path`` (.mcap, ROS 2). Returns the path."""
    from depthguard.io import ros2
    from depthguard.io.mcap_ros2 import Ros2McapWriter

    path = Path(path)
    with Ros2McapWriter(path) as w:
        for topic, msgs in channels.items():
            for t, msg in msgs:
                if topic == "/joint_states" and "position" in msg:
                    q = np.asarray(msg["position"], float)
                    names = msg.get("name") or [f"joint{i + 1}" for i in range(q.size)]
                    w.write(topic, "sensor_msgs/msg/JointState", ros2.joint_state_msg(t, names, q), t)
                else:
                    fields = {k: v for k, v in msg.items() if not isinstance(v, str)}
                    w.write(topic, "std_msgs/msg/Float64MultiArray", ros2.labelled_array_msg(fields), t)
    return path
