"""One 1 kHz control cycle of the avoidance controller (ICRA'12 §V), with a safe stop on bad data.

Per cycle (:func:`control_cycle`), a sequence of small stages:

1. :func:`~depthguard.control.inputs.check_inputs`: every input field explicitly (shapes, NaN, -inf,
   time stamps, freshness); anything wrong turns the cycle into a jerk-limited stop with the reason as
   its status;
2. the resume latch (:func:`_resume_latch`): after any stop, motion resumes only once the inputs have
   been valid for ``resume_time`` in a row (``STOP_RESUME_WAIT`` until then), then smoothly from the
   current motion state;
3. :func:`joint_bounds`: the joint-velocity bounds that hold in every cycle, v_max and the bounds that
   let every joint brake before its position limits (:mod:`depthguard.control.otg`);
4. unless stopping, :func:`plan_motion`: forward kinematics and the control points at the measured
   ``q``; end effector (eqs. 7, 10): ``xdot_c = xdot_d + V_R(P_EE)``; body points (eqs. 12-14): the
   bounds tightened further; eq. 11 under those bounds by SNS (:mod:`depthguard.control.sns`), with
   damped least squares near singularities. With ``avoidance`` "ssm" or "both", speed and separation
   monitoring (:mod:`depthguard.control.ssm`) scales the task velocity before SNS (from the input's
   ``monitor_distances`` when given, else from the same distances), and its protective stop
   (``STOP_PROTECTIVE``) brakes like any other stop (with "both" and ``stop_evades``, the task stops but
   the end effector's repulsion alone may still move the arm away, within the body bounds). For robots
   whose joints the compiled kinematics handles (:mod:`depthguard.robot.fk`), stages 3 and 4 run as one
   compiled call (:mod:`depthguard.control.plan_kernel`: the same numbers, tested to 1e-12);
5. :func:`generate`: Ruckig (velocity mode) towards the target, the fallback braking step if Ruckig
   fails (``ERROR_OTG``), and :func:`~depthguard.control.bounded.enforce_velocity_bounds`: the command
   of every cycle lies within that cycle's bounds; when a bound shrinks faster than the jerk limit can
   follow, the bound wins and the output reports ``bound_limited``.

Nothing here raises in the real-time path: the outcome is a :class:`CycleStatus`; an unexpected
exception is caught and turned into a jerk-limited stop (``STOP_INTERNAL_ERROR``). Bad *configuration*
(a field outside its form when the :class:`ControllerConfig` is made; a per-joint limit of the wrong length
or an ``a_max`` too small for the robot's speeds when the controller is built) raises ``ValueError`` naming
the field, once, at start-up.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from depthguard.control.body import body_bounds_inplace
from depthguard.control.bounded import braking_step, enforce_velocity_bounds
from depthguard.control.endeffector import commanded_task_velocity, dls_apply, dls_damping, repulsive_velocity
from depthguard.control.inputs import CheckedInput, check_inputs
from depthguard.control.otg import JointOtg, OtgState, joint_velocity_bounds
from depthguard.control.plan_kernel import both_finite, cycle_layout, plan_cycle, plan_params
from depthguard.control.sns import sns_velocity_unchecked
from depthguard.control.step import generate
from depthguard.control.types import ControllerConfig, CycleInput, CycleOutput, CycleStatus, check_config_for_robot
from depthguard.robot.control_points import ControlPointSet

__all__ = [
    "CycleStatus",
    "ControllerConfig",
    "CycleInput",
    "CycleOutput",
    "ControllerState",
    "AvoidanceController",
    "control_cycle",
    "Bounds",
    "joint_bounds",
    "plan_motion",
    "generate",
]

M_TASK = 3  # task dimension: end-effector linear velocity (ICRA'12 experiments)


class ControllerState(NamedTuple):
    """What the controller carries from one cycle to the next.

    Attributes:
        otg: the motion state of the trajectory generator (None before the first valid joint state).
        t_prev: the latest cycle time seen, s (-inf at start).
        latched: a stop happened and the inputs have not yet been valid for ``resume_time``.
        valid_since: time of the first valid cycle while latched, s (NaN if none).
        valid_cycles: valid cycles in a row while latched.
    """

    otg: OtgState | None = None
    t_prev: float = -math.inf
    latched: bool = False
    valid_since: float = math.nan
    valid_cycles: int = 0


class Plan(NamedTuple):
    """The motion a cycle asks for: SNS target (n,) rad/s, task scale, commanded task velocity (3,) m/s."""

    target: np.ndarray
    scale: float
    xdot_c: np.ndarray
    ssm: object | None = None


@dataclass
class AvoidanceController:
    """The avoidance controller of ICRA'12 §V for one robot and one control-point set.

    Holds the fixed parts (model, points, limits, the Ruckig instance) and the state between cycles.
    Call :meth:`step` once per period; :func:`control_cycle` is the same as a function of an explicit
    state.
    """

    points: ControlPointSet
    config: ControllerConfig = field(default_factory=ControllerConfig)

    def __post_init__(self) -> None:
        model = self.points.model
        n = model.n_dof
        self.n = n
        cfg = self.config
        self.v_max = np.asarray(model.v_max, dtype=float) * float(cfg.velocity_scale)
        check_config_for_robot(cfg, self.v_max)  # (the fields alone are checked when the config is made)
        self.q_min = np.asarray(model.q_min, dtype=float)
        self.q_max = np.asarray(model.q_max, dtype=float)
        a_max, j_max = np.asarray(cfg.a_max, dtype=float), np.asarray(cfg.j_max, dtype=float)
        self.otg = JointOtg(n, float(cfg.dt), a_max, j_max, cfg.synchronization, v_max=self.v_max)
        self.plan_ahead = 2.0 * float(np.max(self.otg.a_max / self.otg.j_max))  # s, see Bounds
        self.body_use = np.ones(self.points.n_points, dtype=bool)
        self.body_use[0] = False  # the end effector is handled by its repulsive velocity (eq. 10)
        self.state: ControllerState | None = None
        self.compiled = _compiled_parts(self.points, cfg, self.plan_ahead)  # (3-D task: M_TASK)
        self.sensor_fault: str | None = None
        self.monitor = None
        if cfg.avoidance != "repulsion":
            from depthguard.control.braking import chain_lengths
            from depthguard.control.ssm import SsmConfig, SsmMonitor

            L = chain_lengths(model, self.points.joints, self.points.offsets)
            self.monitor = SsmMonitor(L, self.otg.a_max, self.otg.j_max, cfg.ssm or SsmConfig())

    def set_sensor_fault(self, fault: str | None) -> None:
        """Report a sensor fault (e.g. ``"camera0: frozen"``) or its end (None). While set, every cycle
        reports ``STOP_SENSOR_FAULT`` and stops; afterwards the resume latch applies."""
        self.sensor_fault = fault

    def reset(self) -> None:
        """Forget the state (the next cycle starts from the measured velocity, unlatched)."""
        self.state = None

    def step(self, inp: CycleInput) -> CycleOutput:
        """Run one cycle and keep the state. Never raises: problems come back as the output's status."""
        out, self.state = control_cycle(self, inp, self.state)
        return out


def _compiled_parts(points: ControlPointSet, cfg: ControllerConfig, plan_ahead: float) -> tuple | None:
    """The arrays :mod:`depthguard.control.plan_kernel` needs: the chain (parent, idx_v, kind, axis,
    placement), the control points (joints, offsets, support), the parameter vectors of the plan and of the
    joint bounds (``latency, position_margin, plan_ahead``) and the ``out`` layout; None when the robot
    has joints that the compiled kinematics does not handle (then the stage functions run)."""
    chain = points.model._chain_kinematics
    if chain is None:
        return None
    c = np.ascontiguousarray
    parts = (c(chain.parent), c(chain.idx_v), c(chain.kind), c(chain.axis), c(chain.placement))
    pts = (c(points.joints, dtype=np.int64), c(points.offsets, dtype=np.float64), c(points.support, dtype=np.bool_))
    layout = cycle_layout(points.model.n_dof, points.n_points, M_TASK)
    jprm = np.array([2.0 * cfg.dt, cfg.position_margin, plan_ahead])
    return parts, pts, plan_params(cfg), jprm, layout


def control_cycle(
    ctrl: AvoidanceController, inp: CycleInput, state: ControllerState | None
) -> tuple[CycleOutput, ControllerState]:
    """One control cycle (module docstring) as a function of the controller, the inputs and the state
    of the previous cycle (None at start). Returns the output and the new state. Never raises."""
    st = state if state is not None else ControllerState()
    try:
        return _cycle(ctrl, inp, st)
    except Exception:  # noqa: BLE001 - the real-time path stops, it does not raise
        return _emergency_stop(ctrl, st)


def _cycle(ctrl: AvoidanceController, inp: CycleInput, st: ControllerState) -> tuple[CycleOutput, ControllerState]:
    """The stages of the module docstring, in order."""
    chk = check_inputs(inp, ctrl.n, ctrl.points.n_points, M_TASK, ctrl.config, st.t_prev)
    if ctrl.sensor_fault is not None and chk.status == CycleStatus.OK:
        chk = chk._replace(status=CycleStatus.STOP_SENSOR_FAULT)
    t_prev = st.t_prev if math.isnan(chk.t) else max(st.t_prev, chk.t)
    st = ControllerState(st.otg, t_prev, st.latched, st.valid_since, st.valid_cycles)  # (faster than _replace)
    status, st = _resume_latch(ctrl.config, chk, st)
    otg = _sync_state(st.otg, chk, ctrl.v_max)
    if otg is None:  # no joint state yet: nothing to command but rest
        return _rest_output(ctrl, status), st._replace(latched=True, valid_since=math.nan, valid_cycles=0)
    if status.stopping:
        b = joint_bounds(ctrl, otg)
        plan = Plan(np.zeros(ctrl.n), 0.0, np.zeros(M_TASK))
    else:
        data_age = max(chk.t - float(inp[7]), 0.0)  # (t_distances; a plain tuple too)
        if ctrl.compiled is not None:  # stages 3 and 4 in one compiled call (control.plan_kernel)
            b, plan, finite = _plan_compiled(ctrl, chk, otg, data_age)
        else:
            b = joint_bounds(ctrl, otg)
            plan = plan_motion(ctrl, chk, b, otg, data_age)
            finite = both_finite(plan.target, plan.xdot_c)
        if not finite:
            status, plan = CycleStatus.STOP_INVALID_INPUT, Plan(np.zeros(ctrl.n), 0.0, np.zeros(M_TASK))
        elif plan.ssm is not None and plan.ssm.scale <= 0.0:
            status = CycleStatus.STOP_PROTECTIVE
            if not _evades(ctrl.config):  # (an evasive plan already holds the repulsion alone)
                plan = Plan(np.zeros(ctrl.n), 0.0, np.zeros(M_TASK), plan.ssm)
        elif plan.scale < 1.0 - 1e-9 or (plan.ssm is not None and plan.ssm.scale < 1.0):
            status = CycleStatus.SCALED
    away = None
    if status == CycleStatus.STOP_PROTECTIVE and _evades(ctrl.config):
        away = _evasion_gradient(ctrl, otg, chk)
    new, ok, limited = generate(ctrl.otg, otg, plan.target, b.lo, b.hi, away)
    if not ok:
        status = CycleStatus.ERROR_OTG
    # the SSM stop has its own hysteresis (the monitor releases it): it does not latch the resume wait
    if status.stopping and status not in (CycleStatus.STOP_RESUME_WAIT, CycleStatus.STOP_PROTECTIVE):
        st = st._replace(latched=True, valid_since=math.nan, valid_cycles=0)
    out = CycleOutput(
        new.velocity, new.position, new.acceleration, status, float(plan.scale), plan.target, b.lo, b.hi,
        plan.xdot_c, limited, plan.ssm,
    )  # fmt: skip
    return out, ControllerState(new, st.t_prev, st.latched, st.valid_since, st.valid_cycles)


def _resume_latch(cfg: ControllerConfig, chk: CheckedInput, st: ControllerState) -> tuple[CycleStatus, ControllerState]:
    """Apply the resume latch: a stop status latches; valid inputs release it after ``resume_time``."""
    if chk.status != CycleStatus.OK:
        return chk.status, st._replace(latched=True, valid_since=math.nan, valid_cycles=0)
    if not st.latched:
        return CycleStatus.OK, st
    since = chk.t if st.valid_cycles == 0 else st.valid_since
    cycles = st.valid_cycles + 1
    tol = 1e-9
    if chk.t - since >= cfg.resume_time - tol and (cycles - 1) * cfg.dt >= cfg.resume_time - tol:
        return CycleStatus.OK, st._replace(latched=False, valid_since=math.nan, valid_cycles=0)
    return CycleStatus.STOP_RESUME_WAIT, st._replace(valid_since=since, valid_cycles=cycles)


def _sync_state(otg: OtgState | None, chk: CheckedInput, v_max: np.ndarray) -> OtgState | None:
    """The generator state for this cycle: the previous one at the measured ``q`` (if valid); at start,
    the measured motion (from rest if the measured velocity is unusable; clipped to ``v_max``, which the
    robot cannot exceed); None if there is no joint state yet."""
    if otg is None:
        if chk.q is None:
            return None
        v0 = np.clip(chk.qdot, -v_max, v_max) if chk.qdot is not None else np.zeros_like(chk.q)
        return OtgState(chk.q.copy(), v0, np.zeros_like(chk.q))
    if chk.q is not None:
        return OtgState(chk.q.copy(), otg.velocity, otg.acceleration)
    return otg


class Bounds(NamedTuple):
    """A cycle's joint-velocity bounds, rad/s, each (n,), ``lo <= 0 <= hi``.

    ``lo``/``hi`` hold for the command of this cycle (enforced, reported). ``lo_s``/``hi_s`` (within
    them) are the ones SNS plans with: the position-limit bounds there are evaluated ``2 a_max / j_max``
    seconds (the largest over the joints) ahead along the current velocity, so that braking towards a
    position limit starts while the jerk limit can still follow the shrinking bound.
    """

    lo: np.ndarray
    hi: np.ndarray
    lo_s: np.ndarray
    hi_s: np.ndarray


def joint_bounds(ctrl: AvoidanceController, otg: OtgState) -> Bounds:
    """The bounds that hold in every cycle: ``|qdot| <= v_max`` and the position-limit braking bounds at
    the state's position (two periods of latency, ``position_margin`` inside the limits)."""
    cfg, j = ctrl.config, ctrl.otg
    lo, hi, lo_s, hi_s = joint_velocity_bounds(
        otg.position, otg.velocity, ctrl.q_min, ctrl.q_max, ctrl.v_max,
        j.a_max, j.j_max, 2.0 * cfg.dt, cfg.position_margin, ctrl.plan_ahead,
    )  # fmt: skip
    return Bounds(lo, hi, lo_s, hi_s)


def plan_motion(
    ctrl: AvoidanceController, chk: CheckedInput, b: Bounds, otg: OtgState | None = None, data_age: float = 0.0
) -> Plan:
    """Stage 4 of the module docstring for valid inputs: end-effector repulsion (unless ``avoidance`` is
    "ssm"), body bounds (which tighten all of ``b`` in place), the SSM speed scale of the task (when on;
    ``otg`` is the current motion, ``data_age`` the age of the distances, s) and SNS within
    ``b.lo_s``/``b.hi_s``."""
    cfg = ctrl.config
    cps = ctrl.points.evaluate(chk.q)
    dist, dirs = chk.distances, chk.directions
    if cfg.avoidance == "ssm":
        xdot_c = np.asarray(chk.xdot_d, dtype=float).copy()
    else:
        v_rep = repulsive_velocity(dist[0], dirs[0], cfg.v_rep_max, cfg.rho_ee, cfg.alpha_ee)
        xdot_c = commanded_task_velocity(chk.xdot_d, v_rep)
    dist0 = np.maximum(dist, 0.0)
    for lo, hi in ((b.lo, b.hi), (b.lo_s, b.hi_s)):  # (the body bounds only ever tighten lo/hi)
        body_bounds_inplace(
            cps.jacobians, dist0, dirs, ctrl.body_use, ctrl.v_max,
            cfg.rho_body, cfg.alpha_body, cfg.contact_distance, 1e-6, lo, hi,
        )  # fmt: skip
    J = np.ascontiguousarray(cps.jacobians[0])
    lam = dls_damping(J, cfg.dls_eps, cfg.dls_lambda_max)
    ssm = None
    if ctrl.monitor is not None and otg is not None:  # speed and separation monitoring scales the task
        nominal = dls_apply(J, lam, xdot_c)
        ssm = ctrl.monitor.update(
            cps.jacobians, otg.velocity, otg.acceleration, nominal, chk.monitor_distances, chk.monitor_directions,
            data_age,
        )  # fmt: skip
        if ssm.scale <= 0.0 and _evades(cfg):  # protective stop: no task, the repulsion may still evade
            xdot_c = commanded_task_velocity(np.zeros_like(xdot_c), v_rep)
        else:
            xdot_c = xdot_c * ssm.scale
    target, scale = sns_velocity_unchecked(J, xdot_c, b.lo_s, b.hi_s, lam)
    return Plan(target, float(scale), xdot_c, ssm)


def _plan_compiled(
    ctrl: AvoidanceController, chk: CheckedInput, otg: OtgState, data_age: float
) -> tuple[Bounds, Plan, bool]:
    """:func:`joint_bounds` and :func:`plan_motion` through :func:`~depthguard.control.plan_kernel.plan_cycle`
    (the same numbers in one call): the bounds (``lo_s``/``hi_s`` are the kernel's own, not returned:
    their places hold ``lo``/``hi``), the plan and whether it is finite."""
    cfg, (chain, pts, prm, jprm, layout) = ctrl.config, ctrl.compiled
    mon = ctrl.monitor
    out = np.empty(layout["size"].stop)
    if mon is None:
        T_r, lengths, mprm, v_h, rng, hyst, stopped, age = 0.0, _NO_LENGTHS, prm, _NO_SPEED, 0.0, 0.0, False, 0.0
    else:
        age, T_r, mprm, v_h = mon.kernel_inputs(data_age)
        lengths, rng, hyst, stopped = mon.lengths, float(mon.config.sensing_range), mon.config.hysteresis, mon.stopped
    scale, s, stopped, ended, T_s, binding, finite = plan_cycle(
        chk.q, otg.velocity, otg.acceleration, *chain, *pts, chk.distances, chk.directions, chk.monitor_distances,
        chk.monitor_directions, ctrl.body_use, ctrl.q_min, ctrl.q_max, ctrl.v_max, ctrl.otg.a_max, ctrl.otg.j_max,
        chk.xdot_d, prm, jprm, cfg.avoidance != "ssm", mon is not None, _evades(cfg), lengths, mprm, v_h, rng,
        hyst, stopped, age, out,
    )  # fmt: skip
    L = layout
    lo, hi = out[L["lo"]], out[L["hi"]]
    ssm = None
    if mon is not None:
        ssm = mon.finish(s, stopped, ended, T_s, binding, out[L["separation"]], out[L["s_p"]], out[L["margin"]], T_r)
    return Bounds(lo, hi, lo, hi), Plan(out[L["target"]], float(scale), out[L["xdot_c"]], ssm), bool(finite)


_NO_LENGTHS = np.zeros((1, 1))  # (placeholders for the monitor's arrays when there is no monitor)
_NO_SPEED = np.zeros(1)


def _evades(cfg: ControllerConfig) -> bool:
    """A protective stop keeps the end effector's repulsion ("both" mode with ``stop_evades``)."""
    return cfg.avoidance == "both" and cfg.stop_evades


def _evasion_gradient(ctrl: AvoidanceController, otg: OtgState, chk: CheckedInput) -> np.ndarray:
    """``J_eeᵀ n`` (n,) at the current motion's position: the end effector's distance to its obstacle
    grows along it (``n``: the end effector's repulsive direction, 0 when nothing is within reach)."""
    return chk.directions[0] @ ctrl.points.evaluate(otg.position).jacobians[0]


def _rest_output(ctrl: AvoidanceController, status: CycleStatus) -> CycleOutput:
    """Output before any valid joint state: zero velocity, ``q_cmd`` = 0 clipped into the joint limits
    (there is no measured position to hold; a position-controlled robot must not use it)."""
    z = np.zeros(ctrl.n)
    q = np.minimum(np.maximum(z, ctrl.q_min), ctrl.q_max)
    return CycleOutput(z, q, z.copy(), status, 0.0, z.copy(), z.copy(), z.copy(), np.zeros(M_TASK), False)


def _emergency_stop(ctrl: AvoidanceController, st: ControllerState) -> tuple[CycleOutput, ControllerState]:
    """After an unexpected exception: the fallback braking step from the last state, within the joint
    bounds (v_max, position limits)."""
    st = st._replace(latched=True, valid_since=math.nan, valid_cycles=0)
    status = CycleStatus.STOP_INTERNAL_ERROR
    if st.otg is None:
        return _rest_output(ctrl, status), st
    try:
        j = ctrl.otg
        b = joint_bounds(ctrl, st.otg)
        lo, hi = b.lo, b.hi
        new, limited = enforce_velocity_bounds(st.otg, braking_step(st.otg, j.a_max, j.j_max, j.dt), lo, hi,
                                               j.a_max, j.j_max, j.dt)  # fmt: skip
        if not (np.isfinite(new.position).all() and np.isfinite(new.velocity).all()):
            raise FloatingPointError
    except Exception:  # noqa: BLE001 - last resort: hold the last position
        z = np.zeros(ctrl.n)
        pos = np.nan_to_num(st.otg.position)
        new, limited, lo, hi = OtgState(pos, z, z.copy()), True, z.copy(), z.copy()
    z = np.zeros(ctrl.n)
    out = CycleOutput(new.velocity, new.position, new.acceleration, status, 0.0, z, lo, hi, np.zeros(M_TASK), limited)
    return out, st._replace(otg=new)
