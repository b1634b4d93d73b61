"""The net-latency bench's frame publisher: images serialised once, restamped per publication."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from depthguard.io import ros2
from depthguard.nodes.bench import _restamped


@settings(max_examples=40, deadline=None)
@given(st.floats(0.0, 2.0e9), st.integers(1, 9), st.integers(1, 9), st.text(min_size=0, max_size=12))
def test_a_restamped_image_decodes_with_the_new_stamp_and_the_same_pixels(t, h, w, frame_id):
    depth = (np.arange(h * w, dtype=np.float32).reshape(h, w) + 1.0) / 7.0  # (all valid: 0 reads as no depth)
    payload = ros2.serialize(ros2.image_msg(123.5, frame_id, depth, "32FC1"), "sensor_msgs/msg/Image")
    msg = ros2.deserialize(_restamped(payload, t), "sensor_msgs/msg/Image")
    ns = int(round(t * 1e9))
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (ns // 1_000_000_000, ns % 1_000_000_000)
    assert msg.header.frame_id == frame_id
    assert np.array_equal(ros2.image_to_depth(msg), depth)
