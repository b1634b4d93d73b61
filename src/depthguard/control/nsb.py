"""Null-space-based (NSB) collision avoidance with robot-mounted proximity sensors (SAPHARI D4.1.1 §5.2).

Two tasks, resolved in the configuration space and mixed by a weighting function of the nearest reading:

* eq. 5.4  end-effector task ``qdot_g = J_g^# (xdot_d + gamma_g (x_d - k(q)))`` with the weighted
  pseudo-inverse of footnote 1, ``J^# = W J^T (J W J^T)^-1`` (W diagonal, larger entries for the arm
  than for the base so that the arm moves first; a small damping keeps it defined near singularities);
* eq. 5.5  energy task ``qdot_o = J_o^+ (sigma_dot_d + gamma_o (sigma_d - sigma(q)))`` with
  ``sigma_d = sigma_dot_d = 0``, ``J_o`` the (1, n) energy gradient of eqs. 5.6-5.7 and
  ``J_o^+ = J_o^T / ||J_o||^2`` its Moore-Penrose pseudo-inverse;
* eq. 5.8  ``qdot = (1 - lambda(d)) qdot_g + lambda(d) (qdot_o + (I - J_o^+ J_o) qdot_g)`` with
  ``d = min_k d_k`` (eq. 5.9) and ``lambda`` the switching (5.10), arctan (5.11) or piecewise-linear (5.12)
  function of the activation threshold ``f`` (:func:`weight`).

Discrete time at the sensor rate: ``q[k+1] = q[k] + dt qdot[k]``. With ``dt * gamma < 2`` the discrete
CLIK error dynamics ``e[k+1] = (1 - dt gamma) e[k]`` are stable, ``dt * gamma <= 1`` without overshoot
(Siciliano's discrete CLIK analysis, the paper's ref. [10]); :class:`NSBConfig` enforces the former.
The commanded joint velocities are scaled down uniformly to the joint limits ``qdot_max``.

Pure array maths plus a :class:`~depthguard.robot.model.RobotModel`; no simulator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numba
import numpy as np

from depthguard.robot.model import RobotModel
from depthguard.robot.sensor_kinematics import SensorArray
from depthguard.sensors.buffer import energy_gradient, total_energy
from depthguard.validation import check_finite_array, is_real_scalar, real_array

__all__ = [
    "LAMBDA_KINDS",
    "weight",
    "weighted_pinv",
    "nsb_velocity",
    "NSBConfig",
    "NSBOutput",
    "NSBController",
]

LAMBDA_KINDS = ("switch", "arctan", "linear")


def weight(d: float, kind: str = "arctan", f: float = 0.25, K: float = 40.0, delta: float = 0.15) -> float:
    """lambda(d): eq. 5.10 (``switch``), 5.11 (``arctan``, slope ``K`` 1/m) or 5.12 (``linear``, width
    ``delta`` m) around the activation threshold ``f`` (m). ``d = inf``: nothing seen, 0 (with the arctan
    its limit); ``d = -inf``: 1 (likewise); NaN counts as 0 m (safe side). ``ValueError`` naming ``d``
    unless it is a real number (a bool is not), ``f`` unless finite, ``K``/``delta`` unless finite > 0."""
    d = _number(d, "d")
    if not (
        math.isfinite(_number(f, "f")) and 0 < _number(K, "K") < math.inf and 0 < _number(delta, "delta") < math.inf
    ):
        raise ValueError(f"weight: f must be finite, K and delta finite > 0, got f={f!r}, K={K!r}, delta={delta!r}")
    if np.isnan(d):
        d = 0.0
    if kind == "switch":
        return 1.0 if d <= f else 0.0
    if kind == "arctan":
        return float(d < 0) if np.isinf(d) else float(np.arctan(-K * (d - f)) / np.pi + 0.5)
    if kind == "linear":
        if d <= f - delta / 2:
            return 1.0
        if d >= f + delta / 2:
            return 0.0
        return float(0.5 - (d - f) / delta)
    raise ValueError(f"lambda kind must be one of {LAMBDA_KINDS}, got {kind!r}")


def _number(value: object, name: str) -> float:
    """``value`` as a float if it is a real number (not a bool, not an array), else ``ValueError`` naming it."""
    if not is_real_scalar(value):
        raise ValueError(f"{name} must be a real number, got {value!r}")
    return float(value)


def _reals(value: object, name: str, shape: tuple[int, ...]) -> np.ndarray:
    """``value`` as a float array of ``shape``, or ``ValueError`` naming ``name`` (bools, strings, complex
    numbers and other shapes are refused; finiteness is left to the caller)."""
    if not (type(value) is np.ndarray and value.dtype == np.float64):
        value = real_array(value, name, f"a {shape} array")
    if value.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {value.shape}")
    return value


def weighted_pinv(J: np.ndarray, w: np.ndarray, damping: float = 1e-6) -> np.ndarray:
    """Footnote 1: ``W J^T (J W J^T + damping I)^-1`` for (r, n) ``J`` and (n,) positive weights ``w``."""
    JW = J * w  # J W
    A = JW @ J.T + damping * np.eye(J.shape[0])
    return np.linalg.solve(A, JW).T


def _targets(x_d: object, xdot_d: object) -> tuple[np.ndarray, np.ndarray]:
    """``x_d``, ``xdot_d`` as float (3,) arrays, or ValueError naming the one that is not finite (3,)."""
    x, v = _reals(x_d, "x_d", (3,)), _reals(xdot_d, "xdot_d", (3,))
    if x.shape != (3,) or v.shape != (3,) or not math.isfinite(x.sum() + v.sum()):
        check_finite_array(x_d, (3,), "x_d"), check_finite_array(xdot_d, (3,), "xdot_d")  # raises, naming it
    return x, v


class NSBTerms(NamedTuple):
    """The parts of one NSB solution: ``qdot`` (n,), ``qdot_g`` (n,), ``qdot_o`` (n,), ``lam``."""

    qdot: np.ndarray
    qdot_g: np.ndarray
    qdot_o: np.ndarray
    lam: float


def _nsb_arrays(J_g, task_error, xdot_d, J_o, w) -> list[np.ndarray]:
    """:func:`nsb_velocity`'s arrays as float arrays, or ``ValueError`` naming the one that is not finite real
    numbers of its shape (``w`` also > 0)."""
    try:
        r, n = np.shape(J_g)
    except ValueError:
        raise ValueError(f"J_g must be a 2-D (r, n) array of real numbers, got {J_g!r}") from None
    out = []
    for name, v, shape in (
        ("J_g", J_g, (r, n)), ("task_error", task_error, (r,)), ("xdot_d", xdot_d, (r,)), ("J_o", J_o, (n,)),
        ("w", w, (n,)),
    ):  # fmt: skip
        a = _reals(v, name, shape)
        if not np.all(np.isfinite(a)) or (name == "w" and not np.all(a > 0)):
            raise ValueError(f"{name} must be finite{' and > 0' if name == 'w' else ''}, got {a!r}")
        out.append(a)
    return out


def nsb_velocity(
    J_g: np.ndarray,
    task_error: np.ndarray,
    xdot_d: np.ndarray,
    sigma: float,
    J_o: np.ndarray,
    lam: float,
    w: np.ndarray,
    gamma_g: float,
    gamma_o: float,
    damping: float = 1e-6,
) -> NSBTerms:
    """eqs. 5.4, 5.5 and 5.8 for one instant.

    Args:
        J_g: (r, n) task Jacobian.  task_error: (r,) ``x_d - k(q)``.  xdot_d: (r,) desired task velocity.
        sigma: total energy (eq. 5.2), m^2.  J_o: (n,) its gradient.  lam: lambda(d) in [0, 1].
        w: (n,) weights of the weighted pseudo-inverse.  gamma_g, gamma_o: CLIK gains, 1/s.
    Raises:
        ValueError: naming the argument that is not of that shape, not real numbers (bools refused) or not
            finite, or ``w`` not > 0, or ``lam`` outside [0, 1], or ``sigma``, ``gamma_g``, ``gamma_o`` or
            ``damping`` negative.
    """
    J_g, task_error, xdot_d, J_o, w = _nsb_arrays(J_g, task_error, xdot_d, J_o, w)
    for name, v, hi in (("sigma", sigma, math.inf), ("lam", lam, 1.0), ("gamma_g", gamma_g, math.inf),
                        ("gamma_o", gamma_o, math.inf), ("damping", damping, math.inf)):  # fmt: skip
        if not (0.0 <= _number(v, name) <= hi and math.isfinite(v)):
            raise ValueError(f"{name} must be a finite number in [0, {hi}], got {v!r}")
    qg = weighted_pinv(J_g, w, damping) @ (xdot_d + gamma_g * task_error)
    n2 = float(J_o @ J_o)
    if n2 > 1e-12:
        Jo_pinv = J_o / n2
        qo = Jo_pinv * (gamma_o * (0.0 - sigma))
        proj = qg - Jo_pinv * float(J_o @ qg)  # (I - J_o^+ J_o) qdot_g
    else:
        qo = np.zeros_like(qg)
        proj = qg
    return NSBTerms((1.0 - lam) * qg + lam * (qo + proj), qg, qo, lam)


@numba.njit(cache=True, nogil=True)
def _energy_kernel(d, rest, axes, Js):  # pragma: no cover
    """eqs. 5.1-5.2 and 5.6-5.7: sigma and J_o (n,) (NaN distances count as 0, negative as 0)."""
    N, n = Js.shape[0], Js.shape[2]
    sigma = 0.0
    Jo = np.zeros(n)
    for k in range(N):
        dk = d[k]
        if np.isnan(dk) or dk < 0.0:
            dk = 0.0
        if dk <= rest[k]:
            sigma += 0.5 * (dk - rest[k]) ** 2
            c = -(dk - rest[k])
            for i in range(n):
                Jo[i] += c * (axes[k, 0] * Js[k, 0, i] + axes[k, 1] * Js[k, 1, i] + axes[k, 2] * Js[k, 2, i])
    return sigma, Jo


@numba.njit(cache=True, nogil=True)
def _wpinv_apply(Jg, w, damping, rhs):  # pragma: no cover
    """Footnote 1 applied to ``rhs``: ``W J^T (J W J^T + damping I)^-1 rhs`` by Gaussian elimination."""
    r, n = Jg.shape
    A = np.empty((r, r))
    for a in range(r):
        for b in range(r):
            acc = 0.0
            for i in range(n):
                acc += Jg[a, i] * w[i] * Jg[b, i]
            A[a, b] = acc + (damping if a == b else 0.0)
    y = rhs.copy()
    for c in range(r):  # elimination with partial pivoting
        p = c
        for a in range(c + 1, r):
            if abs(A[a, c]) > abs(A[p, c]):
                p = a
        if p != c:
            for b in range(r):
                A[c, b], A[p, b] = A[p, b], A[c, b]
            y[c], y[p] = y[p], y[c]
        for a in range(c + 1, r):
            fac = A[a, c] / A[c, c]
            for b in range(c, r):
                A[a, b] -= fac * A[c, b]
            y[a] -= fac * y[c]
    for c in range(r - 1, -1, -1):
        acc = y[c]
        for b in range(c + 1, r):
            acc -= A[c, b] * y[b]
        y[c] = acc / A[c, c]
    qg = np.empty(n)
    for i in range(n):
        acc = 0.0
        for a in range(r):
            acc += Jg[a, i] * y[a]
        qg[i] = w[i] * acc
    return qg


@numba.njit(cache=True, nogil=True)
def _nsb_kernel(Jg, err, xd, d, rest, axes, Js, w, gamma_g, gamma_o, lam, damping, qdot_max):  # pragma: no cover
    """Compiled cycle: energy and gradient, eqs. 5.4, 5.5, 5.8 and the uniform velocity scaling.

    Returns (qdot (n,), sigma, J_o (n,), scale). Same maths as :func:`nsb_velocity` (tested equal). A command
    that is not finite (an overflow, or an exactly singular ``Jg`` with no damping) is a stop: 0, scale 0."""
    sigma, Jo = _energy_kernel(d, rest, axes, Js)
    qg = _wpinv_apply(Jg, w, damping, xd + gamma_g * err)
    n = qg.shape[0]
    n2 = 0.0
    jq = 0.0
    for i in range(n):
        n2 += Jo[i] * Jo[i]
        jq += Jo[i] * qg[i]
    qdot = np.empty(n)
    ratio = 0.0
    for i in range(n):
        qo, proj = 0.0, qg[i]
        if n2 > 1e-12:
            qo = Jo[i] / n2 * (gamma_o * (0.0 - sigma))
            proj = qg[i] - Jo[i] / n2 * jq
        qdot[i] = (1.0 - lam) * qg[i] + lam * (qo + proj)
        r_i = abs(qdot[i]) / qdot_max[i]
        ratio = r_i if not r_i <= ratio else ratio  # (NaN sticks)
    scale = 1.0 if ratio <= 1.0 else 1.0 / ratio
    if not ratio < np.inf:  # NaN or inf: stop
        scale = 0.0
        qdot[:] = 0.0
    for i in range(n):
        qdot[i] *= scale
    return qdot, sigma, Jo, scale


@dataclass(frozen=True)
class NSBConfig:
    """Parameters of :class:`NSBController`.

    Attributes:
        dt: control period, s (the sensor rate, about 300 Hz).
        gamma_g, gamma_o: CLIK gains of eqs. 5.4-5.5, 1/s (``dt * gamma < 2``).
        weights: (n,) diagonal of W (footnote 1); larger = that joint moves more.
        rest: (N,) or scalar spring rest lengths r_k, m.
        lambda_kind: ``"switch"``, ``"arctan"`` or ``"linear"``.
        f, K, delta: activation threshold (m), arctan slope (1/m), linear width (m).
        qdot_max: (n,) joint velocity limits (m/s, rad/s); the command is scaled uniformly into them.
    """

    dt: float = 1.0 / 300.0
    gamma_g: float = 5.0
    gamma_o: float = 10.0
    weights: tuple[float, ...] = (0.2, 0.2, 0.2, 1.0, 1.0, 1.0, 1.0, 1.0)
    rest: tuple[float, ...] | float = 0.3
    lambda_kind: str = "arctan"
    f: float = 0.25
    K: float = 40.0
    delta: float = 0.15
    qdot_max: tuple[float, ...] = (0.8, 0.8, 1.5, 1.5, 1.5, 1.5, 1.5, 1.5)
    damping: float = 1e-6

    def __post_init__(self) -> None:
        for name in ("dt", "gamma_g", "gamma_o", "f", "K", "delta"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"NSBConfig.{name} must be a positive finite number, got {v!r}")
        if self.dt * max(self.gamma_g, self.gamma_o) >= 2.0:
            raise ValueError(
                f"NSBConfig: dt * gamma must be < 2 for a stable discrete CLIK, got dt={self.dt}, "
                f"gamma_g={self.gamma_g}, gamma_o={self.gamma_o}"
            )
        if self.lambda_kind not in LAMBDA_KINDS:
            raise ValueError(f"NSBConfig.lambda_kind must be one of {LAMBDA_KINDS}, got {self.lambda_kind!r}")
        w = np.asarray(self.weights, float)
        if not np.all(np.isfinite(w) & (w > 0)):
            raise ValueError(f"NSBConfig.weights must be positive finite numbers, got {self.weights!r}")
        if not np.all(np.asarray(self.qdot_max, float) > 0):  # (NaN fails too; inf: no limit)
            raise ValueError(f"NSBConfig.qdot_max must be positive joint velocity limits, got {self.qdot_max!r}")
        if not (np.isfinite(self.damping) and self.damping >= 0):
            raise ValueError(f"NSBConfig.damping must be a finite number >= 0, got {self.damping!r}")


class NSBOutput(NamedTuple):
    """One NSB cycle: ``qdot`` (n,) command, ``q_next`` (n,) = q + dt qdot, ``lam``, ``sigma`` (m^2),
    ``d_min`` (m, inf = nothing), ``J_o`` (n,), ``ee`` (3,) end-effector position, ``scale`` (<= 1; 0 with a
    zero command when the unscaled one was not finite, e.g. an overflow)."""

    qdot: np.ndarray
    q_next: np.ndarray
    lam: float
    sigma: float
    d_min: float
    J_o: np.ndarray
    ee: np.ndarray
    scale: float


class NSBController:
    """eqs. 5.4-5.12 on a robot with mounted proximity sensors (end-effector position task, r = 3).

    Args:
        model: the robot.  mounts: its sensors.  config: :class:`NSBConfig`.
        ee_point: (3,) end-effector point in the model's ``ee_frame``, m.
    """

    def __init__(self, model: RobotModel, mounts: object, config: NSBConfig | None = None, ee_point=None) -> None:
        self.cfg = config or NSBConfig()
        self.sensors = SensorArray(model, mounts, ee_point)
        n = model.n_dof
        self.w = np.asarray(self.cfg.weights, float)
        self.qdot_max = np.asarray(self.cfg.qdot_max, float)
        if self.w.shape != (n,) or self.qdot_max.shape != (n,):
            raise ValueError(f"NSBConfig.weights and qdot_max must have {n} entries (the robot's DOF)")
        try:
            self.rest = np.broadcast_to(np.asarray(self.cfg.rest, float), (self.sensors.n_sensors,)).copy()
        except ValueError:
            raise ValueError(f"NSBConfig.rest must be a scalar or {self.sensors.n_sensors} rest lengths") from None
        if not np.all(np.isfinite(self.rest) & (self.rest > 0)):
            raise ValueError(f"NSBConfig.rest must be positive finite lengths (m), got {self.cfg.rest!r}")

    def _inputs(self, q: object, x_d: object, xdot_d: object, distances: object) -> tuple[np.ndarray, ...]:
        """The arguments of :meth:`step` as float arrays, or ``ValueError`` naming the bad one (``q``'s
        shape and finiteness are checked by the sensor array)."""
        d = _reals(distances, "distances", (self.sensors.n_sensors,))
        if not (type(q) is np.ndarray and q.dtype == np.float64):
            q = _reals(q, "q", (len(self.w),))
        return (q, *_targets(x_d, xdot_d), d)

    def step(self, q: np.ndarray, x_d: np.ndarray, xdot_d: np.ndarray, distances: np.ndarray) -> NSBOutput:
        """One cycle: ``q`` (n,), desired EE position ``x_d`` (3,) m and velocity ``xdot_d`` (3,) m/s,
        sensor readings ``distances`` (N,) m along each optical axis (inf = nothing in range). A non-finite
        or mis-shaped ``q``, ``x_d`` or ``xdot_d``, mis-shaped ``distances``, or any of them not real numbers
        (bools, strings, complex numbers) raises ``ValueError`` naming it."""
        cfg = self.cfg
        q, x_d, xdot_d, d = self._inputs(q, x_d, xdot_d, distances)
        st = self.sensors.evaluate(q)
        d_safe = np.where(np.isnan(d), 0.0, d)
        d_min = float(d_safe.min())
        lam = weight(d_min, cfg.lambda_kind, cfg.f, cfg.K, cfg.delta)
        err = x_d - st.ee_position
        qdot, sigma, J_o, scale = _nsb_kernel(
            st.ee_jacobian, err, xdot_d, d, self.rest, st.axes, st.jacobians, self.w,
            cfg.gamma_g, cfg.gamma_o, lam, cfg.damping, self.qdot_max,
        )  # fmt: skip
        return NSBOutput(
            qdot, np.asarray(q, float) + cfg.dt * qdot, lam, float(sigma), d_min, J_o, st.ee_position, scale
        )

    def step_reference(self, q: np.ndarray, x_d: np.ndarray, xdot_d: np.ndarray, distances: np.ndarray) -> NSBOutput:
        """:meth:`step` in plain numpy (eqs. 5.2, 5.6-5.7 through :mod:`depthguard.sensors.buffer` and
        :func:`nsb_velocity`): the reference the compiled kernel is tested against."""
        cfg = self.cfg
        q, x_d, xdot_d, d = self._inputs(q, x_d, xdot_d, distances)
        st = self.sensors.evaluate(q)
        sigma = total_energy(d, self.rest)
        J_o = energy_gradient(d, self.rest, st.axes, st.jacobians)
        d_min = float(np.where(np.isnan(d), 0.0, d).min())
        lam = weight(d_min, cfg.lambda_kind, cfg.f, cfg.K, cfg.delta)
        terms = nsb_velocity(
            st.ee_jacobian, x_d - st.ee_position, xdot_d, sigma, J_o, lam,
            self.w, cfg.gamma_g, cfg.gamma_o, cfg.damping,
        )  # fmt: skip
        ratio = float(np.max(np.abs(terms.qdot) / self.qdot_max))
        scale = 1.0 if ratio <= 1.0 else 1.0 / ratio
        qdot = terms.qdot * scale if ratio < np.inf else np.zeros_like(terms.qdot)  # NaN or inf: a stop
        scale = scale if ratio < np.inf else 0.0
        return NSBOutput(qdot, np.asarray(q, float) + cfg.dt * qdot, lam, sigma, d_min, J_o, st.ee_position, scale)
