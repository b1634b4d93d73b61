"""Stages 3 and 4 of the control cycle (:func:`depthguard.control.cycle.joint_bounds` and
:func:`~depthguard.control.cycle.plan_motion`) in one compiled call, :func:`plan_cycle`.

The numbers are those of the stage functions it replaces, in the same order and with the same
floating-point operations: the joint bounds (:func:`~depthguard.control.otg.joint_velocity_bounds`), the
chain kinematics (:mod:`depthguard.robot.fk`), the control points
(:func:`~depthguard.robot.fk.fixed_points`), the end effector's repulsive velocity (ICRA'12 eq. 7, as
:func:`~depthguard.control.endeffector.repulsive_velocity`), the commanded task velocity (eq. 10), the body
bounds (eqs. 12-14, :func:`~depthguard.control.body.body_bounds_inplace`, on both pairs of bounds), the
damped-least-squares damping, for speed and separation monitoring the task's nominal joint velocity
(:func:`~depthguard.control.endeffector.dls_apply`) and the monitor's update
(:func:`depthguard.control.ssm.SsmMonitor.update`), and SNS
(:func:`~depthguard.control.sns.sns_velocity_unchecked`). ``tests/test_plan_kernel.py`` checks every
output against the stage functions.

Why: each stage alone is a small kernel or a few numpy calls of 1-3 µs of call overhead; at 1 kHz that
glue was about a third of the cycle (BENCHMARKS.md, "The control cycle in fewer calls"); returning
new arrays costs about 1 µs each, so :func:`plan_cycle` writes its arrays into one buffer.

Parameter vector ``prm`` (float64, 8): ``v_rep_max, rho_ee, alpha_ee, rho_body, alpha_body,
contact_distance, dls_eps, dls_lambda_max``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from depthguard.control.body import body_bounds_inplace
from depthguard.control.endeffector import _dls_apply, _dls_damping, repulsive_velocity_kernel
from depthguard.control.otg import joint_velocity_bounds
from depthguard.control.sns import sns_velocity_unchecked
from depthguard.control.ssm_kernels import _update
from depthguard.robot.fk import _chain_fk, fixed_points

__all__ = ["plan_prepare", "plan_cycle", "plan_params", "both_finite", "cycle_layout"]

_INFLUENCE_EPS = 1e-6  # as plan_motion: joints that cannot move a point along its direction are not bound


def plan_params(cfg) -> np.ndarray:
    """The ``prm`` vector (module docstring) of a :class:`~depthguard.control.types.ControllerConfig`."""
    return np.array(
        [cfg.v_rep_max, cfg.rho_ee, cfg.alpha_ee, cfg.rho_body, cfg.alpha_body, cfg.contact_distance,
         cfg.dls_eps, cfg.dls_lambda_max],
        dtype=np.float64,
    )  # fmt: skip


@njit(cache=True, nogil=True)
def plan_prepare(
    q, parent, idx_v, kind, axis, placement, joints, offsets, support,
    dist, dirs, body_use, v_max, xdot_d, prm, repel, nominal, lo, hi, lo_s, hi_s,
):  # fmt: skip
    """Kinematics, control points, repulsion, body bounds (``lo``/``hi``/``lo_s``/``hi_s`` tightened in
    place), damping and (if ``nominal``) the nominal joint velocity.

    Args:
        q: (n,) finite joint positions, rad; parent..placement: the chain of
            :class:`~depthguard.robot.fk.ChainKinematics`; joints, offsets, support: the control points'
            joint slots (N,), offsets (N, 3) m and supporting joints (N, n) bool.
        dist: (N,) distances (finite or +inf), m; dirs: (N, 3) directions (finite where dist is finite).
        body_use: (N,) bool, the points that bound the body; v_max: (n,) rad/s; xdot_d: (3,) m/s.
        prm: the parameter vector (module docstring); repel: add the end effector's repulsion (eq. 10).
    Returns:
        ``(jac, J, lam, xdot_c, v_rep, qdot_nominal)``: the points' Jacobians (N, 3, n), the end effector's
        (3, n) (a copy), the DLS damping, the commanded task velocity (3,), the repulsive velocity (3,)
        and ``J^T (J J^T + lam^2 I)^-1 xdot_c`` (n,) (zeros unless ``nominal``).
    """
    H, Jw = _chain_fk(q, parent, idx_v, kind, axis, placement)
    _, jac = fixed_points(H, joints, offsets, Jw, support)
    xdot_c = xdot_d.copy()
    if repel:
        v_rep = repulsive_velocity_kernel(dist[0], dirs[0], prm[0], prm[1], prm[2])
        for i in range(3):
            xdot_c[i] += v_rep[i]
    else:
        v_rep = np.zeros(3)
    dist0 = np.maximum(dist, 0.0)
    body_bounds_inplace(jac, dist0, dirs, body_use, v_max, prm[3], prm[4], prm[5], _INFLUENCE_EPS, lo, hi)
    body_bounds_inplace(jac, dist0, dirs, body_use, v_max, prm[3], prm[4], prm[5], _INFLUENCE_EPS, lo_s, hi_s)
    J = jac[0].copy()
    lam = _dls_damping(J, prm[6], prm[7])
    qn = _dls_apply(J, lam, xdot_c) if nominal else np.zeros(q.shape[0])
    return jac, J, lam, xdot_c, v_rep, qn


def cycle_layout(n: int, N: int, m: int = 3) -> dict[str, slice]:
    """Where :func:`plan_cycle` writes its arrays in its ``out`` buffer (float64); ``"size"``: all of it,
    ``3 n + m + 3 N``."""
    sizes = (("lo", n), ("hi", n), ("target", n), ("xdot_c", m), ("separation", N), ("s_p", N), ("margin", N))
    layout, at = {}, 0
    for name, size in sizes:
        layout[name] = slice(at, at + size)
        at += size
    layout["size"] = slice(0, at)
    return layout


@njit(cache=True, nogil=True)
def plan_cycle(
    q, v, acc, parent, idx_v, kind, axis, placement, joints, offsets, support,
    dist, dirs, mdist, mdirs, body_use, q_min, q_max, v_max, a_max, j_max, xdot_d, prm, jprm, repel,
    monitor, evades, lengths, mprm, v_h, sensing_range, hysteresis, stopped, age, out,
):  # fmt: skip
    """Stages 3 and 4 of the control cycle in one call, for valid inputs: the joint bounds
    (:func:`~depthguard.control.otg.joint_velocity_bounds` at ``q`` with the motion ``v``; ``jprm`` =
    ``(latency, position_margin, plan_ahead)``), :func:`plan_prepare`, when ``monitor`` the separation
    monitor (:func:`depthguard.control.ssm_kernels._update` on ``mdist``/``mdirs`` with the current ``v``, ``acc``;
    its parameters ``lengths, mprm, v_h, sensing_range, hysteresis, stopped, age`` from
    :meth:`~depthguard.control.ssm.SsmMonitor.kernel_inputs`), the task scaled by it (or, in a protective
    stop with ``evades``, the end effector's repulsion alone), and SNS.

    Writes ``out`` (:func:`cycle_layout`): the cycle's bounds ``lo``/``hi`` (body bounds included), the SNS
    target, the commanded task velocity and, with a monitor, its separation, ``S_p`` and margin. Returns
    ``(scale, ssm_s, stopped, stop_ended, T_s, binding, finite)``: the SNS scale; the monitor's scale
    (-1: protective stop), latched stop, stop ended, stopping time and binding point (unused without a
    monitor); ``finite``: target and task velocity are finite.
    """
    n, N, m = q.shape[0], dist.shape[0], xdot_d.shape[0]
    lo, hi, lo_s, hi_s = joint_velocity_bounds(q, v, q_min, q_max, v_max, a_max, j_max, jprm[0], jprm[1], jprm[2])
    jac, J, lam, xdot_c, v_rep, nominal = plan_prepare(
        q, parent, idx_v, kind, axis, placement, joints, offsets, support,
        dist, dirs, body_use, v_max, xdot_d, prm, repel, monitor, lo, hi, lo_s, hi_s,
    )  # fmt: skip
    s, ended, T_s, binding = 1.0, False, 0.0, -1
    o_sep, o_sp = 3 * n + m, 3 * n + m + N
    if monitor:
        s, stopped, ended, T_s, binding = _update(
            jac, v, acc, nominal, mdist, mdirs, sensing_range, lengths, a_max, j_max, v_h, mprm, stopped,
            hysteresis, out[o_sep : o_sep + N], out[o_sp : o_sp + N], age,
        )  # fmt: skip
        for k in range(N):
            out[o_sp + N + k] = out[o_sep + k] - out[o_sp + k]
        if max(s, 0.0) <= 0.0 and evades:  # protective stop: no task, the repulsion may still evade
            for i in range(m):
                xdot_c[i] = v_rep[i] + 0.0
        else:
            for i in range(m):
                xdot_c[i] *= max(s, 0.0)
    target, scale = sns_velocity_unchecked(J, xdot_c, lo_s, hi_s, lam)
    for i in range(n):
        out[i], out[n + i], out[2 * n + i] = lo[i], hi[i], target[i]
    for i in range(m):
        out[3 * n + i] = xdot_c[i]
    return scale, s, stopped, ended, T_s, binding, both_finite(target, xdot_c)


@njit(cache=True, nogil=True)
def both_finite(a: np.ndarray, b: np.ndarray) -> bool:
    """True if every element of the 1-D float arrays ``a`` and ``b`` is finite (one call for the cycle's
    check of its plan)."""
    for i in range(a.shape[0]):
        if not np.isfinite(a[i]):
            return False
    for i in range(b.shape[0]):
        if not np.isfinite(b[i]):
            return False
    return True
