"""The ``[robot]`` section of a cell file (:mod:`depthguard.io.cellfile`): a shipped model or a URDF, the
control-point preset, explicit control spheres and attached tools and payloads."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from depthguard.io.cell_schema import _NUM, CellError, _finite, _section, _vector

__all__ = ["CONTROL_POINT_CHOICES", "MAX_ATTACHMENT_SIZE", "MODEL_EE_FRAMES", "Attachment", "CellRobot", "Sphere"]

#: ``robot.control_points``: the presets of :data:`depthguard.robot.control_points.PRESETS` (not imported here,
#: to keep reading a cell file free of pinocchio; a test keeps the two equal), "auto" and "ee" (the end effector
#: alone)
CONTROL_POINT_CHOICES = ("ral-9", "icra-exp3", "auto", "ee")
#: ``robot.ee_frame`` of each shipped model (its end effector is fixed; a test keeps this equal to the model's)
MODEL_EE_FRAMES = {"lwr4": "lwr_ee"}
#: the largest size (m) of a tool or payload: ``robot.attachments[i].size`` (a larger one is mm, not m)
MAX_ATTACHMENT_SIZE = 10.0


@dataclass(frozen=True)
class Sphere:
    """An explicit control sphere: centre ``position`` (3,) m in ``link``'s frame, ``radius`` m."""

    link: str
    position: tuple[float, float, float]
    radius: float


@dataclass(frozen=True)
class Attachment:
    """A tool or payload fixed to ``link``: a primitive or a mesh, posed by ``xyz`` (m) and ``rpy`` (rad)."""

    name: str
    link: str
    shape: str
    size: tuple[float, ...] = ()
    mesh: Path | None = None
    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class CellRobot:
    model: str | None
    urdf: Path | None
    ee_frame: str | None
    joint_names: tuple[str, ...] | None
    control_points: str
    ee_radius: float
    spheres: tuple[Sphere, ...]
    attachments: tuple[Attachment, ...]


def robot_section(src: Path, table: Any) -> CellRobot:
    """The ``[robot]`` table ``table`` of the cell file ``src``, checked (``CellError`` naming the key)."""
    r = _section(src, "robot", "robot", table)
    if (r["model"] is None) == (r["urdf"] is None):
        raise CellError(f"{src}: [robot] needs exactly one of 'model' (a shipped model: lwr4) or 'urdf' (a path)")
    if r["model"] is not None and r["model"] not in MODEL_EE_FRAMES:
        raise CellError(
            f"{src}: robot.model must be one of {list(MODEL_EE_FRAMES)}, got {r['model']!r} (or give 'urdf')"
        )
    if r["model"] is not None and r["ee_frame"] not in (None, MODEL_EE_FRAMES[r["model"]]):  # (it would be ignored)
        raise CellError(
            f"{src}: robot.ee_frame of the shipped model {r['model']!r} is {MODEL_EE_FRAMES[r['model']]!r}, got"
            f" {r['ee_frame']!r} (leave it out, or give 'urdf' to choose another end effector)"
        )
    urdf = None
    if r["urdf"] is not None:
        urdf = (src.parent / r["urdf"]).resolve()
        if not urdf.is_file():
            raise CellError(f"{src}: robot.urdf '{r['urdf']}' is not a file (looked at {urdf})")
    if r["control_points"] not in CONTROL_POINT_CHOICES:
        raise CellError(
            f"{src}: robot.control_points must be one of {list(CONTROL_POINT_CHOICES)}, got {r['control_points']!r}"
        )
    names = r["joint_names"]
    if names is not None and (
        not names or not all(isinstance(x, str) and x for x in names) or len(set(names)) < len(names)
    ):
        raise CellError(f"{src}: robot.joint_names must name each joint once (non-empty strings), got {names!r}")
    spheres = []
    for i, s in enumerate(r["spheres"]):
        s = _section(src, f"robot.spheres[{i}]", "sphere", s)
        pos = _vector(src, f"robot.spheres[{i}].position", s["position"], 3)
        if s["radius"] < 0:
            raise CellError(f"{src}: robot.spheres[{i}].radius must be >= 0")
        spheres.append(Sphere(s["link"], pos, float(s["radius"])))  # type: ignore[arg-type]
    atts = []
    for i, a in enumerate(r["attachments"]):
        where = f"robot.attachments[{i}]"
        a = _section(src, where, "attachment", a)
        numbers = all(isinstance(x, _NUM) and not isinstance(x, bool) and _finite(x) for x in a["size"])
        size = tuple(float(x) for x in a["size"]) if numbers else None
        need = {"box": 3, "cylinder": 2, "sphere": 1, "mesh": 0}[a["shape"]]
        if size is None or len(size) != need or not all(0 < x <= MAX_ATTACHMENT_SIZE for x in size):
            raise CellError(  # (a size in mm taken for m would also make the cover sample a huge surface)
                f"{src}: {where}.size must be {need} numbers in (0, {MAX_ATTACHMENT_SIZE:g}] m for a {a['shape']},"
                f" got {a['size']}"
            )
        mesh = None
        if a["shape"] != "mesh" and a["mesh"] is not None:  # (it would be ignored)
            raise CellError(f'{src}: {where}.mesh is for shape = "mesh", not a {a["shape"]}: remove one of them')
        if a["shape"] == "mesh":
            if a["mesh"] is None:
                raise CellError(f"{src}: {where} is a mesh: give 'mesh' (a path to an STL/OBJ/DAE file)")
            mesh = (src.parent / a["mesh"]).resolve()
            if not mesh.is_file():
                raise CellError(f"{src}: {where}.mesh '{a['mesh']}' is not a file")
        xyz = _vector(src, f"{where}.xyz", a["xyz"], 3)
        rpy = _vector(src, f"{where}.rpy", a["rpy"], 3)
        atts.append(Attachment(a["name"], a["link"], a["shape"], size, mesh, xyz, rpy))  # type: ignore[arg-type]
    return CellRobot(
        r["model"],
        urdf,
        r["ee_frame"],
        tuple(names) if names is not None else None,
        r["control_points"],
        float(r["ee_radius"]),
        tuple(spheres),
        tuple(atts),
    )
