"""SAPHARI §6.3 contact experiments end to end (``depthguard scenario saphari-contact-*``): the JSON
contract and its tolerances with ``--quick``, the options, and the outputs."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("mujoco")

from depthguard.sim.contact_experiment import make_setup  # noqa: E402
from depthguard.sim.saphari_contact import run  # noqa: E402

KEYS = (
    "detection_delay_ms",
    "force_error_rms_n",
    "force_error_steady_rel",
    "contact_point_error_m",
    "false_detections",
    "peak_displacement_m",
)


def _check_contract(m: dict) -> None:
    for k in KEYS:
        assert k in m, k
    assert m["detection_delay_ms"] is not None and 0.0 <= m["detection_delay_ms"] <= 20.0
    assert m["force_error_steady_rel"] <= 0.10
    assert m["contact_point_error_m"] <= 0.05
    assert m["false_detections"] == 0
    assert m["peak_displacement_m"] > 0.0
    json.dumps(m)  # JSON-able


@pytest.mark.slow
@pytest.mark.parametrize(
    ("name", "contacts"), [("saphari-contact-soft", 1), ("saphari-contact-stiff", 1), ("saphari-contact-soft", 2)]
)
def test_quick_experiments_meet_the_stated_tolerances(name, contacts, tmp_path):
    out = tmp_path if contacts == 2 else None
    m = run(name=name, quick=True, out_dir=out, options={"contacts": contacts, "rate": None})
    _check_contract(m)
    assert m["contacts"] == contacts
    if name.endswith("stiff"):
        assert m["most_loaded_joint"] == 2  # Fig. 26: joint 2 is the most stressed
        assert m["peak_displacement_m"] < 0.03  # stiff: balanced force, small displacement
        assert m["unobservable_directions"] >= 1 and m["observable_fraction"] > 0.7
    else:
        assert m["peak_displacement_m"] > 0.05  # soft: the contact point gives way
    if out is not None:
        for key in ("plot", "depth", "recording", "metrics"):
            assert (tmp_path / m["files"][key].split("/")[-1]).stat().st_size > 0
        from mcap.reader import make_reader

        with open(m["files"]["recording"], "rb") as fh:
            topics = {c.topic for c in make_reader(fh).get_summary().channels.values()}
        assert {"/camera0/depth", "/camera0/contact_overlay", "/contact", "/residual"} <= topics


def test_setup_options_are_validated():
    with pytest.raises(ValueError, match="contacts"):
        make_setup("soft", contacts=3)
    with pytest.raises(ValueError, match="experiment"):
        make_setup("medium")
    with pytest.raises(ValueError, match="rate"):
        run(name="saphari-contact-soft", quick=True, options={"rate": 5.0})
    s = make_setup("stiff", quick=False)
    assert s.hands[0].link == "lwr_link_3" and s.hands[0].duration == pytest.approx(5.0)
    assert np.allclose(s.hands[0].unit(), [0, 0, -1])
    s = make_setup("soft", contacts=2, rate=1000.0)
    assert s.rate == 1000.0 and {h.link for h in s.hands} == {"lwr_link_6", "lwr_link_3"}
    assert s.hands[0].duration == pytest.approx(0.74)
