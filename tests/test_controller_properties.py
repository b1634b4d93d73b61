"""Property test: random cycle sequences with injected faults (NaN, +-inf, wrong shapes, stale, jumping and
reordered time stamps). ``step()`` never raises, and the joint command stays finite, within the position
and velocity limits and within each cycle's bounds; acceleration and jerk limits hold in every cycle that
does not report ``bound_limited``."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

pytest.importorskip("pinocchio")
pytest.importorskip("ruckig")

from depthguard.control import AvoidanceController, ControllerConfig, CycleInput, CycleStatus  # noqa: E402
from depthguard.robot.control_points import ControlPointSet  # noqa: E402
from depthguard.robot.model import load_lwr4  # noqa: E402

DT, A_MAX, J_MAX = 0.001, 10.0, 500.0
POINTS = None

# faults whose cycle must report STOP_INVALID_INPUT
INVALID = [
    "nan_q", "inf_q", "short_q", "none_q", "nan_qdot", "none_qdot", "nan_xdot", "inf_xdot", "short_xdot",
    "nan_dist", "minus_inf_dist", "nan_dir_finite_dist", "inf_dir_finite_dist", "short_dist", "bad_dirs",
    "nan_t", "inf_t", "nan_t_joints", "minus_inf_t_distances", "future_t_joints", "future_t_distances",
    "t_backwards", "str_q", "none_everything",
]  # fmt: skip
# faults with a defined other outcome, or none
OTHER = ["stale_joints", "stale_distances", "missing_distances", "t_jump", "t_repeat", "q_jump",
         "plus_inf_dist_nan_dir", "negative_dist", "huge_xdot", "wild_qdot"]  # fmt: skip


def _points() -> ControlPointSet:
    global POINTS
    if POINTS is None:
        POINTS = ControlPointSet.build(load_lwr4(), "ral-9")
    return POINTS


@st.composite
def scenarios(draw):
    n_cycles = draw(st.integers(20, 80))
    faults = draw(
        st.lists(
            st.one_of(st.just("ok"), st.just("ok"), st.just("ok"), st.sampled_from(INVALID + OTHER)),
            min_size=n_cycles,
            max_size=n_cycles,
        )
    )
    seed = draw(st.integers(0, 2**32 - 1))
    return faults, seed


def _inputs(fault: str, t: float, q, qd, xd, d, dirs, rng):
    """The cycle's CycleInput with ``fault`` injected (times: t now)."""
    N = len(d)
    d, dirs, q_in, qd_in, xd_in = d.copy(), dirs.copy(), q.copy(), qd.copy(), xd.copy()
    tt = [t, t, t]  # t, t_joints, t_distances
    k = int(rng.integers(N))
    match fault:
        case "nan_q" | "inf_q":
            q_in[int(rng.integers(7))] = np.nan if fault == "nan_q" else -np.inf
        case "short_q":
            q_in = q_in[:-1]
        case "none_q":
            q_in = None
        case "str_q":
            q_in = "q"
        case "nan_qdot":
            qd_in[0] = np.nan
        case "none_qdot":
            qd_in = None
        case "nan_xdot" | "inf_xdot":
            xd_in[1] = np.nan if fault == "nan_xdot" else np.inf
        case "short_xdot":
            xd_in = xd_in[:2]
        case "nan_dist":
            d[k] = np.nan
        case "minus_inf_dist":
            d[k] = -np.inf
        case "nan_dir_finite_dist" | "inf_dir_finite_dist":
            d[k] = 0.1
            dirs[k, int(rng.integers(3))] = np.nan if fault.startswith("nan") else np.inf
        case "short_dist":
            d = d[:-1]
        case "bad_dirs":
            dirs = dirs[:, :2]
        case "nan_t" | "inf_t":
            tt[0] = np.nan if fault == "nan_t" else np.inf
        case "nan_t_joints":
            tt[1] = np.nan
        case "minus_inf_t_distances":
            tt[2] = -np.inf
        case "future_t_joints":
            tt[1] = t + 0.5
        case "future_t_distances":
            tt[2] = t + 0.5
        case "t_backwards":
            tt = [t - 0.05] * 3
        case "none_everything":
            return CycleInput(None, None, None, None, None, None, None, None)
        case "stale_joints":
            tt[1] = t - 0.5
        case "stale_distances":
            tt[2] = t - 0.5
        case "missing_distances":
            d, dirs = None, None
        case "plus_inf_dist_nan_dir":
            d[k], dirs[k] = np.inf, np.nan
        case "negative_dist":
            d[k] = -0.05
        case "huge_xdot":
            xd_in = np.array([1e300, -1e300, 1e300])
        case "wild_qdot":
            qd_in = rng.uniform(-1e3, 1e3, 7)
    return CycleInput(tt[0], q_in, qd_in, tt[1], xd_in, d, dirs, tt[2])


def _scene(points, q, ball):
    st_ = points.evaluate(q)
    diff = st_.centres - ball
    norm = np.linalg.norm(diff, axis=1)
    d = norm - st_.radii - 0.05
    return np.where(d < 0.4, d, np.inf), diff / norm[:, None]


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(scenarios())
def test_step_never_raises_and_commands_stay_within_limits(sc) -> None:
    faults, seed = sc
    points = _points()
    model = points.model
    rng = np.random.default_rng(seed)
    ctrl = AvoidanceController(points, ControllerConfig(resume_time=float(rng.choice([0.0, 0.005, 0.1]))))
    q_lo, q_hi = model.q_min + 0.05, model.q_max - 0.05
    q = rng.uniform(q_lo, q_hi)
    qd = rng.uniform(-0.5, 0.5, 7) * model.v_max
    xd = rng.normal(size=3) * rng.uniform(0.0, 0.6)
    st_ = points.evaluate(q)
    ball = st_.centres[int(rng.integers(1, points.n_points))] + rng.normal(size=3) * 0.15
    t, prev = 0.0, None
    for fault in faults:
        if fault == "t_jump":
            t += float(rng.uniform(0.01, 5.0))
        elif fault == "q_jump":
            q = np.clip(q + rng.uniform(-0.01, 0.01, 7), q_lo, q_hi)
        d, dirs = _scene(points, q, ball)
        t_prev = ctrl.state.t_prev if ctrl.state is not None else -np.inf
        out = ctrl.step(_inputs(fault, t, q, qd, xd, d, dirs, rng))
        assert isinstance(out.status, CycleStatus)
        # (a time stamp is "backwards" only against an earlier cycle's: at the first valid time it is not)
        if fault in INVALID and not (fault == "t_backwards" and t - 0.05 >= t_prev):
            assert out.status == CycleStatus.STOP_INVALID_INPUT, (fault, out.status.name)
        for x in (out.q_cmd, out.qdot_cmd, out.qddot_cmd, out.qdot_min, out.qdot_max):
            assert x.shape == (7,) and np.all(np.isfinite(x))
        assert np.all(out.q_cmd >= model.q_min) and np.all(out.q_cmd <= model.q_max)
        assert np.all(np.abs(out.qdot_cmd) <= model.v_max * (1 + 1e-12))
        assert np.all(out.qdot_cmd >= out.qdot_min - 1e-9) and np.all(out.qdot_cmd <= out.qdot_max + 1e-9)
        if not out.bound_limited:
            assert np.all(np.abs(out.qddot_cmd) <= A_MAX + 1e-9)
            if prev is not None:
                assert np.all(np.abs(out.qddot_cmd - prev.qddot_cmd) <= J_MAX * DT * (1 + 1e-6) + 1e-9)
        prev = out
        if ctrl.state is not None and ctrl.state.otg is not None:  # (before any joint state: nothing moves)
            q, qd = out.q_cmd, out.qdot_cmd
        if fault != "t_repeat":
            t += DT
