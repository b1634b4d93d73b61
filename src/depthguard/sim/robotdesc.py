"""The robot description the simulator builds its arm from: joints and capsules read from the URDF.

The simulated arm and the controller's model must agree, so both come from the same URDF
(``depthguard/robot/data/lwr4/lwr4.urdf``, written for the controller). URDF has no capsule: each link
capsule is written there as a cylinder plus a sphere at each end, which we read back as one capsule.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["JointDesc", "CapsuleDesc", "RobotDesc", "load_robot_desc", "rpy_to_matrix"]


@dataclass(frozen=True)
class CapsuleDesc:
    """A capsule in its link's frame: segment ``a``-``b`` (3,) m and ``radius`` m (``a == b``: sphere)."""

    link: str
    a: tuple[float, float, float]
    b: tuple[float, float, float]
    radius: float
    kind: str = "capsule"  # "capsule" or "cylinder"


@dataclass(frozen=True)
class JointDesc:
    """A URDF joint: origin (xyz, rpy) in the parent link frame, axis, limits (rad, rad/s)."""

    name: str
    parent: str
    child: str
    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float]
    axis: tuple[float, float, float]
    type: str
    lower: float = -math.pi
    upper: float = math.pi
    velocity: float = 2.0


@dataclass(frozen=True)
class RobotDesc:
    """A serial robot: ``joints`` from the base outwards, link ``capsules``, the root link, the tool link."""

    name: str
    root: str
    joints: tuple[JointDesc, ...]
    capsules: tuple[CapsuleDesc, ...]
    ee_link: str
    source: str

    @property
    def actuated(self) -> tuple[JointDesc, ...]:
        return tuple(j for j in self.joints if j.type in ("revolute", "continuous"))


def rpy_to_matrix(rpy: tuple[float, float, float]) -> np.ndarray:
    """URDF fixed-axis roll-pitch-yaw to a (3, 3) rotation: ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def _vec(text: str | None, default: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> tuple[float, float, float]:
    if text is None:
        return default
    vals = [float(x) for x in text.split()]
    if len(vals) != 3:
        raise ValueError(f"URDF: expected 3 numbers, got {text!r}")
    return (vals[0], vals[1], vals[2])


def parse_urdf(text: str, source: str = "<string>", ee_link: str | None = None) -> RobotDesc:
    """Parse a URDF string into a :class:`RobotDesc` (cylinder + end spheres -> capsule)."""
    root = ET.fromstring(text)
    joints: list[JointDesc] = []
    for j in root.findall("joint"):
        origin = j.find("origin")
        axis = j.find("axis")
        limit = j.find("limit")
        joints.append(
            JointDesc(
                name=j.get("name", ""),
                parent=j.find("parent").get("link"),
                child=j.find("child").get("link"),
                xyz=_vec(origin.get("xyz") if origin is not None else None),
                rpy=_vec(origin.get("rpy") if origin is not None else None),
                axis=_vec(axis.get("xyz") if axis is not None else None, (1.0, 0.0, 0.0)),
                type=j.get("type", "fixed"),
                lower=float(limit.get("lower", -math.pi)) if limit is not None else -math.pi,
                upper=float(limit.get("upper", math.pi)) if limit is not None else math.pi,
                velocity=float(limit.get("velocity", 2.0)) if limit is not None else 2.0,
            )
        )
    children = {j.child for j in joints}
    links = [lk.get("name") for lk in root.findall("link")]
    roots = [lk for lk in links if lk not in children]
    if len(roots) != 1:
        raise ValueError(f"URDF {source}: expected one root link, got {roots}")
    # order joints from the root outwards
    ordered: list[JointDesc] = []
    frontier = [roots[0]]
    while frontier:
        parent = frontier.pop(0)
        for j in joints:
            if j.parent == parent:
                ordered.append(j)
                frontier.append(j.child)
    capsules: list[CapsuleDesc] = []
    for lk in root.findall("link"):
        name = lk.get("name")
        cyl = []
        for c in lk.findall("collision"):
            geom = c.find("geometry")
            origin = c.find("origin")
            xyz = np.array(_vec(origin.get("xyz") if origin is not None else None))
            rot = rpy_to_matrix(_vec(origin.get("rpy") if origin is not None else None))
            cy = geom.find("cylinder")
            if cy is not None:
                half = 0.5 * float(cy.get("length"))
                a = xyz - rot[:, 2] * half
                b = xyz + rot[:, 2] * half
                cyl.append((a, b, float(cy.get("radius"))))
        spheres = [
            (
                np.array(_vec(c.find("origin").get("xyz") if c.find("origin") is not None else None)),
                float(c.find("geometry/sphere").get("radius")),
            )
            for c in lk.findall("collision")
            if c.find("geometry/sphere") is not None
        ]
        for a, b, r in cyl:
            # a cylinder with a sphere of its radius at each end is a capsule
            ends = [s for s in spheres if abs(s[1] - r) < 1e-9]
            at_a = any(np.linalg.norm(s[0] - a) < 0.02 for s in ends)
            at_b = any(np.linalg.norm(s[0] - b) < 0.02 for s in ends)
            if at_a and at_b:
                # use the sphere centres (they may extend slightly beyond the cylinder)
                ca = min(ends, key=lambda s: np.linalg.norm(s[0] - a))[0]
                cb = min(ends, key=lambda s: np.linalg.norm(s[0] - b))[0]
                capsules.append(CapsuleDesc(name, tuple(ca), tuple(cb), r, "capsule"))
            else:
                capsules.append(CapsuleDesc(name, tuple(a), tuple(b), r, "cylinder"))
    if ee_link is None:
        ee_link = ordered[-1].child if ordered else roots[0]
    return RobotDesc(
        name=root.get("name", "robot"),
        root=roots[0],
        joints=tuple(ordered),
        capsules=tuple(capsules),
        ee_link=ee_link,
        source=source,
    )


def load_robot_desc() -> RobotDesc:
    """The LWR IV description, read from the same URDF as the controller's model."""
    from depthguard.robot.model import lwr4_urdf_path

    path = lwr4_urdf_path()
    return parse_urdf(Path(path).read_text(), source=str(path), ee_link="lwr_ee")
