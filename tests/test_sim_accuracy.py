"""Evaluated against true distances (depthguard.sim.accuracy, depthguard.sim.pointtruth).

The truth per control point comes from coal (PointClearance), checked here against the analytic
primitives of depthguard.scene; the metrics are checked on a hand-made log; and the quick ral-hexagon
run must never evaluate a control point at zero while its true clearance exceeds 5 cm.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

pytest.importorskip("mujoco")
pytest.importorskip("coal")

from depthguard.scene import Box, Capsule  # noqa: E402
from depthguard.sim.accuracy import accuracy_metrics, under_report_series  # noqa: E402


def _log(t, e, c, tol, names=("a", "b")):
    return SimpleNamespace(
        acc_t=list(t),
        acc_eval=list(np.ravel(e)),
        acc_true=list(np.ravel(c)),
        acc_tol=list(np.ravel(tol)),
        point_names=tuple(names),
    )


def test_accuracy_metrics_on_a_hand_made_log():
    t = [0.0, 0.003, 0.006, 0.009]
    e = np.array([[0.10, np.inf], [0.0, 0.30], [0.002, 0.35], [0.20, 0.41]])
    c = np.array([[0.12, 0.39], [0.20, 0.31], [0.03, 0.36], [0.19, 0.50]])
    tol = np.full_like(e, 0.02)
    m = accuracy_metrics(_log(t, e, c, tol), rho=0.4, period=0.003)
    # samples with c < rho: all but the last of point b; inf counts as rho
    over = np.array([0.10 - 0.12, 0.40 - 0.39, 0.0 - 0.20, 0.30 - 0.31, 0.002 - 0.03, 0.35 - 0.36, 0.20 - 0.19])
    assert m["max_over_report"] == pytest.approx(over.max())
    assert m["median_under_report"] == pytest.approx(np.median(-over))
    assert m["time_at_zero_s"] == pytest.approx(0.003)  # only the second call: 0 while the truth is 0.2
    assert m["declared_tolerance"] == pytest.approx(0.02)
    assert m["over_report_within_tolerance"] is True
    assert m["accuracy_samples"] == 7
    assert m["accuracy_per_point"]["a"]["time_at_zero_s"] == pytest.approx(0.003)
    ts, under, zero = under_report_series(_log(t, e, c, tol), 0.4)
    assert zero.tolist() == [False, True, False, False]
    assert np.isnan(under[3, 1]) and under[1, 0] == pytest.approx(0.2)
    bad = accuracy_metrics(_log(t, e + 0.05, c, tol), rho=0.4, period=0.003)
    assert bad["over_report_within_tolerance"] is False


def test_point_clearance_matches_the_analytic_primitives():
    from depthguard.sim import scenario_setup as setup
    from depthguard.sim import scenarios as S
    from depthguard.sim.pointtruth import PointClearance

    sc = S.load_scenario("ral-hexagon")
    cell, _, _ = setup.build_scenario_cell(sc, quick=True, cameras=1)
    pc = PointClearance(cell)
    snap = pc.snapshot(cell.data)
    m, d = cell.model, cell.data
    rng = np.random.default_rng(1)
    for name in ("parcel", "table", "carol_torso"):
        g = next(i for i, n in enumerate(pc.names) if n == name)
        gid = pc.geoms[g]
        pos, R = d.geom_xpos[gid], d.geom_xmat[gid].reshape(3, 3)
        for _ in range(5):
            p = pos + rng.uniform(-0.6, 0.6, 3)
            if m.geom_type[gid] == 6:  # box, in its own frame
                truth = Box(np.zeros(3), m.geom_size[gid].copy()).distance((R.T @ (p - pos))[None])[0]
            else:  # capsule along its z axis
                hz = m.geom_size[gid][1]
                truth = Capsule(pos - R[:, 2] * hz, pos + R[:, 2] * hz, m.geom_size[gid][0]).distance(p[None])[0]
            one = PointClearance.__new__(PointClearance)
            one.__dict__.update(pc.__dict__)
            keep = [g]
            one.geoms, one.shapes, one.names = pc.geoms[keep], [pc.shapes[g]], [name]
            one.rbound, one.planes = pc.rbound[keep], pc.planes[:0]
            sub = (snap[0][keep], snap[1][keep], snap[2][:0], snap[3][:0])
            got, _ = one.evaluate(p[None], np.array([0.05]), sub)
            assert got[0] == pytest.approx(max(min(truth - 0.05, pc.distmax), 0.0), abs=1e-6), name


@pytest.mark.slow
def test_quick_ral_hexagon_has_no_phantom_contact():
    """Two cameras, the quick form: no control point may be evaluated at zero (<= 5 mm) while its true
    clearance exceeds 5 cm; the evaluation may not exceed the truth by more than its declared tolerance nor
    by 3 cm, and the median under-report stays within 3 cm (the accuracy issue's targets). With the upright
    "ral" pair the shoulder sphere read zero for 0.2-1.8 s (the second camera's projector shadow of the
    table's corner runs behind the shoulder in the principal view) and the median was 6 cm; the scenario's
    "ral-rolled-far" placement turns the second camera on its side (docs/phantom-zero.md)."""
    from depthguard.sim.scenarios import run_scenario

    r = run_scenario("ral-hexagon", quick=True, cameras=2, variants=False)
    assert r["placement"] == "ral-rolled-far"
    assert r["accuracy_samples"] > 1000
    assert r["time_at_zero_s"] == 0.0, r["accuracy_per_point"]
    assert r["over_report_within_tolerance"], r
    assert r["max_over_report"] <= 0.03
    assert r["median_under_report"] <= 0.03


@pytest.mark.slow
def test_quick_panda_hexagon_stays_within_the_measured_bound():
    """The Panda from its own meshes on ``ral-hexagon``'s placement (docs/robots.md): no collision, at most
    1 s at a phantom zero (2.7 s on the upright pair), and the fused distance within tolerance of the measured
    bound, which counts the self-filter's inflated meshes as robot. When it counted only the inner capsules,
    one sampled call read 0.208 m over it (the sliver between a link's capsule and its inflated mesh)."""
    from depthguard.sim.scenarios import run_scenario

    r = run_scenario("ral-hexagon-panda", quick=True, cameras=2, variants=False)
    assert r["placement"] == "ral-rolled-far"
    assert r["collision_steps"] == 0
    assert r["time_at_zero_s"] <= 1.0
    assert r["over_report_within_tolerance"], r
    assert r["measured_bound"]["over_measured_bound_within_tolerance"], r["measured_bound"]


def test_principal_camera_sees_the_space_of_interest():
    """RA-L'16 §I, assumption 1: the principal camera of each ral scenario's placement sees the space within ρ
    of every control point along the ral scenarios' task (above 0.35 m; below, a sliver of space low in
    front of the camera near the end effector's lowest waypoints lies under the image's bottom edge, see
    docs/phantom-zero.md). Aimed at 0.35 m, the space above the arm was cut by the top edge."""
    from depthguard.sim import scenario_setup as setup
    from depthguard.sim import scenarios as S
    from depthguard.sim.depthcam import kinect_camera, placement
    from depthguard.sim.pipeline import Kinematics

    kin = Kinematics("ral-9", 0.12)
    rng = np.random.default_rng(0)
    pts = []
    for name in ("ral-hexagon", "ral-shadow", "ral-hidden"):
        sc = S.load_scenario(name)
        q = setup.solve_ik(kin, np.array(sc["q0"], float), np.asarray(sc["ee_start"], float))
        for wp in [sc["ee_start"], *sc["task"]["waypoints"]]:
            q = setup.solve_ik(kin, q, np.asarray(wp, float))
            cp = kin.evaluate(q)
            for c, r in zip(cp.centres, cp.radii, strict=True):
                x = rng.normal(size=(400, 3))
                x *= ((r + 0.4) * rng.random(400) ** (1 / 3) / np.linalg.norm(x, axis=1))[:, None]
                pts.append(c + x)
    P = np.concatenate(pts)
    P = P[P[:, 2] > 0.35]

    def outside(cam):
        pc = cam.world_to_camera(P)
        u = cam.fx * pc[:, 0] / pc[:, 2] + cam.cx
        v = cam.fy * pc[:, 1] / pc[:, 2] + cam.cy
        return ~((pc[:, 2] > cam.min_depth) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height))

    for name in ("ral", "ral-rolled", "ral-rolled-far"):
        assert not outside(placement(name, 160, 120)[0]).any(), name
    principal = placement("ral", 160, 120)[0]
    old = kinect_camera(principal.position, (0.0, 0.0, 0.35), width=160, height=120)
    assert outside(old).any()  # the old aim did not (the test can fail)


def test_measured_bound_metrics_on_a_hand_made_log():
    """c - b, b - e and e - b over the sampled rows with c < rho only (rho = 0.4)."""
    from depthguard.sim.accuracy import measured_bound_metrics

    e = [[0.10, 0.40], [0.05, 0.20], [0.30, 0.30]]
    c = [[0.20, 0.50], [0.15, 0.30], [0.35, 0.38]]
    log = _log([0.0, 0.003, 0.006], e, c, np.full((3, 2), 0.02))
    assert measured_bound_metrics(log, 0.4) is None
    log.bound_row, log.bound, log.bound_spacing = [0, 2], [[0.12, np.nan], [0.29, 0.33]], 0.01
    m = measured_bound_metrics(log, 0.4)
    assert m["samples"] == 3  # row 0 point b: c >= rho (and no bound)
    assert m["median_unmeasured_under_report"] == pytest.approx(np.median([0.08, 0.06, 0.05]))
    assert m["median_excess_under_report"] == pytest.approx(np.median([0.02, -0.01, 0.03]))
    assert m["max_over_measured_bound"] == pytest.approx(0.01)
    assert m["over_measured_bound_within_tolerance"]


@pytest.mark.slow
def test_two_camera_under_report_is_the_cameras_not_the_fusions():
    """With two cameras the quick ral-hexagon run under-reports by several cm at the median (space that
    neither camera measures, docs/phantom-zero.md). Against the measured bound (an independent brute-force
    sampler of the space that no camera sees free), the fusion adds at most 2 cm at the median, and never
    claims free beyond it by more than its declared tolerance."""
    from depthguard.sim.scenarios import run_scenario

    r = run_scenario("ral-hexagon", quick=True, cameras=2, variants=False)
    mb = r["measured_bound"]
    assert mb["samples"] >= 50, mb
    assert mb["over_measured_bound_within_tolerance"], mb
    assert mb["median_excess_under_report"] <= 0.02, mb
    assert mb["median_unmeasured_under_report"] >= 0.5 * r["median_under_report"], (mb, r["median_under_report"])
