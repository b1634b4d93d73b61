"""Compiled kernels of the momentum observer (:class:`depthguard.robot.residual.MomentumObserver`).

* :func:`_observer_step` / :func:`_checked_observer_step`: one discrete residual update from pinocchio's
  ``M``, ``C``, ``g`` (the default);
* :func:`_momentum_terms` / :func:`_chain_observer_step`: ``p = M q̇`` and ``Cᵀ q̇ - g`` of a chain of
  one-coordinate joints in one O(n) pass, without forming M or C (``MomentumObserver(terms="compiled")``;
  equal to pinocchio's to rounding, ``tests/test_residual.py``).

The equations and the discrete-time integration are in :mod:`depthguard.robot.residual`'s docstring.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from depthguard.robot.fk import _chain_fk_into, _unpack_chain

__all__: list[str] = []


@njit(cache=True, nogil=True)
def _observer_step(M, C, g, qd, tau, par, h, average, first, state):  # pragma: no cover - compiled
    """One discrete residual update (module docstring), in place on ``state`` (5, n): the integral I,
    p(0), β of the previous sample, τ of the previous sample, r. ``par`` (3, n): armature, damping D,
    gain K_I. ``M`` is read from its upper triangle (what pinocchio's crba always fills); ``first``
    initialises p(0) and β and gives r = 0. Returns a copy of r (n,)."""
    n = qd.shape[0]
    out = np.empty(n)
    for i in range(n):
        p = par[0, i] * qd[i]  # (M + diag(armature)) q̇
        beta = -g[i] - par[1, i] * qd[i]  # Cᵀ q̇ - g - D q̇
        for j in range(n):
            p += (M[i, j] if i <= j else M[j, i]) * qd[j]
            beta += C[j, i] * qd[j]
        _observer_update(i, p, beta, tau, par, h, average, first, state)
        out[i] = state[4, i]
    return out


@njit(cache=True, nogil=True)
def _observer_update(i, p, beta, tau, par, h, average, first, state):  # pragma: no cover - compiled
    """The update of joint ``i`` from its momentum ``p`` and ``β = Cᵀ q̇ - g - D q̇`` (:func:`_observer_step`)."""
    if first:
        state[0, i], state[1, i], state[2, i], state[3, i], state[4, i] = 0.0, p, beta, tau[i], 0.0
    else:
        tau_int = tau[i] * h if average else 0.5 * h * (tau[i] + state[3, i])
        partial = state[0, i] + tau_int + 0.5 * h * (beta + state[2, i]) + 0.5 * h * state[4, i]
        gain = par[2, i]
        r = gain * (p - state[1, i] - partial) / (1.0 + 0.5 * gain * h)
        state[0, i], state[2, i], state[3, i], state[4, i] = partial + 0.5 * h * r, beta, tau[i], r


@njit(cache=True, nogil=True)
def _checked_observer_step(M, C, g, q, qd, tau, par, h, average, first, state, out):  # pragma: no cover
    """:func:`_observer_step` with r written into ``out`` (n,), after checking that ``q``, ``qd`` and ``tau``
    (n,) are finite; with a NaN or an inf among them it returns False and leaves ``state`` untouched (the
    caller then raises)."""
    for i in range(qd.shape[0]):
        if not (np.isfinite(q[i]) and np.isfinite(qd[i]) and np.isfinite(tau[i])):
            return False
    out[:] = _observer_step(M, C, g, qd, tau, par, h, average, first, state)
    return True


@njit(cache=True, nogil=True)
def _momentum_terms(q, qd, parent, idx_v, kind, axis, placement, body, p_out, b_out):  # pragma: no cover
    """``p = M q̇`` into ``p_out`` (n,) and ``Cᵀ q̇ - g`` into ``b_out`` (n,) of a chain of one-coordinate
    joints (:class:`~depthguard.robot.fk.ChainKinematics`' arrays), without forming M or C.

    World frame, spatial vectors (linear, angular) about the world origin; ``S_i`` the joint's column of
    the WORLD joint Jacobian, ``v_i`` body i's velocity, ``H_i`` the spatial momentum of the bodies that
    joint i carries (its subtree), ``W_i`` their gravity wrench. With ``T = ½ q̇ᵀ M q̇`` the kinetic and ``U``
    the potential energy, ``p_i = S_iᵀ H_i``, ``(Cᵀ q̇)_i = ∂T/∂q_i = -S_iᵀ (v_i ×* H_i)`` (moving joint i
    turns its subtree about ``S_i``; the ``Ṁ = C + Cᵀ`` factorisation gives ``Cᵀ q̇ = Ṁ q̇ - C q̇ = ∂T/∂q``)
    and ``g_i = ∂U/∂q_i = -S_iᵀ W_i``. ``body`` (J, 13): row 0 the gravity (3); row j, joint j's body: mass,
    centre of mass (3) and rotational inertia about it (3 × 3, row-major), in the joint frame."""
    nj = parent.shape[0]
    H = np.zeros((nj, 4, 4))
    Jw = np.zeros((6, q.shape[0]))
    _chain_fk_into(q, parent, idx_v, kind, axis, placement, H, Jw)
    V = np.zeros((nj, 6))  # body velocity
    Hm = np.zeros((nj, 6))  # spatial momentum, then summed over the subtree
    Wg = np.zeros((nj, 6))  # gravity wrench, likewise
    g0, g1, g2 = body[0, 0], body[0, 1], body[0, 2]
    for j in range(1, nj):
        col, pj = idx_v[j], parent[j]
        for a in range(6):
            V[j, a] = V[pj, a] + Jw[a, col] * qd[col]
        m, lx, ly, lz = body[j, 0], body[j, 1], body[j, 2], body[j, 3]
        T = H[j]
        c0 = T[0, 0] * lx + T[0, 1] * ly + T[0, 2] * lz + T[0, 3]  # centre of mass, world
        c1 = T[1, 0] * lx + T[1, 1] * ly + T[1, 2] * lz + T[1, 3]
        c2 = T[2, 0] * lx + T[2, 1] * ly + T[2, 2] * lz + T[2, 3]
        v0, v1, v2, w0, w1, w2 = V[j, 0], V[j, 1], V[j, 2], V[j, 3], V[j, 4], V[j, 5]
        l0 = m * (v0 + w1 * c2 - w2 * c1)  # linear momentum m (v_O + ω × c)
        l1 = m * (v1 + w2 * c0 - w0 * c2)
        l2 = m * (v2 + w0 * c1 - w1 * c0)
        b0 = T[0, 0] * w0 + T[1, 0] * w1 + T[2, 0] * w2  # ω in the joint frame
        b1 = T[0, 1] * w0 + T[1, 1] * w1 + T[2, 1] * w2
        b2 = T[0, 2] * w0 + T[1, 2] * w1 + T[2, 2] * w2
        i0 = body[j, 4] * b0 + body[j, 5] * b1 + body[j, 6] * b2  # I_c ω, joint frame
        i1 = body[j, 7] * b0 + body[j, 8] * b1 + body[j, 9] * b2
        i2 = body[j, 10] * b0 + body[j, 11] * b1 + body[j, 12] * b2
        Hm[j, 0], Hm[j, 1], Hm[j, 2] = l0, l1, l2
        Hm[j, 3] = T[0, 0] * i0 + T[0, 1] * i1 + T[0, 2] * i2 + c1 * l2 - c2 * l1  # R I_c Rᵀ ω + c × l
        Hm[j, 4] = T[1, 0] * i0 + T[1, 1] * i1 + T[1, 2] * i2 + c2 * l0 - c0 * l2
        Hm[j, 5] = T[2, 0] * i0 + T[2, 1] * i1 + T[2, 2] * i2 + c0 * l1 - c1 * l0
        f0, f1, f2 = m * g0, m * g1, m * g2
        Wg[j, 0], Wg[j, 1], Wg[j, 2] = f0, f1, f2
        Wg[j, 3], Wg[j, 4], Wg[j, 5] = c1 * f2 - c2 * f1, c2 * f0 - c0 * f2, c0 * f1 - c1 * f0
    for j in range(nj - 1, 0, -1):  # children before parents (pinocchio numbers parents first)
        col, pj = idx_v[j], parent[j]
        s0, s1, s2, s3, s4, s5 = Jw[0, col], Jw[1, col], Jw[2, col], Jw[3, col], Jw[4, col], Jw[5, col]
        hl0, hl1, hl2, ha0, ha1, ha2 = Hm[j, 0], Hm[j, 1], Hm[j, 2], Hm[j, 3], Hm[j, 4], Hm[j, 5]
        v0, v1, v2, w0, w1, w2 = V[j, 0], V[j, 1], V[j, 2], V[j, 3], V[j, 4], V[j, 5]
        p_out[col] = s0 * hl0 + s1 * hl1 + s2 * hl2 + s3 * ha0 + s4 * ha1 + s5 * ha2
        x0, x1, x2 = w1 * hl2 - w2 * hl1, w2 * hl0 - w0 * hl2, w0 * hl1 - w1 * hl0  # v ×* H: (ω × l,
        y0 = w1 * ha2 - w2 * ha1 + v1 * hl2 - v2 * hl1  # ω × L + v_O × l)
        y1 = w2 * ha0 - w0 * ha2 + v2 * hl0 - v0 * hl2
        y2 = w0 * ha1 - w1 * ha0 + v0 * hl1 - v1 * hl0
        ctqd = -(s0 * x0 + s1 * x1 + s2 * x2 + s3 * y0 + s4 * y1 + s5 * y2)
        grav = s0 * Wg[j, 0] + s1 * Wg[j, 1] + s2 * Wg[j, 2] + s3 * Wg[j, 3] + s4 * Wg[j, 4] + s5 * Wg[j, 5]
        b_out[col] = ctqd + grav  # Cᵀ q̇ - g, g = -S·W
        for a in range(6):
            Hm[pj, a] += Hm[j, a]
            Wg[pj, a] += Wg[j, a]


@njit(cache=True, nogil=True)
def _chain_observer_step(q, qd, tau, ints, floats, h, first, state, out):  # pragma: no cover - compiled
    """:func:`_checked_observer_step` with ``p`` and ``Cᵀ q̇ - g`` from :func:`_momentum_terms` instead of
    pinocchio's M, C and g: one compiled call. ``ints``, ``floats``: the chain packed with
    :func:`~depthguard.robot.fk._pack_chain`, with the τ mode (1: average) and the bodies (J, 13) then
    ``par`` (3, n) appended (:func:`_chain_dynamics`)."""
    n = qd.shape[0]
    for i in range(n):
        if not (np.isfinite(q[i]) and np.isfinite(qd[i]) and np.isfinite(tau[i])):
            return False
    parent, idx_v, kind, axis, placement, extra_i, extra_f = _unpack_chain(ints, floats)
    nj = parent.shape[0]
    body = extra_f[: 13 * nj].reshape((nj, 13))
    par = extra_f[13 * nj : 13 * nj + 3 * n].reshape((3, n))
    average = extra_i[0] != 0
    p = np.empty(n)
    b = np.empty(n)
    _momentum_terms(q, qd, parent, idx_v, kind, axis, placement, body, p, b)
    for i in range(n):
        _observer_update(i, par[0, i] * qd[i] + p[i], b[i] - par[1, i] * qd[i], tau, par, h, average, first, state)
        out[i] = state[4, i]
    return True


def _body_array(model) -> np.ndarray:
    """(J, 13) what :func:`_momentum_terms` reads of a pinocchio model: row 0 the gravity, row j the mass,
    centre of mass and rotational inertia of joint j's body (joint frame)."""
    nj = int(model.njoints)
    body = np.zeros((nj, 13))
    body[0, :3] = np.asarray(model.gravity.linear)
    for j in range(1, nj):
        inertia = model.inertias[j]
        body[j, 0] = inertia.mass
        body[j, 1:4] = np.asarray(inertia.lever)
        body[j, 4:] = np.asarray(inertia.inertia).reshape(9)
    return body
