"""Forward kinematics and the WORLD joint Jacobian of a chain of one-coordinate joints, in one compiled call.

pinocchio's ``computeJointJacobians`` itself takes 1-2 µs for a 7-DOF arm, but reading its results back
costs far more in a control cycle: every ``data.oMi[j].homogeneous`` builds a new numpy array (about
2 µs each, measured), so the 5-10 joint poses that the control points, sensors or contact points need
cost 10-25 µs per cycle. :class:`ChainKinematics` computes the same quantities in one numba kernel from
the model's constant parts, read once from pinocchio:

* joint poses ``H`` (njoints, 4, 4), world frame: ``H[j] = H[parent(j)] · placement(j) · X_j(q)`` with
  ``X_j`` a rotation by ``q`` about the joint's unit axis (revolute) or a translation by ``q`` along it
  (prismatic), ``H[0]`` the identity (the universe);
* the joint Jacobian ``Jw`` (6, n) in pinocchio's WORLD convention (``data.J`` after
  ``computeJointJacobians``): column ``idx_v(j)`` = ``oMi[j].act(S_j)``, i.e. ``(o_j × ω_j, ω_j)`` for a
  revolute joint with world axis ``ω_j`` through ``o_j`` and ``(a_j, 0)`` for a prismatic one. A body
  point ``c`` moves with ``J_lin + J_ang × c`` over the joints that support it.

Only models whose joints are all revolute or prismatic with one coordinate are compiled (the ones
:class:`~depthguard.robot.model.RobotModel` accepts; the axis is read from the joint's motion subspace,
so aligned and unaligned axes alike). :func:`ChainKinematics.from_model` returns None for anything else
(helical, spherical, free-flyer, ...), and the callers then use pinocchio. ``tests/test_fk.py`` checks
both outputs against pinocchio on every shipped robot.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["ChainKinematics", "fixed_points", "fixed_directions", "world_point_jacobian", "checked_point_jacobian"]

_REVOLUTE, _PRISMATIC = 0, 1


@njit(cache=True, nogil=True)
def _chain_fk(q, parent, idx_v, kind, axis, placement):  # pragma: no cover - compiled
    """World poses (J, 4, 4) and WORLD joint Jacobian (6, n) at ``q`` (module docstring)."""
    H = np.zeros((parent.shape[0], 4, 4))
    Jw = np.zeros((6, q.shape[0]))
    _chain_fk_into(q, parent, idx_v, kind, axis, placement, H, Jw)
    return H, Jw


@njit(cache=True, nogil=True)
def _chain_fk_into(q, parent, idx_v, kind, axis, placement, H, Jw):  # pragma: no cover - compiled
    """:func:`_chain_fk` into ``H`` (J, 4, 4) and ``Jw`` (6, n), zeros on entry (one scratch matrix for all
    joints)."""
    nj = parent.shape[0]
    T = np.empty((4, 4))
    for i in range(4):
        H[0, i, i] = 1.0
    for j in range(1, nj):
        A = H[parent[j]]
        P = placement[j]
        for r in range(3):
            for c in range(4):
                T[r, c] = A[r, 0] * P[0, c] + A[r, 1] * P[1, c] + A[r, 2] * P[2, c] + (A[r, 3] if c == 3 else 0.0)
        x, y, z = axis[j, 0], axis[j, 1], axis[j, 2]
        v = q[idx_v[j]]
        Hj = H[j]
        Hj[3, 3] = 1.0
        if kind[j] == _REVOLUTE:  # T · Rot(axis, v) (Rodrigues)
            s, co = np.sin(v), np.cos(v)
            t = 1.0 - co
            R00, R01, R02 = t * x * x + co, t * x * y - s * z, t * x * z + s * y
            R10, R11, R12 = t * x * y + s * z, t * y * y + co, t * y * z - s * x
            R20, R21, R22 = t * x * z - s * y, t * y * z + s * x, t * z * z + co
            for r in range(3):
                a0, a1, a2 = T[r, 0], T[r, 1], T[r, 2]
                Hj[r, 0] = a0 * R00 + a1 * R10 + a2 * R20
                Hj[r, 1] = a0 * R01 + a1 * R11 + a2 * R21
                Hj[r, 2] = a0 * R02 + a1 * R12 + a2 * R22
                Hj[r, 3] = T[r, 3]
        else:  # T · Trans(axis v)
            for r in range(3):
                Hj[r, 0], Hj[r, 1], Hj[r, 2] = T[r, 0], T[r, 1], T[r, 2]
                Hj[r, 3] = T[r, 3] + v * (T[r, 0] * x + T[r, 1] * y + T[r, 2] * z)
        w0 = Hj[0, 0] * x + Hj[0, 1] * y + Hj[0, 2] * z  # the axis in the world frame
        w1 = Hj[1, 0] * x + Hj[1, 1] * y + Hj[1, 2] * z
        w2 = Hj[2, 0] * x + Hj[2, 1] * y + Hj[2, 2] * z
        col = idx_v[j]
        if kind[j] == _REVOLUTE:
            o0, o1, o2 = Hj[0, 3], Hj[1, 3], Hj[2, 3]
            Jw[0, col] = o1 * w2 - o2 * w1
            Jw[1, col] = o2 * w0 - o0 * w2
            Jw[2, col] = o0 * w1 - o1 * w0
            Jw[3, col], Jw[4, col], Jw[5, col] = w0, w1, w2
        else:
            Jw[0, col], Jw[1, col], Jw[2, col] = w0, w1, w2


class ChainKinematics:
    """The compiled forward kinematics of a pinocchio model (module docstring). Build with
    :meth:`from_model`; :meth:`compute` is thread-safe (no shared buffers)."""

    def __init__(
        self,
        parent: np.ndarray,
        idx_v: np.ndarray,
        kind: np.ndarray,
        axis: np.ndarray,
        placement: np.ndarray,
        n_dof: int,
    ) -> None:
        self.parent, self.idx_v, self.kind, self.axis, self.placement = parent, idx_v, kind, axis, placement
        self.n_dof = n_dof

    @classmethod
    def from_model(cls, model) -> ChainKinematics | None:
        """From a ``pinocchio.Model``; None if some joint is not a one-coordinate revolute/prismatic joint."""
        nj = int(model.njoints)
        parent = np.zeros(nj, dtype=np.int64)
        idx_v = np.zeros(nj, dtype=np.int64)
        kind = np.zeros(nj, dtype=np.int64)
        axis = np.zeros((nj, 3))
        placement = np.zeros((nj, 4, 4))
        placement[0] = np.eye(4)
        for j in range(1, nj):
            jm = model.joints[j]
            if jm.nq != 1 or jm.nv != 1:
                return None
            jd = jm.createData()
            jm.calc(jd, np.zeros(1))
            S = np.asarray(jd.S).reshape(6)  # motion subspace, LOCAL: (linear, angular)
            lin, ang = S[:3], S[3:]
            if np.linalg.norm(lin) < 1e-12 and abs(np.linalg.norm(ang) - 1.0) < 1e-9:
                kind[j], axis[j] = _REVOLUTE, ang
            elif np.linalg.norm(ang) < 1e-12 and abs(np.linalg.norm(lin) - 1.0) < 1e-9:
                kind[j], axis[j] = _PRISMATIC, lin
            else:
                return None
            parent[j] = int(model.parents[j])
            idx_v[j] = int(model.idx_vs[j])
            placement[j] = np.asarray(model.jointPlacements[j].homogeneous)
        return cls(parent, idx_v, kind, axis, placement, int(model.nv))

    def compute(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Joint poses ``H`` (njoints, 4, 4) (world frame, m) and the WORLD joint Jacobian ``Jw`` (6, n)
        at ``q`` (n,) rad or m, a finite float64 array (not checked here)."""
        return _chain_fk(q, self.parent, self.idx_v, self.kind, self.axis, self.placement)


@njit(cache=True, nogil=True)
def fixed_points(
    H: np.ndarray, slot: np.ndarray, offsets: np.ndarray, Jw: np.ndarray, support: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """World positions (N, 3) and positional Jacobians (N, 3, n) of N points fixed to joint frames.

    ``offsets`` (N, 3) m in the frames ``H[slot[k]]`` (H: (U, 4, 4) joint poses); ``Jw`` (6, n) the WORLD
    joint Jacobian; ``support`` (N, n) bool, the joints that move each point. A body point c moves with
    ``v_O + w x c``, so ``J_c = J_lin + J_ang x c`` over the joints that support it."""
    N, n = slot.shape[0], Jw.shape[1]
    centres = np.empty((N, 3))
    jac = np.zeros((N, 3, n))
    for k in range(N):
        M = H[slot[k]]
        for i in range(3):
            centres[k, i] = M[i, 0] * offsets[k, 0] + M[i, 1] * offsets[k, 1] + M[i, 2] * offsets[k, 2] + M[i, 3]
        c0, c1, c2 = centres[k, 0], centres[k, 1], centres[k, 2]
        for j in range(n):
            if support[k, j]:
                w0, w1, w2 = Jw[3, j], Jw[4, j], Jw[5, j]
                jac[k, 0, j] = Jw[0, j] + w1 * c2 - w2 * c1
                jac[k, 1, j] = Jw[1, j] + w2 * c0 - w0 * c2
                jac[k, 2, j] = Jw[2, j] + w0 * c1 - w1 * c0
    return centres, jac


@njit(cache=True, nogil=True)
def fixed_directions(H: np.ndarray, joint: np.ndarray, v: np.ndarray) -> np.ndarray:  # pragma: no cover
    """(N, 3) directions ``v`` (N, 3), fixed in the frames ``H[joint[k]]`` (H: (U, 4, 4)), in the world frame."""
    out = np.empty_like(v)
    for k in range(v.shape[0]):
        R = H[joint[k]]
        for i in range(3):
            out[k, i] = R[i, 0] * v[k, 0] + R[i, 1] * v[k, 1] + R[i, 2] * v[k, 2]
    return out


@njit(cache=True, nogil=True)
def world_point_jacobian(Jw: np.ndarray, p: np.ndarray, support: np.ndarray) -> np.ndarray:  # pragma: no cover
    """(3, n) positional Jacobian of the world point ``p`` (3,) m moving with a body whose supporting joints
    are ``support`` (n,) bool, from the WORLD joint Jacobian ``Jw`` (6, n): ``J_lin + J_ang x p``."""
    J = np.zeros((3, Jw.shape[1]))
    _point_jacobian_into(Jw, p, support, J)
    return J


@njit(cache=True, nogil=True)
def _point_jacobian_into(Jw, p, support, J):  # pragma: no cover - compiled
    """:func:`world_point_jacobian` into the supported columns of ``J`` (3, n) (the others are left alone)."""
    for j in range(Jw.shape[1]):
        if support[j]:
            w0, w1, w2 = Jw[3, j], Jw[4, j], Jw[5, j]
            J[0, j] = Jw[0, j] + w1 * p[2] - w2 * p[1]
            J[1, j] = Jw[1, j] + w2 * p[0] - w0 * p[2]
            J[2, j] = Jw[2, j] + w0 * p[1] - w1 * p[0]


def _pack_chain(chain: ChainKinematics, ints: np.ndarray | None = None, floats: np.ndarray | None = None):
    """The chain's arrays as two 1-D buffers for the one-call kernels (fewer arguments to unbox):
    int64 ``(J, parent, idx_v, kind, ints…)`` and float64 ``(axis, placement, floats…)``; see
    :func:`_unpack_chain`."""
    nj = len(chain.parent)
    extra_i = np.zeros(0, np.int64) if ints is None else np.asarray(ints, np.int64).ravel()
    extra_f = np.zeros(0) if floats is None else np.asarray(floats, float).ravel()
    i = np.concatenate([[nj], chain.parent, chain.idx_v, chain.kind, extra_i]).astype(np.int64)
    f = np.concatenate([chain.axis.ravel(), chain.placement.ravel(), extra_f])
    return i, f


@njit(cache=True, nogil=True)
def _unpack_chain(ints, floats):  # pragma: no cover - compiled
    """``(parent, idx_v, kind, axis, placement, ints…, floats…)`` views of :func:`_pack_chain`'s buffers."""
    nj = ints[0]
    parent, idx_v, kind = ints[1 : 1 + nj], ints[1 + nj : 1 + 2 * nj], ints[1 + 2 * nj : 1 + 3 * nj]
    axis = floats[: 3 * nj].reshape((nj, 3))
    placement = floats[3 * nj : 19 * nj].reshape((nj, 4, 4))
    return parent, idx_v, kind, axis, placement, ints[1 + 3 * nj :], floats[19 * nj :]


@njit(cache=True, nogil=True)
def checked_point_jacobian(
    q: np.ndarray, p: np.ndarray, ints: np.ndarray, floats: np.ndarray, J: np.ndarray
) -> bool:  # pragma: no cover - compiled
    """:func:`world_point_jacobian` of the point ``p`` (3,) at ``q`` (n,) from the compiled kinematics, in one
    call, into ``J`` (3, n), zeros on entry; ``ints``, ``floats``: :func:`_pack_chain` of the chain with the
    point's support mask (n,) (0/1) as ``ints``. Returns False (``J`` untouched) when ``q`` is not finite:
    the caller then raises."""
    n = q.shape[0]
    for j in range(n):
        if not np.isfinite(q[j]):
            return False
    parent, idx_v, kind, axis, placement, support, _ = _unpack_chain(ints, floats)
    H = np.zeros((parent.shape[0], 4, 4))
    Jw = np.zeros((6, n))
    _chain_fk_into(q, parent, idx_v, kind, axis, placement, H, Jw)
    _point_jacobian_into(Jw, p, support, J)
    return True
