"""The control cycle never raises: malformed inputs stop the robot (jerk-limited), a failed Ruckig brakes,
and after any stop motion resumes only once the inputs have been valid for ``resume_time`` in a row."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pinocchio")
pytest.importorskip("ruckig")

from depthguard.control import AvoidanceController, ControllerConfig, CycleInput, CycleStatus  # noqa: E402
from depthguard.robot.control_points import ControlPointSet  # noqa: E402
from depthguard.robot.model import load_lwr4  # noqa: E402

Q0 = np.array([0.0, 0.5, 0.0, -1.2, 0.0, 0.8, 0.0])
XD = np.array([0.2, 0.0, 0.0])
DT, A_MAX, J_MAX = 0.001, 10.0, 500.0


@pytest.fixture(scope="module")
def points() -> ControlPointSet:
    return ControlPointSet.build(load_lwr4(), "ral-9")


def _free(N: int) -> tuple[np.ndarray, np.ndarray]:
    return np.full(N, np.inf), np.zeros((N, 3))


def _obstacle(points, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distances and directions to a 5 cm ball 0.3 m below the forearm point (all finite)."""
    st = points.evaluate(q)
    diff = st.centres - (st.centres[4] + np.array([0.0, 0.0, -0.3]))
    norm = np.linalg.norm(diff, axis=1)
    return norm - st.radii - 0.05, diff / norm[:, None]


def _moving(points, cfg: ControllerConfig | None = None, cycles: int = 400):
    """A controller that has been moving freely for ``cycles`` cycles; returns it and (t, q, qd)."""
    ctrl = AvoidanceController(points, cfg or ControllerConfig())
    q, qd, t = Q0.copy(), np.zeros(7), 0.0
    for _ in range(cycles):
        out = ctrl.step(CycleInput(t, q, qd, t, XD, *_free(points.n_points), t))
        q, qd, t = out.q_cmd, out.qdot_cmd, t + DT
    assert out.status == CycleStatus.OK and np.linalg.norm(out.qdot_cmd) > 0.1
    return ctrl, (t, q, qd)


def _check_jerk_limited_stop(outs: list) -> None:
    v = np.array([o.qdot_cmd for o in outs])
    a = np.array([o.qddot_cmd for o in outs])
    assert np.all(np.isfinite(v)) and np.all(np.isfinite(a))
    assert np.all(np.abs(v[-1]) < 1e-9)  # stopped
    assert np.all(np.abs(a) <= A_MAX + 1e-9)
    assert np.all(np.abs(np.diff(a, axis=0)) <= J_MAX * DT * (1 + 1e-6))  # jerk-limited
    assert np.all(np.abs(np.diff(v, axis=0)) <= A_MAX * DT * (1 + 1e-6))  # no velocity jumps
    assert np.linalg.norm(v[0]) > 0.05  # it brakes from motion, no jump to 0


def _corrupt(case: str, t: float, q, qd, d, dirs):
    """One cycle's input with one field corrupted as ``case`` says; everything else valid."""
    N = len(d)
    d, dirs = d.copy(), dirs.copy()
    if case == "nan_direction":  # the review's case: NaN direction with a finite distance
        dirs[3] = np.nan
    elif case == "inf_direction":
        dirs[0, 1] = np.inf
    elif case == "minus_inf_distance_ee":  # used to switch end-effector repulsion off
        d[0] = -np.inf
    elif case == "minus_inf_distance_body":
        d[5] = -np.inf
    elif case == "nan_distance":
        d[2] = np.nan
    elif case == "short_distances":
        d = d[:-1]
    elif case == "directions_2d":
        dirs = dirs[:, :2]
    elif case == "directions_flat":
        dirs = dirs.ravel()
    elif case == "distances_str":
        d = "far"
    if case in DISTANCE_CASES:
        return CycleInput(t, q, qd, t, XD, d, dirs, t)
    bad = {
        "nan_q": (t, np.r_[q[:6], np.nan], qd, t, XD, d, dirs, t),
        "inf_q": (t, np.r_[q[:6], np.inf], qd, t, XD, d, dirs, t),
        "short_q": (t, q[:6], qd, t, XD, d, dirs, t),
        "q_2d": (t, q[None, :], qd, t, XD, d, dirs, t),
        "none_q": (t, None, qd, t, XD, d, dirs, t),
        "nan_qdot": (t, q, np.full(7, np.nan), t, XD, d, dirs, t),
        "long_qdot": (t, q, np.zeros(8), t, XD, d, dirs, t),
        "none_qdot": (t, q, None, t, XD, d, dirs, t),
        "nan_xdot": (t, q, qd, t, np.array([0.0, np.nan, 0.0]), d, dirs, t),
        "minus_inf_xdot": (t, q, qd, t, np.array([0.0, -np.inf, 0.0]), d, dirs, t),
        "xdot_6d": (t, q, qd, t, np.zeros(6), d, dirs, t),
        "none_xdot": (t, q, qd, t, None, d, dirs, t),
        "nan_t_joints": (t, q, qd, np.nan, XD, d, dirs, t),
        "minus_inf_t_distances": (t, q, qd, t, XD, d, dirs, -np.inf),
        "nan_t": (np.nan, q, qd, t, XD, d, dirs, t),
        "future_t_joints": (t, q, qd, t + 1.0, XD, d, dirs, t),
        "future_t_distances": (t, q, qd, t, XD, d, dirs, t + 1.0),
        "str_t": ("now", q, qd, t, XD, d, dirs, t),
        "object_q": (t, np.array(["a"] * 7, dtype=object), qd, t, XD, d, dirs, t),
    }[case]
    assert N == len(dirs)
    return CycleInput(*bad)


DISTANCE_CASES = [
    "nan_direction",
    "inf_direction",
    "minus_inf_distance_ee",
    "minus_inf_distance_body",
    "nan_distance",
    "short_distances",
    "directions_2d",
    "directions_flat",
    "distances_str",
]
CASES = DISTANCE_CASES + [
    "nan_q",
    "inf_q",
    "short_q",
    "q_2d",
    "none_q",
    "nan_qdot",
    "long_qdot",
    "none_qdot",
    "nan_xdot",
    "minus_inf_xdot",
    "xdot_6d",
    "none_xdot",
    "nan_t_joints",
    "minus_inf_t_distances",
    "nan_t",
    "future_t_joints",
    "future_t_distances",
    "str_t",
    "object_q",
]


@pytest.mark.parametrize("case", CASES)
def test_malformed_input_gives_a_jerk_limited_stop(points, case: str) -> None:
    ctrl, (t, q, qd) = _moving(points, cycles=200)
    outs = []
    for _ in range(150):
        d, dirs = _obstacle(points, q)
        out = ctrl.step(_corrupt(case, t, q, qd, d, dirs))
        outs.append(out)
        q, qd, t = out.q_cmd, out.qdot_cmd, t + DT
    assert all(o.status == CycleStatus.STOP_INVALID_INPUT for o in outs), {o.status.name for o in outs}
    _check_jerk_limited_stop(outs)


def test_time_going_backwards_is_invalid(points) -> None:
    ctrl, (t, q, qd) = _moving(points, cycles=50)
    d, dirs = _free(points.n_points)
    t_old = t - 0.01  # a reordered (older) message, internally consistent
    out = ctrl.step(CycleInput(t_old, q, qd, t_old, XD, d, dirs, t_old))
    assert out.status == CycleStatus.STOP_INVALID_INPUT


def test_plus_inf_distance_is_valid_and_its_direction_is_ignored(points) -> None:
    ctrl = AvoidanceController(points)
    d, dirs = _obstacle(points, Q0)
    ref = AvoidanceController(points).step(CycleInput(0.0, Q0, np.zeros(7), 0.0, XD, d, dirs, 0.0))
    d[3], dirs[3] = np.inf, np.nan  # nothing within rho at point 3: its direction means nothing
    out = ctrl.step(CycleInput(0.0, Q0, np.zeros(7), 0.0, XD, d, dirs, 0.0))
    assert out.status in (CycleStatus.OK, CycleStatus.SCALED)
    assert np.all(np.isfinite(out.qdot_cmd))
    d[3], dirs[3] = np.inf, 0.0
    out2 = AvoidanceController(points).step(CycleInput(0.0, Q0, np.zeros(7), 0.0, XD, d, dirs, 0.0))
    np.testing.assert_array_equal(out.qdot_target, out2.qdot_target)
    assert ref.status in (CycleStatus.OK, CycleStatus.SCALED)


@pytest.mark.parametrize(
    "garbage",
    [None, 42, "cycle", (), (1.0, 2.0), CycleInput(*([None] * 8)), CycleInput(*(["x"] * 8))],
)
def test_step_never_raises_on_garbage(points, garbage) -> None:
    ctrl, _ = _moving(points, cycles=20)
    out = ctrl.step(garbage)
    assert out.status == CycleStatus.STOP_INVALID_INPUT
    assert np.all(np.isfinite(out.qdot_cmd)) and np.all(np.isfinite(out.q_cmd))


def test_step_never_raises_before_any_joint_state(points) -> None:
    ctrl = AvoidanceController(points)
    out = ctrl.step(CycleInput(0.0, None, None, 0.0, XD, None, None, 0.0))
    assert out.status == CycleStatus.STOP_INVALID_INPUT
    assert np.all(out.qdot_cmd == 0.0)
    model = points.model
    assert np.all(out.q_cmd >= model.q_min) and np.all(out.q_cmd <= model.q_max)


class _FailingRuckig:
    """Fault injection at the library boundary: the real Ruckig object, whose update fails on demand."""

    def __init__(self, real, mode: str) -> None:
        self.real, self.mode, self.failing = real, mode, False

    def update(self, inp, out):
        if not self.failing:
            return self.real.update(inp, out)
        if self.mode == "raise":
            import ruckig

            raise ruckig.RuckigError("injected")
        import ruckig

        return ruckig.Result.ErrorExecutionTimeCalculation


@pytest.mark.parametrize("mode", ["code", "raise"])
def test_ruckig_failure_brakes_instead_of_holding_the_velocity(points, mode: str) -> None:
    ctrl, (t, q, qd) = _moving(points, cycles=400)
    fake = _FailingRuckig(ctrl.otg._otg, mode)
    ctrl.otg._otg = fake
    fake.failing = True
    outs = []
    for _ in range(400):
        out = ctrl.step(CycleInput(t, q, qd, t, XD, *_free(points.n_points), t))
        outs.append(out)
        q, qd, t = out.q_cmd, out.qdot_cmd, t + DT
    assert all(o.status == CycleStatus.ERROR_OTG for o in outs)
    _check_jerk_limited_stop(outs)
    fake.failing = False  # Ruckig works again: the latch still waits resume_time before moving on
    out = ctrl.step(CycleInput(t, q, qd, t, XD, *_free(points.n_points), t))
    assert out.status == CycleStatus.STOP_RESUME_WAIT


@pytest.mark.parametrize("resume_time", [0.1, 0.03])
def test_resume_latch_waits_for_valid_inputs_in_a_row_then_resumes_smoothly(points, resume_time: float) -> None:
    cfg = ControllerConfig(resume_time=resume_time)
    ctrl, (t, q, qd) = _moving(points, cfg, cycles=300)
    N = points.n_points
    d, dirs = _free(N)
    statuses, outs = [], []

    def cycle(valid: bool) -> None:
        nonlocal q, qd, t
        dd = d if valid else np.full(N, np.nan)
        out = ctrl.step(CycleInput(t, q, qd, t, XD, dd, dirs, t))
        statuses.append(out.status)
        outs.append(out)
        q, qd, t = out.q_cmd, out.qdot_cmd, t + DT

    for _ in range(30):  # a stop that has not finished braking yet
        cycle(False)
    half = int(round(resume_time / DT / 2))
    for _ in range(half):  # valid, but not long enough ...
        cycle(True)
    cycle(False)  # ... interrupted: the count starts again
    wait = int(round(resume_time / DT))
    for _ in range(wait + 300):
        cycle(True)
    s = [x.name for x in statuses]
    assert s[:30] == ["STOP_INVALID_INPUT"] * 30
    assert s[30 : 30 + half] == ["STOP_RESUME_WAIT"] * half
    assert s[30 + half] == "STOP_INVALID_INPUT"
    k0 = 31 + half
    assert s[k0 : k0 + wait] == ["STOP_RESUME_WAIT"] * wait  # valid for less than resume_time
    assert s[k0 + wait] in ("OK", "SCALED")  # resume_time of valid inputs in a row: moving again
    assert all(x in ("OK", "SCALED") for x in s[k0 + wait :])
    # the whole sequence (braking, waiting, resuming from the current motion) is jerk-limited
    v = np.array([o.qdot_cmd for o in outs])
    a = np.array([o.qddot_cmd for o in outs])
    assert np.all(np.abs(a) <= A_MAX + 1e-9)
    assert np.all(np.abs(np.diff(a, axis=0)) <= J_MAX * DT * (1 + 1e-6))
    assert np.all(np.abs(np.diff(v, axis=0)) <= A_MAX * DT * (1 + 1e-6))
    assert np.linalg.norm(v[-1]) > 0.1  # it did resume


def test_resume_time_must_be_a_non_negative_number(points) -> None:
    with pytest.raises(ValueError, match="resume_time"):
        AvoidanceController(points, ControllerConfig(resume_time=-1.0))
    with pytest.raises(ValueError, match="resume_time"):
        AvoidanceController(points, ControllerConfig(resume_time=float("nan")))


def test_an_unexpected_exception_inside_the_cycle_becomes_a_jerk_limited_stop(points, monkeypatch) -> None:
    ctrl, (t, q, qd) = _moving(points, cycles=200)

    import depthguard.control.cycle as cycle_module

    def broken(*args, **kwargs):
        raise RuntimeError("injected fault in the solver")

    monkeypatch.setattr(cycle_module, "sns_velocity_unchecked", broken)
    monkeypatch.setattr(cycle_module, "plan_cycle", broken)  # (the compiled stage: control.plan_kernel)
    outs = []
    for _ in range(150):
        out = ctrl.step(CycleInput(t, q, qd, t, XD, *_free(points.n_points), t))
        outs.append(out)
        q, qd, t = out.q_cmd, out.qdot_cmd, t + DT
    # the fault latches the stop; while it waits for resume_time nothing is solved, then it fails again
    assert outs[0].status == CycleStatus.STOP_INTERNAL_ERROR
    assert {o.status for o in outs} == {CycleStatus.STOP_INTERNAL_ERROR, CycleStatus.STOP_RESUME_WAIT}
    _check_jerk_limited_stop(outs)


def test_plain_eight_field_tuple_equals_cycle_input(points) -> None:
    """The 8-field input of the first release (a plain tuple) still works and gives the same command as a
    :class:`CycleInput` without the optional monitor fields; a 9-tuple is malformed."""
    d, u = _obstacle(points, Q0)
    a = AvoidanceController(points, ControllerConfig(avoidance="both"))
    b = AvoidanceController(points, ControllerConfig(avoidance="both"))
    for k in range(50):
        t = k * DT
        oa = a.step((t, Q0, np.zeros(7), t, XD, d, u, t))
        ob = b.step(CycleInput(t, Q0, np.zeros(7), t, XD, d, u, t))
        assert oa.status == ob.status and oa.status != CycleStatus.STOP_INVALID_INPUT
        np.testing.assert_array_equal(oa.qdot_cmd, ob.qdot_cmd)
    bad = AvoidanceController(points, ControllerConfig()).step((0.0, Q0, np.zeros(7), 0.0, XD, d, u, 0.0, d))
    assert bad.status == CycleStatus.STOP_INVALID_INPUT
