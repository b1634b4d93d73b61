"""One 1 kHz control cycle of the avoidance controller (ICRA'12 §V), with a safe stop on stale data.

Per cycle (:func:`control_cycle`):

1. check the inputs: joint state present, finite and fresh; distances present, NaN-free and fresh;
   otherwise command a jerk-limited stop (target velocity 0 through Ruckig) and report why;
2. forward kinematics and the control points (positions, Jacobians) at the measured ``q``;
3. end effector (eqs. 7, 10): ``xdot_c = xdot_d + V_R(P_EE)``;
4. body points (eqs. 12-14): joint-velocity bounds, intersected with the velocity limits and with the
   bounds that let every joint brake before its position limits (:mod:`depthguard.control.otg`);
5. eq. 11 under those bounds by SNS (:mod:`depthguard.control.sns`), with damped least squares near
   singularities;
6. Ruckig (velocity mode): the jerk-limited joint command for the next cycle.

Nothing here raises in the real-time path: the outcome is a :class:`CycleStatus`. Bad *configuration*
(wrong sizes at construction) raises ``ValueError`` once, at start-up.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum
from typing import NamedTuple

import numpy as np

from depthguard.control.body import _body_bounds
from depthguard.control.endeffector import commanded_task_velocity, dls_damping, repulsive_velocity
from depthguard.control.otg import JointOtg, OtgState, position_limited_velocity_bounds
from depthguard.control.sns import sns_velocity_unchecked
from depthguard.robot.control_points import ControlPointSet

__all__ = [
    "CycleStatus",
    "ControllerConfig",
    "CycleInput",
    "CycleOutput",
    "AvoidanceController",
    "control_cycle",
]


class CycleStatus(IntEnum):
    """Outcome of one cycle (ruckig style: an explicit code instead of exceptions)."""

    OK = 0  #: task executed at full scale
    SCALED = 1  #: constraints active: the task was scaled down by SNS (scale < 1)
    STOP_STALE_DISTANCES = 2  #: distances missing, NaN or older than the timeout: jerk-limited stop
    STOP_STALE_JOINTS = 3  #: joint state older than the timeout: jerk-limited stop
    STOP_INVALID_INPUT = 4  #: joint state or task velocity missing / non-finite / wrong size: stop
    ERROR_OTG = 5  #: Ruckig failed; the previous command is held for this cycle

    @property
    def stopping(self) -> bool:
        return self in (
            CycleStatus.STOP_STALE_DISTANCES,
            CycleStatus.STOP_STALE_JOINTS,
            CycleStatus.STOP_INVALID_INPUT,
        )


@dataclass(frozen=True)
class ControllerConfig:
    """Controller parameters (SI units). Defaults follow ICRA'12 Exp. 1-3 where the paper gives them.

    Attributes:
        dt: control period, s (1 kHz).
        rho_ee, alpha_ee, v_rep_max: end-effector repulsion (eq. 7): 0.4 m, 6, 2 m/s (Exp. 1).
        rho_body, alpha_body: body constraints (eqs. 12-14).
        contact_distance: distance at which motion towards an obstacle is denied, m.
        velocity_scale: fraction of the model's joint velocity limits that the controller may use.
        a_max, j_max: joint acceleration (rad/s^2) and jerk (rad/s^3) limits, scalar or (n,).
        position_margin: stop this far inside the joint position limits, rad.
        distance_timeout: distances older than this trigger the safe stop, s (3 frames at 30 Hz).
        joint_timeout: joint states older than this trigger the safe stop, s.
        dls_eps, dls_lambda_max: damped least squares below this singular value / largest damping.
        synchronization: Ruckig synchronization, "none" (default), "time" or "phase". With "none" every
            joint brakes and accelerates on its own time-optimal profile; "time"/"phase" stretch the faster
            joints' profiles to finish together, which slows their braking below the acceleration limit
            that the position-limit bounds assume (a test drove a joint past its limit that way).
    """

    dt: float = 0.001
    rho_ee: float = 0.4
    alpha_ee: float = 6.0
    v_rep_max: float = 2.0
    rho_body: float = 0.4
    alpha_body: float = 6.0
    contact_distance: float = 0.0
    velocity_scale: float = 1.0
    a_max: float | tuple[float, ...] = 10.0
    j_max: float | tuple[float, ...] = 500.0
    position_margin: float = 0.02
    distance_timeout: float = 0.1
    joint_timeout: float = 0.005
    dls_eps: float = 0.02
    dls_lambda_max: float = 0.05
    synchronization: str = "none"


class CycleInput(NamedTuple):
    """Inputs of one cycle.

    Attributes:
        t: current time, s.
        q: (n,) measured joint positions, rad (None = missing).
        qdot: (n,) measured joint velocities, rad/s (used only to start the generator).
        t_joints: time stamp of ``q``, s.
        xdot_d: (3,) desired end-effector linear velocity, m/s (ICRA'12 Exp.: m = 3).
        distances: (N,) per control point (the order of the :class:`ControlPointSet`, end effector
            first), distance from the sphere surface, m; inf = nothing within rho; None = missing.
        directions: (N, 3) unit repulsive directions, from the obstacle towards the point.
        t_distances: time stamp of the distances, s.
    """

    t: float
    q: np.ndarray | None
    qdot: np.ndarray | None
    t_joints: float
    xdot_d: np.ndarray
    distances: np.ndarray | None
    directions: np.ndarray | None
    t_distances: float


class CycleOutput(NamedTuple):
    """Result of one cycle.

    Attributes:
        qdot_cmd: (n,) joint velocity to command for the next period, rad/s (jerk-limited).
        q_cmd: (n,) joint position reached by the command after one period, rad.
        qddot_cmd: (n,) joint acceleration, rad/s^2.
        status: :class:`CycleStatus`.
        scale: SNS task scale in [0, 1] (0 while stopping).
        qdot_target: (n,) SNS velocity given to Ruckig as target, rad/s.
        qdot_min, qdot_max: (n,) the velocity bounds used, rad/s.
        xdot_c: (3,) commanded end-effector velocity (eq. 10), m/s.
    """

    qdot_cmd: np.ndarray
    q_cmd: np.ndarray
    qddot_cmd: np.ndarray
    status: CycleStatus
    scale: float
    qdot_target: np.ndarray
    qdot_min: np.ndarray
    qdot_max: np.ndarray
    xdot_c: np.ndarray


def _finite(x: object, shape: tuple[int, ...]) -> bool:
    return isinstance(x, np.ndarray) and x.shape == shape and bool(np.all(np.isfinite(x)))


@dataclass
class AvoidanceController:
    """The avoidance controller of ICRA'12 §V for one robot and one control-point set.

    Holds the fixed parts (model, points, limits, the Ruckig instance) and the generator state
    between cycles. Call :meth:`step` once per period; :func:`control_cycle` is the same as a function
    of an explicit state.
    """

    points: ControlPointSet
    config: ControllerConfig = field(default_factory=ControllerConfig)

    def __post_init__(self) -> None:
        model = self.points.model
        n = model.n_dof
        self.n = n
        cfg = self.config
        if not 0.0 < cfg.velocity_scale <= 1.0:
            raise ValueError(f"velocity_scale must be in (0, 1], got {cfg.velocity_scale}")
        self.v_max = np.asarray(model.v_max, dtype=float) * cfg.velocity_scale
        self.q_min = np.asarray(model.q_min, dtype=float)
        self.q_max = np.asarray(model.q_max, dtype=float)
        self.otg = JointOtg(n, cfg.dt, np.asarray(cfg.a_max), np.asarray(cfg.j_max), cfg.synchronization)
        self.body_use = np.ones(self.points.n_points, dtype=bool)
        self.body_use[0] = False  # the end effector is handled by its repulsive velocity (eq. 10)
        self.state: OtgState | None = None

    def reset(self) -> None:
        """Forget the generator state (the next cycle starts from the measured velocity)."""
        self.state = None

    def step(self, inp: CycleInput) -> CycleOutput:
        """Run one cycle and keep the generator state."""
        out, self.state = control_cycle(self, inp, self.state)
        return out


def control_cycle(
    ctrl: AvoidanceController, inp: CycleInput, state: OtgState | None
) -> tuple[CycleOutput, OtgState | None]:
    """One control cycle (module docstring) as a function of the controller, the inputs and the
    generator state of the previous cycle (None at start). Returns the output and the new state."""
    cfg, n, m = ctrl.config, ctrl.n, 3
    status = CycleStatus.OK
    q, qdot = inp.q, inp.qdot
    xdot_d = np.asarray(inp.xdot_d, dtype=float) if inp.xdot_d is not None else None
    if not (_finite(q, (n,)) and _finite(qdot, (n,)) and xdot_d is not None and _finite(xdot_d, (m,))):
        status = CycleStatus.STOP_INVALID_INPUT
    elif not inp.t - inp.t_joints <= cfg.joint_timeout:
        status = CycleStatus.STOP_STALE_JOINTS
    else:
        N = ctrl.points.n_points
        d, dirs = inp.distances, inp.directions
        if (
            d is None
            or dirs is None
            or np.shape(d) != (N,)
            or np.shape(dirs) != (N, 3)
            or np.any(np.isnan(d))
            or not inp.t - inp.t_distances <= cfg.distance_timeout
        ):
            status = CycleStatus.STOP_STALE_DISTANCES

    if state is None:  # start from the measured motion, or from rest if there is none
        if _finite(q, (n,)):
            v0 = qdot if _finite(qdot, (n,)) else np.zeros(n)
            state = OtgState(np.array(q, dtype=float), np.array(v0, dtype=float), np.zeros(n))
        else:
            zero = np.zeros(n)
            out = CycleOutput(zero, zero, zero, status, 0.0, zero, zero, zero, np.zeros(m))
            return out, None
    if _finite(q, (n,)):
        state = OtgState(np.array(q, dtype=float), state.velocity, state.acceleration)

    lo_p, hi_p = position_limited_velocity_bounds(
        state.position,
        ctrl.q_min,
        ctrl.q_max,
        ctrl.otg.a_max,
        ctrl.otg.j_max,
        2.0 * cfg.dt,
        cfg.position_margin,
    )
    if status.stopping:
        target = np.zeros(n)
        scale, lo, hi, xdot_c = 0.0, np.zeros(n), np.zeros(n), np.zeros(m)
    else:
        model = ctrl.points.model
        model.update(q)
        cps = ctrl.points.evaluate(q, updated=True)
        dist = np.asarray(inp.distances, dtype=float)
        dirs = np.asarray(inp.directions, dtype=float)
        v_rep = repulsive_velocity(dist[0], dirs[0], cfg.v_rep_max, cfg.rho_ee, cfg.alpha_ee)
        xdot_c = commanded_task_velocity(xdot_d, v_rep)
        lo, hi = -ctrl.v_max, ctrl.v_max.copy()
        _body_bounds(
            cps.jacobians,
            np.maximum(dist, 0.0),
            np.ascontiguousarray(dirs),
            ctrl.body_use,
            ctrl.v_max,
            cfg.rho_body,
            cfg.alpha_body,
            cfg.contact_distance,
            1e-6,
            lo,
            hi,
        )
        lo = np.minimum(np.maximum(lo, lo_p), 0.0)
        hi = np.maximum(np.minimum(hi, hi_p), 0.0)
        J = np.ascontiguousarray(cps.jacobians[0])
        lam = dls_damping(J, cfg.dls_eps, cfg.dls_lambda_max)
        target, scale = sns_velocity_unchecked(J, xdot_c, lo, hi, lam)
        if scale < 1.0 - 1e-9:
            status = CycleStatus.SCALED
    new_state, _, code = ctrl.otg.step(state, target)
    if code < 0:
        status = CycleStatus.ERROR_OTG
    out = CycleOutput(
        new_state.velocity,
        new_state.position,
        new_state.acceleration,
        status,
        float(scale),
        target,
        lo,
        hi,
        xdot_c,
    )
    return out, new_state
