"""Admittance reaction at the contact point (SAPHARI D4.1.1 §6.3), at the joint-velocity level.

For each contact i with estimated force ``F̂_i`` (N, :mod:`depthguard.robot.contact_force`), the contact
point's commanded velocity ``v_i`` follows a Cartesian mass-damper, optionally with a spring to the
contact point's position at the onset ``x_i0``::

    M_a v̇_i + D_a v_i + K_a (x_i - x_i0) = F̂_i          (discretised implicitly in D_a and K_a)

Soft and stiff parameter sets (:data:`SOFT`, :data:`STIFF`) reproduce the two behaviours of
Experiments 1 and 2. The joint velocity comes from task priority (Siciliano-Slotine): the stacked
contact-point tasks first, the end-effector position task second, in the null space of the first::

    q̇ = J_c^# v_c + (J_e N_c)^# (v_e - J_e J_c^# v_c),      N_c = I - J_c^# J_c

so the end effector holds its position with whatever joints the contact does not need (for a
contact on link 3 of a 7-DOF arm, joints 4-7 keep the end effector nearly still; for a contact on link 6
the two tasks share joints and the end effector gives way). Pseudo-inverses are damped (DLS) and the
result is scaled uniformly into the joint velocity limits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from depthguard.robot.contact_force import point_jacobian
from depthguard.validation import check_finite_array, real_array, real_number

__all__ = ["AdmittanceParams", "SOFT", "STIFF", "admittance_step", "task_priority_velocity", "ContactAdmittance"]


@dataclass(frozen=True)
class AdmittanceParams:
    """Cartesian admittance at a contact point: ``mass`` kg, ``damping`` N s/m, ``stiffness`` N/m (0: none);
    finite numbers (not bools or strings: ValueError naming the field)."""

    mass: float
    damping: float
    stiffness: float = 0.0

    def __post_init__(self) -> None:
        for name in ("mass", "damping", "stiffness"):
            value = getattr(self, name)
            x = real_number(value, name, "a finite number (admittance parameter)")
            if not (math.isfinite(x) and (x > 0 if name == "mass" else x >= 0)):
                raise ValueError(f"admittance needs mass > 0, damping >= 0, stiffness >= 0 (finite); {name}={value!r}")
            object.__setattr__(self, name, x)


#: Experiment 1: a soft, yielding contact point (time constant D/K ≈ 0.5 s, 20 N -> 0.3 m/s at first).
SOFT = AdmittanceParams(mass=1.5, damping=60.0, stiffness=120.0)
#: Experiment 2: a stiff contact point (30 N -> about 1 cm, settling ≈ 0.2 s).
STIFF = AdmittanceParams(mass=3.0, damping=450.0, stiffness=3000.0)


def admittance_step(p: AdmittanceParams, v: np.ndarray, e: np.ndarray, force: np.ndarray, dt: float) -> np.ndarray:
    """One step of ``M v̇ + D v + K e = F`` (each (3,)): the new velocity (3,) m/s.

    Implicit (backward Euler, with ``e⁺ = e + dt v⁺``): ``v⁺ = (M v + dt (F - K e)) / (M + dt D + dt² K)``.
    Stable for any dt > 0: the energy ``M |v|²/2 + K |e - F/K|²/2`` of a constant force never grows.

    Raises:
        ValueError naming the argument: ``p`` not :class:`AdmittanceParams`, ``v``, ``e``, ``force`` not finite
        (3,) arrays, ``dt`` not a finite number > 0, or a result beyond float range (absurd magnitudes).
    """
    if not isinstance(p, AdmittanceParams):
        raise ValueError(f"p must be AdmittanceParams, got {p!r}")
    v, e = check_finite_array(v, (3,), "v"), check_finite_array(e, (3,), "e")
    force = check_finite_array(force, (3,), "force")
    dt = real_number(dt, "dt", "a finite number of seconds > 0")
    if not 0.0 < dt < math.inf:
        raise ValueError(f"dt must be a finite number of seconds > 0, got {dt!r}")
    with np.errstate(over="ignore", invalid="ignore"):  # (refused below)
        out = (p.mass * v + dt * (force - p.stiffness * e)) / (p.mass + dt * p.damping + dt * dt * p.stiffness)
    if not math.isfinite(out.sum()):
        raise ValueError("admittance_step: v, e, force, dt and p overflow float range (inf or NaN velocity)")
    return out


def _dls(J: np.ndarray, lam: float) -> np.ndarray:
    """Damped pseudo-inverse ``Jᵀ (J Jᵀ + λ² I)⁻¹``, as ``V diag(s / (s² + λ²)) Uᵀ`` over the singular values
    above rounding (``s > s_max max(m, n) eps``): the solve of ``J Jᵀ + λ² I`` turned the rounding of a
    singular value 0 (J2 N1 has rank n - k < its rows with two contacts) into joint velocities of the order
    of ``1e-16 |J| / λ²`` (20 rad/s off at λ = 1e-9, tests/test_reaction_guarantees.py), and raised for λ = 0."""
    U, sv, Vt = np.linalg.svd(J, full_matrices=False)
    keep = sv > sv.max(initial=0.0) * max(J.shape) * np.finfo(float).eps
    return (Vt.T[:, keep] * (sv[keep] / (sv[keep] ** 2 + lam * lam))) @ U[:, keep].T


def _task(J: object, v: object, n: int | None, name: str) -> tuple[np.ndarray, np.ndarray]:
    Ja = real_array(J, f"J{name}", "an (m, n) matrix")
    if Ja.ndim != 2 or Ja.shape[0] < 1 or (n is not None and Ja.shape[1] != n) or not np.all(np.isfinite(Ja)):
        raise ValueError(f"J{name} must be a finite (m, {n or 'n'}) matrix, got shape {Ja.shape}")
    return Ja, check_finite_array(v, (Ja.shape[0],), f"v{name}")


def task_priority_velocity(
    J1: np.ndarray, v1: np.ndarray, J2: np.ndarray | None = None, v2: np.ndarray | None = None, lam: float = 0.01
) -> np.ndarray:
    """Joint velocity (n,) for task 1 ``J1 q̇ = v1`` and, in its null space, task 2 ``J2 q̇ = v2``; damped
    pseudo-inverses (``lam`` finite >= 0, 0: the pseudo-inverse). ValueError naming the argument for shapes
    that do not fit, non-finite numbers, ``J2`` without ``v2``."""
    J1, v1 = _task(J1, v1, None, "1")
    lam = real_number(lam, "lam", "a finite number >= 0")
    if not 0.0 <= lam < math.inf:
        raise ValueError(f"lam must be a finite number >= 0, got {lam!r}")
    if (J2 is None) != (v2 is None):
        raise ValueError("J2 and v2 must be given together (the secondary task)")
    if J2 is not None:
        J2, v2 = _task(J2, v2, J1.shape[1], "2")
    J1p = _dls(J1, lam)
    qd = J1p @ v1
    if J2 is None:
        return qd
    N1 = np.eye(J1.shape[1]) - J1p @ J1
    J2n = J2 @ N1
    return qd + N1 @ (_dls(J2n, lam) @ (v2 - J2 @ qd))


@dataclass
class _Contact:
    link: str
    local: np.ndarray  # in the link's parent-joint frame
    joint: int
    x0: np.ndarray
    v: np.ndarray = field(default_factory=lambda: np.zeros(3))


class ContactAdmittance:
    """Admittance reaction for one or more contacts, with the end effector held in the null space.

    Args:
        model: :class:`depthguard.robot.model.RobotModel`.
        params: :class:`AdmittanceParams` (e.g. :data:`SOFT`, :data:`STIFF`).
        ee_gain: proportional gain of the end-effector position task, 1/s.
        lam: DLS damping of the pseudo-inverses.
    """

    def __init__(self, model, params: AdmittanceParams, ee_gain: float = 5.0, lam: float = 0.01) -> None:
        if not isinstance(params, AdmittanceParams):
            raise ValueError(f"params must be AdmittanceParams (e.g. SOFT, STIFF), got {params!r}")
        gain, lam_f = (
            real_number(ee_gain, "ee_gain", "a finite gain >= 0"),
            real_number(lam, "lam", "a finite number >= 0"),
        )
        if not 0.0 <= gain < math.inf:
            raise ValueError(f"ee_gain must be a finite gain >= 0 (1/s), got {ee_gain!r}")
        if not 0.0 <= lam_f < math.inf:  # (NaN made every command NaN; the scaling into the limits let it pass)
            raise ValueError(f"lam must be a finite DLS damping >= 0, got {lam!r}")
        self.model, self.params, self.ee_gain, self.lam = model, params, gain, lam_f
        self.contacts: list[_Contact] = []

    def _world(self, c: _Contact) -> np.ndarray:
        R, p = self.model.joint_poses()
        return R[c.joint] @ c.local + p[c.joint]

    def set_contacts(self, q: np.ndarray, links: list[str], points_world: list[np.ndarray]) -> None:
        """Start (or restart) the admittance at contact points ``points_world`` (each (3,) m) on ``links``.

        A contact on a link already held keeps its velocity and its displacement from the spring origin
        (a sliding hand moves the origin by as much as the contact point moved along the surface)."""
        R, p = self.model.joint_poses(self.model.check_q(q))
        new = []
        for link, pw in zip(links, points_world, strict=True):
            pw = check_finite_array(pw, (3,), "contact point")
            j = int(self.model.model.frames[self.model.frame_id(link)].parentJoint)
            old = next((c for c in self.contacts if c.link == link), None)
            local = R[j].T @ (pw - p[j])
            if old is not None:
                moved = pw - (R[old.joint] @ old.local + p[old.joint])
                new.append(_Contact(link, local, j, old.x0 + moved, old.v))
            else:
                new.append(_Contact(link, local, j, pw.copy()))
        self.contacts = new

    def errors(self) -> np.ndarray:
        """(k, 3) contact point displacements ``x_i - x_i0`` at the last :meth:`step`'s configuration."""
        return np.array([self._world(c) - c.x0 for c in self.contacts]).reshape(-1, 3)

    def step(
        self, q: np.ndarray, forces: np.ndarray, ee_target: np.ndarray, dt: float, ee_velocity: np.ndarray | None = None
    ) -> np.ndarray:
        """Joint velocity command (n,) rad/s for estimated ``forces`` (k, 3) N at the contacts.

        Args:
            q: (n,) joint positions, rad.
            forces: (k, 3) estimated contact forces (zeros after release: the spring brings the points back).
            ee_target: (3,) end-effector position to hold, m.
            dt: control period, s.
            ee_velocity: optional (3,) feed-forward end-effector velocity, m/s (a moving target).
        Raises:
            ValueError naming the argument when one is of the wrong shape or not finite (or dt <= 0).
        """
        import pinocchio as pin

        m = self.model
        q = m.check_q(q)
        try:
            F = np.asarray(forces, float).reshape(-1, 3)
        except (TypeError, ValueError):
            raise ValueError(f"forces must have shape ({len(self.contacts)}, 3), got {forces!r}") from None
        if len(F) != len(self.contacts):
            raise ValueError(f"forces must have shape ({len(self.contacts)}, 3), got {F.shape}")
        if not np.all(np.isfinite(F)):  # (a NaN would also escape the scaling into the joint limits)
            raise ValueError("forces must be finite (no NaN or inf)")
        ee_target = check_finite_array(ee_target, (3,), "ee_target")
        if ee_velocity is not None:
            ee_velocity = check_finite_array(ee_velocity, (3,), "ee_velocity")
        dt = real_number(dt, "dt", "a finite number of seconds > 0")
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be a finite number of seconds > 0, got {dt!r}")
        pin.computeJointJacobians(m.model, m.data, q)
        pin.updateFramePlacements(m.model, m.data)
        x_ee = m.data.oMf[m.ee_frame_id].translation.copy()
        J_ee = pin.getFrameJacobian(m.model, m.data, m.ee_frame_id, pin.LOCAL_WORLD_ALIGNED)[:3]
        v_ee = self.ee_gain * (np.asarray(ee_target, float) - x_ee)
        if ee_velocity is not None:
            v_ee = v_ee + np.asarray(ee_velocity, float)
        if not self.contacts:
            return self._limit(task_priority_velocity(J_ee, v_ee, lam=self.lam))
        Jc, vc = [], []
        for c, f in zip(self.contacts, F, strict=True):
            x = self._world(c)
            c.v = admittance_step(self.params, c.v, x - c.x0, f, dt)
            Jc.append(point_jacobian(m, q, c.link, x, update=False))
            vc.append(c.v)
        qd = task_priority_velocity(np.vstack(Jc), np.concatenate(vc), J_ee, v_ee, self.lam)
        return self._limit(qd)

    def _limit(self, qd: np.ndarray) -> np.ndarray:
        """``qd`` scaled uniformly into the joint velocity limits; not finite (overflow): a stop (zeros)."""
        s = np.max(np.abs(qd) / self.model.v_max)
        if not math.isfinite(s):  # (NaN > 1.0 is False: it would pass unscaled)
            return np.zeros_like(qd)
        return qd / s if s > 1.0 else qd

    def clear(self) -> None:
        """Forget the contacts (back to the end-effector task alone)."""
        self.contacts = []

    def settled(self, tol: float = 0.005, vtol: float = 0.01) -> bool:
        """True when every contact point is back within ``tol`` m of its origin and slower than ``vtol`` m/s."""
        e = self.errors()
        return all(
            np.linalg.norm(ei) < tol and np.linalg.norm(c.v) < vtol for ei, c in zip(e, self.contacts, strict=True)
        )
