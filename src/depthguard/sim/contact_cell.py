"""A torque-controlled MuJoCo cell for the contact experiments (SAPHARI D4.1.1 §6.3).

Unlike the avoidance cell (:mod:`depthguard.sim.cell`: position servos, no gravity, no contacts) the arm
here is loaded from the same URDF by MuJoCo's own URDF importer (inertias, masses, joint damping exactly
as pinocchio reads them), with gravity on, an ``armature`` on every joint and one torque motor per joint.

* Joint-level controller (the robot's drive, at every 1 ms physics step): computed torque tracking
  the commanded joint velocity ``q̇_cmd`` and its integral ``q_ref``::

      τ = M(q) (K_p (q_ref - q) + K_d (q̇_cmd - q̇)) + c(q, q̇) + g(q) + D q̇

  using MuJoCo's ``qM``/``qfrc_bias``/``qfrc_passive`` (split step ``mj_step1``/``mj_step2``, Euler
  integrator). The motor torques it applies are read back (``qfrc_actuator``) and averaged over the
  control period: that average is the τ the residual sees.
* Hands: spheres (radius 4.5 cm, 1 kg, gravity compensated) on three slide joints with force motors,
  each with a forearm capsule that the camera sees but that touches nothing. Only hand-robot contacts
  exist (``contype``/``conaffinity``), for these experiments only. A hand follows a :class:`HandScript`:
  approach at constant speed, push with a force profile along its direction, retract.
* Ground truth: the contact forces on the robot (``mj_contactForce``), their points and links, the
  exact external joint torque ``qfrc_constraint`` (no joint limit is reached in these experiments), and
  per hand the contact onset ``onset`` (first physics step with a force above 1 N).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from depthguard.camera import Camera

__all__ = ["HandScript", "ContactCell", "hand_touch_point"]

GROUP_ENV, GROUP_ROBOT, GROUP_PEOPLE = 0, 1, 2


@dataclass(frozen=True)
class HandScript:
    """A hand that pushes a robot link.

    Attributes:
        name: hand name.
        link: the URDF link pushed.
        s: where along the link's capsule axis (0-1).
        direction: (3,) push direction in the world frame (normalised here).
        force: peak push force, N.
        t_touch: time the hand reaches the surface, s.
        duration: push duration (from ``t_touch`` to the end of the ramp down), s.
        rise: force ramp time, s.
        approach: start distance from the touch position, m; ``v_approach``: approach speed, m/s.
        radius: hand radius, m.
    """

    name: str
    link: str
    s: float
    direction: tuple[float, float, float]
    force: float
    t_touch: float
    duration: float
    rise: float = 0.03
    approach: float = 0.10
    v_approach: float = 0.15
    radius: float = 0.045

    def unit(self) -> np.ndarray:
        d = np.asarray(self.direction, float)
        return d / np.linalg.norm(d)

    def push_force(self, t: float) -> float:
        """Push force magnitude (N) at time t: smooth ramp up, hold, ramp down."""
        a, b = self.t_touch, self.t_touch + self.duration

        def ramp(x: float) -> float:
            x = min(max(x, 0.0), 1.0)
            return x * x * (3 - 2 * x)

        return self.force * min(ramp((t - a) / self.rise), ramp((b - t) / self.rise))


def hand_touch_point(model, q: np.ndarray, h: HandScript) -> tuple[np.ndarray, np.ndarray]:
    """Hand centre touching ``h.link`` at ``q`` and the surface point: ((3,), (3,)) m.

    The hand sits on the capsule's surface normal through the axis point at ``s`` that is closest to
    the push direction."""
    a, b, r = model.link_capsules(q)
    k = next(i for i, c in enumerate(model.capsules) if c.link == h.link)
    c = a[k] + h.s * (b[k] - a[k])
    ax = b[k] - a[k]
    ax = ax / max(np.linalg.norm(ax), 1e-12)
    d = h.unit()
    n = d - (d @ ax) * ax
    n /= np.linalg.norm(n)
    return c - (r[k] + h.radius) * n, c - r[k] * n


def _add_hand(spec, robot, q0: np.ndarray, h: HandScript) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Add hand ``h`` to the MjSpec (sphere palm that touches the robot, forearm that only the camera sees,
    three slide joints). Returns (touch centre, surface point, start centre), each (3,) m."""
    import mujoco

    G = mujoco.mjtGeom
    centre, surf = hand_touch_point(robot, q0, h)
    start = centre - h.approach * h.unit()
    body = spec.worldbody.add_body(name=h.name, pos=[0, 0, 0], gravcomp=1.0)
    for ax, nm in zip(np.eye(3), "xyz", strict=True):
        body.add_joint(name=f"{h.name}_{nm}", type=mujoco.mjtJoint.mjJNT_SLIDE, axis=ax)
    blue = [0.3, 0.5, 0.9, 1]
    body.add_geom(
        name=f"{h.name}_palm",
        type=G.mjGEOM_SPHERE,
        size=[h.radius, 0, 0],
        mass=1.0,
        group=GROUP_PEOPLE,
        contype=1,
        conaffinity=2,
        rgba=blue,
    )
    f = -h.unit() + np.array([0.0, 0.0, 0.4])
    f /= np.linalg.norm(f)
    body.add_geom(
        name=f"{h.name}_forearm",
        type=G.mjGEOM_CAPSULE,
        size=[0.035, 0, 0],
        mass=0.01,
        fromto=np.concatenate([f * (h.radius + 0.04), f * 0.34]),
        group=GROUP_PEOPLE,
        contype=4,
        conaffinity=0,
        rgba=blue,
    )
    return centre, surf, start


class ContactCell:
    """The compiled cell. See the module docstring.

    Args:
        hands: the hand scripts.
        camera: the depth camera (also a MuJoCo camera ``depthcam0``).
        q0: (7,) initial joint positions, rad.
        timestep: physics step, s.
        armature: rotor inertia of every joint, kg m².
        kp, kd: joint controller gains, 1/s², 1/s.
        frictionloss: Coulomb friction of every arm joint, N m (model-error studies; the observer
            does not know it).
    """

    def __init__(
        self,
        hands: list[HandScript],
        camera: Camera,
        q0: np.ndarray,
        timestep: float = 0.001,
        armature: float = 0.05,
        kp: float = 900.0,
        kd: float = 60.0,
        frictionloss: float = 0.0,
    ) -> None:
        import mujoco

        from depthguard.robot.model import load_lwr4, lwr4_urdf_path

        self._mj = mujoco
        self.robot = load_lwr4()
        self.hands = list(hands)
        self.camera = camera
        self.q0 = np.asarray(q0, float)
        self.kp, self.kd, self.armature = kp, kd, armature
        spec = mujoco.MjSpec.from_file(str(lwr4_urdf_path()))
        spec.option.timestep = timestep
        spec.option.integrator = mujoco.mjtIntegrator.mjINT_EULER
        spec.option.gravity = [0.0, 0.0, -9.81]
        for g in spec.geoms:  # the arm: touches hands only
            g.group, g.contype, g.conaffinity, g.rgba = GROUP_ROBOT, 2, 0, [0.95, 0.55, 0.1, 1]
        arm_joints = [j.name for j in spec.joints]
        wb = spec.worldbody
        G = mujoco.mjtGeom
        for name, typ, pos, size, rgba in (
            ("floor", G.mjGEOM_PLANE, [0, 0, -0.8], [5, 5, 0.1], [0.5, 0.5, 0.5, 1]),
            ("table", G.mjGEOM_BOX, [0, 0, -0.4], [0.3, 0.3, 0.4], [0.6, 0.6, 0.65, 1]),
            ("wall", G.mjGEOM_BOX, [1.6, 0, 0.7], [0.05, 2.5, 1.5], [0.85, 0.85, 0.8, 1]),
        ):
            # contype 4 touches nothing here but keeps MuJoCo's URDF compiler from discarding it as visual
            wb.add_geom(name=name, type=typ, pos=pos, size=size, rgba=rgba, group=GROUP_ENV, contype=4, conaffinity=0)
        self._touch = [_add_hand(spec, self.robot, self.q0, h) for h in self.hands]
        for jn in arm_joints:
            spec.add_actuator(name=f"{jn}_motor", target=jn, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        for h in self.hands:
            for nm in "xyz":
                spec.add_actuator(
                    name=f"{h.name}_{nm}_motor", target=f"{h.name}_{nm}", trntype=mujoco.mjtTrn.mjTRN_JOINT
                )
        self.spec = spec
        m = self.model = spec.compile()
        self.data = mujoco.MjData(m)
        jid = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n) for n in arm_joints]
        self.dof = np.array([m.jnt_dofadr[j] for j in jid])
        self.qadr = np.array([m.jnt_qposadr[j] for j in jid])
        m.dof_armature[self.dof] = armature
        m.dof_frictionloss[self.dof] = frictionloss
        self.damping = np.array(m.dof_damping[self.dof])
        self.hand_dof = [
            np.array([m.jnt_dofadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, f"{h.name}_{a}")] for a in "xyz"])
            for h in self.hands
        ]
        self.hand_geom = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, f"{h.name}_palm") for h in self.hands]
        self.robot_geoms = set(np.flatnonzero(m.geom_group == GROUP_ROBOT).tolist())
        self.geom_body = [
            mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, m.geom_bodyid[g]) or "world" for g in range(m.ngeom)
        ]
        self._M = np.zeros((m.nv, m.nv))
        self.reset()

    def reset(self) -> None:
        """Arm at rest at ``q0``, hands at their start positions, ``q_ref = q0``."""
        d = self.data
        self._mj.mj_resetData(self.model, d)
        d.qpos[self.qadr] = self.q0
        for k, (_, _, start) in enumerate(self._touch):
            d.qpos[self.model.jnt_qposadr[self.model.dof_jntid[self.hand_dof[k]]]] = start
        self.q_ref = self.q0.copy()
        self.onset: list[float | None] = [None] * len(self.hands)
        self.mean_contacts = [(np.zeros(3), np.full(3, np.nan), "") for _ in self.hands]
        self._retract: list[np.ndarray | None] = [None] * len(self.hands)
        self._mj.mj_forward(self.model, d)

    @property
    def t(self) -> float:
        return float(self.data.time)

    def q(self) -> np.ndarray:
        return self.data.qpos[self.qadr].copy()

    def qd(self) -> np.ndarray:
        return self.data.qvel[self.dof].copy()

    def hand_positions(self) -> np.ndarray:
        """(k, 3) hand centres, m."""
        d, m = self.data, self.model
        return np.array([d.qpos[m.jnt_qposadr[m.dof_jntid[hd]]] for hd in self.hand_dof]).reshape(-1, 3)

    def _hand_force(self, k: int, t: float) -> np.ndarray:
        h, (touch, _, start) = self.hands[k], self._touch[k]
        d = h.unit()
        x = self.hand_positions()[k]
        v = self.data.qvel[self.hand_dof[k]]
        K, D = 400.0, 40.0
        t_start = h.t_touch - h.approach / h.v_approach
        if t < h.t_touch:  # approach with velocity feed-forward
            s = min(max((t - t_start) * h.v_approach, 0.0), h.approach)
            vr = h.v_approach * d if t >= t_start else np.zeros(3)
            return K * (start + s * d - x) + D * (vr - v)
        if t < h.t_touch + h.duration:  # push: force along d, hold the line across it
            e = touch - x
            e_perp, v_perp = e - (e @ d) * d, v - (v @ d) * d
            return h.push_force(t) * d + K * e_perp - D * v_perp - 30.0 * (v @ d) * d
        if self._retract[k] is None:
            self._retract[k] = x.copy()
        back = self._retract[k] - min((t - h.t_touch - h.duration) * 0.3, 0.15) * d
        return K * (back - x) - D * v

    def step(self, qd_cmd: np.ndarray, n: int) -> np.ndarray:
        """Run ``n`` physics steps with the joint velocity command ``qd_cmd`` (7,) rad/s (zero-order hold).

        Returns the mean motor torque (7,) N m applied over those steps; :attr:`mean_contacts` holds the
        true contacts averaged over them (see :meth:`contacts`)."""
        mj, m, d = self._mj, self.model, self.data
        tau_sum = np.zeros(len(self.dof))
        nh = len(self.hands)
        f_sum, fp_sum, w, links = np.zeros((nh, 3)), np.zeros((nh, 3)), np.zeros((nh, 1)), [""] * nh
        h = m.opt.timestep
        ix = np.ix_(self.dof, self.dof)
        for _ in range(n):
            mj.mj_step1(m, d)
            q, qd = d.qpos[self.qadr], d.qvel[self.dof]
            self.q_ref = q + np.clip(self.q_ref + qd_cmd * h - q, -0.05, 0.05)  # anti wind-up
            mj.mj_fullM(m, d, self._M)
            acc = self.kp * (self.q_ref - q) + self.kd * (qd_cmd - qd)
            tau = self._M[ix] @ acc + d.qfrc_bias[self.dof] - d.qfrc_passive[self.dof]
            d.ctrl[: len(self.dof)] = tau
            for k in range(len(self.hands)):
                d.ctrl[len(self.dof) + 3 * k : len(self.dof) + 3 * k + 3] = self._hand_force(k, d.time)
            mj.mj_step2(m, d)
            tau_sum += d.qfrc_actuator[self.dof]
            if d.ncon:
                for k, (f, p, link) in enumerate(self.contacts()):
                    fn = float(np.linalg.norm(f))
                    if fn > 0:
                        f_sum[k] += f
                        fp_sum[k] += fn * p
                        w[k] += fn
                        links[k] = link
                    if self.onset[k] is None and fn > 1.0:
                        self.onset[k] = float(d.time)
        pts = np.where(w > 0, fp_sum / np.maximum(w, 1e-300), np.nan)
        self.mean_contacts = [(f_sum[k] / n, pts[k], links[k]) for k in range(nh)]
        return tau_sum / n

    def contacts(self) -> list[tuple[np.ndarray, np.ndarray, str]]:
        """True hand-robot contacts, one per hand: (force on the robot (3,) N, point (3,) m, link) with
        zero force and NaN point for a hand not touching."""
        mj, m, d = self._mj, self.model, self.data
        out = []
        f6 = np.zeros(6)
        for hg in self.hand_geom:
            F, P, w, link = np.zeros(3), np.zeros(3), 0.0, ""
            for i in range(d.ncon):
                c = d.contact[i]
                if hg not in (c.geom1, c.geom2) or not ({c.geom1, c.geom2} & self.robot_geoms):
                    continue
                mj.mj_contactForce(m, d, i, f6)
                fw = c.frame.reshape(3, 3).T @ f6[:3]  # force of geom1 on geom2, world
                fw = fw if c.geom2 != hg else -fw
                F += fw
                wn = float(np.linalg.norm(fw))
                P += wn * c.pos
                w += wn
                link = self.geom_body[c.geom1 if c.geom2 == hg else c.geom2]
            out.append((F, P / w if w > 0 else np.full(3, np.nan), link))
        return out

    def set_applied_force(
        self, link: str | None, point: np.ndarray | None = None, force: np.ndarray | None = None
    ) -> None:
        """Apply a constant external ``force`` (3,) N at world ``point`` (3,) m of ``link`` from now on
        (``mj_applyFT`` into ``qfrc_applied``); ``link=None`` removes it."""
        mj, m, d = self._mj, self.model, self.data
        d.qfrc_applied[:] = 0.0
        if link is None:
            return
        body = mj.mj_name2id(m, mj.mjtObj.mjOBJ_BODY, link)
        mj.mj_forward(m, d)
        mj.mj_applyFT(m, d, np.asarray(force, float), np.zeros(3), np.asarray(point, float), body, d.qfrc_applied)

    def tau_ext(self) -> np.ndarray:
        """(7,) exact external joint torque on the arm (constraint forces: contacts and joint friction,
        plus any applied force), N m."""
        return self.data.qfrc_constraint[self.dof] + self.data.qfrc_applied[self.dof]
