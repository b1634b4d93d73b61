"""Contact force estimation from the residual (SAPHARI D4.1.1 §6.1).

With the residual ``r ≈ τ_ext = J_cᵀ(q) F_c`` (3-D forces at known contact points, no moments), the
force is estimated by pseudo-inversion, for one contact or for several at once (stacked form)::

    F̂_c = (J_cᵀ)^# r,            (F̂_1; F̂_2) = (J_1ᵀ  J_2ᵀ)^# r

Let ``A = (J_1ᵀ … J_kᵀ)`` (n × 3k). Only the part of the force in the range of ``Aᵀ`` is observable:
forces in the null space of ``A`` produce no joint torque, so the residual cannot see them (the
deliverable notes that they do no work and are absorbed by the structure). :class:`ForceEstimate` reports
that null space (``unobservable``) and the projector onto the observable subspace; force errors are
compared on the observable projection only (:func:`observable_error`).

Near singular contact Jacobians the pseudo-inverse is damped, direction by direction (a selective form
of the Nakamura/Maciejewski variable damping): with the singular values σ_i of ``A``,
``F̂ = Σ σ_i / (σ_i² + λ_i²) v_i u_iᵀ r`` and ``λ_i² = λ_max² (1 - (σ_i/ε)²)`` when ``σ_i < ε``, 0
otherwise, so that well-conditioned directions stay exact while a weak one cannot amplify torque noise.
It is computed from the eigen-decomposition of the small Gram matrix ``AᵀA`` (3k × 3k).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

__all__ = ["ForceEstimate", "estimate_contact_forces", "point_jacobian", "observable_error"]

_JOINT_OF_LINK: dict[int, dict[str, int]] = {}


class ForceEstimate(NamedTuple):
    """Result of :func:`estimate_contact_forces` for k contacts.

    Attributes:
        forces: (k, 3) estimated contact forces in the world frame, N.
        stacked: (3k,) the same, stacked.
        singular_values: (3k,) singular values of ``A = (J_1ᵀ … J_kᵀ)``, descending (m per N m/N).
        unobservable: (3k, u) orthonormal basis of the force directions the residual cannot see
            (singular value below ``tol`` times the largest), possibly with ``u = 0`` columns.
        projector: (3k, 3k) projector onto the observable force subspace.
        damping: the largest damping λ_i² that was used (0 when well conditioned).
    """

    forces: np.ndarray
    stacked: np.ndarray
    singular_values: np.ndarray
    unobservable: np.ndarray
    projector: np.ndarray
    damping: float


def point_jacobian(model, q: np.ndarray, link: str, point_world: np.ndarray, update: bool = True) -> np.ndarray:
    """(3, n) positional Jacobian of the point ``point_world`` (3,) m rigidly attached to ``link``.

    Args:
        model: a :class:`depthguard.robot.model.RobotModel`.
        q: (n,) joint positions, rad.
        link: the link (pinocchio BODY frame) the point belongs to.
        point_world: (3,) the point's current world position, m.
        update: run ``computeJointJacobians`` first (pass False when already done for this ``q``).
    """
    import pinocchio as pin

    if update:
        pin.computeJointJacobians(model.model, model.data, q)
    cache = _JOINT_OF_LINK.setdefault(id(model), {})
    jid = cache.get(link)
    if jid is None:
        jid = cache[link] = int(model.model.frames[model.frame_id(link)].parentJoint)
    J = pin.getJointJacobian(model.model, model.data, jid, pin.LOCAL_WORLD_ALIGNED)
    dx, dy, dz = np.asarray(point_world, float) - model.data.oMi[jid].translation
    # v_p = v_o + ω × d  ->  J_v + [ω]× d = J_v - [d]× J_ω
    Jw = J[3:]
    return J[:3] + np.array([[0.0, dz, -dy], [-dz, 0.0, dx], [dy, -dx, 0.0]]) @ Jw


def estimate_contact_forces(
    jacobians: list[np.ndarray] | np.ndarray,
    r: np.ndarray,
    eps: float = 0.005,
    lambda_max: float = 0.02,
    tol: float = 1e-3,
) -> ForceEstimate:
    """Contact forces from the residual ``r`` (n,) N m and the contact Jacobians (each (3, n)).

    Args:
        jacobians: k positional contact Jacobians (3, n), or one (3, n) array.
        r: (n,) residual (≈ external joint torque), N m.
        eps: smallest singular value (m, an effective lever arm) below which damping starts: 5 mm keeps
            the well-observable directions of two contacts on one arm exact (their weakest singular value
            is about 1 cm on the LWR) and damps only true near-singularities.
        lambda_max: largest damping factor λ (m).
        tol: relative singular value below which a direction is reported unobservable.
    """
    if isinstance(jacobians, np.ndarray) and jacobians.ndim == 2:
        A = jacobians.T
        n = A.shape[0]
        if jacobians.shape[0] != 3:
            raise ValueError(f"jacobians must all be finite with shape (3, n), got {[jacobians.shape]}")
    else:
        Js = [np.asarray(J, float) for J in jacobians]
        if not Js or Js[0].ndim != 2:
            raise ValueError("jacobians must be one (3, n) array or a list of them")
        n = Js[0].shape[1]
        if any(J.shape != (3, n) for J in Js):
            raise ValueError(f"jacobians must all be finite with shape (3, n), got {[J.shape for J in Js]}")
        A = np.vstack(Js).T  # (n, 3k) = (J_1ᵀ … J_kᵀ)
    r = np.asarray(r, float)
    if r.shape != (n,):
        raise ValueError(f"r must be finite with shape ({n},), got shape {r.shape}")
    out = _estimate_kernel(np.ascontiguousarray(A, dtype=float), r, float(eps), float(lambda_max), float(tol))
    if out is None:
        raise ValueError("jacobians and r must be finite (no NaN or inf)")
    stacked, sig, U, P, lam2 = out
    return ForceEstimate(stacked.reshape(-1, 3), stacked, sig, U, P, lam2)


@njit(cache=True)
def _estimate_kernel(A, r, eps, lambda_max, tol):
    """Selectively damped ``A^# r`` from the eigen-decomposition of ``AᵀA`` (module docstring).

    Returns (F (m,), σ descending (m,), unobservable basis (m, u), projector (m, m), max λ²), or None when
    the input is not finite."""
    if not (np.all(np.isfinite(A)) and np.all(np.isfinite(r))):
        return None
    m = A.shape[1]
    w, V = np.linalg.eigh(A.T @ A)  # ascending σ²
    w = np.maximum(w, 0.0)
    sig = np.sqrt(w)
    lam2 = np.zeros(m)
    inv = np.zeros(m)
    for i in range(m):
        if sig[i] < eps:
            lam2[i] = lambda_max**2 * (1.0 - (sig[i] / eps) ** 2)
        den = w[i] + lam2[i]
        if den > 1e-300:
            inv[i] = 1.0 / den
    F = V @ (inv * (V.T @ (A.T @ r)))
    smax = max(sig[m - 1], 1e-300)
    nbad = 0
    for i in range(m):
        if sig[i] < tol * smax:
            nbad += 1
    U = np.empty((m, nbad))
    k = 0
    for i in range(m):
        if sig[i] < tol * smax:
            U[:, k] = V[:, i]
            k += 1
    P = np.eye(m) - U @ U.T
    return F, sig[::-1].copy(), U, P, lam2.max()


def observable_error(est: ForceEstimate, applied: np.ndarray) -> tuple[np.ndarray, float]:
    """Error of the estimate against the observable part of the ``applied`` forces ((k, 3) or (3k,), N).

    Returns ``(error (3k,), observable_fraction)``: ``F̂ - P F`` with ``P`` the projector onto the range of
    ``Aᵀ``, and ``‖P F‖ / ‖F‖`` (1 = fully observable).
    """
    F = np.asarray(applied, float).ravel()
    PF = est.projector @ F
    nf = float(np.linalg.norm(F))
    return est.stacked - PF, (float(np.linalg.norm(PF)) / nf if nf > 0 else 1.0)
