"""``depthguard scenario NAME --view``: the live view fed by a simulated run (no browser needed here; the
browser test is tests/test_live_view.py). Checks what the view was handed and drew: both cameras' clouds,
the control spheres, and with the octree backend the octree's nodes, one square per node of each kind."""

from __future__ import annotations

import random

import numpy as np
import pytest

pytest.importorskip("viser")
pytest.importorskip("mujoco")

from depthguard.cli import main  # noqa: E402


def _spy_view(monkeypatch) -> list:
    """Capture the LiveView that a scenario opens; before it closes, draw its last state once more and keep
    what was drawn (``drawn``) beside the state it was drawn from (``last``)."""
    from depthguard.sim import live_run

    seen: list = []
    real_open = live_run.open_view

    def spy(*a, **k):
        view = real_open(*a, **k)
        real_close = view.close

        def close():
            with view._draw_lock:
                view.draw()
                view.last = dict(view.state)
                view.drawn = {k: np.asarray(h.points, float) for k, h in view.clouds.items()}
            real_close()

        view.close = close
        seen.append(view)
        return view

    monkeypatch.setattr(live_run, "open_view", spy)
    return seen


@pytest.mark.slow
def test_scenario_view_draws_clouds_spheres_and_the_octree(monkeypatch):
    from depthguard.octree.fusion import OCCLUDED, OCCUPIED, UNSEEN
    from depthguard.sim import scenarios as S

    seen = _spy_view(monkeypatch)
    sc = S.load_scenario("ral-hexagon")
    sc["quick_duration"] = 0.7
    port = random.randint(36100, 39000)
    S._run_one(sc, quick=True, avoidance=True, cameras=None, progress=False, label="view", backend="octree", view=port)
    (view,) = seen
    assert view.draws >= 1 and not view._thread.is_alive()
    assert {"cloud0", "cloud1"} <= set(view.drawn), "each camera's point cloud is drawn"
    centres, radii, res = view.last["res"]
    assert centres.shape == (9, 3) and np.all(radii > 0) and len(res.distance) == 9
    frame = view.last["octree"]
    assert frame is not None and np.count_nonzero(frame.kind == OCCUPIED) > 0, "the person fills some nodes"
    for name, code in (("occupied", OCCUPIED), ("occluded", OCCLUDED), ("unseen", UNSEEN)):
        want = np.asarray(frame.box.origin) + (np.argwhere(frame.kind == code) + 0.5) * frame.box.res
        got = view.drawn.get(f"octree_{name}", np.zeros((0, 3)))
        assert got.shape == want.shape, name

        # viser keeps the points as float16 (about 1 mm at 1-2 m): node centres to within that
        def node(p):  # (node index of a centre, as the sort key)
            return np.floor((p - np.asarray(frame.box.origin)) / frame.box.res).astype(int)

        got_sorted = got[np.lexsort(node(got).T[::-1])]
        np.testing.assert_allclose(got_sorted, want[np.lexsort(node(want).T[::-1])], atol=2e-3)


def test_live_view_keeps_stdout_for_json(capsys):
    """viser's start banner must not reach stdout: ``--json`` commands print one object there."""
    from depthguard.camera import Camera
    from depthguard.robot.model import load_lwr4
    from depthguard.viz.live import LiveView

    cam = Camera(width=64, height=48, fx=50.0, fy=50.0, cx=32.0, cy=24.0, R=np.eye(3), t=np.array([0, 0, 2.0]))
    view = LiveView.for_scene("t", load_lwr4(), [cam], 0.4, port=random.randint(39100, 41000))
    view.close()
    assert capsys.readouterr().out == ""


@pytest.mark.parametrize("name", ["pivot", "saphari-skin", "saphari-contact-soft"])
def test_view_refused_for_scenarios_without_depth_cameras(name, capsys):
    assert main(["scenario", name, "--quick", "--view", "--json"]) == 2
    err = capsys.readouterr().err
    assert "--view" in err and name in err and "ral-hexagon" in err and "Traceback" not in err


def test_view_port_checked(capsys):
    assert main(["scenario", "ral-hexagon", "--quick", "--view", "--view-port", "70000", "--json"]) == 2
    assert "--view-port" in capsys.readouterr().err
