"""What :class:`depthguard.robot.model.RobotModel` cannot represent faithfully in a URDF, found before anything is
built: :func:`check_urdf` raises ``ValueError`` naming the joint or link (docs/robots.md, "Loading a robot")."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

__all__ = ["check_urdf", "continuous_as_revolute"]

_GEOMETRIES = ("box", "cylinder", "sphere", "mesh", "capsule")


def _numbers(text: str | None, n: int, what: str) -> list[float] | None:
    """``n`` finite numbers from an XML attribute (None if absent), or ``ValueError`` naming ``what``."""
    if text is None:
        return None
    try:
        vals = [float(x) for x in text.split()]
    except ValueError:
        vals = []
    if len(vals) != n or not all(np.isfinite(vals)):
        raise ValueError(f"{what}: expected {n} finite numbers, got {text!r}")
    return vals


def _check_limit(lim: ET.Element | None, typ: str, jw: str) -> None:
    """``ValueError`` naming the joint ``jw`` unless its ``<limit>`` bounds it (rules in :func:`check_urdf`)."""
    if lim is None:
        why = "its speed is unknown" if typ == "continuous" else "URDF requires one"
        raise ValueError(f"{jw} is {typ} without <limit> ({why}; give <limit velocity=... effort=...>)")
    for attr in ("velocity", "effort"):
        if lim.get(attr) is None:
            raise ValueError(f"{jw}: <limit> has no {attr} (URDF requires it; velocity in rad/s or m/s)")
    vel = _numbers(lim.get("velocity"), 1, f"{jw} <limit velocity>")[0]
    eff = _numbers(lim.get("effort"), 1, f"{jw} <limit effort>")[0]
    if vel < 0:
        raise ValueError(f"{jw}: <limit velocity> must be >= 0 (the joint's top speed), got {lim.get('velocity')!r}")
    if eff < 0:
        raise ValueError(f"{jw}: <limit effort> must be >= 0, got {lim.get('effort')!r}")
    if typ == "continuous":
        return  # (lower / upper, if given, mean nothing for a continuous joint: URDF spec)
    lo = _numbers(lim.get("lower", "0"), 1, f"{jw} <limit lower>")[0]
    hi = _numbers(lim.get("upper", "0"), 1, f"{jw} <limit upper>")[0]
    if lo > hi:
        raise ValueError(f"{jw}: <limit> lower {lo} > upper {hi}")


def continuous_as_revolute(root: ET.Element) -> tuple[str, list[str]]:
    """The URDF text with every ``continuous`` joint made ``revolute`` (limits ±1 rad as placeholders: the
    caller sets them to ±inf on the built model), and the names of those joints.

    pinocchio builds a continuous joint with two coordinates (cos, sin); DepthGuard's ``q`` has one per
    joint, the angle in rad, unbounded (docs/robots.md). ``root`` is not modified."""
    import copy

    root = copy.deepcopy(root)
    names = []
    for joint in root.findall("joint"):
        if joint.get("type") == "continuous":
            joint.set("type", "revolute")
            lim = joint.find("limit")  # check_urdf made sure it exists
            lim.set("lower", "-1")
            lim.set("upper", "1")
            names.append(joint.get("name", ""))
    return ET.tostring(root, encoding="unicode"), names


def check_urdf(root: ET.Element, urdf_path: Path) -> None:
    """``ValueError`` naming the element for what :class:`RobotModel` cannot represent faithfully.

    Joints must be ``revolute`` or ``prismatic`` with a ``<limit>`` (``lower <= upper``, finite
    ``effort >= 0``, finite ``velocity >= 0``: the speed bounds every motion the controller plans; 0 holds the
    joint) and a non-zero axis, ``continuous`` with a ``<limit>`` giving ``velocity`` and ``effort`` (loaded as
    a revolute joint without position limits: :func:`continuous_as_revolute`), or ``fixed``: a ``planar`` or
    ``floating`` joint has no one-coordinate form here (pinocchio would give it 3-7 coordinates). The root must
    be ``<robot name="...">``. Origins need 3 finite numbers per ``xyz`` / ``rpy``;
    ``<collision>`` elements one geometry of box, cylinder, sphere, mesh or capsule, with positive finite
    sizes (a mesh: a filename). Mimic joints are loaded as coordinates of their own (docs/robots.md).
    """
    where = f"URDF {urdf_path}"
    if root.tag != "robot" or not root.get("name"):
        raise ValueError(f'{where}: the root element must be <robot name="..."> (URDF requires the name)')
    for joint in root.findall("joint"):
        name, typ = joint.get("name", ""), joint.get("type", "")
        jw = f"{where}: joint '{name}'"
        if typ in ("planar", "floating"):
            raise ValueError(
                f"{jw} is {typ}: not supported (only revolute, continuous and prismatic joints with <limit>, "
                "and fixed joints)"
            )
        if typ not in ("revolute", "continuous", "prismatic", "fixed"):
            raise ValueError(f"{jw}: unknown joint type {typ!r}")
        org = joint.find("origin")
        if org is not None:
            _numbers(org.get("xyz"), 3, f"{jw} <origin xyz>")
            _numbers(org.get("rpy"), 3, f"{jw} <origin rpy>")
        if typ == "fixed":
            continue
        ax = joint.find("axis")
        axis = _numbers(ax.get("xyz") if ax is not None else None, 3, f"{jw} <axis xyz>")
        if axis is not None and np.linalg.norm(axis) < 1e-12:
            raise ValueError(f"{jw}: <axis xyz> is zero, {ax.get('xyz')!r}")
        _check_limit(joint.find("limit"), typ, jw)
    for link in root.findall("link"):
        lname = link.get("name", "")
        for i, col in enumerate(link.findall("collision")):
            cw = f"{where}: link '{lname}' <collision> {col.get('name') or i}"
            org = col.find("origin")
            if org is not None:
                _numbers(org.get("xyz"), 3, f"{cw} <origin xyz>")
                _numbers(org.get("rpy"), 3, f"{cw} <origin rpy>")
            geom = col.find("geometry")
            if geom is None or len(geom) != 1:
                raise ValueError(f"{cw}: needs exactly one geometry in <geometry>")
            g = geom[0]
            if g.tag not in _GEOMETRIES:
                raise ValueError(f"{cw}: geometry <{g.tag}> is not supported (only {', '.join(_GEOMETRIES)})")
            if g.tag == "mesh":
                if not g.get("filename"):
                    raise ValueError(f"{cw}: <mesh> has no filename")
                sc = g.get("scale")
                if sc is not None:
                    vals = _numbers(sc, 1 if len(sc.split()) == 1 else 3, f"{cw} <mesh scale>")
                    if min(abs(v) for v in vals) == 0.0:
                        raise ValueError(f"{cw}: <mesh scale> {sc!r} flattens the mesh (a zero factor)")
                continue
            need = {"box": [("size", 3)], "sphere": [("radius", 1)]}.get(g.tag, [("radius", 1), ("length", 1)])
            for attr, n in need:
                vals = _numbers(g.get(attr), n, f"{cw} <{g.tag} {attr}>")
                if vals is None or min(vals) <= 0:
                    raise ValueError(f"{cw}: <{g.tag}> needs {attr} of {n} positive number(s), got {g.get(attr)!r}")
