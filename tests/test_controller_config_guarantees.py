"""The controller's configuration and the output of its cycle, attacked with property tests.

* every :class:`ControllerConfig` field with a hostile value (NaN, ±inf, 0, negative, a string, a bool, a
  per-joint limit of the wrong length, an unknown mode) is refused when the config is made (or, for the
  per-joint length, when the controller is built), naming the field; the legal domain is written here,
  independently, from the docstring and the equations (:func:`_legal`);
* with any accepted config and random valid inputs, a closed loop (a perfect robot: ``q = q_cmd``) keeps every
  command finite, within the cycle's bounds and within ``v_max * velocity_scale`` of the *model*, and every
  joint within the model's position limits less ``position_margin``;
* :func:`~depthguard.control.warmup.warm_up` starts every joint strictly inside its limits (one infinite limit
  included), does not raise for continuous or prismatic joints, and leaves nothing behind.
"""

from __future__ import annotations

import copy
import dataclasses
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

pytest.importorskip("pinocchio")
pytest.importorskip("ruckig")

from depthguard.control import AvoidanceController, ControllerConfig, CycleInput  # noqa: E402
from depthguard.control import warmup as warmup_module  # noqa: E402
from depthguard.control.ssm import SsmConfig  # noqa: E402
from depthguard.control.warmup import warm_up  # noqa: E402
from depthguard.robot.control_points import ControlPointSet  # noqa: E402
from depthguard.robot.model import RobotModel, load_lwr4  # noqa: E402

NAN, INF = math.nan, math.inf
_CACHE: dict = {}


def _lwr() -> ControlPointSet:
    if "lwr" not in _CACHE:
        _CACHE["lwr"] = ControlPointSet.build(load_lwr4(), "ral-9")
    return _CACHE["lwr"]


_URDF = """<robot name="mixed">
  <link name="base"><collision><geometry><cylinder radius="0.05" length="0.2"/></geometry></collision></link>
  <link name="l1"><collision><origin xyz="0 0 0.15"/><geometry><cylinder radius="0.04" length="0.3"/></geometry>
  </collision></link>
  <link name="l2"><collision><origin xyz="0.1 0 0"/><geometry><box size="0.2 0.06 0.06"/></geometry></collision></link>
  <link name="l3"><collision><origin xyz="0 0 0.1"/><geometry><cylinder radius="0.03" length="0.2"/></geometry>
  </collision></link>
  <link name="l4"><collision><origin xyz="0 0 0.05"/><geometry><sphere radius="0.03"/></geometry></collision></link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><origin xyz="0 0 0.1"/>
    <axis xyz="0 0 1"/><limit lower="0.3" upper="2.0" velocity="1.5" effort="1"/></joint>
  <joint name="j2" type="prismatic"><parent link="l1"/><child link="l2"/><origin xyz="0 0 0.3"/>
    <axis xyz="1 0 0"/><limit lower="0.1" upper="0.5" velocity="0.5" effort="1"/></joint>
  <joint name="j3" type="continuous"><parent link="l2"/><child link="l3"/><origin xyz="0.2 0 0"/>
    <axis xyz="0 1 0"/><limit velocity="2.0" effort="1"/></joint>
  <joint name="j4" type="revolute"><parent link="l3"/><child link="l4"/><origin xyz="0 0 0.2"/>
    <axis xyz="1 0 0"/><limit lower="-1.0" upper="1.0" velocity="2.0" effort="1"/></joint>
</robot>
"""


def _mixed(tmp_path_factory) -> ControlPointSet:
    """A 4-joint robot with a revolute joint whose limits are both > 0, a prismatic and a continuous joint."""
    if "mixed" not in _CACHE:
        path = tmp_path_factory.mktemp("mixed") / "mixed.urdf"
        path.write_text(_URDF)
        _CACHE["mixed"] = ControlPointSet.build(RobotModel(path, ee_frame="l4"), "auto")
    return _CACHE["mixed"]


# ---------------------------------------------------------------------------------------------------------------
# the legal domain of every field, written from the docstring and the equations (an independent reference)

_POSITIVE = ("dt", "rho_ee", "alpha_ee", "rho_body", "alpha_body", "distance_timeout", "joint_timeout")
_NON_NEGATIVE = ("v_rep_max", "contact_distance", "position_margin", "dls_eps", "dls_lambda_max", "resume_time")


def _real(v) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))


def _limits_legal(v) -> bool:
    if _real(v):
        return math.isfinite(v) and v > 0
    if isinstance(v, (tuple, list)):
        return len(v) > 0 and all(_real(x) and math.isfinite(x) and x > 0 for x in v)
    return False


def _legal(field: str, v) -> bool:
    """Whether ``ControllerConfig(**{field: v})`` (the other fields at their defaults) must be accepted."""
    if field in _POSITIVE:
        return _real(v) and math.isfinite(v) and v > 0
    if field in _NON_NEGATIVE:
        return _real(v) and math.isfinite(v) and v >= 0
    if field == "velocity_scale":
        return _real(v) and 0 < v <= 1
    if field in ("a_max", "j_max"):
        if not _limits_legal(v):
            return False
        a = np.asarray(v if field == "a_max" else 10.0, float)  # the other at its default
        j = np.asarray(v if field == "j_max" else 500.0, float)
        with np.errstate(over="ignore"):
            return bool(np.all(np.isfinite((a / j) ** 2)))  # the braking bounds square a/j
    if field == "synchronization":
        return v in ("none", "time", "phase") and isinstance(v, str)
    if field == "avoidance":
        return v in ("repulsion", "ssm", "both") and isinstance(v, str)
    if field == "ssm":
        return v is None or isinstance(v, SsmConfig)
    if field == "stop_evades":
        return isinstance(v, (bool, np.bool_))
    raise AssertionError(field)


_NUMERIC = _POSITIVE + _NON_NEGATIVE + ("velocity_scale", "a_max", "j_max")
_HOSTILE = (NAN, INF, -INF, 0.0, -0.0, -1.0, -1e-300, 5e-324, 1e308, "1.0", True, False, None, 2, 1.5)
# (field, value) pairs, each refused by name: every numeric field with every hostile value it cannot take
CASES = [(f, v) for f in _NUMERIC for v in _HOSTILE if not _legal(f, v)] + [
    ("a_max", (1.0, NAN)), ("a_max", ()), ("a_max", ((1.0, 2.0),)), ("j_max", (500.0, -1.0)),
    ("a_max", "10"), ("j_max", [True] * 7), ("j_max", 1e-300), ("a_max", 1e300),
    ("synchronization", "Time"), ("synchronization", 1), ("synchronization", None),
    ("avoidance", "ISO"), ("avoidance", ""), ("avoidance", None),
    ("ssm", "on"), ("ssm", 1), ("ssm", {}), ("stop_evades", "no"), ("stop_evades", 2), ("stop_evades", None),
]  # fmt: skip


@pytest.mark.parametrize(("field", "value"), CASES, ids=[f"{f}={v!r}" for f, v in CASES])
def test_a_hostile_field_is_refused_naming_it_and_its_form(field: str, value) -> None:
    assert not _legal(field, value)
    with pytest.raises(ValueError, match=rf"ControllerConfig\.(\w+ / )?{field}\b.*must be") as exc:
        ControllerConfig(**{field: value})
    assert "got" in str(exc.value)
    with pytest.raises(ValueError, match=rf"ControllerConfig\.(\w+ / )?{field}\b"):  # (replace runs the same check)
        dataclasses.replace(ControllerConfig(), **{field: value})


_VALUES = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(-(2**70), 2**70),
    st.booleans(),
    st.text(max_size=3),
    st.none(),
    st.lists(st.floats(-1e3, 1e3), max_size=9).map(tuple),
    st.sampled_from(["none", "time", "phase", "repulsion", "ssm", "both", SsmConfig(), np.float32(0.5)]),
)
_FIELDS = [f.name for f in dataclasses.fields(ControllerConfig)]


@settings(max_examples=300, deadline=None)
@given(st.sampled_from(_FIELDS), _VALUES)
@example("position_margin", -0.5)  # a negative margin: the braking bounds aim past the limits
@example("distance_timeout", INF)  # stale distances never seen: the controller never stops for them
@example("joint_timeout", NAN)
@example("rho_ee", NAN)  # the plan turned NaN: every cycle a STOP_INVALID_INPUT blamed on the inputs
@example("a_max", INF)  # the braking bounds NaN
@example("dt", True)
@example("ssm", "on")
def test_a_field_is_accepted_exactly_on_its_legal_domain(field: str, value) -> None:
    if _legal(field, value):
        cfg = ControllerConfig(**{field: value})
        assert getattr(cfg, field) is value
    else:
        with pytest.raises(ValueError, match=rf"ControllerConfig\.(\w+ / )?{field}\b"):
            ControllerConfig(**{field: value})


@pytest.mark.parametrize("field", ["a_max", "j_max"])
@pytest.mark.parametrize("length", [2, 6, 8])
def test_a_per_joint_limit_of_the_wrong_length_is_refused_by_the_controller(field: str, length: int) -> None:
    cfg = ControllerConfig(**{field: tuple([1.0 if field == "a_max" else 500.0] * length)})
    with pytest.raises(ValueError, match=rf"ControllerConfig\.{field} must be one number or 7"):
        AvoidanceController(_lwr(), cfg)


@pytest.mark.parametrize("a_max", [1e-320, 5e-324, (1.0, 1.0, 1.0, 1e-310, 1.0, 1.0, 1.0)], ids=str)
def test_an_a_max_too_small_to_brake_over_the_joint_ranges_is_refused(a_max) -> None:
    """Reference: the braking bound of eq. ``v^2/(2a) + ... <= d`` is about ``sqrt(2 d a)`` for tiny a, far below
    v_max; an overflow of ``2 d / a`` gave v_max itself (full speed 0.01 rad before a limit)."""
    with pytest.raises(ValueError, match=r"ControllerConfig\.a_max must be large enough"):
        AvoidanceController(_lwr(), ControllerConfig(a_max=a_max, j_max=1.0))


def test_legal_edges_are_accepted_and_build_a_controller() -> None:
    """Zero where the docstring gives 0 a meaning, numpy scalars and per-joint sequences, the defaults."""
    for kw in (
        {}, dict(v_rep_max=0, contact_distance=0.0, position_margin=0.0, dls_eps=0.0, dls_lambda_max=0.0,
                 resume_time=0.0),
        dict(dt=np.float64(0.002), velocity_scale=np.float32(0.5), a_max=[5.0] * 7, j_max=np.full(7, 300.0)),
        dict(a_max=tuple(range(1, 8)), j_max=np.int64(100), stop_evades=np.bool_(False), avoidance="both",
             ssm=SsmConfig(), synchronization="phase"),
    ):  # fmt: skip
        ctrl = AvoidanceController(_lwr(), ControllerConfig(**kw))
        assert ctrl.otg.a_max.shape == (7,)


# ---------------------------------------------------------------------------------------------------------------
# the closed loop with any accepted config


@st.composite
def configs(draw) -> ControllerConfig:
    per_joint = draw(st.booleans())
    a = tuple(draw(st.lists(st.floats(1.0, 40.0), min_size=7, max_size=7))) if per_joint else draw(st.floats(1, 40))
    j = draw(st.floats(20.0, 5000.0))
    return ControllerConfig(
        dt=draw(st.sampled_from([2.5e-4, 1e-3, 2e-3, 4e-3])),
        rho_ee=draw(st.floats(0.05, 1.0)), alpha_ee=draw(st.floats(0.5, 20.0)), v_rep_max=draw(st.floats(0.0, 3.0)),
        rho_body=draw(st.floats(0.05, 1.0)), alpha_body=draw(st.floats(0.5, 20.0)),
        contact_distance=draw(st.floats(0.0, 0.1)), velocity_scale=draw(st.floats(0.05, 1.0)), a_max=a, j_max=j,
        position_margin=draw(st.floats(0.0, 0.2)), dls_eps=draw(st.floats(0.0, 0.2)),
        dls_lambda_max=draw(st.floats(0.0, 0.2)), synchronization=draw(st.sampled_from(["none", "time", "phase"])),
        resume_time=draw(st.sampled_from([0.0, 0.01])), avoidance=draw(st.sampled_from(["repulsion", "ssm", "both"])),
        stop_evades=draw(st.booleans()), distance_timeout=1.0, joint_timeout=1.0,
    )  # fmt: skip


def _closed_loop(points: ControlPointSet, cfg: ControllerConfig, seed: int, cycles: int) -> None:
    """Drive the controller ``cycles`` periods with a perfect robot and random obstacles; check every output
    against the model's own limits."""
    model, rng = points.model, np.random.default_rng(seed)
    lo, hi = np.asarray(model.q_min, float), np.asarray(model.q_max, float)
    vmax = np.asarray(model.v_max, float) * cfg.velocity_scale
    m = cfg.position_margin
    inner_lo, inner_hi = np.where(np.isfinite(lo), lo + m, -3.0), np.where(np.isfinite(hi), hi - m, 3.0)
    # (a margin of half the range, 0.2 on the 0.1-0.5 m prismatic joint: lo + m and hi - m cross by a rounding)
    mid, crossed = 0.5 * (inner_lo + inner_hi), inner_lo > inner_hi
    inner_lo, inner_hi = np.where(crossed, mid, inner_lo), np.where(crossed, mid, inner_hi)
    # start at rest inside the margins, half the joints near a limit
    q = rng.uniform(inner_lo, inner_hi)
    near = rng.uniform(size=q.size) < 0.5
    q = np.where(near, np.where(rng.uniform(size=q.size) < 0.5, inner_lo, inner_hi) * 0.999 + q * 0.001, q)
    q = np.clip(q, inner_lo, inner_hi)
    qd, ctrl = np.zeros_like(q), AvoidanceController(points, cfg)
    xd = rng.normal(size=3) * rng.uniform(0.0, 2.0)
    ball = rng.normal(size=3) * 0.5
    for k in range(cycles):
        t = k * cfg.dt
        if k % 50 == 0:
            xd = rng.normal(size=3) * rng.uniform(0.0, 2.0)
        s = points.evaluate(q)
        diff = s.centres - ball
        nrm = np.maximum(np.linalg.norm(diff, axis=1), 1e-9)
        d = np.maximum(nrm - s.radii - 0.05, 0.0)
        out = ctrl.step(CycleInput(t, q, qd, t, xd, np.where(d < 1.0, d, np.inf), diff / nrm[:, None], t))
        v, qn = np.asarray(out.qdot_cmd), np.asarray(out.q_cmd)
        assert np.all(np.isfinite(v)) and np.all(np.isfinite(qn)) and np.all(np.isfinite(out.qddot_cmd)), k
        assert np.all(out.qdot_min - 1e-12 <= v) and np.all(v <= out.qdot_max + 1e-12), (k, out.status)
        assert np.all(np.abs(v) <= vmax * (1 + 1e-9) + 1e-12), (k, out.status, v, vmax)
        tol = 1e-6 + 1e-9 * np.abs(qn)
        assert np.all(qn >= lo + m - tol) and np.all(qn <= hi - m + tol), (k, out.status, qn - lo, hi - qn)
        q, qd = qn, v


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(configs(), st.integers(0, 2**32 - 1))
def test_any_accepted_config_keeps_the_closed_loop_within_the_models_limits(cfg, seed) -> None:
    _closed_loop(_lwr(), cfg, seed, 300)


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cfg=configs(), seed=st.integers(0, 2**32 - 1))
@example(  # position_margin = half the prismatic joint's range (the test's start range was empty)
    cfg=ControllerConfig(
        dt=0.00025, rho_ee=1.0, alpha_ee=1.0, v_rep_max=0.0, rho_body=1.0, alpha_body=1.0, a_max=1.0, j_max=20.0,
        position_margin=0.2, distance_timeout=1.0, joint_timeout=1.0, dls_eps=0.0, dls_lambda_max=0.0,
        resume_time=0.0, stop_evades=False,
    ),
    seed=0,
)  # fmt: skip
def test_the_closed_loop_holds_for_prismatic_and_continuous_joints(tmp_path_factory, cfg, seed) -> None:
    a = cfg.a_max if np.ndim(cfg.a_max) == 0 else cfg.a_max[0]
    _closed_loop(_mixed(tmp_path_factory), dataclasses.replace(cfg, a_max=a), seed, 250)


# ---------------------------------------------------------------------------------------------------------------
# warm_up


def _first_joint_state(monkeypatch, points, cfg, model) -> np.ndarray:
    """The first joint positions that :func:`warm_up` gives its controller."""
    seen: list[np.ndarray] = []
    step = AvoidanceController.step

    def spy(self, inp):
        if inp.q is not None and not seen:
            seen.append(np.array(inp.q, float))
        return step(self, inp)

    monkeypatch.setattr(warmup_module.AvoidanceController, "step", spy)
    warm_up(points, cfg, model, cycles=2)
    return seen[0]


LIMITS = [  # (q_min, q_max) of joint 0; the rest keep the LWR's
    (0.2, INF),
    (-INF, -0.3),
    (1e300, INF),
    (-INF, -1e300),
    (1e307, 1.7e308),
    (-1.7e308, 1.7e308),
    (-INF, INF),
    (0.5, 2.0),
    (-2.0, -0.5),
]


@pytest.mark.parametrize(("lo", "hi"), LIMITS, ids=[f"{a!r}..{b!r}" for a, b in LIMITS])
def test_warm_up_starts_every_joint_strictly_inside_its_limits(monkeypatch, lo: float, hi: float) -> None:
    base = _lwr().model
    model = copy.copy(base)  # (the same kinematics; joint 0's limits replaced)
    model.q_min, model.q_max = base.q_min.copy(), base.q_max.copy()
    model.q_min[0], model.q_max[0] = lo, hi
    points = ControlPointSet.build(model, "ral-9")
    q = _first_joint_state(monkeypatch, points, ControllerConfig(), model)
    assert np.all(np.isfinite(q))
    assert np.all(model.q_min < q) and np.all(q < model.q_max), (q[0], lo, hi)


def test_warm_up_does_not_raise_for_prismatic_and_continuous_joints(tmp_path_factory, monkeypatch) -> None:
    points = _mixed(tmp_path_factory)
    m = points.model
    for cfg in (ControllerConfig(), ControllerConfig(avoidance="both", position_margin=0.0, resume_time=0.0)):
        met = warm_up(points, cfg, m, cycles=3)
        assert "OK" in met and "STOP_STALE_DISTANCES" in met, met
    q = _first_joint_state(monkeypatch, points, ControllerConfig(), m)
    assert np.all(m.q_min < q) and np.all(q < m.q_max), q


def test_warm_up_leaves_nothing_behind() -> None:
    """A controller's outputs on a fixed input sequence are the same before and after a warm-up."""
    points = _lwr()
    cfg = ControllerConfig(avoidance="both")

    def run() -> list[np.ndarray]:
        ctrl, q, qd, N, outs = AvoidanceController(points, cfg), np.full(7, 0.3), np.zeros(7), points.n_points, []
        for k in range(60):
            t = k * cfg.dt
            d = np.linspace(0.05, 0.3, N)
            out = ctrl.step(CycleInput(t, q, qd, t, np.array([0.1, 0, 0]), d, np.tile([0, 0, 1.0], (N, 1)), t))
            q, qd = out.q_cmd, out.qdot_cmd
            outs.append(np.concatenate([out.qdot_cmd, out.q_cmd, [out.status]]))
        return outs

    before = run()
    cfg_before = dataclasses.asdict(cfg)
    warm_up(points, cfg, points.model, cycles=5)
    assert dataclasses.asdict(cfg) == cfg_before
    np.testing.assert_array_equal(np.array(run()), np.array(before))
