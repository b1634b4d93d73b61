"""saphari-skin: the quick run stops the robot before contact, Gray code never glitches, binary does, and
every multi-line binary transition is sampled inside its skew window; no-avoidance touches at full speed."""

import numpy as np
import pytest

pytest.importorskip("mujoco")

from depthguard.sensors.skin import SkinLayout  # noqa: E402
from depthguard.sim.saphari_skin import run  # noqa: E402
from depthguard.sim.skin_cell import HandScript, SkinCell  # noqa: E402


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("skin")
    return run(name="saphari-skin", quick=True, avoidance=True, out_dir=str(out), progress=False, options={}), out


@pytest.mark.slow
def test_quick_run_contract(quick):
    res, out = quick
    assert res["max_speed_at_contact_mm_s"] is not None and res["max_speed_at_contact_mm_s"] <= 10.0
    assert res["gray_code_glitches"] == 0 and res["online_gray_glitches"] == 0
    assert res["binary_code_glitches"] > 0
    cover = res["binary_multibit_transitions"]
    assert set(cover) == {"1->2", "3->4", "5->6", "6->5", "4->3", "2->1"}
    assert all(n_in >= 1 for _, n_in in cover.values())
    assert res["max_level"] == 7 and res["collision_steps"] > 0
    assert 0 < res["detection_to_stop_s"] < 0.5 and res["contact_to_stop_s"] < 0.02
    # resumes only after the hand is back beyond the minimum safety distance (5 cm at 0.25 m/s = 0.2 s)
    assert 0.2 <= res["resume_s"] < 0.4
    for k in ("collision_steps", "min_clearance", "task_completion", "path_error", "distance_hz_median"):
        assert k in res
    for f in ("fig11.png", "graycode.png", "recording.mcap", "metrics.json"):
        assert (out / f).stat().st_size > 0


@pytest.mark.slow
def test_without_levels_the_touch_is_at_full_speed():
    res = run(name="saphari-skin", quick=True, avoidance=False, out_dir=None, progress=False, options={})
    assert res["max_speed_at_contact_mm_s"] > 300


def test_skin_layout_and_rays_against_geometry():
    L = SkinLayout(link="forearm_link")
    assert L.n_elements == 49 and (L.kinds() == "P").sum() == 28
    cell = SkinCell(L, hand_module=4, hand_element=3)
    q = np.array([0.3, -1.7, 1.6, -1.2, -1.57, 0.4])
    for gap in (0.08, 0.03, 0.0, -0.002):
        cell.set_state(q, gap)
        r = cell.ranges()
        under = [4 * 7 + e for e in (2, 3, 4)]  # elements under the 12 cm palm
        np.testing.assert_allclose(r[under], gap, atol=1e-6)
        assert cell.clearance() == pytest.approx(gap, abs=1e-6)  # mj_geomDistance agrees with the rays
    assert HandScript().gap(0.0) == HandScript().far_gap
