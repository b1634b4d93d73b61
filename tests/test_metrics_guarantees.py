"""The metrics that report a run's safety and accuracy, attacked with property tests against brute force.

``depthguard.sim.accuracy`` (over-report, under-report, time at zero), ``depthguard.sim.scenario_metrics``
(collision steps, time below the margin, path error, task completion, rates) and ``depthguard.sim.ssm_metrics``
(the true sphere clearance and the ``--ssm`` keys) are held to loops written here over every sample, to coal's
distances and to MuJoCo's ``mj_geomDistance``, on random series with NaN, +-inf, values exactly at the
thresholds, empty and reordered logs.

Found and pinned (``@example``): a NaN evaluation (which the controllers read as contact) was not counted in
``time_at_zero_s``, a NaN truth dropped its sample from ``max_over_report``, and ``time_at_zero_s`` was rounded
to 0.1 ms (one phantom contact at a 10 us period read 0); a NaN truth step was neither a collision step nor
time below the margin; a zero call time read an infinite rate (``Infinity`` in the JSON), reordered call times
a wrong one, and a log without rows raised; ``sphere_clearance`` read planes, meshes and height fields as
absent (``inf``: an over-report), took a negative geom id as the last geom and a negative radius as given;
``_finite_min`` and ``min_separation_margin`` read a series with a NaN or ``-inf`` as "nobody in the scene"
(None), hiding a collision next to it; a mis-sized ``acc_*`` log gave numpy's reshape error.
"""

from __future__ import annotations

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, example, given, settings
from hypothesis import strategies as st

mujoco = pytest.importorskip("mujoco")
coal = pytest.importorskip("coal")

from depthguard.control.ssm import MonitorState, SsmConfig  # noqa: E402
from depthguard.sim.accuracy import ZERO_EVAL, ZERO_TRUE, accuracy_metrics, under_report_series  # noqa: E402
from depthguard.sim.loop import LoopConfig, Task  # noqa: E402
from depthguard.sim.scenario_metrics import MARGIN, _path_distance, compute_metrics  # noqa: E402
from depthguard.sim.ssm_metrics import _finite_min, sphere_clearance, ssm_metrics  # noqa: E402

SETTINGS = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
NAN, INF = math.nan, math.inf
RHO = 0.4


def _same(got, ref, rel: float = 1e-9, abs_: float = 1e-12) -> bool:
    """``got`` equals the reference: both None, both NaN, the same infinity or within the tolerance."""
    if got is None or ref is None:
        return got is None and ref is None
    if math.isnan(ref) or math.isnan(got):
        return math.isnan(ref) and math.isnan(got)
    if math.isinf(ref) or math.isinf(got):
        return got == ref
    return abs(got - ref) <= abs_ + rel * abs(ref)


def _max(xs: list[float]) -> float | None:
    """max by a loop: None if empty, NaN if any NaN."""
    if not xs:
        return None
    if any(math.isnan(x) for x in xs):
        return NAN
    best = -INF
    for x in xs:
        best = x if x > best else best
    return best


def _median(xs: list[float]) -> float | None:
    if not xs:
        return None
    if any(math.isnan(x) for x in xs):
        return NAN
    s = sorted(xs)
    n = len(s)
    return s[n // 2] if n % 2 else (s[n // 2 - 1] + s[n // 2]) / 2


# ------------------------------------------------------------------------------------------------ accuracy

_E = st.one_of(st.sampled_from([NAN, INF, -INF, 0.0, ZERO_EVAL, RHO, ZERO_TRUE]), st.floats(-0.1, 1.0))
_C = st.one_of(st.sampled_from([NAN, 0.0, ZERO_TRUE, RHO, INF, -INF]), st.floats(-0.1, 1.0))
_TOL = st.one_of(st.just(NAN), st.floats(0.0, 0.05))


@st.composite
def _acc_case(draw):
    n_t, n_p = draw(st.integers(0, 5)), draw(st.integers(1, 3))
    k = n_t * n_p
    e = draw(st.lists(_E, min_size=k, max_size=k))
    c = draw(st.lists(_C, min_size=k, max_size=k))
    tol = draw(st.lists(_TOL, min_size=k, max_size=k))
    period = draw(st.one_of(st.sampled_from([0.003, 1e-5]), st.floats(1e-9, 0.05)))
    return np.reshape(e, (n_t, n_p)), np.reshape(c, (n_t, n_p)), np.reshape(tol, (n_t, n_p)), period


def _acc_log(e, c, tol, groups=()):
    n_t, n_p = np.shape(e)
    return SimpleNamespace(
        acc_t=[0.003 * i for i in range(n_t)],
        acc_eval=list(np.ravel(e)),
        acc_true=list(np.ravel(c)),
        acc_tol=list(np.ravel(tol)),
        point_names=tuple(f"p{k}" for k in range(n_p)),
        acc_excluded_groups=groups,
    )


def _acc_reference(e, c, tol, period):
    """Per sample by a loop: the compared samples are those whose truth is not known to be >= rho."""
    n_t, n_p = e.shape
    overs, tols, per_over, zero_rows, per_zero = [], [], [[] for _ in range(n_p)], 0, [0] * n_p
    for i in range(n_t):
        row_zero = False
        for k in range(n_p):
            ev, cv = float(e[i, k]), float(c[i, k])
            if not cv >= RHO:
                o = (RHO if ev > RHO else ev) - cv
                overs.append(o)
                tols.append(float(tol[i, k]))
                per_over[k].append(o)
            if (math.isnan(ev) or ev <= ZERO_EVAL) and cv > ZERO_TRUE:  # NaN: read as contact
                row_zero = True
                per_zero[k] += 1
        zero_rows += row_zero
    return {
        "max_over_report": _max(overs),
        "median_under_report": _median([-o for o in overs]),
        "declared_tolerance": _max(tols),
        "over_report_within_tolerance": all(o <= t for o, t in zip(overs, tols, strict=True)),
        "accuracy_samples": len(overs),
        "zero_rows": zero_rows,
        "per": [(_max(per_over[k]), _median([-o for o in per_over[k]]), per_zero[k]) for k in range(n_p)],
    }


@SETTINGS
@given(case=_acc_case(), groups=st.sampled_from([(), (3,), (1, 4)]))
@example(case=(np.array([[NAN]]), np.array([[0.2]]), np.array([[0.01]]), 0.003), groups=())  # NaN read as contact
@example(case=(np.array([[0.5, 0.1]]), np.array([[NAN, 0.3]]), np.full((1, 2), 0.01), 0.003), groups=())
@example(case=(np.array([[0.0]]), np.array([[0.3]]), np.array([[0.01]]), 1e-5), groups=())  # one call of 10 us
@example(case=(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros((0, 2)), 0.003), groups=(2,))  # an empty log
def test_accuracy_metrics_match_brute_force(case, groups):
    e, c, tol, period = case
    log = _acc_log(e, c, tol, groups)
    got = accuracy_metrics(log, RHO, period)
    ref = _acc_reference(e, c, tol, period)
    for key in ("max_over_report", "median_under_report", "declared_tolerance"):
        assert _same(got[key], ref[key]), (key, got[key], ref[key])
    assert got["over_report_within_tolerance"] is ref["over_report_within_tolerance"]
    assert got["accuracy_samples"] == ref["accuracy_samples"]
    # time at zero: the count times the period, and never 0 when some call was at zero
    assert _same(got["time_at_zero_s"], ref["zero_rows"] * period)
    assert (got["time_at_zero_s"] > 0) == (ref["zero_rows"] > 0)
    for k, (mx, med, nz) in enumerate(ref["per"]):
        p = got["accuracy_per_point"][f"p{k}"]
        assert _same(p["max_over_report"], mx) and _same(p["median_under_report"], med), (k, p)
        assert _same(p["time_at_zero_s"], nz * period) and (p["time_at_zero_s"] > 0) == (nz > 0)
    # the left-out geom groups are named, and change no number
    assert (str(list(groups)) in got["accuracy_truth"]) == bool(groups)
    plain = accuracy_metrics(_acc_log(e, c, tol), RHO, period)
    assert json.dumps({k: v for k, v in plain.items() if k != "accuracy_truth"}) == json.dumps(
        {k: v for k, v in got.items() if k != "accuracy_truth"}
    )
    _, under, at_zero = under_report_series(log, RHO)
    assert int(at_zero.sum()) == ref["zero_rows"] and under.shape == e.shape


@pytest.mark.parametrize("field", ["acc_eval", "acc_true", "acc_tol"])
def test_accuracy_log_of_the_wrong_size_is_named(field):
    log = _acc_log(np.zeros((2, 2)), np.zeros((2, 2)), np.zeros((2, 2)))
    setattr(log, field, getattr(log, field)[:-1])
    with pytest.raises(ValueError, match=f"{field} must hold len\\(acc_t\\) x len\\(point_names\\)"):
        accuracy_metrics(log, RHO, 0.003)


# ------------------------------------------------------------------------------------------ scenario metrics

_STEP = st.one_of(
    st.sampled_from([0.0, -0.0, MARGIN, NAN, INF, -INF, float(np.nextafter(0.0, 1.0)), float(np.nextafter(MARGIN, 0))]),
    st.floats(-0.2, 0.3),
)


def _run_log(steps, ee=None, wall_distance=(), t_distance=(), wall_control=(0.001,)):
    n = len(steps)
    return SimpleNamespace(
        step_true_min=list(steps),
        true_links=[[s] for s in steps],
        links=["link"],
        ee=list(np.zeros((n, 3)) if ee is None else ee),
        true_dynamic=list(steps),
        wall_distance=list(wall_distance),
        wall_control=list(wall_control),
        wall_frame=[],
        wall_camera=[],
        t_distance=list(t_distance),
        nearest_obstacle={},
        wall_total=0.0,
        acc_t=[],
        acc_eval=[],
        acc_true=[],
        acc_tol=[],
        point_names=("a",),
    )


def _points_task(n: int = 1) -> Task:
    return Task("points", np.array([[0.1 * i, 0.0, 0.0] for i in range(n)]))


@SETTINGS
@given(steps=st.lists(_STEP, min_size=1, max_size=40), dt=st.sampled_from([0.001, 0.0005]))
@example(steps=[0.1, NAN], dt=0.001)  # a NaN truth was neither a collision step nor time below the margin
@example(steps=[0.0, MARGIN, -0.0], dt=0.001)
def test_collision_steps_and_time_below_margin_match_counts(steps, dt):
    m = compute_metrics(_run_log(steps), _points_task(), LoopConfig(control_dt=dt))
    assert m["collision_steps"] == sum(1 for s in steps if not s > 0.0)  # at 0 and NaN (unknown) count
    assert _same(m["time_below_margin_s"], sum(1 for s in steps if not s >= MARGIN) * dt)
    low = NAN if any(math.isnan(s) for s in steps) else min(steps)
    assert _same(m["min_clearance"], low) and _same(m["min_clearance_per_link"]["link"], low)
    assert _same(m["min_clearance_people_boxes"], low)


def test_a_log_without_rows_gives_null_minima():
    for task in (_points_task(2), Task("hold", np.array([[0.0, 0.0, 0.5]]))):
        m = compute_metrics(_run_log([], wall_control=()), task, LoopConfig())
        for key in ("min_clearance", "path_error", "path_error_max", "control_ms_median", "max_over_report"):
            assert m[key] is None, key
        assert m["collision_steps"] == 0 and m["time_below_margin_s"] == 0.0 and m["task_completion"] == 0.0
        json.dumps(m, allow_nan=False)


_COORD = st.one_of(st.sampled_from([0.0, 0.5, 1e-7]), st.floats(-1.0, 1.0))
_PT = st.tuples(_COORD, _COORD, _COORD)


def _brute_polyline(p: np.ndarray, path: np.ndarray, n: int = 4001) -> tuple[float, float]:
    """(distance to the densest sampling of the polyline, its spacing bound): the true distance lies in
    ``[d - spacing / 2, d]``."""
    if len(path) == 1:
        return float(np.sqrt(np.sum((p - path[0]) ** 2))), 0.0
    s = np.linspace(0.0, 1.0, n)[:, None]
    best, step = INF, 0.0
    for a, b in zip(path[:-1], path[1:], strict=True):
        pts = a + s * (b - a)
        best = min(best, float(np.sqrt(np.min(np.sum((pts - p) ** 2, axis=1)))))
        step = max(step, float(np.sqrt(np.sum((b - a) ** 2))) / (n - 1))
    return best, step


@SETTINGS
@given(path=st.lists(_PT, min_size=1, max_size=5), pts=st.lists(_PT, min_size=1, max_size=6))
@example(path=[(0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (1.0, 0.0, 0.0)], pts=[(0.5, 0.3, 0.0), (-1.0, 0.0, 0.0)])
@example(path=[(0.5, 0.5, 0.5)], pts=[(0.0, 0.0, 0.0)])
@example(path=[(0.0, 0.0, 0.0), (1e-7, 0.0, 0.0)], pts=[(0.5, 0.0, 0.0)])
@example(path=[(0.0, 0.0, 1e-07), (0.0, 0.0, 0.0)], pts=[(0.0, 0.0, 0.0)])  # read 1e-7 m off its own vertex
def test_path_distance_matches_the_sampled_polyline(path, pts):
    P, X = np.array(path, float), np.array(pts, float)
    got = _path_distance(X, P)
    assert got.shape == (len(X),)
    for x, d in zip(X, got, strict=True):
        ref, step = _brute_polyline(x, P)
        assert ref - step / 2 - 1e-9 <= d <= ref + 1e-9
        assert d <= min(np.sqrt(np.sum((P - x) ** 2, axis=1))) + 1e-12  # never beyond the nearest vertex


@SETTINGS
@given(
    kind=st.sampled_from(["points", "cycle", "hold"]),
    n_wp=st.integers(1, 4),
    reached=st.integers(0, 12),
    off=st.one_of(st.sampled_from([0.0, 0.0299, 0.0301, NAN]), st.floats(0.0, 0.2)),
)
def test_task_completion_for_every_kind(kind, n_wp, reached, off):
    wp = np.array([[0.4 + 0.1 * i, 0.1, 0.5] for i in range(n_wp)])
    task = Task(kind, wp, start=np.array([0.3, 0.0, 0.5]))
    task.reached = min(reached, n_wp) if kind == "points" else reached
    ee = [wp[0] + np.array([0.0, 0.0, off])]  # the last row
    m = compute_metrics(_run_log([0.2], ee=ee), task, LoopConfig())
    if kind == "hold":
        ref = 1.0 if abs(off) < 0.03 else 0.0  # (NaN: not back)
    else:
        ref = min(task.reached / n_wp, 1.0)
    assert m["task_completion"] == ref
    if kind == "hold" and not math.isnan(off):
        assert _same(m["path_error"], abs(off)) and _same(m["path_error_max"], abs(off))


def _percentile(xs: list[float], q: float) -> float:
    """numpy's default (linear) percentile written out."""
    s = sorted(xs)
    pos = q / 100.0 * (len(s) - 1)
    lo, hi = math.floor(pos), math.ceil(pos)
    return s[lo] + (s[hi] - s[lo]) * (pos - lo)


def _rate_ref(t: float) -> float | None:
    return 1.0 / t if t > 0 and math.isfinite(t) else None


@SETTINGS
@given(
    wd=st.lists(st.one_of(st.just(0.0), st.floats(1e-7, 0.02)), max_size=20),
    td=st.lists(st.sampled_from([0.0, 0.003, 0.006, 0.009, 0.012, 0.015]), max_size=8),
)
@example(wd=[0.0], td=[0.0, 0.0])  # a zero call time read an infinite rate (Infinity in the JSON)
@example(wd=[0.002, 0.004], td=[0.0, 0.006, 0.003])  # reordered call times
def test_distance_rates_match_the_call_times(wd, td):
    m = compute_metrics(_run_log([0.2], wall_distance=wd, t_distance=td), _points_task(), LoopConfig())
    for key, q in (("distance_hz_median", 50), ("distance_hz_p99", 99)):
        assert _same(m[key], _rate_ref(_percentile(wd, q)) if wd else 0.0), (key, m[key])
    if m["distance_hz_median"] and m["distance_hz_p99"]:
        assert m["distance_hz_p99"] <= m["distance_hz_median"] * (1 + 1e-12)  # p99 of times: the slow end
    steps = np.diff(sorted(td))
    ref = _rate_ref(_median(list(steps))) if len(td) > 1 else 0.0
    assert _same(m["distance_stage_sim_hz"], ref)
    keys = ("distance_hz_median", "distance_hz_p99", "distance_ms_median", "distance_stage_sim_hz")
    json.dumps({k: m[k] for k in keys}, allow_nan=False)


# ------------------------------------------------------------------------------------------- SSM: clearance

_TYPES = ("sphere", "capsule", "box", "cylinder", "ellipsoid", "plane", "mesh", "hfield")
_EXACT = {"sphere", "capsule", "box", "plane"}  # equal to the reference; the others never above it
_XML = """<mujoco><asset>
  <mesh name="m" vertex="0 0 0  0.3 0 0  0 0.2 0  0 0 0.25  0.2 0.2 0.1  -0.05 0.1 0.2"/>
  <hfield name="h" nrow="4" ncol="5" size="0.3 0.2 0.15 0.05"/>
</asset><worldbody>
  <body mocap="true"><geom name="sphere" type="sphere" size="0.12"/></body>
  <body mocap="true"><geom name="capsule" type="capsule" size="0.07 0.2"/></body>
  <body mocap="true"><geom name="box" type="box" size="0.2 0.1 0.05"/></body>
  <body mocap="true"><geom name="cylinder" type="cylinder" size="0.08 0.15"/></body>
  <body mocap="true"><geom name="ellipsoid" type="ellipsoid" size="0.1 0.2 0.05"/></body>
  <body mocap="true"><geom name="plane" type="plane" size="1 1 0.1"/></body>
  <body mocap="true"><geom name="mesh" type="mesh" mesh="m"/></body>
  <body mocap="true"><geom name="hfield" type="hfield" hfield="h"/></body>
  <body mocap="true"><geom name="probe" type="sphere" size="0.05"/></body>
</worldbody></mujoco>"""
_MODEL: list = []


def _model():
    if not _MODEL:
        m = mujoco.MjModel.from_xml_string(_XML)
        m.hfield_data[:] = np.random.default_rng(0).random(m.hfield_data.size)
        _MODEL.append((m, mujoco.MjData(m)))
    return _MODEL[0]


def _coal_shape(name: str, size: np.ndarray):
    return {
        "sphere": lambda: coal.Sphere(size[0]),
        "capsule": lambda: coal.Capsule(size[0], 2 * size[1]),
        "box": lambda: coal.Box(*(2 * size)),
        "cylinder": lambda: coal.Cylinder(size[0], 2 * size[1]),
        "ellipsoid": lambda: coal.Ellipsoid(*size),
        "plane": lambda: coal.Halfspace(np.array([0.0, 0.0, 1.0]), 0.0),
    }[name]()


def _reference(m, d, name: str, gid: int, c: np.ndarray, r: float) -> float:
    """The sphere's clearance from coal (signed), or from mj_geomDistance for meshes and height fields."""
    if name in ("mesh", "hfield"):
        probe = m.ngeom - 1
        m.geom_size[probe, 0], m.geom_rbound[probe] = max(r, 1e-6), max(r, 1e-6)
        d.mocap_pos[m.body_mocapid[m.geom_bodyid[probe]]] = c
        mujoco.mj_kinematics(m, d)
        return mujoco.mj_geomDistance(m, d, probe, gid, 10.0, np.zeros(6)) + (max(r, 1e-6) - r)
    req, res = coal.DistanceRequest(), coal.DistanceResult()
    req.enable_signed_distance = True
    pose = coal.Transform3s(d.geom_xmat[gid].reshape(3, 3).copy(), d.geom_xpos[gid].copy())
    sphere = coal.Transform3s(np.eye(3), c)
    return coal.distance(coal.Sphere(max(r, 1e-9)), sphere, _coal_shape(name, m.geom_size[gid]), pose, req, res)


_UNIT = st.floats(-1.0, 1.0)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    pos=st.tuples(*[st.floats(-0.5, 0.5)] * 3),
    quat=st.tuples(_UNIT, _UNIT, _UNIT, _UNIT),
    rel=st.tuples(*[st.floats(-0.6, 0.6)] * 3),
    r=st.one_of(st.just(0.0), st.floats(0.0, 0.2)),
)
@example(pos=(0.0, 0.0, 0.0), quat=(1.0, 0.0, 0.0, 0.0), rel=(0.0, 0.0, 0.5), r=0.05)
@example(pos=(0.1, 0.0, 0.0), quat=(1.0, 0.0, 0.0, 0.0), rel=(0.0, 0.0, 0.01), r=0.05)  # overlapping
@pytest.mark.parametrize("name", _TYPES)
def test_sphere_clearance_matches_coal_and_mujoco(name, pos, quat, rel, r):
    """Every geom type in random poses, the sphere often overlapping: planes, meshes and height fields read
    ``inf`` before (an over-report); the exact types equal the reference, the others never exceed it, and an
    overlap is never read positive."""
    q = np.array(quat)
    assume(np.linalg.norm(q) > 0.1)
    m, d = _model()
    gid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, name)
    body = m.body_mocapid[m.geom_bodyid[gid]]
    d.mocap_pos[:] = 50.0  # the others out of the way
    d.mocap_pos[body], d.mocap_quat[body] = pos, q / np.linalg.norm(q)
    mujoco.mj_kinematics(m, d)
    c = np.array(pos) + np.array(rel)
    got = float(sphere_clearance(m, d, np.array([gid]), c[None], np.array([r]))[0])
    ref = _reference(m, d, name, gid, c, r)
    assert got <= ref + 1e-6, (got, ref)  # never over-reported
    if ref <= 0.0:
        assert got <= 1e-9, (got, ref)  # an overlap never reads positive
    if name in _EXACT and (ref > 0.0 or name != "box"):
        assert got == pytest.approx(ref, abs=1e-7)


def test_sphere_clearance_takes_the_nearest_of_several_geoms():
    m, d = _model()
    d.mocap_pos[:] = [[0.0, 0.0, 0.3 * i] for i in range(len(d.mocap_pos))]
    d.mocap_quat[:] = [1.0, 0.0, 0.0, 0.0]
    mujoco.mj_kinematics(m, d)
    gids = np.arange(m.ngeom - 1)
    rng = np.random.default_rng(5)
    c = rng.uniform(-1.0, 1.0, (30, 3))
    r = rng.uniform(0.0, 0.1, 30)
    got = sphere_clearance(m, d, gids, c, r)
    each = np.array([sphere_clearance(m, d, np.array([g]), c, r) for g in gids])  # (G, N)
    assert np.array_equal(got, each.min(axis=0))
    assert np.isinf(sphere_clearance(m, d, np.zeros(0), c, r)).all()


@pytest.mark.parametrize(
    ("geoms", "centres", "radii", "field"),
    [
        ([-1], np.zeros((1, 3)), [0.1], "geoms"),  # read the last geom
        ([1.5], np.zeros((1, 3)), [0.1], "geoms"),  # truncated to 1
        ([99], np.zeros((1, 3)), [0.1], "geoms"),
        ([0], np.zeros(3), [0.1], "centres"),
        ([0], np.zeros((2, 3)), [0.1], "radii"),  # broadcast
        ([0], np.zeros((1, 3)), [-0.5], "radii"),  # a negative radius read farther
    ],
    ids=["negative-id", "float-id", "id-beyond", "centres-3", "radii-short", "radius-negative"],
)
def test_sphere_clearance_bad_input_is_named(geoms, centres, radii, field):
    m, d = _model()
    with pytest.raises(ValueError, match=f"^{field} must"):
        sphere_clearance(m, d, np.asarray(geoms), centres, np.asarray(radii, float))


# --------------------------------------------------------------------------------------------- SSM: metrics

_SEP = st.one_of(st.sampled_from([NAN, INF, -INF, 0.0]), st.floats(-0.2, 1.0))


def _min_ref(xs: list[float]) -> float | None:
    """None when empty or all +inf (nobody in the scene), NaN when any NaN, else the minimum (-inf too)."""
    if not xs or all(x == INF for x in xs):
        return None
    if any(math.isnan(x) for x in xs):
        return NAN
    return min(xs)


@SETTINGS
@given(x=st.lists(_SEP, max_size=8))
@example(x=[-0.05, NAN])  # a collision next to a NaN read None ("nobody in the scene")
@example(x=[-INF, 1.0])
@example(x=[INF, INF])
def test_finite_min(x):
    assert _same(_finite_min(np.array(x, float)), _min_ref(x))


class _Rec:
    def __init__(self, rows: dict) -> None:
        self.rows, self.ssm_config = rows, SsmConfig()

    def arrays(self) -> dict:
        return {k: np.asarray(v) for k, v in self.rows.items()}


@st.composite
def _ssm_case(draw):
    n_t, n_p = draw(st.integers(1, 12)), draw(st.integers(1, 3))
    states = draw(st.lists(st.sampled_from([-1, 0, 1, 2]), min_size=n_t, max_size=n_t))
    grid = st.lists(st.lists(_SEP, min_size=n_p, max_size=n_p), min_size=n_t, max_size=n_t)
    s_true, s_p, cap = draw(grid), draw(grid), draw(grid)
    qd = draw(st.lists(st.sampled_from([0.0, 1e-3, 0.5]), min_size=n_t, max_size=n_t))
    scale = draw(st.lists(st.floats(0.0, 1.0), min_size=n_t, max_size=n_t))
    return states, s_true, s_p, cap, qd, scale


@SETTINGS
@given(case=_ssm_case())
@example(case=([0, 0], [[INF, NAN], [INF, 0.3]], [[0.1, 0.1], [0.1, 0.1]], [[NAN] * 2] * 2, [0.5, 0.5], [1.0, 1.0]))
@example(case=([1], [[-INF, INF]], [[0.1, 0.1]], [[-INF, 0.2]], [0.0], [0.5]))
def test_ssm_metrics_match_brute_force(case):
    states, s_true, s_p, cap, qd, scale = case
    rows = {"state": states, "scale": scale, "s_true": s_true, "s_p": s_p, "s_capture": cap, "qd": qd}
    names = tuple(f"p{k}" for k in range(len(s_true[0])))
    dt = 0.001
    got = ssm_metrics(_Rec(rows), dt, names, SsmConfig())
    allowed = [s in (MonitorState.MONITOR_OK, MonitorState.REDUCED) for s in states]
    moving = [v > 1e-3 for v in qd]
    margins = [
        t - p
        for row_t, row_p, a in zip(s_true, s_p, allowed, strict=True)
        if a
        for t, p in zip(row_t, row_p, strict=True)
    ]
    assert _same(got["min_separation_margin"], _min_ref(margins)), (got["min_separation_margin"], margins)
    if got["binding_point"] is not None:  # a point whose own margin is the reported one
        k = names.index(got["binding_point"])
        mine = [row_t[k] - row_p[k] for row_t, row_p, a in zip(s_true, s_p, allowed, strict=True) if a]
        assert _same(_min_ref(mine), got["min_separation_margin"])
    caps = [
        x - p for row_c, row_p, a in zip(cap, s_p, allowed, strict=True) if a for x, p in zip(row_c, row_p, strict=True)
    ]
    caps = [INF if math.isnan(x) else x for x in caps]  # (NaN: no frame yet)
    assert _same(got["min_separation_margin_at_capture"], _min_ref(caps))
    sep = [_min_ref(row) if not any(math.isnan(v) for v in row) else NAN for row in s_true]
    sep = [INF if v is None else v for v in sep]  # a row of +inf: nobody
    assert _same(got["min_true_separation"], _min_ref(sep))
    ref_mov = [s for s, mv in zip(sep, moving, strict=True) if mv]
    assert _same(got["min_true_separation_while_moving"], _min_ref(ref_mov))
    ref_all = [s for s, mv, a in zip(sep, moving, allowed, strict=True) if mv and a]
    assert _same(got["min_true_separation_while_allowed"], _min_ref(ref_all))
    stopped = [s == MonitorState.PROTECTIVE_STOP for s in states]
    runs = sum(1 for i, s in enumerate(stopped) if s and (i == 0 or not stopped[i - 1]))
    assert got["protective_stops"] == runs
    ends = [i for i in range(1, len(states)) if stopped[i - 1] and not stopped[i]]
    assert got["resumed"] == any(moving[j] and allowed[j] for e in ends for j in range(e, len(states)))
    assert _same(got["time_stopped_s"], sum(stopped) * dt)
    assert _same(got["time_reduced_s"], sum(s == MonitorState.REDUCED for s in states) * dt)
    assert _same(got["min_scale"], min((v for v, a in zip(scale, allowed, strict=True) if a), default=0.0))
