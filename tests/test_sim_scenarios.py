"""Scenarios end to end, in their quick form (160x120 depth, short runs).

Each scenario must be collision-free with avoidance and must collide without it (so that it tests
something); the single-camera failure cases of RA-L'16 must show with one camera and disappear with two.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("mujoco")
pytest.importorskip("pinocchio")

from depthguard.sim.scenarios import list_scenarios, load_scenario, run_scenario  # noqa: E402

KEYS = ("collision_steps", "min_clearance", "task_completion", "path_error", "distance_hz_median")

# scenario -> cameras for the "avoid" check; ral-shadow/hidden are checked in their own tests
AVOID = ["icra-exp1", "icra-exp2", "icra-exp3", "icra-exp4", "ral-hexagon"]
# ral-hidden's target is inside the obstacle
COMPLETION_NOT_EXPECTED = {"ral-hidden"}


def test_shipped_scenarios_load():
    names = list_scenarios()
    assert {"icra-exp1", "icra-exp2", "icra-exp3", "icra-exp4", "ral-hexagon", "ral-shadow", "ral-hidden"} <= set(names)
    for n in names:
        sc = load_scenario(n)
        assert sc["name"] == n


def test_unknown_scenario_is_a_clear_error():
    with pytest.raises(ValueError, match="unknown scenario"):
        load_scenario("no-such-scenario")


@pytest.mark.parametrize("name", AVOID)
def test_quick_scenario_avoids(name):
    r = run_scenario(name, quick=True, variants=False)
    for k in KEYS:
        assert k in r
    json.dumps(r)  # JSON-ready
    assert r["collision_steps"] == 0, r
    assert r["min_clearance"] > 0.0
    if name not in COMPLETION_NOT_EXPECTED:
        assert r["task_completion"] == 1.0, r
    if name == "icra-exp3":  # the elbow avoids the box through the redundancy: the end effector keeps its path
        assert r["path_error"] < 0.03, r
    assert r["distance_hz_median"] > 0


@pytest.mark.parametrize("name", AVOID)
def test_quick_scenario_collides_without_avoidance(name):
    r = run_scenario(name, quick=True, avoidance=False, variants=False)
    assert r["collision_steps"] > 0, r
    assert r["min_clearance"] < 0.0


def test_shadow_one_camera_swerves_two_cameras_keep_the_path():
    """RA-L'16 Figs. 8 and 12: the second camera sees that the shadow of the panel is free (measured:
    path error 0.6 m and 9 s at a phantom zero with one camera, 0.05 m and 0.6 s with two)."""
    one = run_scenario("ral-shadow", quick=True, cameras=1, variants=False)
    two = run_scenario("ral-shadow", quick=True, cameras=2, variants=False)
    assert one["collision_steps"] == 0 and two["collision_steps"] == 0
    assert two["path_error"] < 0.08, two
    assert two["time_at_zero_s"] < 0.2 * one["time_at_zero_s"], (one, two)
    assert one["path_error"] > 3 * two["path_error"] and one["path_error"] > 0.1, (one, two)


def test_hidden_one_camera_misses_two_cameras_avoid():
    one = run_scenario("ral-hidden", quick=True, cameras=1, variants=False)
    two = run_scenario("ral-hidden", quick=True, cameras=2, variants=False)
    assert one["collision_steps"] > 0, one  # the box hidden behind the robot is not seen
    assert two["collision_steps"] == 0, two
    assert two["min_clearance"] > 0.05


def test_run_folder_has_metrics_plots_and_recording(tmp_path):
    pytest.importorskip("matplotlib")
    pytest.importorskip("mcap")
    r = run_scenario("icra-exp1", quick=True, out_dir=tmp_path, variants=True)
    assert "no_pivot" in r["variants"]
    data = json.loads((tmp_path / "metrics.json").read_text())
    for k in KEYS:
        assert k in data
    for f in ("ee_paths.png", "distances.png", "distance_rate.png", "recording.mcap"):
        assert (tmp_path / f).stat().st_size > 1000
    from mcap.reader import make_reader

    with open(tmp_path / "recording.mcap", "rb") as fh:
        reader = make_reader(fh)
        topics = {c.topic for c in reader.get_summary().channels.values()}
        want = {"/camera0/depth/image_raw", "/joint_states", "/depthguard/distances", "/depthguard/repulsion",
                "/depthguard/true_clearance", "/depthguard/markers"}  # fmt: skip
        assert want <= topics
        assert reader.get_header().profile == "ros2"
    from depthguard.io import ros2
    from depthguard.io.mcap_ros2 import read_messages

    for _, typename, _, msg in read_messages(tmp_path / "recording.mcap", topics=["/camera0/depth/image_raw"]):
        assert typename == "sensor_msgs/msg/Image"
        assert msg.encoding == "16UC1" and msg.width == 160 and msg.height == 120
        assert ros2.image_to_depth(msg).shape == (120, 160)
        break


def test_three_rates_in_simulated_time():
    """Frames every 33 ms, distance stage every 3 ms, control every 1 ms (simulated time)."""
    from depthguard.sim import scenarios as S

    sc = load_scenario("icra-exp1")
    sc["quick_duration"] = 1.0
    cell, log, task, cfg = S._run_one(sc, quick=True, avoidance=True, cameras=None, progress=False, label="")
    assert len(log.wall_control) == 1000
    assert len(log.wall_frame) == 30
    td = np.diff(log.t_distance)
    assert np.allclose(td, 0.003, atol=1.1e-3)
