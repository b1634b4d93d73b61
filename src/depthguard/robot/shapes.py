"""Collision shapes fixed to robot links: URDF ``<collision>`` elements and user attachments (tools, payloads).

A :class:`Shape` is plain data (a dataclass), so that shapes can come from a URDF, from code, or from a
cell file: ``Shape(link="panda_hand", kind="box", size=(0.1, 0.05, 0.2), xyz=(0, 0, 0.15))``.

Geometry (:class:`ShapeGeometry`, computed once at load time, in the *link* frame, metres):

* ``mesh`` (STL, OBJ, PLY, ... read with ``trimesh``; DAE needs ``pycollada``), ``box`` and ``cylinder``
  become triangle meshes. A cylinder becomes a prism whose polygon circumscribes its circle
  (``n_sides`` sides, radius ``r / cos(pi / n_sides)``), so the prism contains the cylinder. For the
  self-filter boxes also get :attr:`ShapeGeometry.filter_mesh`, their Minkowski sum with a polyhedral ball
  (:func:`depthguard.robot.inflation.rounded_offset_mesh`), which lies within the margin of the box.
* ``sphere`` and ``capsule`` stay analytic capsules (segment ``a``-``b`` swept by ``radius``); so does a
  cylinder that has a sphere of its radius at each end (the capsule idiom of URDF, as in the shipped arm).

``package://NAME/rest`` mesh paths are resolved against the URDF's own folders (a folder called ``NAME``
or holding a ``package.xml`` that names it), ``ROS_PACKAGE_PATH`` and the installed ``example-robot-data``
package; plain and ``file://`` paths are relative to the URDF's folder.
"""

from __future__ import annotations

import os
import sys
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from depthguard.robot.inflation import rounded_box

__all__ = ["Shape", "ShapeGeometry", "parse_collision_shapes", "resolve_mesh_path", "shape_geometry"]

KINDS = ("mesh", "box", "cylinder", "sphere", "capsule")


@dataclass(frozen=True)
class Shape:
    """One collision shape fixed to ``link``.

    Attributes:
        link: link (pinocchio BODY frame) the shape is fixed to.
        kind: ``"mesh"``, ``"box"``, ``"cylinder"``, ``"sphere"`` or ``"capsule"``.
        size: box ``(x, y, z)`` full edge lengths; cylinder and capsule ``(radius, length)`` (capsule length
            between the centres of its end spheres, along z); sphere ``(radius,)``; metres.
        mesh: mesh file (kind ``"mesh"``), absolute or relative to the working directory.
        scale: mesh scale per axis.
        xyz, rpy: pose of the shape in the link frame (URDF ``<origin>``: m, rad).
        name: optional label.
    """

    link: str
    kind: str
    size: tuple[float, ...] = ()
    mesh: str | None = None
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    name: str = ""

    def __post_init__(self) -> None:
        where = f"shape '{self.name or self.link}'"
        if self.kind not in KINDS:
            raise ValueError(f"{where}: kind must be one of {KINDS}, got {self.kind!r}")
        need = {"box": 3, "cylinder": 2, "capsule": 2, "sphere": 1, "mesh": 0}[self.kind]
        if len(self.size) != need or not all(np.isfinite(s) and s > 0 for s in self.size):
            raise ValueError(f"{where}: {self.kind} needs size of {need} positive numbers, got {self.size!r}")
        if self.kind == "mesh" and not self.mesh:
            raise ValueError(f"{where}: kind 'mesh' needs a mesh file")
        for nm in ("scale", "xyz", "rpy"):
            v = getattr(self, nm)
            if len(v) != 3 or not all(np.isfinite(x) for x in v):
                raise ValueError(f"{where}: {nm} must be 3 finite numbers, got {v!r}")

    @property
    def rotation(self) -> np.ndarray:
        """(3, 3) shape frame -> link frame."""
        return rpy_to_matrix(self.rpy)


@dataclass
class ShapeGeometry:
    """Link-frame geometry of one shape: a triangle mesh (``vertices`` (V, 3), ``faces`` (F, 3)) or an
    analytic capsule (``a``, ``b`` (3,), ``radius``), metres. ``source_vertices`` (P, 3) and
    ``source_radii`` (P,): what the ``auto`` control points cover: the vertices of the original mesh (before
    any decimation) and points sampled on its faces (radius 0); for a capsule, balls centred on its
    segment whose union contains it."""

    shape: Shape
    vertices: np.ndarray | None = None
    faces: np.ndarray | None = None
    a: np.ndarray | None = None
    b: np.ndarray | None = None
    radius: float = 0.0
    source_vertices: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    source_radii: np.ndarray | None = None  # (P,) balls around source_vertices to cover (None: points)
    slack: float = 0.0  # how far the original surface may lie outside ``vertices``' surface (decimation), m
    excess: float = 0.0  # how far ``vertices``' surface may lie outside the original surface (decimation), m
    # boxes: the self-filter's mesh with explicit inflation offsets (inflation.rounded_offset_mesh)
    filter_mesh: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    # a closed mesh: a capsule inside it (a, b, radius; link frame, m) for the robot-interior corrections
    inscribed: tuple[np.ndarray, np.ndarray, float] | None = None

    @property
    def is_mesh(self) -> bool:
        return self.vertices is not None


def rpy_to_matrix(rpy) -> np.ndarray:
    """URDF fixed-axis roll-pitch-yaw to a (3, 3) rotation: ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    r, p, y = (float(x) for x in rpy)
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


# ---------------------------------------------------------------------------------------------- URDF


def _package_roots(urdf_path: Path) -> list[Path]:
    roots = [p for p in urdf_path.resolve().parents]
    for entry in os.environ.get("ROS_PACKAGE_PATH", "").split(os.pathsep):
        if entry:
            roots.append(Path(entry))
    for sp in sys.path:  # the installed example-robot-data (cmeel layout) and friends
        share = Path(sp) / "cmeel.prefix" / "share"
        if share.is_dir():
            roots.append(share)
    return roots


def resolve_mesh_path(filename: str, urdf_path: Path) -> Path:
    """Resolve a URDF mesh ``filename`` (``package://``, ``file://`` or a path) to an existing file."""
    base = urdf_path.resolve().parent
    if filename.startswith("file://"):
        filename = filename[len("file://") :]
    if not filename.startswith("package://"):
        p = Path(filename)
        p = p if p.is_absolute() else base / p
        if p.is_file():
            return p
        raise ValueError(f"URDF {urdf_path}: mesh file '{filename}' not found (looked at {p})")
    pkg, _, rest = filename[len("package://") :].partition("/")
    tried = []
    for root in _package_roots(urdf_path):
        cands = [root / pkg / rest] if root.name != pkg else [root / rest]
        if (root / "package.xml").is_file() and f"<name>{pkg}</name>" in (root / "package.xml").read_text():
            cands.append(root / rest)
        for c in cands:
            tried.append(str(c))
            if c.is_file():
                return c
    raise ValueError(
        f"URDF {urdf_path}: cannot resolve '{filename}'; looked for package '{pkg}' in the URDF's folders, "
        f"ROS_PACKAGE_PATH and installed robot-data packages ({len(tried)} candidates, e.g. {tried[:2]})"
    )


def _vec3(
    text: str | None, default=(0.0, 0.0, 0.0), what: str = "", uniform: bool = False
) -> tuple[float, float, float]:
    if text is None:
        return default
    try:
        vals = [float(x) for x in text.split()]
    except ValueError:
        raise ValueError(f"URDF {what}: expected 3 numbers, got {text!r}") from None
    if len(vals) == 1 and uniform:  # URDF allows a uniform mesh scale (one number), nothing else
        vals = vals * 3
    if len(vals) != 3:
        raise ValueError(f"URDF {what}: expected 3 numbers, got {text!r}")
    return (vals[0], vals[1], vals[2])


def parse_collision_shapes(urdf_path: str | Path) -> list[Shape]:
    """All ``<collision>`` elements of a URDF as :class:`Shape` (mesh paths resolved to files)."""
    urdf_path = Path(urdf_path)
    root = ET.parse(urdf_path).getroot()
    out: list[Shape] = []
    for link in root.findall("link"):
        lname = link.get("name", "")
        for i, col in enumerate(link.findall("collision")):
            geom = col.find("geometry")
            if geom is None or len(geom) == 0:
                continue
            g = geom[0]
            org = col.find("origin")
            xyz = _vec3(org.get("xyz") if org is not None else None, what=f"link {lname} origin")
            rpy = _vec3(org.get("rpy") if org is not None else None, what=f"link {lname} origin")
            name = col.get("name") or f"{lname}/{i}"
            kw = dict(link=lname, xyz=xyz, rpy=rpy, name=name)
            if g.tag == "mesh":
                path = resolve_mesh_path(g.get("filename", ""), urdf_path)
                scale = _vec3(g.get("scale"), (1.0, 1.0, 1.0), f"link {lname} mesh scale", uniform=True)
                out.append(Shape(kind="mesh", mesh=str(path), scale=scale, **kw))
            elif g.tag == "box":
                out.append(Shape(kind="box", size=_vec3(g.get("size"), what=f"link {lname} box"), **kw))
            elif g.tag in ("cylinder", "capsule"):
                out.append(Shape(kind=g.tag, size=(float(g.get("radius")), float(g.get("length"))), **kw))
            elif g.tag == "sphere":
                out.append(Shape(kind="sphere", size=(float(g.get("radius")),), **kw))
            else:  # (RobotModel checks this first; here for direct callers)
                raise ValueError(
                    f"URDF {urdf_path}: link '{lname}' <collision> {name}: geometry <{g.tag}> not supported"
                )
    return out


# ------------------------------------------------------------------------------------------ geometry


def _box_mesh(size) -> tuple[np.ndarray, np.ndarray]:
    h = 0.5 * np.asarray(size, float)
    v = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float) * h
    f = np.array(
        [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6], [0, 2, 6],
         [0, 6, 4], [1, 5, 7], [1, 7, 3]]
    )  # fmt: skip
    return v, f


def _prism_mesh(radius: float, length: float, n_sides: int) -> tuple[np.ndarray, np.ndarray]:
    """A prism along z whose n-gon circumscribes the circle of ``radius`` (it contains the cylinder)."""
    rr = radius / np.cos(np.pi / n_sides)
    ang = 2 * np.pi * np.arange(n_sides) / n_sides
    ring = np.stack([rr * np.cos(ang), rr * np.sin(ang)], axis=1)
    v = np.vstack([np.c_[ring, np.full(n_sides, -0.5 * length)], np.c_[ring, np.full(n_sides, 0.5 * length)]])
    v = np.vstack([v, [[0, 0, -0.5 * length], [0, 0, 0.5 * length]]])
    faces = []
    for i in range(n_sides):
        j = (i + 1) % n_sides
        faces += [[i, j, n_sides + j], [i, n_sides + j, n_sides + i], [2 * n_sides, j, i]]
        faces += [[2 * n_sides + 1, n_sides + i, n_sides + j]]
    return v, np.array(faces)


def load_mesh(path: str, scale=(1.0, 1.0, 1.0)) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) m and faces (F, 3) of a mesh file, duplicate vertices merged, ``scale`` applied.

    A mirroring ``scale`` (an odd number of negative components, as URDF allows) also reverses every face's
    winding, so that the normals still point out of the solid."""
    try:
        import trimesh
    except ImportError as e:  # pragma: no cover
        raise ValueError("mesh collision geometry needs trimesh (pip install 'depthguard[robot]')") from e
    try:
        m = trimesh.load(path, force="mesh", process=True)
    except Exception as e:  # noqa: BLE001 - any loader failure is a bad file
        raise ValueError(f"mesh file '{path}' could not be read: {e}") from e
    if len(m.faces):
        trimesh.repair.fix_normals(m)  # consistent winding, outward normals (per connected body)
    v, f = np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)
    if len(f) == 0 or not np.all(np.isfinite(v)):
        raise ValueError(f"mesh file '{path}' has no triangles or non-finite vertices")
    scale = np.asarray(scale, float)
    if np.prod(np.sign(scale)) < 0:  # a mirror turns the outward normals inward: reverse the winding
        f = np.ascontiguousarray(f[:, ::-1])
    return v * scale, f


def capsule_balls(a: np.ndarray, b: np.ndarray, radius: float, spacing: float = 0.005) -> dict:
    """Balls whose union contains the capsule ``a``-``b`` of ``radius``: centres on the segment at most
    ``spacing`` apart, radius ``radius + spacing / 2`` (every capsule point is within ``radius`` of a segment
    point, which is within ``spacing / 2`` of a centre). As ShapeGeometry keyword arguments."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    n = int(np.ceil(np.linalg.norm(b - a) / spacing)) + 1
    centres = a + np.linspace(0.0, 1.0, n)[:, None] * (b - a)
    return {"source_vertices": centres, "source_radii": np.full(n, radius + 0.5 * spacing)}


def surface_points(v: np.ndarray, f: np.ndarray, spacing: float = 0.02) -> np.ndarray:
    """The vertices (V, 3) plus points on each triangle at most about ``spacing`` m apart (barycentric grid)."""
    tri = v[f]
    edge = np.max(np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2), axis=1)
    nsub = np.ceil(edge / spacing).astype(int)
    out = [v]
    for n in np.unique(nsub[nsub > 1]):
        ij = np.array([(i, j) for i in range(n + 1) for j in range(n + 1 - i)], float) / n
        w = np.c_[ij, 1.0 - ij.sum(axis=1)]  # (G, 3) barycentric weights
        out.append(np.einsum("gk,tkd->tgd", w, tri[nsub == n]).reshape(-1, 3))
    return np.vstack(out)


def shape_geometry(shape: Shape, n_sides: int = 24) -> ShapeGeometry:
    """Link-frame geometry of one shape (rules in the module docstring)."""
    R, p = shape.rotation, np.asarray(shape.xyz, float)
    if shape.kind in ("sphere", "capsule"):
        r = shape.size[0]
        half = 0.0 if shape.kind == "sphere" else 0.5 * shape.size[1]
        a, b = p - R[:, 2] * half, p + R[:, 2] * half
        return ShapeGeometry(shape, a=a, b=b, radius=float(r), **capsule_balls(a, b, r))
    filt = None
    if shape.kind == "mesh":
        v, f = load_mesh(shape.mesh, shape.scale)
    elif shape.kind == "box":
        v, f = _box_mesh(shape.size)
        filt = rounded_box(shape.size)
    else:
        v, f = _prism_mesh(shape.size[0], shape.size[1], n_sides)
    v = v @ R.T + p
    if filt is not None:
        filt = (filt[0] @ R.T + p, filt[1] @ R.T, filt[2])
    return ShapeGeometry(shape, vertices=v, faces=f, source_vertices=surface_points(v, f), filter_mesh=filt)


def capsule_idiom(shapes: list[Shape]) -> tuple[list[ShapeGeometry], list[Shape]]:
    """Find cylinders with a sphere of their radius at each end (URDF's capsule idiom).

    Returns the merged capsules (as geometry) and the shapes left over (spheres at such ends consumed).
    """
    used: set[int] = set()
    caps: list[ShapeGeometry] = []
    for i, s in enumerate(shapes):
        if s.kind != "cylinder":
            continue
        r, half = s.size[0], 0.5 * s.size[1]
        R, p = s.rotation, np.asarray(s.xyz, float)
        a, b = p - R[:, 2] * half, p + R[:, 2] * half
        ends = []
        for end in (a, b):
            k = next(
                (
                    j
                    for j, t in enumerate(shapes)
                    if j not in used and t.link == s.link and t.kind == "sphere" and abs(t.size[0] - r) < 1e-9
                    and np.linalg.norm(np.asarray(t.xyz) - end) < 1e-6
                ),
                None,
            )  # fmt: skip
            ends.append(k)
        if None in ends:
            continue
        used.update([i, *ends])
        cap = Shape(link=s.link, kind="capsule", size=(r, 2 * half), xyz=s.xyz, rpy=s.rpy, name=s.name)
        caps.append(ShapeGeometry(cap, a=a, b=b, radius=float(r), **capsule_balls(a, b, r)))
    rest = [s for i, s in enumerate(shapes) if i not in used]
    return caps, rest
