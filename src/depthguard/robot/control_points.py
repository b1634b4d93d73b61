"""Control points: spheres that bound the robot's links (ICRA'12 §IV-B, Fig. 8; RA-L'16 §VII-VIII).

Each link capsule (segment ``a``-``b`` of length L, radius r; see :mod:`depthguard.robot.model`) is
covered by ``k`` spheres:

* ``k = 1``: one sphere at the segment's midpoint with radius ``L/2 + r``;
* ``k >= 2``: centres at ``a + i/(k-1) (b - a)``, ``i = 0..k-1``, all with radius
  ``sqrt(r^2 + (L / (2 (k-1)))^2)``. Neighbouring spheres then cover the cylinder between them and the
  end spheres cover the hemispherical caps, so the union of the spheres contains the capsule.

The sphere centres are the control points; a reported distance is measured from the sphere surface
(``docs/conventions.md``). The end-effector point is a sphere of radius ``ee_radius`` centred at the model's
end-effector frame; it is always point 0.

Presets for the shipped LWR (:func:`depthguard.robot.model.load_lwr4`):

* ``"icra-exp3"``: ICRA'12 Exp. 3, the end effector plus five points on the arm and forearm
  (upper arm A2-A4: three, forearm A4-A6: two; the base and shoulder are not considered).
* ``"ral-9"``: RA-L'16 §VIII, nine points including the end effector (upper arm three, forearm four,
  wrist one, plus the end effector).

For any robot:

* ``"auto"``: every link that moves gets up to ``auto_spheres`` spheres (default 3, one per ``auto_length``
  = 0.08 m of its longest extent at least) that cover all vertices of its real collision geometry (meshes
  before decimation, primitives, attached tools and payloads; :mod:`depthguard.robot.spheres`, where the
  count/accuracy trade-off is documented). Computed once, in :meth:`ControlPointSet.build`.
* a ``{link_name: count}`` mapping: ``count`` spheres per capsule of :attr:`RobotModel.capsules`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property
from typing import NamedTuple

import numpy as np

from depthguard.robot.fk import fixed_points
from depthguard.robot.model import RobotModel
from depthguard.robot.spheres import cover_points, grow_to_contain

__all__ = ["PRESETS", "ControlPointSet", "ControlPointState", "bounding_spheres", "control_points"]

PRESETS: dict[str, dict[str, int]] = {
    "icra-exp3": {"lwr_link_2": 1, "lwr_link_3": 2, "lwr_link_4": 1, "lwr_link_5": 1},
    "ral-9": {"lwr_link_2": 1, "lwr_link_3": 2, "lwr_link_4": 2, "lwr_link_5": 2, "lwr_link_6": 1},
}


def bounding_spheres(a: np.ndarray, b: np.ndarray, radius: float, k: int) -> tuple[np.ndarray, np.ndarray]:
    """``k`` spheres whose union contains the capsule ``a``-``b`` (3,) of ``radius`` (m).

    Returns:
        centres (k, 3) in the frame of ``a``, ``b``, and radii (k,), metres.
    """
    if k < 1:
        raise ValueError(f"sphere count per link must be >= 1, got {k}")
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    L = float(np.linalg.norm(b - a))
    if k == 1:
        return (0.5 * (a + b))[None], np.array([0.5 * L + radius])
    t = np.linspace(0.0, 1.0, k)
    centres = a + t[:, None] * (b - a)
    return centres, np.full(k, np.hypot(radius, 0.5 * L / (k - 1)))


class ControlPointState(NamedTuple):
    """Control points at one configuration.

    Attributes:
        centres: (N, 3) sphere centres in the world frame, m.
        radii: (N,) sphere radii, m.
        jacobians: (N, 3, n) positional Jacobians, ``d centre / dq`` (m/rad).
        names: N names; ``names[0] == "ee"``.
    """

    centres: np.ndarray
    radii: np.ndarray
    jacobians: np.ndarray
    names: tuple[str, ...]


def _in_joint_frame(frame, centre: np.ndarray) -> np.ndarray:
    """A point given in a link's (pinocchio BODY) frame, expressed in its parent joint's frame, m."""
    M = frame.placement
    return M.rotation @ np.asarray(centre, float) + M.translation


@dataclass(frozen=True)
class ControlPointSet:
    """A fixed set of control spheres on a robot; build once, evaluate every cycle.

    Attributes:
        model: the robot.
        names: N point names, ``"ee"`` first, then ``"<link>/<i>"``.
        joints: (N,) pinocchio parent-joint index of each point.
        offsets: (N, 3) centre in the parent joint frame, m.
        radii: (N,) sphere radii, m.
        support: (N, n) bool, the joint coordinates that move each point.
    """

    model: RobotModel
    names: tuple[str, ...]
    joints: np.ndarray
    offsets: np.ndarray
    radii: np.ndarray
    support: np.ndarray

    @classmethod
    def build(
        cls,
        model: RobotModel,
        counts: str | Mapping[str, int] = "ral-9",
        ee_radius: float = 0.06,
        *,
        auto_spheres: int = 3,
        auto_length: float = 0.08,
    ) -> ControlPointSet:
        """Cover the links named in ``counts`` (a preset name, ``"auto"`` or ``{link: spheres}``) plus the
        end effector.

        Links with several capsules get ``count`` spheres per capsule. With ``"auto"`` (module docstring)
        ``auto_spheres`` (>= 1) caps the spheres per link and ``auto_length`` (m) sets one per that length.
        """
        if isinstance(counts, str) and counts == "auto":
            return cls._build_auto(model, ee_radius, auto_spheres, auto_length)
        if isinstance(counts, str):
            if counts not in PRESETS:
                raise ValueError(f"unknown control-point preset '{counts}'; known: {sorted(PRESETS) + ['auto']}")
            counts = PRESETS[counts]
        links = {c.link for c in model.capsules}
        unknown = [name for name in counts if name not in links]
        if unknown:
            raise ValueError(f"control-point links {unknown} have no collision capsule; links: {sorted(links)}")
        if not np.isfinite(ee_radius) or ee_radius < 0:
            raise ValueError(f"ee_radius must be a finite number >= 0, got {ee_radius!r}")
        ee = model.model.frames[model.ee_frame_id]
        names, joints = ["ee"], [int(ee.parentJoint)]
        offsets, radii = [np.array(ee.placement.translation)], [float(ee_radius)]
        for link, k in counts.items():
            frame = model.model.frames[model.frame_id(link)]
            caps = [c for c in model.capsules if c.link == link]
            for ci, cap in enumerate(caps):
                centres, rr = bounding_spheres(cap.a, cap.b, cap.radius, int(k))
                for i, (c, r) in enumerate(zip(centres, rr, strict=True)):
                    suffix = f"{i}" if len(caps) == 1 else f"{ci}.{i}"
                    names.append(f"{link}/{suffix}")
                    joints.append(int(frame.parentJoint))
                    offsets.append(_in_joint_frame(frame, c))
                    radii.append(float(r))
        return cls._from_lists(model, names, joints, offsets, radii)

    @classmethod
    def _from_lists(cls, model: RobotModel, names, joints, offsets, radii) -> ControlPointSet:
        """The set from per-point lists: names, parent joints, offsets in the joint frame (m), radii (m)."""
        joints_a = np.array(joints, dtype=np.int64)
        support = np.array([model.joint_support_mask(j) for j in joints_a])
        return cls(model, tuple(names), joints_a, np.array(offsets), np.array(radii), support)

    @classmethod
    def _build_auto(cls, model: RobotModel, ee_radius: float, k_max: int, length: float) -> ControlPointSet:
        if isinstance(k_max, bool) or int(k_max) != k_max or k_max < 1:
            raise ValueError(f"auto_spheres must be an integer >= 1, got {k_max!r}")
        if not (np.isfinite(length) and length > 0):
            raise ValueError(f"auto_length must be a finite number > 0, got {length!r}")
        if not np.isfinite(ee_radius) or ee_radius < 0:
            raise ValueError(f"ee_radius must be a finite number >= 0, got {ee_radius!r}")
        ee = model.model.frames[model.ee_frame_id]
        names, joints = ["ee"], [int(ee.parentJoint)]
        offsets, radii = [np.array(ee.placement.translation)], [float(ee_radius)]
        tris = model.geometry.link_triangles()
        for link, (pts, prad) in model.geometry.link_points().items():
            frame = model.model.frames[model.frame_id(link)]
            if not model.joint_support_mask(int(frame.parentJoint)).any():
                continue  # fixed to the base: it cannot move away from anything
            extent = float(np.max(np.ptp(pts, axis=0)) + 2 * np.max(prad))
            k = int(min(k_max, max(1, np.ceil(extent / length))))
            centres, rr = cover_points(pts, k, radii=prad)
            if link in tris:  # the surface between the samples too
                rr = grow_to_contain(centres, rr, tris[link])
            for i, (c, r) in enumerate(zip(centres, rr, strict=True)):
                names.append(f"{link}/{i}")
                joints.append(int(frame.parentJoint))
                offsets.append(_in_joint_frame(frame, c))
                radii.append(float(r))
        return cls._from_lists(model, names, joints, offsets, radii)

    def with_spheres(self, spheres) -> ControlPointSet:
        """A new set: these points plus ``spheres``, items ``(name, link, centre (3,) m in the link frame,
        radius m)`` (explicit spheres of a cell file, covers of attached tools)."""
        names, joints = list(self.names), [int(j) for j in self.joints]
        offsets, radii = [np.asarray(o, float) for o in self.offsets], [float(r) for r in self.radii]
        for name, link, centre, radius in spheres:
            c = np.asarray(centre, float)
            if c.shape != (3,) or not np.all(np.isfinite(c)) or not (np.isfinite(radius) and radius >= 0):
                raise ValueError(f"control sphere '{name}': centre must be 3 finite numbers and radius >= 0")
            frame = self.model.model.frames[self.model.frame_id(link)]  # ValueError naming an unknown link
            names.append(str(name))
            joints.append(int(frame.parentJoint))
            offsets.append(_in_joint_frame(frame, c))
            radii.append(float(radius))
        return self._from_lists(self.model, names, joints, offsets, radii)

    @cached_property
    def _unique_joints(self) -> list[int]:
        return sorted({int(j) for j in self.joints})

    @cached_property
    def _joint_slot(self) -> np.ndarray:
        u = self._unique_joints
        return np.array([u.index(int(j)) for j in self.joints], dtype=np.int64)

    @property
    def n_points(self) -> int:
        return len(self.names)

    def evaluate(self, q: np.ndarray, *, updated: bool = False) -> ControlPointState:
        """Centres, radii and Jacobians of all points at ``q`` (n,) in one call.

        Args:
            q: joint positions (n,), rad.
            updated: True if ``model.update(q)`` has already run for this ``q``: the poses are then read
                from the model's pinocchio buffer. Otherwise they come from
                :meth:`RobotModel.joint_kinematics` (compiled; the pinocchio buffer is left as it is).
        """
        if not updated:
            H, Jw = self.model.joint_kinematics(self.model.check_q(q))  # (njoints, 4, 4), (6, n)
            centres, jac = fixed_points(H, self.joints, self.offsets, Jw, self.support)
            return ControlPointState(centres, self.radii.copy(), jac, self.names)
        oMi = self.model.data.oMi
        H = np.array([oMi[j].homogeneous for j in self._unique_joints])  # (U, 4, 4)
        # (6, n): linear part at the world origin, angular part (reshaped: pinocchio gives (6,) when n = 1)
        Jw = np.asarray(self.model.data.J).reshape(6, self.model.n_dof)
        centres, jac = fixed_points(H, self._joint_slot, self.offsets, Jw, self.support)
        return ControlPointState(centres, self.radii.copy(), jac, self.names)


def control_points(
    model: RobotModel, q: np.ndarray, preset: str | Mapping[str, int] = "ral-9", ee_radius: float = 0.06
) -> ControlPointState:
    """One-shot convenience: build the set named ``preset`` and evaluate it at ``q`` (n,).

    For a control loop build a :class:`ControlPointSet` once and call :meth:`ControlPointSet.evaluate`.
    """
    return ControlPointSet.build(model, preset, ee_radius).evaluate(q)
