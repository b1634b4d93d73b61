"""Robot kinematic model: URDF loading (pinocchio), forward kinematics, point Jacobians, limits, capsules.

The shipped model, :func:`load_lwr4`, is a KUKA LWR IV-like 7-DOF arm, the robot of Flacco et al.
(ICRA 2012, RA-L 2016). Its kinematic parameters are the LWR 4 link lengths of KUKA's LWR 4+ data sheet
as used in the published DH tables (d1 = 0.3105 m base to shoulder, d3 = 0.40 m upper arm,
d5 = 0.39 m forearm, d7 = 0.078 m wrist to flange; e.g. Jubien, Gautier, Janot, "Dynamic identification
of the KUKA LightWeight robot", IFAC 2014) and the open ROS description kuka-isir/rtt_lwr
(``lwr_description/urdf/lwr.urdf.xacro``), whose joint placement and axis signs the URDF follows. Joint
position limits are +-170 deg (A1, A3, A5, A7) and +-120 deg (A2, A4, A6); velocity limits are the
data sheet's, approximately. Details are in the header of ``data/lwr4/lwr4.urdf``.

Conventions: SI units; the world frame is the robot base frame, whose root link is at the world
origin (``docs/conventions.md``). Only joints of one coordinate are supported: revolute, prismatic, and
continuous (built as revolute with infinite position limits: ``q`` holds its angle, not pinocchio's cos/sin).

Collision geometry is also read back from the URDF as coarse *capsules* (segment ``a``-``b`` swept by a
sphere of ``radius``, :meth:`RobotModel.link_capsules`; used by the capsule self-filter baseline, the
robot-interior windows and the calibration's robot model):

* ``<cylinder>`` -> the capsule over its axis (it bounds the cylinder);
* ``<sphere>`` at an end of such a cylinder, no larger than it -> absorbed; any other sphere -> a
  zero-length capsule;
* ``<box>`` -> a capsule along its longest axis that bounds it;
* links with only meshes (or none) -> a capsule from the link origin to each child joint origin with
  ``default_radius`` (a coarse fallback; give such robots primitive collision geometry for real use).

The self-filter and the ``auto`` control points use the real collision geometry instead
(:attr:`RobotModel.geometry`, :mod:`depthguard.robot.geometry`): meshes (``package://`` paths resolved),
boxes, cylinders, spheres and capsules, plus shapes attached by the user (:meth:`RobotModel.attach`).

A :class:`RobotModel` owns one ``pinocchio.Data`` buffer: it is not thread-safe; use one per thread.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import cached_property
from importlib import resources
from pathlib import Path

import numpy as np

from depthguard.robot.fk import ChainKinematics
from depthguard.robot.geometry import RobotGeometry
from depthguard.robot.shapes import Shape, parse_collision_shapes, rpy_to_matrix
from depthguard.robot.urdf_check import check_urdf, continuous_as_revolute
from depthguard.validation import check_finite_array

__all__ = ["LinkCapsule", "RobotModel", "check_urdf", "load_lwr4", "lwr4_urdf_path"]


def lwr4_urdf_path() -> Path:
    """Path of the shipped LWR IV-like URDF (``depthguard/robot/data/lwr4/lwr4.urdf``)."""
    return Path(str(resources.files("depthguard.robot") / "data" / "lwr4" / "lwr4.urdf"))


@dataclass(frozen=True)
class LinkCapsule:
    """One collision capsule fixed to a link.

    Attributes:
        name: ``"<link>/<k>"``.
        link: URDF link name (a pinocchio BODY frame).
        a, b: (3,) segment end points in the link frame, metres.
        radius: capsule radius, metres.
    """

    name: str
    link: str
    a: np.ndarray
    b: np.ndarray
    radius: float


def _origin(elem: ET.Element | None) -> tuple[np.ndarray, np.ndarray]:
    if elem is None:
        return np.eye(3), np.zeros(3)
    xyz = np.array([float(x) for x in elem.get("xyz", "0 0 0").split()])
    rpy = np.array([float(x) for x in elem.get("rpy", "0 0 0").split()])
    return rpy_to_matrix(rpy), xyz


def _parse_capsules(urdf_path: Path, default_radius: float) -> list[LinkCapsule]:
    """Capsules from the URDF's ``<collision>`` primitives (rules in the module docstring)."""
    root = ET.parse(urdf_path).getroot()
    child_origins: dict[str, list[np.ndarray]] = {}
    for joint in root.findall("joint"):
        parent = joint.find("parent")
        if parent is not None:
            child_origins.setdefault(parent.get("link", ""), []).append(_origin(joint.find("origin"))[1])
    out: list[LinkCapsule] = []
    for link in root.findall("link"):
        lname = link.get("name", "")
        caps: list[tuple[np.ndarray, np.ndarray, float]] = []
        spheres: list[tuple[np.ndarray, float]] = []
        has_collision = False
        for col in link.findall("collision"):
            geom = col.find("geometry")
            if geom is None:
                continue
            has_collision = True
            R, p = _origin(col.find("origin"))
            if (g := geom.find("cylinder")) is not None or (g := geom.find("capsule")) is not None:
                r, half = float(g.get("radius")), 0.5 * float(g.get("length"))
                caps.append((p - R[:, 2] * half, p + R[:, 2] * half, r))
            elif (g := geom.find("sphere")) is not None:
                spheres.append((p, float(g.get("radius"))))
            elif (g := geom.find("box")) is not None:
                h = 0.5 * np.array([float(x) for x in g.get("size").split()])
                k = int(np.argmax(h))
                others = [i for i in range(3) if i != k]
                caps.append((p - R[:, k] * h[k], p + R[:, k] * h[k], float(np.hypot(*h[others]))))
        for c, r in spheres:
            absorbed = any(
                r <= rc + 1e-9 and min(np.linalg.norm(c - a), np.linalg.norm(c - b)) < 1e-6 for a, b, rc in caps
            )
            if not absorbed:
                caps.append((c, c.copy(), r))
        if not caps and has_collision:  # meshes only: coarse fallback along the kinematic chain
            ends = child_origins.get(lname, []) or [np.zeros(3)]
            caps = [(np.zeros(3), e, default_radius) for e in ends]
        for k, (a, b, r) in enumerate(caps):
            out.append(LinkCapsule(f"{lname}/{k}", lname, np.asarray(a, float), np.asarray(b, float), float(r)))
    return out


def _build_pinocchio_model(pin, root: ET.Element, urdf_path: Path):
    """The pinocchio model of a checked URDF, and the names of its continuous joints: those are built as
    revolute joints (one coordinate, the angle) whose position limits are set to ±inf."""
    if not any(j.get("type") == "continuous" for j in root.findall("joint")):
        return pin.buildModelFromUrdf(str(urdf_path)), ()
    text, names = continuous_as_revolute(root)
    model = pin.buildModelFromXML(text)
    lo, hi = np.array(model.lowerPositionLimit), np.array(model.upperPositionLimit)
    for name in names:
        k = model.idx_qs[model.getJointId(name)]
        lo[k], hi[k] = -np.inf, np.inf
    model.lowerPositionLimit, model.upperPositionLimit = lo, hi
    return model, tuple(names)


class RobotModel:
    """A fixed-base robot loaded from URDF with pinocchio.

    Attributes:
        n_dof: number of joint coordinates n.
        joint_names: the n joint names, in the order of ``q``.
        q_min, q_max: (n,) joint position limits, rad (or m); ∓inf for continuous joints.
        continuous_joints: names of the URDF's continuous joints (revolute, unbounded angle).
        v_max: (n,) joint velocity limits, rad/s (or m/s).
        ee_frame: name of the end-effector frame.
        capsules: tuple of :class:`LinkCapsule`, the collision geometry.
    """

    def __init__(
        self,
        urdf_path: str | Path,
        ee_frame: str | None = None,
        default_radius: float = 0.05,
        *,
        attachments: tuple[Shape, ...] | list[Shape] = (),
        max_triangles: int | None = None,
    ) -> None:
        import pinocchio as pin

        self._pin = pin
        self.urdf_path = Path(urdf_path)
        if not self.urdf_path.is_file():
            raise ValueError(f"urdf_path '{self.urdf_path}' is not a file")
        try:  # (a clear one-line error before the URDF parser, which logs its own to stderr, sees bad XML)
            root = ET.parse(self.urdf_path).getroot()
        except (ET.ParseError, UnicodeDecodeError) as exc:
            raise ValueError(f"{self.urdf_path}: not a valid URDF (XML): {exc}") from None
        check_urdf(root, self.urdf_path)  # what cannot be represented: a ValueError naming the element
        self.model, self.continuous_joints = _build_pinocchio_model(pin, root, self.urdf_path)
        self.data = self.model.createData()
        odd = [self.model.names[j] for j in range(1, self.model.njoints) if self.model.joints[j].nq != 1]
        if self.model.nq != self.model.nv or odd:
            raise ValueError(f"RobotModel supports only one-coordinate joints (revolute/prismatic); joints {odd}")
        self.n_dof = int(self.model.nv)
        self.joint_names = tuple(self.model.names[i] for i in range(1, self.model.njoints))
        self.q_min = np.array(self.model.lowerPositionLimit, dtype=float)
        self.q_max = np.array(self.model.upperPositionLimit, dtype=float)
        self.v_max = np.array(self.model.velocityLimit, dtype=float)
        for arr in (self.q_min, self.q_max, self.v_max):
            arr.setflags(write=False)
        if ee_frame is None:  # the last BODY frame
            bodies = [f.name for f in self.model.frames if f.type == pin.FrameType.BODY]
            ee_frame = bodies[-1]
        self.ee_frame = ee_frame
        self.ee_frame_id = self.frame_id(ee_frame)
        self.capsules = tuple(_parse_capsules(self.urdf_path, default_radius))
        self._cap_joint = np.array([self._parent_joint(c.link) for c in self.capsules], dtype=np.int64)
        # capsule ends in the parent *joint* frame, so that one oMi lookup per joint serves all
        a_j, b_j = [], []
        for c in self.capsules:
            M = self.model.frames[self.frame_id(c.link)].placement
            a_j.append(M.rotation @ c.a + M.translation)
            b_j.append(M.rotation @ c.b + M.translation)
        self._cap_a = np.array(a_j).reshape(-1, 3)
        self._cap_b = np.array(b_j).reshape(-1, 3)
        self.capsule_radii = np.array([c.radius for c in self.capsules], dtype=float)
        self.capsule_radii.setflags(write=False)
        if max_triangles is not None and (isinstance(max_triangles, bool) or int(max_triangles) < 4):
            raise ValueError(f"max_triangles must be an integer >= 4 or None, got {max_triangles!r}")
        self.max_triangles = max_triangles
        self._urdf_shapes = tuple(parse_collision_shapes(self.urdf_path))
        self.attachments: tuple[Shape, ...] = ()
        self.geometry = RobotGeometry(self, self._urdf_shapes, max_triangles)
        if attachments:
            self.attach(*attachments)

    def attach(self, *shapes: Shape) -> None:
        """Fix tools or payloads (:class:`depthguard.robot.shapes.Shape`: mesh, box, cylinder, sphere) to
        links; the self-filter removes them and ``auto`` control points built afterwards cover them."""
        for s in shapes:
            if not isinstance(s, Shape):
                raise ValueError(f"attach() takes Shape objects, got {type(s).__name__}")
            self.frame_id(s.link)  # ValueError naming the frame if unknown
        self.attachments = self.attachments + tuple(shapes)
        self.geometry = RobotGeometry(self, self._urdf_shapes + self.attachments, self.max_triangles)

    def detach_all(self) -> None:
        """Remove every attached shape."""
        self.attachments = ()
        self.geometry = RobotGeometry(self, self._urdf_shapes, self.max_triangles)

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_urdf(
        cls,
        path: str | Path,
        ee_frame: str | None = None,
        default_radius: float = 0.05,
        *,
        attachments: tuple[Shape, ...] | list[Shape] = (),
        max_triangles: int | None = None,
    ) -> RobotModel:
        """Load any fixed-base URDF (root link at the world origin). ``ee_frame`` defaults to the last link.

        ``default_radius`` (m): capsule of mesh-only links in :attr:`capsules` (the coarse description);
        ``attachments``: shapes fixed to links (:meth:`attach`); ``max_triangles``: decimate each collision
        mesh above this triangle count at load time for the self-filter (needs ``fast-simplification``).
        """
        return cls(
            path, ee_frame=ee_frame, default_radius=default_radius, attachments=attachments, max_triangles=max_triangles
        )

    # ------------------------------------------------------------------ helpers
    def frame_id(self, name: str) -> int:
        """Pinocchio frame index of ``name``; ``ValueError`` if the model has no such frame.

        A name that is both a link's and a joint's (URDF allows it) means the link (its BODY frame)."""
        body = self._pin.FrameType.BODY
        if self.model.existFrame(name, body):
            return int(self.model.getFrameId(name, body))
        if not self.model.existFrame(name):
            raise ValueError(f"frame '{name}' is not in the model; frames: {[f.name for f in self.model.frames]}")
        return next(i for i, f in enumerate(self.model.frames) if f.name == name)

    def _parent_joint(self, link: str) -> int:
        return int(self.model.frames[self.frame_id(link)].parentJoint)

    def check_q(self, q: object, name: str = "q") -> np.ndarray:
        """Return ``q`` as a finite (n,) float array, or raise ``ValueError`` naming ``name``."""
        return check_finite_array(q, (self.n_dof,), name)

    def neutral(self) -> np.ndarray:
        """(n,) the zero configuration, clipped into the joint limits."""
        return np.clip(np.zeros(self.n_dof), self.q_min, self.q_max)

    # ------------------------------------------------------------------ kinematics
    def update(self, q: np.ndarray) -> None:
        """Run forward kinematics and all joint Jacobians for ``q`` (n,) into the internal buffer."""
        self._pin.computeJointJacobians(self.model, self.data, q)

    def joint_kinematics(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World poses of every joint ``H`` (njoints, 4, 4) (``H[0]`` the universe) and the WORLD joint
        Jacobian ``Jw`` (6, n) at ``q`` (n,), a finite float64 array (not checked here).

        The same numbers as ``data.oMi`` / ``data.J`` after :meth:`update`, returned as fresh arrays and
        computed in one compiled call (:mod:`depthguard.robot.fk`; about 3 µs instead of about 2 µs per
        joint read back from pinocchio). Does not touch the internal pinocchio buffer.
        """
        chain = self._chain_kinematics
        if chain is not None:
            return chain.compute(q)
        self.update(q)
        return np.array([M.homogeneous for M in self.data.oMi]), self.world_jacobian()

    @cached_property
    def _chain_kinematics(self) -> ChainKinematics | None:
        return ChainKinematics.from_model(self.model)

    def frame_pose(self, q: np.ndarray, frame: str | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Pose of ``frame`` (default: end effector): ``R`` (3, 3) frame -> world, position ``p`` (3,) m."""
        q = self.check_q(q)
        fid = self.ee_frame_id if frame is None else self.frame_id(frame)
        self._pin.forwardKinematics(self.model, self.data, q)
        M = self._pin.updateFramePlacement(self.model, self.data, fid)
        return np.array(M.rotation), np.array(M.translation)

    def frame_jacobian(self, q: np.ndarray, frame: str | None = None) -> np.ndarray:
        """(6, n) Jacobian of ``frame``'s origin, world-aligned: rows 0-2 linear m/s, 3-5 angular rad/s."""
        q = self.check_q(q)
        fid = self.ee_frame_id if frame is None else self.frame_id(frame)
        J = self._pin.computeFrameJacobian(self.model, self.data, q, fid, self._pin.LOCAL_WORLD_ALIGNED)
        return np.array(J).reshape(6, self.n_dof)  # (pinocchio gives a 1-DOF robot's as (6,))

    def point_jacobian(
        self, q: np.ndarray, frame: str | None = None, point: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """World position (3,) m and positional Jacobian (3, n) of a point fixed in ``frame``.

        Args:
            q: (n,) joint positions.
            frame: frame name (default: end effector).
            point: (3,) coordinates of the point in ``frame``, m (default: its origin).
        """
        R, p = self.frame_pose(q, frame)
        J = self.frame_jacobian(q, frame)
        off = R @ (np.zeros(3) if point is None else check_finite_array(point, (3,), "point"))
        # v_point = v_origin + w x off  ->  J_lin - [off]x J_ang
        return p + off, J[:3] + np.cross(J[3:].T, off).T

    def joint_poses(self, q: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """World rotations (J+1, 3, 3) and origins (J+1, 3) of all pinocchio joints (0 = universe).

        With ``q=None`` it reads the buffer of the last :meth:`update`.
        """
        if q is not None:
            self._pin.forwardKinematics(self.model, self.data, self.check_q(q))
        R = np.array([M.rotation for M in self.data.oMi])
        p = np.array([M.translation for M in self.data.oMi])
        return R, p

    def world_jacobian(self) -> np.ndarray:
        """(6, n) stacked joint motion axes in the WORLD frame from the last :meth:`update`.

        Column j is the spatial velocity (linear part at the world origin, angular part) of unit q̇_j.
        Always two-dimensional, also for a 1-DOF robot (whose ``data.J`` pinocchio returns as (6,)).
        """
        return np.array(self.data.J).reshape(6, self.n_dof)

    def joint_support_mask(self, joint: int) -> np.ndarray:
        """(n,) bool: the coordinates that move pinocchio joint ``joint`` (its kinematic support)."""
        mask = np.zeros(self.n_dof, dtype=bool)
        for j in self.model.supports[int(joint)]:
            if j > 0:
                mask[self.model.idx_vs[j] : self.model.idx_vs[j] + self.model.nvs[j]] = True
        return mask

    def link_capsules(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """World-frame capsules of the robot at ``q`` (n,).

        Returns:
            ``a`` (L, 3) and ``b`` (L, 3) segment ends in metres, ``radius`` (L,) in metres,
            in the order of :attr:`capsules`.
        """
        R, p = self.joint_poses(self.check_q(q))
        Rj, pj = R[self._cap_joint], p[self._cap_joint]
        a = np.einsum("kij,kj->ki", Rj, self._cap_a) + pj
        b = np.einsum("kij,kj->ki", Rj, self._cap_b) + pj
        return a, b, self.capsule_radii.copy()

    def __repr__(self) -> str:
        return f"RobotModel('{self.urdf_path.name}', n_dof={self.n_dof}, ee='{self.ee_frame}')"


def load_lwr4() -> RobotModel:
    """The shipped KUKA LWR IV-like 7-DOF arm (kinematic sources in the module docstring).

    Frames: links ``lwr_link_0`` (base) .. ``lwr_link_7``, ``lwr_flange`` and the tool centre ``lwr_ee``
    0.10 m beyond the flange (the end-effector frame). Zero configuration: arm straight up.
    """
    return RobotModel(lwr4_urdf_path(), ee_frame="lwr_ee")
