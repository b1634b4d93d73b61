"""URDF loading attacked with random robots, against a reference written here from the URDF specification.

A hypothesis strategy draws small robots: serial chains and trees of revolute, continuous (angles beyond a
turn; ``<limit>`` with or without meaningless lower/upper), prismatic and fixed joints (axes aligned,
negative, non-unit and unaligned; origins with rpy at and near +-pi and at gimbal lock;
random limits), optional mimic joints, and links with 0-3 ``<collision>`` elements (box, cylinder, sphere,
mesh files written here with trimesh: a convex box STL and a non-convex annulus OBJ, each off-centre, with
uniform, non-uniform and negative ``scale``, by ``package://`` or relative path). Each robot is written to a
temporary folder and loaded with :meth:`RobotModel.from_urdf`.

The reference never uses depthguard (or pinocchio): it parses the URDF text with ``xml.etree`` and composes
``Trans(xyz) Rz(yaw) Ry(pitch) Rx(roll)`` and the joint motion (rotation about the normalised axis, or
translation along it) with numpy; mesh vertices are the arrays the meshes were made from. Checked: joint
names, order of ``q`` and limits; link poses, joint poses and WORLD Jacobians; frame and point Jacobians by
finite differences of the reference; the self-filter's shapes (vertices placed and sized like the URDF's
collision elements, faces wound outwards, inflation offsets pointing out of the solid and at most one margin
long); the analytic spheres; the coarse capsules holding every primitive; the ``auto`` control spheres
holding every collision vertex and surface point of every moving link, their Jacobians; and clear
``ValueError`` naming the element for what the loader cannot represent (planar and floating joints, a
continuous joint without a speed, a zero axis, missing or inverted limits, a ``<limit>`` without a finite
``velocity >= 0`` or ``effort >= 0``, an unknown geometry, malformed origins and scales).

Documented limits not claimed here: a mimic joint is an independent coordinate of ``q`` (its multiplier and
offset are not applied; docs/robots.md), and the coarse capsules of mesh-only links are a fallback that need
not hold the mesh (model docstring).
"""

from __future__ import annotations

import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

pytest.importorskip("pinocchio")
trimesh = pytest.importorskip("trimesh")

from depthguard.robot.control_points import ControlPointSet  # noqa: E402
from depthguard.robot.model import RobotModel  # noqa: E402

PKG = "gen_robot_description"
N_SIDES = 24  # the prism that the self-filter draws for a cylinder (shapes.shape_geometry)


# ------------------------------------------------------------------------------------------ mesh files


def _mesh_sources() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Vertices and faces of the mesh files, off-centre so that a wrong sign of scale or origin shows."""
    box = trimesh.creation.box(extents=(0.08, 0.12, 0.2))
    box.apply_translation((0.01, -0.02, 0.03))
    ring = trimesh.creation.annulus(r_min=0.02, r_max=0.05, height=0.08, sections=12)
    ring.apply_translation((0.005, 0.0, 0.01))
    # the values the files hold exactly: STL stores float32, OBJ decimals (trimesh writes 8 digits)
    return {
        "box.stl": (np.round(box.vertices, 6).astype(np.float32).astype(float), np.array(box.faces)),
        "ring.obj": (np.round(ring.vertices, 6), np.array(ring.faces)),
    }


MESHES = _mesh_sources()
CONVEX = {"box.stl": True, "ring.obj": False}


def _write_package(root: Path) -> Path:
    """``root/PKG/{package.xml, meshes/*, urdf/}``; returns the urdf folder."""
    pkg = root / PKG
    (pkg / "meshes").mkdir(parents=True)
    (pkg / "urdf").mkdir()
    (pkg / "package.xml").write_text(f"<package><name>{PKG}</name></package>")
    for name, (v, f) in MESHES.items():
        trimesh.Trimesh(v, f, process=False).export(pkg / "meshes" / name)
    return pkg / "urdf"


# ------------------------------------------------------------------------------------------ the strategy

SPECIAL = [0.0, np.pi, -np.pi, np.pi / 2, -np.pi / 2, np.pi - 1e-9, -np.pi + 1e-7, np.pi / 2 - 1e-10, 1e-13]
_angle = st.one_of(st.sampled_from(SPECIAL), st.floats(-np.pi, np.pi, allow_nan=False))
_rpy = st.one_of(
    st.tuples(_angle, _angle, _angle),
    st.tuples(_angle, st.sampled_from([np.pi / 2, -np.pi / 2, np.pi / 2 - 1e-10]), _angle),  # gimbal lock
)
_xyz = st.tuples(*[st.floats(-0.4, 0.4, allow_nan=False)] * 3)
_unit_axes = [(1, 0, 0), (0, 1, 0), (0, 0, 1), (-1, 0, 0), (0, -1, 0), (0, 0, -1), (0, 0, 2), (0, -3, 0)]
_axis = st.one_of(
    st.sampled_from(_unit_axes),
    st.tuples(*[st.floats(-2.0, 2.0, allow_nan=False)] * 3).filter(lambda a: np.linalg.norm(a) > 0.2),
)
_size = st.floats(0.01, 0.2, allow_nan=False)
_scale_component = st.one_of(st.floats(0.3, 2.0), st.floats(-2.0, -0.3))
_scale = st.one_of(
    st.none(),
    st.one_of(st.floats(0.3, 2.0), st.floats(-2.0, -0.3)).map(lambda s: (s,)),  # URDF's uniform scale
    st.tuples(_scale_component, _scale_component, _scale_component),
)


@st.composite
def _collision(draw) -> dict:
    # "idiom": a cylinder with a sphere of its radius at each end (URDF's capsule idiom; three elements)
    kind = draw(st.sampled_from(["box", "cylinder", "sphere", "mesh", "mesh", "capsule", "idiom"]))
    origin = draw(st.one_of(st.none(), st.tuples(_xyz, _rpy), st.tuples(_xyz, st.none())))
    c: dict = {"kind": kind, "origin": origin}
    if kind == "box":
        c["size"] = draw(st.tuples(_size, _size, _size))
    elif kind in ("cylinder", "capsule", "idiom"):
        c["size"] = (draw(_size), draw(_size))
    elif kind == "sphere":
        c["size"] = (draw(_size),)
    else:
        c["file"] = draw(st.sampled_from(sorted(MESHES)))
        c["ref"] = draw(st.sampled_from(["package", "relative"]))
        c["scale"] = draw(_scale)
    return c


@st.composite
def robots(draw, mimic: bool = True) -> dict:
    """A random robot description (rendered to URDF text by :func:`urdf_text`)."""
    n = draw(st.integers(1, 5))
    joints = []
    for i in range(1, n + 1):
        chain = i == 1 or draw(st.booleans())
        parent = i - 1 if chain else draw(st.integers(0, i - 1))
        typ = draw(st.sampled_from(["revolute", "revolute", "prismatic", "fixed", "continuous"]))
        lower = draw(st.floats(-3.0, 0.5))
        origin = draw(st.one_of(st.none(), st.tuples(_xyz, _rpy), st.tuples(_xyz, st.none())))
        joints.append(
            {
                "name": f"l{i}" if draw(st.booleans()) else f"j{i}",  # (a joint may share its child's name)
                "type": typ,
                "parent": parent,
                "child": i,
                "axis": draw(st.one_of(st.none(), _axis)),
                "origin": origin,
                "lower": lower,
                "upper": lower + draw(st.floats(0.0, 3.0)),
                "velocity": draw(st.floats(0.1, 5.0)),
                "mimic": None,
            }
        )
    if all(j["type"] == "fixed" for j in joints):
        joints[0]["type"] = "revolute"
    movable = [j for j in joints if j["type"] != "fixed"]
    if mimic and len(movable) >= 2 and draw(st.booleans()):
        j = movable[-1]
        j["mimic"] = (movable[0]["name"], draw(st.floats(-2.0, 2.0)), draw(st.floats(-0.5, 0.5)))
    links = [{"name": "base"}] + [{"name": f"l{i}"} for i in range(1, n + 1)]
    for k, link in enumerate(links):
        link["collisions"] = draw(st.lists(_collision(), max_size=3))
        for c_i, c in enumerate(link["collisions"]):
            c["name"] = f"c{k}_{c_i}"
    return {"links": links, "joints": joints, "order": (draw(st.randoms()).random(), draw(st.randoms()).random())}


def _f(x: float) -> str:
    return repr(float(x))


def _origin_xml(origin) -> str:
    if origin is None:
        return ""
    xyz, rpy = origin
    s = f'<origin xyz="{" ".join(map(_f, xyz))}"'
    return s + (f' rpy="{" ".join(map(_f, rpy))}"/>' if rpy is not None else "/>")


def _idiom_spheres(c: dict) -> str:
    """The two end spheres of a capsule-idiom cylinder ``c``, as collision elements."""
    xyz, rpy = c["origin"] if c["origin"] is not None else ((0, 0, 0), None)
    R = _rot(rpy if rpy is not None else (0, 0, 0))
    out = ""
    for k, sgn in enumerate((-1, 1)):
        end = np.asarray(xyz, float) + sgn * 0.5 * c["size"][1] * R[:, 2]
        out += f'<collision name="{c["name"]}_s{k}">{_origin_xml((tuple(end), None))}'
        out += f'<geometry><sphere radius="{_f(c["size"][0])}"/></geometry></collision>'
    return out


def urdf_text(robot: dict) -> str:
    """The URDF text; links and joints in a shuffled order (``robot["order"]``: two seeds)."""
    order = robot.get("order", (0.0, 0.0))
    out = ['<robot name="gen">']
    links = list(robot["links"])
    np.random.default_rng(int(order[0] * 2**32)).shuffle(links)
    for link in links:
        out.append(f'<link name="{link["name"]}">')
        for c in link["collisions"]:
            if c["kind"] == "box":
                g = f'<box size="{" ".join(map(_f, c["size"]))}"/>'
            elif c["kind"] in ("cylinder", "capsule", "idiom"):
                tag = "capsule" if c["kind"] == "capsule" else "cylinder"
                g = f'<{tag} radius="{_f(c["size"][0])}" length="{_f(c["size"][1])}"/>'
            elif c["kind"] == "sphere":
                g = f'<sphere radius="{_f(c["size"][0])}"/>'
            else:
                fn = f"package://{PKG}/meshes/{c['file']}" if c["ref"] == "package" else f"../meshes/{c['file']}"
                sc = "" if c["scale"] is None else f' scale="{" ".join(map(_f, c["scale"]))}"'
                g = f'<mesh filename="{fn}"{sc}/>'
            out.append(f'<collision name="{c["name"]}">{_origin_xml(c["origin"])}<geometry>{g}</geometry></collision>')
            if c["kind"] == "idiom":
                out.append(_idiom_spheres(c))
        out.append("</link>")
    names = [link["name"] for link in robot["links"]]
    joints = list(robot["joints"])
    np.random.default_rng(int(order[1] * 2**32)).shuffle(joints)
    for j in joints:
        s = f'<joint name="{j["name"]}" type="{j["type"]}"><parent link="{names[j["parent"]]}"/>'
        s += f'<child link="{names[j["child"]]}"/>{_origin_xml(j["origin"])}'
        if j["type"] != "fixed":
            if j["axis"] is not None:
                s += f'<axis xyz="{" ".join(map(_f, j["axis"]))}"/>'
            if j["type"] == "continuous" and j["lower"] < -1.5:  # (a continuous joint's lower/upper mean nothing)
                s += f'<limit velocity="{_f(j["velocity"])}" effort="1"/>'
            else:
                lim = f'lower="{_f(j["lower"])}" upper="{_f(j["upper"])}" velocity="{_f(j["velocity"])}"'
                s += f'<limit {lim} effort="1"/>'
            if j["mimic"] is not None:
                m, mult, off = j["mimic"]
                s += f'<mimic joint="{m}" multiplier="{_f(mult)}" offset="{_f(off)}"/>'
        out.append(s + "</joint>")
    out.append("</robot>")
    return "\n".join(out)


# ------------------------------------------------------------------------------------------ the reference


def _rot(rpy) -> np.ndarray:
    r, p, y = rpy
    Rx = np.array([[1, 0, 0], [0, np.cos(r), -np.sin(r)], [0, np.sin(r), np.cos(r)]])
    Ry = np.array([[np.cos(p), 0, np.sin(p)], [0, 1, 0], [-np.sin(p), 0, np.cos(p)]])
    Rz = np.array([[np.cos(y), -np.sin(y), 0], [np.sin(y), np.cos(y), 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def _nums(text: str | None, default) -> np.ndarray:
    return np.array(default if text is None else [float(x) for x in text.split()], float)


def _origin_T(elem) -> np.ndarray:
    T = np.eye(4)
    if elem is not None:
        T[:3, :3] = _rot(_nums(elem.get("rpy"), [0, 0, 0]))
        T[:3, 3] = _nums(elem.get("xyz"), [0, 0, 0])
    return T


def _axis_angle(u: np.ndarray, t: float) -> np.ndarray:
    K = np.array([[0, -u[2], u[1]], [u[2], 0, -u[0]], [-u[1], u[0], 0]])
    return np.eye(3) + np.sin(t) * K + (1 - np.cos(t)) * K @ K


class Reference:
    """The URDF read per the specification (xml.etree + numpy only)."""

    def __init__(self, text: str, urdf_dir: Path) -> None:
        root = ET.fromstring(text)
        self.urdf_dir = urdf_dir
        self.joints = {}
        self.child_of = {}
        for j in root.findall("joint"):
            axis = _nums(j.find("axis").get("xyz") if j.find("axis") is not None else None, [1, 0, 0])
            lim = j.find("limit")
            self.joints[j.get("name")] = {
                "type": j.get("type"),
                "parent": j.find("parent").get("link"),
                "child": j.find("child").get("link"),
                "T0": _origin_T(j.find("origin")),
                "axis": axis / np.linalg.norm(axis),
                # continuous: no position limits (URDF spec), q is the angle
                "lower": -np.inf if j.get("type") == "continuous" else None if lim is None else float(lim.get("lower")),
                "upper": np.inf if j.get("type") == "continuous" else None if lim is None else float(lim.get("upper")),
                "velocity": None if lim is None else float(lim.get("velocity")),
            }
            self.child_of[j.find("child").get("link")] = j.get("name")
        self.links = [link.get("name") for link in root.findall("link")]
        self.collisions = {}  # name -> (link, kind, T link<-shape, params)
        for link in root.findall("link"):
            for c in link.findall("collision"):
                g = c.find("geometry")[0]
                params = {k: v for k, v in g.attrib.items()}
                self.collisions[c.get("name")] = (link.get("name"), g.tag, _origin_T(c.find("origin")), params)
        self.movable = [n for n, j in self.joints.items() if j["type"] != "fixed"]

    def link_poses(self, qmap: dict[str, float]) -> dict[str, np.ndarray]:
        T = {}

        def pose(link: str) -> np.ndarray:
            if link in T:
                return T[link]
            if link not in self.child_of:
                T[link] = np.eye(4)  # the root
                return T[link]
            j = self.joints[self.child_of[link]]
            M = np.eye(4)
            if j["type"] in ("revolute", "continuous"):
                M[:3, :3] = _axis_angle(j["axis"], qmap[self.child_of[link]])
            elif j["type"] == "prismatic":
                M[:3, 3] = j["axis"] * qmap[self.child_of[link]]
            T[link] = pose(j["parent"]) @ j["T0"] @ M
            return T[link]

        for link in self.links:
            pose(link)
        return T

    def moving(self, link: str) -> bool:
        while link in self.child_of:
            j = self.joints[self.child_of[link]]
            if j["type"] != "fixed":
                return True
            link = j["parent"]
        return False

    def shape_points(self, name: str, surface: bool = True) -> np.ndarray:
        """Points of collision ``name`` in its link frame: corners / vertices, plus surface samples."""
        _, kind, T, prm = self.collisions[name]
        rng = np.random.default_rng(0)
        if kind == "box":
            h = 0.5 * _nums(prm["size"], None)
            pts = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float) * h
            if surface:
                u = rng.uniform(-1, 1, (300, 3))
                ax = rng.integers(0, 3, 300)
                u[np.arange(300), ax] = np.sign(u[np.arange(300), ax])
                pts = np.vstack([pts, u * h])
        elif kind == "cylinder":
            r, L = float(prm["radius"]), float(prm["length"])
            t = np.linspace(0, 2 * np.pi, 73)
            rim = np.c_[r * np.cos(t), r * np.sin(t), np.zeros_like(t)]
            pts = np.vstack([rim + [0, 0, -L / 2], rim + [0, 0, L / 2]])
            if surface:
                z = rng.uniform(-L / 2, L / 2, 200)
                a = rng.uniform(0, 2 * np.pi, 200)
                pts = np.vstack([pts, np.c_[r * np.cos(a), r * np.sin(a), z], [[0, 0, -L / 2], [0, 0, L / 2]]])
        elif kind in ("sphere", "capsule"):
            r = float(prm["radius"])
            d = rng.normal(size=(200, 3))
            d = np.vstack([np.eye(3), -np.eye(3), d / np.linalg.norm(d, axis=1, keepdims=True)])
            pts = r * d
            if kind == "capsule":  # the end balls' surfaces
                half = 0.5 * float(prm["length"])
                pts = np.vstack([pts + [0, 0, -half], pts + [0, 0, half]])
        else:
            v, f = self.mesh(name)
            pts = v
            if surface:
                w = rng.dirichlet([1, 1, 1], size=(len(f), 6))
                pts = np.vstack([v, np.einsum("fsk,fkd->fsd", w, v[f]).reshape(-1, 3)])
        return pts @ T[:3, :3].T + T[:3, 3]

    def mesh(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """Scaled vertices (mesh frame, before the collision origin) and faces of a mesh collision."""
        _, _, _, prm = self.collisions[name]
        v, f = MESHES[prm["filename"].rsplit("/", 1)[1]]
        s = _nums(prm.get("scale"), [1, 1, 1])
        return v * (s if len(s) == 3 else np.full(3, s[0])), f

    def inside(self, name: str, pts_link: np.ndarray) -> np.ndarray:
        """Whether points (link frame) lie strictly inside the solid of collision ``name``."""
        _, kind, T, prm = self.collisions[name]
        x = (pts_link - T[:3, 3]) @ T[:3, :3]  # shape frame
        if kind == "box":
            return np.all(np.abs(x) < 0.5 * _nums(prm["size"], None), axis=1)
        if kind == "cylinder":
            r, L = float(prm["radius"]), float(prm["length"])
            return (np.hypot(x[:, 0], x[:, 1]) < r) & (np.abs(x[:, 2]) < L / 2)
        v, f = self.mesh(name)
        return np.asarray(trimesh.Trimesh(v, f, process=False).contains(x))


# ------------------------------------------------------------------------------------------ loading


class Loaded:
    def __init__(self, robot: dict) -> None:
        self._tmp = tempfile.TemporaryDirectory()
        urdf_dir = _write_package(Path(self._tmp.name))
        self.text = urdf_text(robot)
        self.path = urdf_dir / "gen.urdf"
        self.path.write_text(self.text)
        self.ref = Reference(self.text, urdf_dir)
        self.model = RobotModel.from_urdf(self.path)

    def close(self) -> None:
        self._tmp.cleanup()

    def qmap(self, q: np.ndarray) -> dict[str, float]:
        return dict(zip(self.model.joint_names, q.tolist(), strict=True))

    def joint_frames(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Reference world rotations (J+1, 3, 3) and origins (J+1, 3) of the model's joints (0: world)."""
        T = self.ref.link_poses(self.qmap(q))
        H = [np.eye(4)] + [T[self.ref.joints[n]["child"]] for n in self.model.joint_names]
        H = np.array(H)
        return H[:, :3, :3], H[:, :3, 3]

    def random_q(self, rng: np.random.Generator) -> np.ndarray:
        lo, hi = self.model.q_min, self.model.q_max  # (continuous joints: ±20 rad, beyond a turn)
        return rng.uniform(np.where(np.isfinite(lo), lo - 0.5, -20.0), np.where(np.isfinite(hi), hi + 0.5, 20.0))


def _load(robot: dict) -> Loaded:
    return Loaded(robot)


_SUPPRESS = dict(deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

# A robot that hits every mesh case at once: mirrored (negative-determinant) scales of the convex box STL
# and of the non-convex ring, a non-uniform positive scale, gimbal-lock and +-pi origins.
MIRRORED = {
    "links": [
        {"name": "base", "collisions": []},
        {
            "name": "l1",
            "collisions": [
                {"kind": "mesh", "origin": ((0.1, 0, 0), (np.pi, np.pi / 2, 0.3)), "file": "box.stl",
                 "ref": "package", "scale": (-1.0, 1.0, 1.0), "name": "c1_0"},
                {"kind": "mesh", "origin": None, "file": "ring.obj", "ref": "relative",
                 "scale": (1.0, 2.0, -0.5), "name": "c1_1"},
                {"kind": "mesh", "origin": ((0, 0.2, 0), None), "file": "ring.obj", "ref": "package",
                 "scale": (0.5, 1.5, 1.0), "name": "c1_2"},
            ],
        },
    ],
    "joints": [
        {"name": "j1", "type": "revolute", "parent": 0, "child": 1, "axis": (0, 0, -2),
         "origin": ((0, 0, 0.3), (-np.pi, 0.2, np.pi - 1e-9)), "lower": -1.0, "upper": 2.0, "velocity": 1.0,
         "mimic": None},
    ],
}  # fmt: skip


ONE_BOX = {
    "links": [
        {"name": "base", "collisions": []},
        {"name": "l1", "collisions": [{"kind": "mesh", "origin": None, "file": "box.stl", "ref": "package",
                                        "scale": None, "name": "c1_0"}]},
    ],
    "joints": [
        {"name": "j1", "type": "revolute", "parent": 0, "child": 1, "axis": None, "origin": None, "lower": 0.0,
         "upper": 0.0, "velocity": 1.0, "mimic": None},
    ],
}  # fmt: skip

# Joints named like their child links (legal URDF): pinocchio then has two frames of that name.
SHARED_NAMES = {
    "links": [
        {"name": "base", "collisions": []},
        {"name": "l1", "collisions": [{"kind": "box", "origin": ((0, 0, 0.1), None), "size": (0.05, 0.05, 0.2),
                                        "name": "c1_0"}]},
        {"name": "l2", "collisions": [{"kind": "sphere", "origin": None, "size": (0.04,), "name": "c2_0"}]},
    ],
    "joints": [
        {"name": "l1", "type": "revolute", "parent": 0, "child": 1, "axis": (0, 1, 0), "origin": None,
         "lower": -1.0, "upper": 1.0, "velocity": 1.0, "mimic": None},
        {"name": "l2", "type": "prismatic", "parent": 1, "child": 2, "axis": (1, 0, 1),
         "origin": ((0, 0, 0.2), (0.1, 0.2, 0.3)), "lower": -0.1, "upper": 0.1, "velocity": 1.0, "mimic": None},
    ],
}  # fmt: skip

# ------------------------------------------------------------------------------------------ kinematics


@settings(max_examples=25, **_SUPPRESS)
@given(robot=robots(), seed=st.integers(0, 2**31 - 1))
@example(robot=MIRRORED, seed=0)
@example(robot=SHARED_NAMES, seed=0)
def test_joints_limits_poses_and_jacobians_match_the_urdf(robot: dict, seed: int) -> None:
    L = _load(robot)
    try:
        m, ref = L.model, L.ref
        # joint names, q order and limits (mimic joints: their own coordinate, docs/robots.md)
        assert sorted(m.joint_names) == sorted(ref.movable) and m.n_dof == len(ref.movable)
        for i, name in enumerate(m.joint_names):
            j = ref.joints[name]
            assert (m.q_min[i], m.q_max[i], m.v_max[i]) == (j["lower"], j["upper"], j["velocity"]), name
        rng = np.random.default_rng(seed)
        for _ in range(2):
            q = L.random_q(rng)
            T = ref.link_poses(L.qmap(q))
            for link in ref.links:
                R, p = m.frame_pose(q, link)
                np.testing.assert_allclose(R, T[link][:3, :3], atol=1e-9, err_msg=link)
                np.testing.assert_allclose(p, T[link][:3, 3], atol=1e-9, err_msg=link)
            # joint poses and the WORLD joint Jacobian (compiled path, and pinocchio's buffer)
            Rr, pr = L.joint_frames(q)
            H, Jw = m.joint_kinematics(q)
            np.testing.assert_allclose(H[:, :3, :3], Rr, atol=1e-9)
            np.testing.assert_allclose(H[:, :3, 3], pr, atol=1e-9)
            Jref = np.zeros((6, m.n_dof))
            for i, name in enumerate(m.joint_names):
                w = Rr[i + 1] @ ref.joints[name]["axis"]
                if ref.joints[name]["type"] in ("revolute", "continuous"):
                    Jref[:, i] = np.r_[np.cross(pr[i + 1], w), w]
                else:
                    Jref[:3, i] = w
            np.testing.assert_allclose(Jw, Jref, atol=1e-9)
            m.update(q)
            np.testing.assert_allclose(m.world_jacobian(), Jref, atol=1e-9)
            # frame and point Jacobians by central differences of the reference
            h = 1e-6
            point = rng.uniform(-0.2, 0.2, 3)
            for link in ref.links:
                J = m.frame_jacobian(q, link)
                pw, Jp = m.point_jacobian(q, link, point)
                np.testing.assert_allclose(pw, T[link][:3, :3] @ point + T[link][:3, 3], atol=1e-9)
                for i in range(m.n_dof):
                    dq = np.zeros(m.n_dof)
                    dq[i] = h
                    Tp, Tm = ref.link_poses(L.qmap(q + dq))[link], ref.link_poses(L.qmap(q - dq))[link]
                    dp = (Tp[:3, 3] - Tm[:3, 3]) / (2 * h)
                    W = (Tp[:3, :3] - Tm[:3, :3]) / (2 * h) @ T[link][:3, :3].T
                    np.testing.assert_allclose(J[:3, i], dp, atol=1e-6, err_msg=f"{link} q{i}")
                    np.testing.assert_allclose(J[3:, i], [W[2, 1], W[0, 2], W[1, 0]], atol=1e-6)
                    dpt = ((Tp[:3, :3] - Tm[:3, :3]) @ point + Tp[:3, 3] - Tm[:3, 3]) / (2 * h)
                    np.testing.assert_allclose(Jp[:, i], dpt, atol=1e-6)
    finally:
        L.close()


# ------------------------------------------------------------------------------------------ geometry


def _in_capsule(x: np.ndarray, a: np.ndarray, b: np.ndarray, r: float) -> np.ndarray:
    d = b - a
    t = np.clip(((x - a) @ d) / max(float(d @ d), 1e-300), 0.0, 1.0)
    return np.linalg.norm(x - (a + t[:, None] * d), axis=1) <= r + 1e-9


def _same_point_sets(a: np.ndarray, b: np.ndarray, tol: float) -> bool:
    d = np.linalg.norm(a[:, None] - b[None], axis=2)
    return bool(d.min(axis=1).max() <= tol and d.min(axis=0).max() <= tol)


@settings(max_examples=15, **_SUPPRESS)
@given(robot=robots(mimic=False), seed=st.integers(0, 2**31 - 1), margin=st.floats(0.002, 0.05))
@example(robot=MIRRORED, seed=0, margin=0.01)
@example(robot=SHARED_NAMES, seed=0, margin=0.01)
def test_self_filter_shapes_are_the_urdf_collision_elements(robot: dict, seed: int, margin: float) -> None:
    """Every mesh the self-filter draws has the URDF element's vertices (world frame, from the reference
    joint poses), outward faces and offsets that point out of the solid, at most one margin long; the
    analytic spheres are the URDF's spheres; the coarse capsules hold every primitive."""
    L = _load(robot)
    try:
        m, ref, geo = L.model, L.ref, L.model.geometry
        q = L.random_q(np.random.default_rng(seed))
        Rj, pj = L.joint_frames(q)
        T = ref.link_poses(L.qmap(q))
        names = [g.shape.name for g in geo.geoms]
        idiom = {n for n in ref.collisions if n + "_s0" in ref.collisions}  # cylinders with end spheres
        assert sorted(names) == sorted(n for n in ref.collisions if n[:-3] not in idiom), names
        tri = geo.world_triangles(Rj, pj)
        meshes = [g for g in geo.geoms if g.is_mesh]
        caps = [g for g in geo.geoms if not g.is_mesh]
        for s, g in enumerate(meshes):
            link, kind, Tc, prm = ref.collisions[g.shape.name]
            a, b = geo.vr[s]
            Tl = T[link]
            V = geo.V[a:b] @ Rj[geo.mesh_joint[s]].T + pj[geo.mesh_joint[s]]
            O = geo.O[a:b] @ Rj[geo.mesh_joint[s]].T
            if kind == "cylinder":  # the circumscribed 24-gon prism over the URDF's cylinder
                x = (V - (Tl @ Tc)[:3, 3]) @ (Tl @ Tc)[:3, :3]
                r, half = float(prm["radius"]), 0.5 * float(prm["length"])
                rad = np.hypot(x[:, 0], x[:, 1])
                assert np.all(np.isclose(np.abs(x[:, 2]), half, atol=1e-9)), g.shape.name
                ok = np.isclose(rad, 0, atol=1e-9) | np.isclose(rad, r / np.cos(np.pi / N_SIDES), atol=1e-9)
                assert np.all(ok), g.shape.name
            else:  # box corners / mesh vertices (a convex mesh: its hull's, here all of them)
                corners = ref.shape_points(g.shape.name, surface=False)
                want = corners @ Tl[:3, :3].T + Tl[:3, 3]
                assert _same_point_sets(V, want, 1e-6), (g.shape.name, prm)
            # faces wound outwards (documented for face_planes): positive signed volume
            t = tri[geo.fr[s][0] : geo.fr[s][1]]
            vol = np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6.0
            assert vol > 0, (g.shape.name, prm, vol)
            # inflation offsets: at most one margin long, and pointing out of the solid
            assert np.all(np.linalg.norm(O, axis=1) <= 1 + 1e-9)
            probe = V + 0.5 * margin * O
            probe_link = (probe - Tl[:3, 3]) @ Tl[:3, :3]
            assert not np.any(ref.inside(g.shape.name, probe_link)), (g.shape.name, prm)
        wa, wb, wr = geo.world_capsules(Rj, pj)
        for k, g in enumerate(caps):
            link, kind, Tc, prm = ref.collisions[g.shape.name]
            assert kind == "sphere" or kind == "capsule" or g.shape.name in idiom, (kind, g.shape.name)
            half = 0.0 if kind == "sphere" else 0.5 * float(prm["length"])
            Tw = T[link] @ Tc
            ends = [Tw[:3, 3] - half * Tw[:3, 2], Tw[:3, 3] + half * Tw[:3, 2]]
            np.testing.assert_allclose([wa[k], wb[k]], ends, atol=1e-9)
            assert wr[k] == float(prm["radius"])
        assert len(caps) == len(wr)
        # the coarse capsules (model.capsules, link_capsules) hold every box, cylinder and sphere
        a, b, r = m.link_capsules(q)
        for name, (link, kind, _, _) in ref.collisions.items():
            if kind == "mesh":
                continue  # (mesh-only links: a documented coarse fallback)
            pts = ref.shape_points(name, surface=False) @ T[link][:3, :3].T + T[link][:3, 3]
            held = np.zeros(len(pts), bool)
            for k, c in enumerate(m.capsules):
                if c.link == link:
                    held |= _in_capsule(pts, a[k], b[k], r[k])
            assert held.all(), (name, kind)
    finally:
        L.close()


@settings(max_examples=12, **_SUPPRESS)
@given(robot=robots(), seed=st.integers(0, 2**31 - 1), k=st.integers(1, 4))
@example(robot=MIRRORED, seed=0, k=1)
@example(robot=SHARED_NAMES, seed=1, k=2)
@example(robot=ONE_BOX, seed=0, k=1)  # (the test's own fault: reference vertices not float32 like the STL's)
def test_auto_control_spheres_hold_every_moving_link_and_move_with_it(robot: dict, seed: int, k: int) -> None:
    L = _load(robot)
    try:
        m, ref = L.model, L.ref
        cps = ControlPointSet.build(m, "auto", auto_spheres=k)
        rng = np.random.default_rng(seed)
        q = L.random_q(rng)
        st_ = cps.evaluate(q)
        m.update(q)  # the path through pinocchio's buffer gives the same (also for a 1-DOF robot)
        again = cps.evaluate(q, updated=True)
        np.testing.assert_allclose(again.centres, st_.centres, atol=1e-12)
        np.testing.assert_allclose(again.jacobians, st_.jacobians, atol=1e-12)
        T = ref.link_poses(L.qmap(q))
        # the end effector: the last link by default, its origin
        np.testing.assert_allclose(st_.centres[0], T[m.ee_frame][:3, 3], atol=1e-9)
        by_link: dict[str, list[np.ndarray]] = {}
        for name, (link, _, _, _) in ref.collisions.items():
            by_link.setdefault(link, []).append(ref.shape_points(name))
        for link, pts_l in by_link.items():
            idx = [i for i, nm in enumerate(st_.names) if nm.startswith(link + "/")]
            if not ref.moving(link):
                assert not idx, link  # fixed to the base: none (documented)
                continue
            assert 1 <= len(idx) <= k, link
            pts_link = np.vstack(pts_l)
            pts = pts_link @ T[link][:3, :3].T + T[link][:3, 3]
            c, r = st_.centres[idx], st_.radii[idx]
            out = (np.linalg.norm(pts[:, None] - c[None], axis=2) - r[None]).min(axis=1)
            assert out.max() <= 1e-9, (link, out.max())
            # and they are not elsewhere: each centre within the geometry's box, radius at most its diameter
            lo, hi = pts.min(axis=0), pts.max(axis=0)
            assert np.all(c >= lo - 1e-9) and np.all(c <= hi + 1e-9), link
            assert np.all(r <= np.linalg.norm(hi - lo) + 0.01), link
            # Jacobians: the centres are points of the link (reference finite differences)
            c_link = (c - T[link][:3, 3]) @ T[link][:3, :3]
            h = 1e-6
            for i in range(m.n_dof):
                dq = np.zeros(m.n_dof)
                dq[i] = h
                Tp, Tm = ref.link_poses(L.qmap(q + dq))[link], ref.link_poses(L.qmap(q - dq))[link]
                fd = (c_link @ (Tp[:3, :3] - Tm[:3, :3]).T + Tp[:3, 3] - Tm[:3, 3]) / (2 * h)
                np.testing.assert_allclose(st_.jacobians[idx, :, i], fd, atol=1e-6)
    finally:
        L.close()


# ------------------------------------------------------------------------------------------ errors

_BASE = """<robot name="e"><link name="a"/><link name="b">{coll}</link>
<joint name="jx" type="{typ}"><parent link="a"/><child link="b"/><origin xyz="0 0 0.1"/>{axis}{limit}</joint>
</robot>"""
_LIMIT = '<limit lower="-1" upper="1" velocity="1" effort="1"/>'


def _coll(geometry: str) -> str:
    return f'<collision name="cq"><geometry>{geometry}</geometry></collision>'


@pytest.mark.parametrize(
    ("typ", "axis", "limit", "coll", "match"),
    [
        ("continuous", '<axis xyz="0 0 1"/>', "", "", "'jx' is continuous without <limit>"),
        ("continuous", '<axis xyz="0 0 1"/>', '<limit effort="1"/>', "", "jx.*no velocity"),
        ("continuous", '<axis xyz="0 0 0"/>', '<limit effort="1" velocity="1"/>', "", "jx.*zero"),
        ("revolute", '<axis xyz="0 0 1"/>', '<limit lower="-1" upper="1" effort="1"/>', "", "jx.*no velocity"),
        ("revolute", '<axis xyz="0 0 1"/>', '<limit lower="-1" upper="1" velocity="1"/>', "", "jx.*no effort"),
        ("prismatic", '<axis xyz="0 0 1"/>', '<limit upper="1" velocity="-1" effort="1"/>', "", "jx.*velocity"),
        ("revolute", '<axis xyz="0 0 1"/>', '<limit upper="1" velocity="nan" effort="1"/>', "", "jx.*velocity"),
        ("revolute", '<axis xyz="0 0 1"/>', '<limit upper="1" velocity="inf" effort="1"/>', "", "jx.*velocity"),
        ("revolute", '<axis xyz="0 0 1"/>', '<limit upper="1" velocity="1" effort="-2"/>', "", "jx.*effort"),
        ("revolute", '<axis xyz="0 0 1"/>', '<limit upper="1" velocity="1" effort="x"/>', "", "jx.*effort"),
        ("planar", '<axis xyz="0 0 1"/>', "", "", "jx"),
        ("floating", "", "", "", "jx"),
        ("revolute", '<axis xyz="0 0 0"/>', _LIMIT, "", "jx"),
        ("prismatic", '<axis xyz="0 0 0"/>', _LIMIT, "", "jx"),
        ("revolute", '<axis xyz="0 0 1"/>', "", "", "jx"),
        ("prismatic", '<axis xyz="0 0 1"/>', "", "", "jx"),
        ("revolute", '<axis xyz="0 0 1"/>', '<limit lower="1" upper="-1" velocity="1" effort="1"/>', "", "jx"),
        (
            "revolute",
            '<axis xyz="0 0 1"/>',
            _LIMIT,
            '<collision name="cz"><geometry><ellipsoid radii="0.1 0.1 0.2"/></geometry></collision>',
            "ellipsoid",
        ),
        (
            "revolute",
            '<axis xyz="0 0 1"/>',
            _LIMIT,
            '<collision><origin xyz="0.1"/><geometry><sphere radius="0.1"/></geometry></collision>',
            "origin",
        ),
        (
            "revolute",
            '<axis xyz="0 0 1"/>',
            _LIMIT,
            '<collision><geometry><mesh filename="../meshes/box.stl" scale="1 2"/></geometry></collision>',
            "scale",
        ),
        (
            "revolute",
            '<axis xyz="0 0 1"/>',
            _LIMIT,
            '<collision><geometry><mesh filename="../meshes/nope.stl"/></geometry></collision>',
            "nope.stl",
        ),
        ("revolute", '<axis xyz="0 0 1"/>', _LIMIT, _coll('<cylinder radius="0.1"/>'), "cq.*length"),
        ("revolute", '<axis xyz="0 0 1"/>', _LIMIT, _coll("<sphere/>"), "cq.*radius"),
        ("revolute", '<axis xyz="0 0 1"/>', _LIMIT, _coll("<box/>"), "cq.*size"),
        ("revolute", '<axis xyz="0 0 1"/>', _LIMIT, _coll('<box size="0 0.1 0.1"/>'), "cq.*size"),
        ("revolute", '<axis xyz="0 0 1"/>', _LIMIT, _coll('<capsule radius="nan" length="0.1"/>'), "cq.*radius"),
        ("revolute", '<axis xyz="0 0 1"/>', _LIMIT, _coll("<mesh/>"), "cq.*filename"),
        ("revolute", '<axis xyz="0 0 1"/>', _LIMIT, "<collision><geometry/></collision>", "'b' <collision>"),
        ("revolute", '<axis xyz="0 inf 1"/>', _LIMIT, "", "jx"),
        (
            "revolute",
            '<axis xyz="0 0 1"/>',
            _LIMIT,
            '<collision><origin rpy="0 0"/><geometry><sphere radius="0.1"/></geometry></collision>',
            "'b'.*rpy",
        ),
        ("helical", '<axis xyz="0 0 1"/>', _LIMIT, "", "jx"),
    ],
)
def test_what_the_loader_cannot_represent_is_a_value_error_naming_it(typ, axis, limit, coll, match, tmp_path) -> None:
    urdf_dir = _write_package(tmp_path)
    path = urdf_dir / "e.urdf"
    path.write_text(_BASE.format(typ=typ, axis=axis, limit=limit, coll=coll))
    with pytest.raises(ValueError, match=match):
        RobotModel.from_urdf(path)
