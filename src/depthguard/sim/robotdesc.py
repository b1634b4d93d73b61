"""The robot description the simulator builds its arm from: joints from the URDF, collision geometry from the
controller's own model.

The simulated arm and the controller's model must agree, so both come from the same URDF. The collision
geometry is not parsed here: it is :attr:`depthguard.robot.model.RobotModel.geometry` (one implementation),
turned into MuJoCo geoms: analytic capsules and spheres (URDF cylinders with a sphere at each end, as in the
shipped arm), boxes, cylinders, and meshes, which MuJoCo reads from their STL/OBJ files itself (other formats
go inline as the vertices that ``trimesh`` read). The simulated robot thus renders from its real meshes,
while the self-filter draws its own inflated copy of them.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from depthguard.robot.shapes import rpy_to_matrix

__all__ = ["JointDesc", "GeomDesc", "RobotDesc", "load_robot_desc", "rpy_to_matrix"]


@dataclass(frozen=True)
class GeomDesc:
    """A collision geom in its link's frame (metres).

    ``kind`` "capsule" (segment ``a``-``b``, ``radius``; ``a == b``: a sphere), "box" (``size`` = half sizes),
    "cylinder" (``size`` = (radius, half length)), "mesh" (``mesh`` file and ``scale``, or inline ``vertices``
    (V, 3) / ``faces`` (F, 3) already in the link frame); ``pos``, ``rot`` (3, 3): pose of box, cylinder
    and file mesh in the link frame.
    """

    link: str
    kind: str
    a: tuple = (0.0, 0.0, 0.0)
    b: tuple = (0.0, 0.0, 0.0)
    radius: float = 0.0
    size: tuple = ()
    pos: tuple = (0.0, 0.0, 0.0)
    rot: np.ndarray | None = None
    mesh: str | None = None
    scale: tuple = (1.0, 1.0, 1.0)
    vertices: np.ndarray | None = None
    faces: np.ndarray | None = None


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
    """A fixed-base robot: ``joints`` from the base outwards, collision ``geoms``, the root link, the tool
    link; ``joint_order``: the actuated joints in the order of the controller's ``q`` (pinocchio's)."""

    name: str
    root: str
    joints: tuple[JointDesc, ...]
    geoms: tuple[GeomDesc, ...]
    ee_link: str
    source: str
    joint_order: tuple[str, ...] = ()

    @property
    def actuated(self) -> tuple[JointDesc, ...]:
        """The moving joints (revolute, continuous, prismatic), in ``joint_order`` when given."""
        moving = [j for j in self.joints if j.type in ("revolute", "continuous", "prismatic")]
        if self.joint_order:
            by_name = {j.name: j for j in moving}
            return tuple(by_name[n] for n in self.joint_order if n in by_name)
        return tuple(moving)

    @property
    def capsules(self) -> tuple[GeomDesc, ...]:
        """The analytic capsules and spheres among the geoms."""
        return tuple(g for g in self.geoms if g.kind == "capsule")


def _vec(text: str | None, default: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> tuple[float, float, float]:
    if text is None:
        return default
    vals = [float(x) for x in text.split()]
    if len(vals) != 3:
        raise ValueError(f"URDF: expected 3 numbers, got {text!r}")
    return (vals[0], vals[1], vals[2])


def _link_name(name: str) -> str:
    """URDF link name as a MuJoCo body name: ``world`` is MuJoCo's own world body (UR5's root link)."""
    return "robot_world" if name == "world" else name


def parse_urdf(
    text: str, source: str = "<string>", ee_link: str | None = None, geoms: tuple[GeomDesc, ...] = ()
) -> RobotDesc:
    """Parse a URDF string's joints into a :class:`RobotDesc` with the given collision ``geoms``."""
    root = ET.fromstring(text)
    joints: list[JointDesc] = []
    for j in root.findall("joint"):
        origin = j.find("origin")
        axis = j.find("axis")
        limit = j.find("limit")
        joints.append(
            JointDesc(
                name=j.get("name", ""),
                parent=_link_name(j.find("parent").get("link")),
                child=_link_name(j.find("child").get("link")),
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
    links = [_link_name(lk.get("name")) for lk in root.findall("link")]
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
    if ee_link is None:
        ee_link = ordered[-1].child if ordered else roots[0]
    return RobotDesc(
        name=root.get("name", "robot"),
        root=roots[0],
        joints=tuple(ordered),
        geoms=tuple(replace(g, link=_link_name(g.link)) for g in geoms),
        ee_link=ee_link,
        source=source,
    )


def geoms_from_model(model) -> tuple[GeomDesc, ...]:
    """MuJoCo-ready geoms from a :class:`depthguard.robot.model.RobotModel`'s collision geometry."""
    out: list[GeomDesc] = []
    for g in model.geometry.geoms:
        sh = g.shape
        if not g.is_mesh:
            out.append(GeomDesc(sh.link, "capsule", a=tuple(g.a), b=tuple(g.b), radius=float(g.radius)))
        elif sh.kind == "box":
            half = tuple(0.5 * float(x) for x in sh.size)
            out.append(GeomDesc(sh.link, "box", size=half, pos=sh.xyz, rot=sh.rotation))
        elif sh.kind == "cylinder":
            size = (float(sh.size[0]), 0.5 * float(sh.size[1]))
            out.append(GeomDesc(sh.link, "cylinder", size=size, pos=sh.xyz, rot=sh.rotation))
        elif str(sh.mesh).lower().endswith((".stl", ".obj")) and g.slack == 0.0:
            out.append(GeomDesc(sh.link, "mesh", pos=sh.xyz, rot=sh.rotation, mesh=sh.mesh, scale=sh.scale))
        else:  # other formats (or decimated): the vertices as loaded, already in the link frame
            out.append(GeomDesc(sh.link, "mesh", vertices=g.vertices, faces=g.faces))
    return tuple(out)


def load_robot_desc(robot: str = "lwr4") -> RobotDesc:
    """The description of a named robot (:func:`depthguard.robot.robots.load_robot`: ``"lwr4"``, ``"panda"``,
    ...), read from the same URDF and geometry as the controller's model."""
    from depthguard.robot.robots import load_robot

    model = load_robot(robot)
    path = model.urdf_path
    ee_link = model.model.frames[model.ee_frame_id].name
    desc = parse_urdf(Path(path).read_text(), source=str(path), ee_link=ee_link, geoms=geoms_from_model(model))
    return RobotDesc(desc.name, desc.root, desc.joints, desc.geoms, desc.ee_link, desc.source, tuple(model.joint_names))
