"""The 1 kHz avoidance controller the simulated loop drives (ICRA'12 §V; stand-in for ``depthguard.control``).

One cycle (:meth:`AvoidanceController.step`):

1. end effector: ``xdot_c = xdot_d + V_R(P_EE)`` (eq. 10), with ``V_R`` from the distance stage;
2. body points: the collision risk ``f(D)`` (eq. 12) and ``s = J_C^T (-n) f`` (eq. 13, ``n`` the repulsive
   direction, pointing away from the obstacle) shrink the joint-velocity bounds (eq. 14): a joint whose
   positive motion drives the point towards the obstacle gets ``qdot_max = V_max (1 - f)``, and
   symmetrically; joint position limits shrink them too;
3. ``qdot = J^# xdot_c`` under those bounds by Saturation in the Null Space (SNS, Flacco et al. ICRA'12);
4. a jerk-limited velocity trajectory (Ruckig, velocity interface) turns it into the joint command.

When the distances are older than ``stale_timeout`` (or missing) the target velocity is zero: a
jerk-limited stop (DESIGN.md §5.3). Without avoidance (``avoid=False``) steps 1-2 are skipped.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ControlParams", "AvoidanceController", "sns"]


@dataclass(frozen=True)
class ControlParams:
    """Controller parameters (ICRA'12 notation)."""

    rho_body: float = 0.3
    alpha_body: float = 6.0
    stale_timeout: float = 0.2
    acc_max: float = 10.0  # rad/s^2
    jerk_max: float = 400.0  # rad/s^3
    vel_scale: float = 0.9  # fraction of the joint velocity limits used
    limit_margin: float = 0.05  # rad from the joint position limits
    damping: float = 1e-3
    body_repulsion: float = 0.3  # m/s: null-space repulsion of the body points (0 = eq. 14 only)


def _pinv(A: np.ndarray, damping: float) -> np.ndarray:
    return A.T @ np.linalg.inv(A @ A.T + damping * np.eye(A.shape[0]))


def sns(
    J: np.ndarray, xdot: np.ndarray, qmin: np.ndarray, qmax: np.ndarray, damping: float = 1e-3
) -> tuple[np.ndarray, float]:
    """Saturation in the Null Space, velocity level (Flacco, De Luca, Khatib, ICRA'12, Alg. 1-2).

    Returns ``(qdot (n,), scale)`` with ``qmin <= qdot <= qmax`` and ``J qdot ~ scale xdot``.
    The bounds must contain 0.
    """
    try:  # the project's implementation, when installed
        from depthguard.control.sns import sns_velocity

        return sns_velocity(J, xdot, qmin, qmax)
    except ImportError:
        pass
    m, n = J.shape
    W = np.ones(n)
    qN = np.zeros(n)
    best = (0.0, W.copy(), qN.copy())
    for _ in range(n + 1):
        JW = J * W
        P = _pinv(JW, damping)
        qd = qN + P @ (xdot - J @ qN)
        if np.all(qd >= qmin - 1e-9) and np.all(qd <= qmax + 1e-9):
            return qd, 1.0
        a = P @ xdot
        b = qd - a
        smax, j_crit = np.inf, -1
        for j in range(n):
            if W[j] == 0 or abs(a[j]) < 1e-12:
                continue
            lo, hi = (qmin[j] - b[j]) / a[j], (qmax[j] - b[j]) / a[j]
            up = max(lo, hi)
            if up < smax:
                smax, j_crit = up, j
        s = float(np.clip(smax, 0.0, 1.0))
        if s > best[0]:
            best = (s, W.copy(), qN.copy())
        if j_crit < 0:
            break
        W[j_crit] = 0.0
        qN[j_crit] = qmax[j_crit] if qd[j_crit] > qmax[j_crit] else qmin[j_crit]
        if np.linalg.matrix_rank(J * W) < m:
            break
    s, W, qN = best
    P = _pinv(J * W, damping)
    qd = qN + P @ (s * xdot - J @ qN)
    if np.any(qd < qmin - 1e-6) or np.any(qd > qmax + 1e-6):
        return np.clip(qd, qmin, qmax) * 0.0, 0.0
    return np.clip(qd, qmin, qmax), s


class AvoidanceController:
    """1 kHz joint-velocity controller with end-effector repulsion and body-point velocity bounds.

    Args:
        q_min, q_max, v_max: (n,) joint limits (rad, rad/s) of the controller's robot model.
        q0: (n,) initial joint positions.
        params: :class:`ControlParams`.
        dt: control period, s (0.001).
    """

    def __init__(
        self,
        q_min: np.ndarray,
        q_max: np.ndarray,
        v_max: np.ndarray,
        q0: np.ndarray,
        params: ControlParams | None = None,
        dt: float = 1e-3,
    ) -> None:
        self.p = params or ControlParams()
        self.q_min, self.q_max = np.asarray(q_min, float), np.asarray(q_max, float)
        self.v_max = np.asarray(v_max, float) * self.p.vel_scale
        self.dt = dt
        self.n = len(q0)
        self.q_cmd = np.asarray(q0, float).copy()
        self.qd_cmd = np.zeros(self.n)
        self.qdd_cmd = np.zeros(self.n)
        try:
            import ruckig

            self._rk = ruckig
            self._otg = ruckig.Ruckig(self.n, dt)
            self._inp = ruckig.InputParameter(self.n)
            self._out = ruckig.OutputParameter(self.n)
            self._inp.control_interface = ruckig.ControlInterface.Velocity
            self._inp.max_acceleration = [self.p.acc_max] * self.n
            self._inp.max_jerk = [self.p.jerk_max] * self.n
            self._inp.max_velocity = list(self.v_max)
        except ImportError:  # pragma: no cover
            self._otg = None

    def bounds(
        self,
        q: np.ndarray,
        body_J: np.ndarray | None,
        body_d: np.ndarray | None,
        body_dir: np.ndarray | None,
        avoid: bool,
    ) -> tuple[np.ndarray, np.ndarray, float]:
        """Joint-velocity bounds (eqs. 12-14 and position limits). Returns (qmin, qmax, max risk)."""
        vmax = self.v_max
        qmin, qmax = -vmax.copy(), vmax.copy()
        k = 5.0
        qmax = np.minimum(qmax, np.maximum(k * (self.q_max - self.p.limit_margin - q), 0.0))
        qmin = np.maximum(qmin, np.minimum(k * (self.q_min + self.p.limit_margin - q), 0.0))
        fmax = 0.0
        if avoid and body_J is not None and body_d is not None:
            for Jc, d, n in zip(body_J, body_d, body_dir, strict=True):
                if not np.isfinite(d):
                    continue
                f = 1.0 / (1.0 + np.exp((d * 2.0 / self.p.rho_body - 1.0) * self.p.alpha_body))
                fmax = max(fmax, f)
                s = Jc.T @ (-np.asarray(n)) * f
                lim = vmax * (1.0 - f)
                pos = s > 1e-4
                neg = s < -1e-4
                qmax[pos] = np.minimum(qmax[pos], lim[pos])
                qmin[neg] = np.maximum(qmin[neg], -lim[neg])
        return qmin, qmax, fmax

    def null_space_repulsion(self, J_ee: np.ndarray, body_J, body_d, body_dir) -> np.ndarray | None:
        """Joint velocity moving the body points away from obstacles, in the null space of the task.

        ``qdot_0 = sum_C J_C^T n_C v_b f(D_C)`` projected by ``I - J^# J``: the redundancy is used to move
        the body away (ICRA'12 §V-C: "exploiting kinematic redundancy"); eq. 14 still bounds the rest.
        """
        if body_J is None or body_d is None or self.p.body_repulsion <= 0:
            return None
        q0 = np.zeros(self.n)
        any_ = False
        for Jc, d, n in zip(body_J, body_d, body_dir, strict=True):
            if not np.isfinite(d):
                continue
            f = 1.0 / (1.0 + np.exp((d * 2.0 / self.p.rho_body - 1.0) * self.p.alpha_body))
            q0 += Jc.T @ np.asarray(n) * (self.p.body_repulsion * f)
            any_ = True
        if not any_:
            return None
        P = np.eye(self.n) - _pinv(J_ee, self.p.damping) @ J_ee
        return P @ q0

    def step(
        self,
        q: np.ndarray,
        J_ee: np.ndarray,
        xdot_task: np.ndarray,
        V_ee: np.ndarray | None,
        body_J: np.ndarray | None,
        body_d: np.ndarray | None,
        body_dir: np.ndarray | None,
        stale: bool,
        avoid: bool = True,
    ) -> tuple[np.ndarray, dict]:
        """One control cycle. Returns the joint position command (n,) and a status dict.

        Args:
            q: measured joint positions (n,).
            J_ee: (3, n) end-effector positional Jacobian.
            xdot_task: (3,) desired end-effector velocity, m/s.
            V_ee: (3,) repulsive velocity at the end effector (eq. 10), or None.
            body_J, body_d, body_dir: (K, 3, n), (K,), (K, 3) body control points' Jacobians, distances
                (inf = none) and repulsive directions.
            stale: the distances are too old or missing -> stop.
        """
        status = {"stale": bool(stale), "scale": 1.0, "risk": 0.0}
        if stale:
            target = np.zeros(self.n)
            status["scale"] = 0.0
        else:
            xc = np.asarray(xdot_task, float).copy()
            if avoid and V_ee is not None:
                xc = xc + V_ee
            qmin, qmax, fmax = self.bounds(q, body_J, body_d, body_dir, avoid)
            qns = self.null_space_repulsion(J_ee, body_J, body_d, body_dir) if avoid else None
            if qns is not None:
                qns = np.clip(qns, qmin, qmax)
                delta, scale = sns(J_ee, xc - J_ee @ qns, qmin - qns, qmax - qns, self.p.damping)
                target = qns + delta
            else:
                target, scale = sns(J_ee, xc, qmin, qmax, self.p.damping)
            status["scale"], status["risk"] = float(scale), float(fmax)
        self._follow(target)
        return self.q_cmd.copy(), status

    def _follow(self, target: np.ndarray) -> None:
        if self._otg is None:  # pragma: no cover - acceleration-limited fallback
            dv = np.clip(target - self.qd_cmd, -self.p.acc_max * self.dt, self.p.acc_max * self.dt)
            self.qd_cmd = self.qd_cmd + dv
            self.q_cmd = self.q_cmd + self.qd_cmd * self.dt
            return
        inp = self._inp
        inp.current_position = list(self.q_cmd)
        inp.current_velocity = list(self.qd_cmd)
        inp.current_acceleration = list(self.qdd_cmd)
        inp.target_velocity = list(np.clip(target, -self.v_max, self.v_max))
        inp.target_acceleration = [0.0] * self.n
        res = self._otg.update(inp, self._out)
        if res in (self._rk.Result.Working, self._rk.Result.Finished):
            self.q_cmd = np.array(self._out.new_position)
            self.qd_cmd = np.array(self._out.new_velocity)
            self.qdd_cmd = np.array(self._out.new_acceleration)
        else:  # an error: hold the velocity decaying (never continue blindly)
            self.qd_cmd *= 0.95
            self.qdd_cmd[:] = 0.0
            self.q_cmd = self.q_cmd + self.qd_cmd * self.dt
