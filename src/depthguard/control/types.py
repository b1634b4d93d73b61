"""The avoidance controller's configuration, cycle inputs, cycle outputs and status codes.

Units are SI (m, s, rad); frames and sign conventions are those of docs/conventions.md.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from enum import IntEnum
from typing import NamedTuple

import numpy as np

__all__ = ["CycleStatus", "ControllerConfig", "CycleInput", "CycleOutput", "check_config_for_robot"]


class CycleStatus(IntEnum):
    """Outcome of one cycle (ruckig style: an explicit code instead of exceptions)."""

    OK = 0  #: task executed at full scale
    SCALED = 1  #: constraints active: the task was scaled down by SNS (scale < 1)
    STOP_STALE_DISTANCES = 2  #: distances missing (None) or older than the timeout: jerk-limited stop
    STOP_STALE_JOINTS = 3  #: joint state older than the timeout: jerk-limited stop
    #: an input is malformed: NaN, -inf or a wrong shape in q, qdot, xdot_d, distances or directions
    #: (a non-finite direction with a finite distance), a non-finite time stamp, a time stamp from the
    #: future or a cycle time that went backwards: jerk-limited stop
    STOP_INVALID_INPUT = 4
    ERROR_OTG = 5  #: Ruckig failed: this cycle brakes with the fallback jerk-limited stop
    #: inputs valid again after a stop, but for less than ``resume_time`` in a row: still stopping
    STOP_RESUME_WAIT = 6
    STOP_INTERNAL_ERROR = 7  #: an unexpected exception inside the cycle: jerk-limited stop
    #: a camera reported a fault (frozen, covered, moved: :mod:`depthguard.robot.health`); the faulty camera
    #: is named in :attr:`AvoidanceController.sensor_fault`: jerk-limited stop, resume latch afterwards
    STOP_SENSOR_FAULT = 8
    #: speed and separation monitoring: the separation is below the protective separation distance even
    #: at rest (ISO/TS 15066): jerk-limited stop until the monitor's hysteresis releases it
    STOP_PROTECTIVE = 9

    @property
    def stopping(self) -> bool:
        """True for every status whose cycle commands a stop (target velocity 0)."""
        return self not in (CycleStatus.OK, CycleStatus.SCALED)


@dataclass(frozen=True)
class ControllerConfig:
    """Controller parameters (SI units). Defaults follow ICRA'12 Exp. 1-3 where the paper gives them.

    Every field is checked when the config is made (``__post_init__``, also on ``dataclasses.replace``): a
    value outside the form given below raises ``ValueError`` naming the field and the expected form. Numbers
    are real numbers (``int``, ``float``, numpy scalars), never ``bool`` or strings; "finite" excludes NaN and
    ±inf. The length of a per-joint ``a_max``/``j_max`` is checked against the robot by
    :class:`~depthguard.control.cycle.AvoidanceController`.

    Attributes:
        dt: control period, s (1 kHz), finite > 0.
        rho_ee, alpha_ee, v_rep_max: end-effector repulsion (eq. 7): 0.4 m, 6, 2 m/s (Exp. 1); rho and alpha
            finite > 0, v_rep_max finite >= 0 (0: no repulsion).
        rho_body, alpha_body: body constraints (eqs. 12-14), finite > 0.
        contact_distance: distance at which motion towards an obstacle is denied, m, finite >= 0 (0: at
            contact only).
        velocity_scale: fraction of the model's joint velocity limits that the controller may use, in (0, 1].
        a_max, j_max: joint acceleration (rad/s^2) and jerk (rad/s^3) limits, finite > 0, scalar or (n,)
            (a tuple, list or 1-D array), with ``(a_max / j_max)**2`` finite (the braking bounds square it:
            an overflow there made the bounds NaN or v_max).
        position_margin: stop this far inside the joint position limits, rad, finite >= 0 (a negative margin
            lets a joint pass its limits).
        distance_timeout: distances older than this trigger the safe stop, s (3 frames at 30 Hz), finite > 0
            (an infinite or NaN timeout would never see stale data).
        joint_timeout: joint states older than this trigger the safe stop, s, finite > 0.
        dls_eps, dls_lambda_max: damped least squares below this singular value / largest damping, both
            finite >= 0 (either 0: no damping, the plain pseudo-inverse).
        synchronization: Ruckig synchronization, "none" (default), "time" or "phase". With "none" every
            joint brakes and accelerates on its own time-optimal profile; "time"/"phase" stretch the faster
            joints' profiles to finish together, which slows their braking below the acceleration limit
            that the position-limit bounds assume (a test drove a joint past its limit that way).
        avoidance: "repulsion" (the papers: end-effector repulsion and body bounds), "ssm" (speed and
            separation monitoring, ISO/TS 15066, scaling the task, plus the body bounds) or "both".
        ssm: the :class:`depthguard.control.ssm.SsmConfig` (None = its defaults) when SSM is on; None or an
            ``SsmConfig``.
        stop_evades: with ``avoidance`` "both", a protective stop halts the task but the end effector's
            repulsion (eq. 10) may still move the arm *away* from what approaches, within the body bounds
            (eqs. 12-14: each point's speed towards its obstacle is limited, to zero at contact); a cycle
            whose time-optimal step would bring the end effector nearer takes the phase-synchronized step
            (:func:`depthguard.control.step.generate`). False: the plain jerk-limited stop, as in "ssm"
            mode. A person who walks into a stopped arm is then hit. A ``bool``.
        resume_time: after any stop, motion resumes only once every input has been valid (and fresh)
            for this long in a row, s (cycles in a row and elapsed time both count); until then the
            cycle reports ``STOP_RESUME_WAIT`` and keeps stopping. Finite >= 0 (0: resume at once).
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
    resume_time: float = 0.1
    avoidance: str = "repulsion"
    ssm: object | None = None
    stop_evades: bool = True

    def __post_init__(self) -> None:
        _check_config(self)


_SYNCHRONIZATIONS = ("none", "time", "phase")
_AVOIDANCE_MODES = ("repulsion", "ssm", "both")
#: (field, smallest legal value, whether that value itself is legal); every one of them must be finite
_NUMBERS = (
    ("dt", 0.0, False), ("rho_ee", 0.0, False), ("alpha_ee", 0.0, False), ("v_rep_max", 0.0, True),
    ("rho_body", 0.0, False), ("alpha_body", 0.0, False), ("contact_distance", 0.0, True),
    ("position_margin", 0.0, True), ("distance_timeout", 0.0, False), ("joint_timeout", 0.0, False),
    ("dls_eps", 0.0, True), ("dls_lambda_max", 0.0, True), ("resume_time", 0.0, True),
)  # fmt: skip


def _is_number(val: object) -> bool:
    """A real number that is not a bool (``True`` is an ``int`` to Python)."""
    return isinstance(val, numbers.Real) and not isinstance(val, (bool, np.bool_))


def _limit_values(name: str, val: object) -> np.ndarray:
    """``a_max``/``j_max`` as a float array (1,) or (n,): finite numbers > 0, else ValueError naming ``name``."""
    form = f"ControllerConfig.{name} must be a finite number > 0 or a non-empty 1-D sequence of them"
    if _is_number(val):
        arr = np.array([float(val)])
    elif isinstance(val, (tuple, list, np.ndarray)) and all(_is_number(v) for v in np.ravel(np.asarray(val, object))):
        arr = np.asarray(val, dtype=float)
        if arr.ndim != 1 or arr.size == 0:
            raise ValueError(f"{form}, got shape {arr.shape}")
    else:
        raise ValueError(f"{form}, got {val!r}")
    if not (np.all(np.isfinite(arr)) and np.all(arr > 0.0)):
        raise ValueError(f"{form}, got {val!r}")
    return arr


def _check_config(cfg: ControllerConfig) -> None:
    """Refuse a field outside its form (:class:`ControllerConfig`'s docstring): ValueError naming it."""
    for name, low, closed in _NUMBERS:
        val = getattr(cfg, name)
        ok = _is_number(val) and math.isfinite(val) and (val >= low if closed else val > low)
        if not ok:
            raise ValueError(f"ControllerConfig.{name} must be a finite number {'>=' if closed else '>'} {low:g}, "
                             f"got {val!r}")  # fmt: skip
    vs = cfg.velocity_scale
    if not (_is_number(vs) and 0.0 < vs <= 1.0):
        raise ValueError(f"ControllerConfig.velocity_scale must be a number in (0, 1], got {vs!r}")
    a, j = _limit_values("a_max", cfg.a_max), _limit_values("j_max", cfg.j_max)
    if a.size > 1 and j.size > 1 and a.size != j.size:
        raise ValueError(f"ControllerConfig.a_max and j_max must have the same length, got {a.size} and {j.size}")
    with np.errstate(over="ignore"):
        ratio_ok = np.all(np.isfinite((a / j) ** 2))
    if not ratio_ok:  # (the braking bounds square it: an overflow there lifted a bound to v_max)
        raise ValueError(f"ControllerConfig.a_max / j_max must be a time (s) whose square is finite, got "
                         f"a_max={cfg.a_max!r}, j_max={cfg.j_max!r}")  # fmt: skip
    for name, choices in (("synchronization", _SYNCHRONIZATIONS), ("avoidance", _AVOIDANCE_MODES)):
        val = getattr(cfg, name)
        if not (isinstance(val, str) and val in choices):
            raise ValueError(f"ControllerConfig.{name} must be one of {list(choices)}, got {val!r}")
    from depthguard.control.ssm import SsmConfig  # (here: ssm imports this package's modules)

    if cfg.ssm is not None and not isinstance(cfg.ssm, SsmConfig):
        raise ValueError(f"ControllerConfig.ssm must be None or an SsmConfig, got {cfg.ssm!r}")
    if not isinstance(cfg.stop_evades, (bool, np.bool_)):
        raise ValueError(f"ControllerConfig.stop_evades must be a bool, got {cfg.stop_evades!r}")


def check_config_for_robot(cfg: ControllerConfig, v_max: np.ndarray) -> None:
    """Refuse what depends on the robot, naming the field (ValueError): a per-joint ``a_max``/``j_max`` whose
    length is not n (``v_max``: (n,) the joint speed limits the controller uses, rad/s), and an ``a_max`` so
    small that the braking bounds (:func:`~depthguard.control.otg.joint_velocity_bounds`) overflow where they
    matter: they take ``2 d / a`` (``a = a_max / 2``) for distances ``d`` up to the braking distance at
    ``v_max``, ``v_max^2 / (2 a) + v_max (a / (2 j_max) + 2 dt)``; an overflow to inf there lifted a bound to
    ``v_max`` (``a_max = 1e-320``: full speed 0.01 rad before a limit). O(n), once, at start-up."""
    n = len(v_max)
    for name in ("a_max", "j_max"):
        size = np.size(getattr(cfg, name))
        if np.ndim(getattr(cfg, name)) != 0 and size != n:
            raise ValueError(f"ControllerConfig.{name} must be one number or {n} (one per joint), got {size}")
    a = 0.5 * np.broadcast_to(np.asarray(cfg.a_max, dtype=float), (n,))
    j = np.broadcast_to(np.asarray(cfg.j_max, dtype=float), (n,))
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
        ok = (a > 0.0) & np.isfinite((v_max / a) ** 2 + 2.0 * v_max * (a / (2.0 * j) + 2.0 * cfg.dt) / a)
    if not np.all(ok):
        raise ValueError(
            f"ControllerConfig.a_max must be large enough that (v_max / a_max)**2 is finite, got "
            f"a_max={(2.0 * a[~ok]).tolist()} for joints {np.flatnonzero(~ok).tolist()} (v_max {v_max[~ok].tolist()})"
        )


class CycleInput(NamedTuple):
    """Inputs of one cycle.

    Every field is checked each cycle; anything malformed gives ``STOP_INVALID_INPUT`` (never an
    exception). Time stamps must be finite; ``t_joints`` and ``t_distances`` may lie at most one period
    ``dt`` in the future of ``t``, and ``t`` must not go backwards from one cycle to the next.

    Attributes:
        t: current time, s.
        q: (n,) measured joint positions, rad (None = missing).
        qdot: (n,) measured joint velocities, rad/s (used only to start the generator).
        t_joints: time stamp of ``q``, s.
        xdot_d: (3,) desired end-effector linear velocity, m/s (ICRA'12 Exp.: m = 3).
        distances: (N,) per control point (the order of the :class:`ControlPointSet`, end effector
            first), distance from the sphere surface, m; +inf = nothing within rho (its direction is then
            ignored); NaN and -inf are invalid; None = missing (``STOP_STALE_DISTANCES``).
        directions: (N, 3) unit repulsive directions, from the obstacle towards the point; finite
            wherever the distance is finite.
        t_distances: time stamp of the distances, s.
        monitor_distances: (N,) or None: the distances that speed and separation monitoring uses, when
            they differ from ``distances`` (those of the repulsion and the body bounds): the same frames
            with the cell's commissioned background (room, table, fixtures) removed, so that the monitor
            sees people and unknown space only while the repulsion keeps avoiding everything. Same rules
            and time stamp as ``distances``; None = the monitor uses ``distances``.
        monitor_directions: (N, 3) or None, the directions of ``monitor_distances`` (both or neither).
    """

    t: float
    q: np.ndarray | None
    qdot: np.ndarray | None
    t_joints: float
    xdot_d: np.ndarray
    distances: np.ndarray | None
    directions: np.ndarray | None
    t_distances: float
    monitor_distances: np.ndarray | None = None
    monitor_directions: np.ndarray | None = None


class CycleOutput(NamedTuple):
    """Result of one cycle.

    Attributes:
        qdot_cmd: (n,) joint velocity to command for the next period, rad/s (jerk-limited unless
            ``bound_limited``); always within ``[qdot_min, qdot_max]``.
        q_cmd: (n,) joint position reached by the command after one period, rad.
        qddot_cmd: (n,) joint acceleration, rad/s^2.
        status: :class:`CycleStatus`.
        scale: SNS task scale in [0, 1] (0 while stopping).
        qdot_target: (n,) SNS velocity given to Ruckig as target, rad/s (0 while stopping).
        qdot_min, qdot_max: (n,) the cycle's velocity bounds, rad/s: v_max, the position-limit braking
            bounds and (when the distances are valid) the body bounds.
        xdot_c: (3,) commanded end-effector velocity (eq. 10), m/s.
        bound_limited: True when a bound shrank faster than the jerk limit can follow, so the bound won:
            ``qdot_cmd`` was set to it, breaking the acceleration or jerk limit in this cycle.
        ssm: the speed and separation monitor's output of this cycle (None when SSM is off or stopping).
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
    bound_limited: bool = False
    ssm: object | None = None  #: the cycle's :class:`depthguard.control.ssm.SsmOutput` when SSM is on
