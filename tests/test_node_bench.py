"""The net-latency bench's frame publisher (images serialised once, restamped per publication) and its CPU
figures."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
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


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="CPU times from /proc: Linux only")
def test_cpu_percent_tells_a_busy_process_from_a_sleeping_one():
    """``cpu_percent_of_one_core``: this process spinning for 0.5 s uses most of a core; a sleeping child
    almost none."""
    from depthguard.nodes.bench import _cpu_percent, _cpu_sample

    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(5)"])
    try:
        time.sleep(0.3)  # (the child's start-up is over)
        pids = {"busy": os.getpid(), "sleeping": child.pid}
        start = _cpu_sample(pids)
        t0, c0 = time.monotonic(), time.process_time()
        end_at = t0 + 0.5
        while time.monotonic() < end_at:
            pass
        got = _cpu_percent({"start": start, "end": _cpu_sample(pids)})
        own = 100.0 * (time.process_time() - c0) / (time.monotonic() - t0)  # (the OS's count of it, another way)
    finally:
        child.kill()
        child.wait()
    assert set(got) == {"busy", "sleeping"}
    # (a loaded 2-core machine may give it well under 100 %: compared with the process's own CPU time; /proc
    # counts in 10 ms ticks, 2 % of 0.5 s, and the other threads of this process may add a little)
    assert got["busy"] > 5.0 and abs(got["busy"] - own) < 10.0, (got, own)
    assert got["sleeping"] < 10.0, got
    assert _cpu_percent({"start": start}) == {}  # (no end: nothing to say)


def test_the_latency_parts_add_up_from_the_logs():
    """``_latencies`` on hand-made log rows (times in s, figures in ms): the wait's and the compute's parts
    add up to their whole, and a row without ``update`` (an older node) counts in ``compute`` only."""
    from depthguard.nodes.bench import _latencies

    dist = [
        dict(frame_pub=10.000, recv=10.001, ready=10.0015, start=10.002, compute=0.008, update=0.003, pub=10.0105),
        dict(frame_pub=10.100, recv=10.101, ready=10.1015, start=10.102, compute=0.008, update=0.005, pub=10.1105),
        dict(frame_pub=10.200, recv=10.201, ready=10.2015, start=10.202, compute=0.008, pub=10.2105),
    ]
    cmds = [dict(dist_pub=10.0105, pub=10.0113, status="OK")]
    p = _latencies(dist, cmds)["frame_to_distances_parts"]
    assert p["compute"]["median_ms"] == pytest.approx(8.0)
    assert p["compute_update"]["median_ms"] == pytest.approx(4.0)  # (3 and 5 ms: the third row has none)
    assert p["compute_query"]["median_ms"] == pytest.approx(4.0)
    assert p["decode_and_pair"]["median_ms"] + p["wake_and_take"]["median_ms"] == pytest.approx(p["wait"]["median_ms"])
    assert p["publish"]["median_ms"] == pytest.approx(0.5)
