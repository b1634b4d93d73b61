"""Scenario saphari-octree end to end (quick form) and the octree backend in the scenario runner."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("mujoco")
pytest.importorskip("mcap")


@pytest.mark.slow
def test_saphari_octree_quick_run_writes_metrics_plots_octomap_and_recording(tmp_path):
    from mcap.reader import make_reader

    from depthguard.sim.saphari_octree import run

    out = run(quick=True, avoidance=False, out_dir=tmp_path, options={"octree_res": 0.05})
    for key in ("collision_steps", "min_clearance", "task_completion", "path_error", "distance_hz_median"):
        assert key in out
    assert set(out["stage_ms"]) >= {"reachability", "fusion", "distance", "camera_capture", "laser"}
    assert all(np.isfinite(v) and v >= 0 for v in out["stage_ms"].values())
    assert out["octree_nodes_median"]["occupied"] > 0
    assert 0.0 < out["reachability_reused"] < 1.0  # the first grid is computed, the moving arm needs more
    assert out["sensors"] == {"cameras": 2, "scanners": 2}
    files = out["files"]
    for k in ("reachability_fig1", "octree_fig6", "occupied.bt", "occluded.bt", "octree.ot", "recording"):
        assert k in files
    with open(files["recording"], "rb") as fh:
        topics = {c.topic for c in make_reader(fh).get_summary().channels.values()}
    assert {"/octree", "/reachability", "/joint_states"} <= topics
    assert json.loads((tmp_path / "metrics.json").read_text())["backend"] == "octree"


def test_saphari_octree_is_registered():
    from depthguard import cli

    assert cli.EXTRA_SCENARIOS["saphari-octree"] == "depthguard.sim.saphari_octree:run"
    assert cli.EXTRA_BENCHES["octree"] == "depthguard.bench.octree:run_octree_benchmark"
    import importlib

    mod, fn = cli.EXTRA_SCENARIOS["saphari-octree"].split(":")
    assert callable(getattr(importlib.import_module(mod), fn))
    mod, fn = cli.EXTRA_BENCHES["octree"].split(":")
    assert callable(getattr(importlib.import_module(mod), fn))
