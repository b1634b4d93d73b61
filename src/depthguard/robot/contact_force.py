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
It is computed from the eigen-decomposition of the small Gram matrix ``AᵀA`` (3k × 3k), by Jacobi
rotations (:func:`sym_eig_jacobi`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from depthguard.robot.fk import ChainKinematics, _pack_chain, checked_point_jacobian, world_point_jacobian
from depthguard.validation import is_real_scalar, real_array

__all__ = ["ForceEstimate", "estimate_contact_forces", "point_jacobian", "observable_error", "sym_eig_jacobi"]

_F64 = np.dtype(np.float64)
_tuple_new = tuple.__new__  # builds the ForceEstimate without its Python-level __new__


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
        update: compute the kinematics at ``q`` (False: ``computeJointJacobians`` already ran on the
            model's pinocchio buffer for this ``q``, and its ``data.J`` is used).
    """
    try:
        entry = model._contact_link_entries[link]
    except (AttributeError, KeyError):
        entry = _link_entry(model, link)
    jid, support, chain = entry
    p = point_world if type(point_world) is np.ndarray and point_world.dtype is _F64 else np.asarray(point_world, float)
    if p.shape != (3,):
        raise ValueError(f"point_world must have shape (3,), got shape {p.shape}")
    if update:  # the compiled kinematics (depthguard.robot.fk), WORLD joint Jacobian
        if chain is not None and type(q) is np.ndarray and q.dtype is _F64 and q.shape == chain[0]:
            J = np.zeros(chain[1])
            if checked_point_jacobian(q, p, chain[2], chain[3], J):  # False: q is not finite
                return J
        _, Jw = model.joint_kinematics(model.check_q(q))
    else:  # computeJointJacobians already ran on model.data for this q
        Jw = model.world_jacobian()  # ((6, n) also for a 1-DOF robot, whose data.J pinocchio gives as (6,))
    return world_point_jacobian(Jw, p, support)


def _link_entry(model, link: str) -> tuple:
    """``(parent joint, its support mask (n,), compiled-chain arguments or None)`` of ``link``, cached on
    the model (``model._contact_link_entries``) where it takes attributes."""
    jid = int(model.model.frames[model.frame_id(link)].parentJoint)
    from depthguard.robot.model import RobotModel

    support = model.joint_support_mask(jid)
    args = None  # what checked_point_jacobian needs when joint_kinematics is RobotModel's compiled one
    if isinstance(model, RobotModel) and type(model).joint_kinematics is RobotModel.joint_kinematics:
        chain = model._chain_kinematics
        if isinstance(chain, ChainKinematics):
            n = chain.n_dof
            args = ((n,), (3, n), *_pack_chain(chain, ints=support))
    entry = (jid, support, args)
    try:
        entries = model.__dict__.setdefault("_contact_link_entries", {})
    except AttributeError:  # no instance dict: not cached
        return entry
    entries[link] = entry
    return entry


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
        tol: relative singular value below which a direction is reported unobservable; without damping
            (``lambda_max = 0``) such a direction gets no force (the pseudo-inverse's rank cut-off: its σ_i is
            rounding noise).
    Raises:
        ValueError: Jacobians or ``r`` of the wrong shape, not numbers (strings, bools, complex) or not finite,
            or so large that the estimate overflows; ``eps`` not a finite number > 0, ``lambda_max`` not a
            finite number >= 0, ``tol`` not in [0, 1) (each a real number, not a bool or a string).
    """
    if not (type(eps) is float and type(lambda_max) is float and type(tol) is float):
        for x, name in ((eps, "eps"), (lambda_max, "lambda_max"), (tol, "tol")):
            if not is_real_scalar(x):
                raise ValueError(f"{name} must be a real number, got {x!r}")
    if not (0.0 < eps < math.inf):
        raise ValueError(f"eps must be a positive finite lever arm in metres, got {eps!r}")
    if not (0.0 <= lambda_max < math.inf):
        raise ValueError(f"lambda_max must be a finite damping factor >= 0 m, got {lambda_max!r}")
    if not (0.0 <= tol < 1.0):
        raise ValueError(f"tol must be a relative singular value in [0, 1), got {tol!r}")
    if type(jacobians) is np.ndarray and jacobians.ndim == 2:  # one contact: Aᵀ = J_c
        At = jacobians if jacobians.dtype is _F64 else real_array(jacobians, "jacobians", "(3, n) arrays")
        if At.shape[0] != 3:
            raise ValueError(f"jacobians must all be finite with shape (3, n), got {[jacobians.shape]}")
    else:
        Js = [
            J if type(J) is np.ndarray and J.dtype is _F64 else real_array(J, "jacobians", "(3, n) arrays")
            for J in jacobians
        ]
        if not Js or Js[0].ndim != 2:
            raise ValueError("jacobians must be one (3, n) array or a list of them")
        n = Js[0].shape[1]
        if any(J.shape != (3, n) for J in Js):
            raise ValueError(f"jacobians must all be finite with shape (3, n), got {[J.shape for J in Js]}")
        At = np.vstack(Js)  # (3k, n) = Aᵀ with A = (J_1ᵀ … J_kᵀ)
    m, n = At.shape
    if type(r) is not np.ndarray or r.dtype is not _F64:
        r = real_array(r, "r", "an (n,) array")
    if r.shape != (n,):
        raise ValueError(f"r must be finite with shape ({n},), got shape {r.shape}")
    out = np.empty((3 + 2 * m, m))  # rows: F, σ, λ², the projector (m rows), the unobservable directions
    nbad = _estimate_kernel(np.ascontiguousarray(At), r, float(eps), float(lambda_max), float(tol), out)
    if nbad < 0:
        if nbad == -2:
            raise ValueError("jacobians and r are so large that the force estimate overflows (not finite)")
        raise ValueError("jacobians and r must be finite (no NaN or inf)")
    stacked = out[0]
    return _tuple_new(
        ForceEstimate, (stacked.reshape(-1, 3), stacked, out[1], out[3 + m : 3 + m + nbad].T, out[3 : 3 + m], out[2, 0])
    )


@njit(cache=True, nogil=True)
def sym_eig_jacobi(S: np.ndarray, max_sweeps: int = 60) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover
    """Eigenvalues (m,) ascending and orthonormal eigenvectors (m, m) (columns) of a small symmetric
    matrix ``S`` (m, m), by cyclic Jacobi rotations (Golub & Van Loan, Matrix Computations, §8.5).

    For the 3×3 or 6×6 Gram matrices of the contact Jacobians this takes well under a microsecond, where a
    LAPACK call (``np.linalg.eigh``) costs about 5 µs of set-up; accurate to a few ulp of ``‖S‖`` like it.
    """
    m = S.shape[0]
    A = S.copy()
    V = np.eye(m)
    total = 0.0
    for i in range(m):
        for j in range(m):
            total += A[i, j] * A[i, j]
    for _ in range(max_sweeps):
        off = 0.0
        for p in range(m - 1):
            for q in range(p + 1, m):
                off += A[p, q] * A[p, q]
        if off <= 1e-30 * total:
            break
        for p in range(m - 1):
            for q in range(p + 1, m):
                apq = A[p, q]
                if apq == 0.0:
                    continue
                theta = (A[q, q] - A[p, p]) / (2.0 * apq)
                t = 1.0 / (abs(theta) + np.sqrt(theta * theta + 1.0))
                if theta < 0.0:
                    t = -t
                c = 1.0 / np.sqrt(t * t + 1.0)
                s = t * c
                for k in range(m):  # A J
                    akp, akq = A[k, p], A[k, q]
                    A[k, p], A[k, q] = c * akp - s * akq, s * akp + c * akq
                for k in range(m):  # Jᵀ (A J)
                    apk, aqk = A[p, k], A[q, k]
                    A[p, k], A[q, k] = c * apk - s * aqk, s * apk + c * aqk
                for k in range(m):  # V J
                    vkp, vkq = V[k, p], V[k, q]
                    V[k, p], V[k, q] = c * vkp - s * vkq, s * vkp + c * vkq
    w = np.empty(m)
    for i in range(m):
        w[i] = A[i, i]
    order = np.argsort(w)
    return w[order].copy(), V[:, order].copy()


@njit(cache=True, nogil=True)
def _estimate_kernel(At, r, eps, lambda_max, tol, out):  # pragma: no cover - compiled
    """Selectively damped ``A^# r`` from the eigen-decomposition of ``AᵀA`` (module docstring), with
    ``At`` = Aᵀ (m, n). Writes into ``out`` (3 + 2m, m): row 0 F, row 1 σ descending, ``out[2, 0]`` the
    largest λ², rows 3..3+m the projector, then the u unobservable directions (one a row). Returns u, or
    -1 when the input is not finite, -2 when the result overflows."""
    m, n = At.shape
    for k in range(n):
        if not np.isfinite(r[k]):
            return -1
        for i in range(m):
            if not np.isfinite(At[i, k]):
                return -1
    G = np.zeros((m, m))
    Ar = np.zeros(m)
    for i in range(m):
        for k in range(n):
            Ar[i] += At[i, k] * r[k]
        for j in range(i, m):
            v = 0.0
            for k in range(n):
                v += At[i, k] * At[j, k]
            G[i, j] = v
            G[j, i] = v
    w, V = sym_eig_jacobi(G)  # ascending σ²
    sig = np.sqrt(np.maximum(w, 0.0))
    smax = max(sig[m - 1], 1e-300)
    lam2_max = 0.0
    coef = np.zeros(m)  # vᵢᵀ Aᵀ r / (σᵢ² + λᵢ²)
    for i in range(m):
        lam2 = lambda_max**2 * (1.0 - (sig[i] / eps) ** 2) if sig[i] < eps else 0.0
        lam2_max = max(lam2_max, lam2)
        den = max(w[i], 0.0) + lam2
        if den > 1e-300 and (lam2 > 0.0 or sig[i] >= tol * smax):  # undamped noise σ: rank cut-off
            for k in range(m):
                coef[i] += V[k, i] * Ar[k]
            coef[i] /= den
    nbad = 0
    for i in range(m):
        if sig[i] < tol * smax:
            for k in range(m):
                out[3 + m + nbad, k] = V[k, i]
            nbad += 1
    for a in range(m):
        f = 0.0
        for i in range(m):
            f += V[a, i] * coef[i]
        out[0, a] = f
        out[1, a] = sig[m - 1 - a]
        for b in range(m):  # P = I - U Uᵀ
            p = 1.0 if a == b else 0.0
            for u in range(nbad):
                p -= out[3 + m + u, a] * out[3 + m + u, b]
            out[3 + a, b] = p
    out[2, 0] = lam2_max
    for a in range(m):
        if not (np.isfinite(out[0, a]) and np.isfinite(out[1, a])):
            return -2
    return nbad


def observable_error(est: ForceEstimate, applied: np.ndarray) -> tuple[np.ndarray, float]:
    """Error of the estimate against the observable part of the ``applied`` forces ((k, 3) or (3k,), N).

    Returns ``(error (3k,), observable_fraction)``: ``F̂ - P F`` with ``P`` the projector onto the range of
    ``Aᵀ``, and ``‖P F‖ / ‖F‖`` (1 = fully observable).
    """
    F = np.asarray(applied, float).ravel()
    PF = est.projector @ F
    nf = float(np.linalg.norm(F))
    return est.stacked - PF, (float(np.linalg.norm(PF)) / nf if nf > 0 else 1.0)
