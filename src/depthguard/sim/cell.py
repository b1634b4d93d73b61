"""The simulated work cell: the arm on a table, a room, boxes, capsule people and depth cameras (MuJoCo 4).

:func:`build_cell` writes MJCF for a :class:`CellSpec` and compiles it through ``mujoco.MjSpec``.

* The arm (``CellSpec.robot``: "lwr4", "panda", ...) is built link by link from the robot's URDF
  (:mod:`depthguard.sim.robotdesc`): one body per link, a hinge per revolute joint, a slide per prismatic
  one, and the collision geometry of the controller's model as MuJoCo geoms (capsules, boxes, cylinders,
  the robot's own meshes). Each joint has a position servo (kp, kv) fed at
  1 kHz with the controller's joint command (position and velocity:
  ``kp (q_cmd - q) + kv (qd_cmd - qd)``); gravity is off (the LWR compensates it) and contacts are
  disabled: collisions are measured (:mod:`depthguard.sim.truth`), not simulated.
* World frame = robot base frame; the base stands on a table whose top is at z = 0; the floor is at
  ``floor_z`` (default -0.8 m), with walls near enough for the cameras to see them within range.
* Geom groups: 0 room/table, 1 robot, 2 people, 3 boxes and carried objects.
* People and movable boxes are mocap bodies posed kinematically from their scripts.
* Every depth camera is also a MuJoCo camera (looking along -z, y up), for the renderer path.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from depthguard.camera import Camera
from depthguard.robot.shapes import rpy_to_matrix
from depthguard.sim.people import PersonScript, person_segments, segment_pose
from depthguard.sim.robotdesc import RobotDesc, load_robot_desc

__all__ = ["BoxSpec", "CellSpec", "Cell", "build_cell", "GROUP_ENV", "GROUP_ROBOT", "GROUP_PEOPLE", "GROUP_BOX"]

GROUP_ENV, GROUP_ROBOT, GROUP_PEOPLE, GROUP_BOX = 0, 1, 2, 3


@dataclass(frozen=True)
class BoxSpec:
    """A box obstacle: ``center`` (3,) and ``half`` sizes (3,) in m; ``movable`` boxes are mocap bodies."""

    name: str
    center: tuple[float, float, float]
    half: tuple[float, float, float]
    movable: bool = False
    rgba: tuple[float, float, float, float] = (0.8, 0.55, 0.2, 1.0)


@dataclass
class CellSpec:
    """What goes into the cell."""

    cameras: list[Camera] = field(default_factory=list)
    boxes: list[BoxSpec] = field(default_factory=list)
    people: list[PersonScript] = field(default_factory=list)
    q0: tuple[float, ...] = (0.0, 0.6, 0.0, -1.4, 0.0, 0.9, 0.0)
    floor_z: float = -0.8
    table_half: tuple[float, float] = (0.3, 0.3)
    room: tuple[float, float, float, float] = (-1.5, 2.3, -1.6, 2.3)  # xmin xmax ymin ymax of the walls
    backdrops: bool = False
    backdrop_distance: float = 1.5
    timestep: float = 0.001
    kp: float = 4000.0
    kv: float = 60.0
    armature: float = 0.1
    robot: str = "lwr4"  # a name of depthguard.robot.robots.load_robot


def _f(v) -> str:
    return " ".join(f"{float(x):.6g}" for x in np.atleast_1d(v))


def _quat_from_matrix(Rm: np.ndarray) -> np.ndarray:
    w = math.sqrt(max(0.0, 1.0 + Rm[0, 0] + Rm[1, 1] + Rm[2, 2])) / 2.0
    if w > 1e-6:
        return np.array(
            [w, (Rm[2, 1] - Rm[1, 2]) / (4 * w), (Rm[0, 2] - Rm[2, 0]) / (4 * w), (Rm[1, 0] - Rm[0, 1]) / (4 * w)]
        )
    # fall back to a robust conversion
    import mujoco

    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, Rm.ravel())
    return q


def _geom_xml(name: str, g, indent: str) -> tuple[str, str]:
    """(geom line, mesh asset line or "") of one :class:`GeomDesc`."""
    style = f'group="{GROUP_ROBOT}" rgba="0.95 0.55 0.1 1"'
    a, b = np.asarray(g.a), np.asarray(g.b)
    if g.kind == "capsule" and np.linalg.norm(b - a) < 1e-9:
        return f'{indent}<geom name="{name}" type="sphere" size="{g.radius:.6g}" pos="{_f(a)}" {style}/>', ""
    if g.kind == "capsule":
        ft = f"{_f(a)} {_f(b)}"
        return f'{indent}<geom name="{name}" type="capsule" size="{g.radius:.6g}" fromto="{ft}" {style}/>', ""
    pose = f'pos="{_f(g.pos)}" quat="{_f(_quat_from_matrix(np.asarray(g.rot)))}"' if g.rot is not None else ""
    if g.kind in ("box", "cylinder"):
        return f'{indent}<geom name="{name}" type="{g.kind}" size="{_f(g.size)}" {pose} {style}/>', ""
    if g.mesh is not None:
        asset = f'    <mesh name="{name}_mesh" file="{g.mesh}" scale="{_f(g.scale)}" inertia="shell"/>'
    else:
        verts, faces = " ".join(_f(v) for v in g.vertices), " ".join(" ".join(str(int(i)) for i in f) for f in g.faces)
        asset = f'    <mesh name="{name}_mesh" vertex="{verts}" face="{faces}" inertia="shell"/>'
    return f'{indent}<geom name="{name}" type="mesh" mesh="{name}_mesh" {pose} {style}/>', asset


def _robot_xml(desc: RobotDesc, armature: float) -> tuple[str, list[str], list[str]]:
    """Nested MJCF bodies of the arm. Returns (xml, actuated joint names, mesh asset lines)."""
    children: dict[str, list] = {}
    for j in desc.joints:
        children.setdefault(j.parent, []).append(j)
    geoms_of: dict[str, list] = {}
    for g in desc.geoms:
        geoms_of.setdefault(g.link, []).append(g)
    actuated: list[str] = []
    assets: list[str] = []

    def geoms(link: str, indent: str) -> str:
        out = []
        for i, g in enumerate(geoms_of.get(link, [])):
            line, asset = _geom_xml(f"{link}_g{i}", g, indent)
            out.append(line)
            if asset:
                assets.append(asset)
        return "\n".join(out)

    def body(link: str, depth: int) -> str:
        ind = "  " * (depth + 2)
        parts = []
        for j in children.get(link, []):
            quat = _quat_from_matrix(rpy_to_matrix(j.rpy))
            inner = []
            if j.type in ("revolute", "continuous", "prismatic"):
                rng = f'range="{j.lower:.6g} {j.upper:.6g}" limited="true"' if j.type != "continuous" else ""
                kind = "slide" if j.type == "prismatic" else "hinge"
                inner.append(
                    f'{ind}  <joint name="{j.name}" type="{kind}" axis="{_f(j.axis)}" {rng} '
                    f'armature="{armature}" damping="0.1"/>'
                )
                actuated.append(j.name)
            inner.append(f'{ind}  <inertial pos="0 0 0.05" mass="1.5" diaginertia="0.01 0.01 0.005"/>')
            g = geoms(j.child, ind + "  ")
            if g:
                inner.append(g)
            if j.child == desc.ee_link:
                inner.append(f'{ind}  <site name="ee" pos="0 0 0" size="0.01" group="{GROUP_ROBOT}"/>')
            sub = body(j.child, depth + 1)
            if sub:
                inner.append(sub)
            parts.append(
                f'{ind}<body name="{j.child}" pos="{_f(j.xyz)}" quat="{_f(quat)}">\n'
                + "\n".join(inner)
                + f"\n{ind}</body>"
            )
        return "\n".join(parts)

    xml = f'    <body name="{desc.root}" pos="0 0 0">\n{geoms(desc.root, "      ")}\n{body(desc.root, 1)}\n    </body>'
    if desc.joint_order:  # the controller's q order
        actuated = [n for n in desc.joint_order if n in actuated]
    return xml, actuated, assets


def mujoco_camera_xml(name: str, cam: Camera) -> str:
    """A MuJoCo camera (looks along -z, y up) matching a depthguard camera (OpenCV axes)."""
    x_cv, y_cv = cam.R[0], cam.R[1]
    fovy = math.degrees(2 * math.atan(cam.height / 2.0 / cam.fy))
    return f'    <camera name="{name}" pos="{_f(cam.position)}" xyaxes="{_f(x_cv)} {_f(-y_cv)}" fovy="{fovy:.8g}"/>'


def cell_xml(spec: CellSpec, desc: RobotDesc) -> tuple[str, list[str]]:
    """MJCF text of the cell and the actuated joint names."""
    fz = spec.floor_z
    xmin, xmax, ymin, ymax = spec.room
    robot, actuated, assets = _robot_xml(desc, spec.armature)
    lines = [
        '<mujoco model="depthguard_cell">',
        '  <compiler angle="radian"/>',
        *(["  <asset>", *assets, "  </asset>"] if assets else []),
        f'  <option timestep="{spec.timestep}" gravity="0 0 0" integrator="implicitfast">',
        '    <flag contact="disable"/>',
        "  </option>",
        '  <statistic extent="5" center="0 0 0.3"/>',
        '  <visual><global offwidth="1280" offheight="960"/><map znear="0.02" zfar="3"/></visual>',
        "  <worldbody>",
        '    <light pos="0 0 3" dir="0 0 -1" directional="true"/>',
        f'    <geom name="floor" type="plane" pos="0 0 {fz}" size="5 5 0.1" group="{GROUP_ENV}" rgba="0.5 0.5 0.5 1"/>',
        f'    <geom name="table" type="box" pos="0 0 {fz / 2:.6g}" '
        f'size="{spec.table_half[0]} {spec.table_half[1]} {-fz / 2:.6g}" '
        f'group="{GROUP_ENV}" rgba="0.6 0.6 0.65 1"/>',
    ]
    wall_h = 1.5
    for name, pos, size in (
        ("wall_xmin", (xmin - 0.05, 0.5 * (ymin + ymax), fz + wall_h), (0.05, 0.5 * (ymax - ymin) + 0.1, wall_h)),
        ("wall_xmax", (xmax + 0.05, 0.5 * (ymin + ymax), fz + wall_h), (0.05, 0.5 * (ymax - ymin) + 0.1, wall_h)),
        ("wall_ymin", (0.5 * (xmin + xmax), ymin - 0.05, fz + wall_h), (0.5 * (xmax - xmin) + 0.1, 0.05, wall_h)),
        ("wall_ymax", (0.5 * (xmin + xmax), ymax + 0.05, fz + wall_h), (0.5 * (xmax - xmin) + 0.1, 0.05, wall_h)),
    ):
        lines.append(
            f'    <geom name="{name}" type="box" pos="{_f(pos)}" size="{_f(size)}" group="{GROUP_ENV}" '
            'rgba="0.85 0.85 0.8 1"/>'
        )
    if spec.backdrops:
        # a screen behind the robot for each camera, so that the background stays within the sensor range
        for k, cam in enumerate(spec.cameras):
            eye = cam.position
            h = np.array([-eye[0], -eye[1], 0.0])
            h /= max(np.linalg.norm(h), 1e-9)
            c = h * spec.backdrop_distance
            yaw = math.atan2(h[1], h[0])
            quat = (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2))
            lines.append(
                f'    <geom name="wall_screen{k}" type="box" pos="{_f((c[0], c[1], fz + 1.3))}" '
                f'quat="{_f(quat)}" size="0.03 2.2 1.3" group="{GROUP_ENV}" rgba="0.8 0.8 0.75 1"/>'
            )
    lines.append(robot)
    for b in spec.boxes:
        geom = f'<geom name="{b.name}" type="box" size="{_f(b.half)}" group="{GROUP_BOX}" rgba="{_f(b.rgba)}"/>'
        if b.movable:
            lines.append(f'    <body name="{b.name}_body" mocap="true" pos="{_f(b.center)}">{geom}</body>')
        else:
            lines.append(f'    {geom[:-2]} pos="{_f(b.center)}"/>')
    for p in spec.people:
        segs = person_segments(np.zeros(2), 0.0, None, None, spec.floor_z)
        for seg, (a, b) in segs.items():
            r = _segment_radius(seg)
            half = 0.5 * float(np.linalg.norm(b - a))
            nm = f"{p.name}_{seg}"
            if half < 1e-6:
                g = f'<geom name="{nm}" type="sphere" size="{r}" group="{GROUP_PEOPLE}" rgba="0.3 0.5 0.9 1"/>'
            else:
                g = (
                    f'<geom name="{nm}" type="capsule" size="{r} {half:.6g}" group="{GROUP_PEOPLE}" '
                    'rgba="0.3 0.5 0.9 1"/>'
                )
            lines.append(f'    <body name="{nm}_body" mocap="true" pos="0 0 -5">{g}</body>')
    for i, cam in enumerate(spec.cameras):
        lines.append(mujoco_camera_xml(f"depthcam{i}", cam))
    lines.append("  </worldbody>")
    lines.append("  <actuator>")
    for jn in actuated:  # position servo: kp (q_cmd - q)
        lines.append(
            f'    <general name="{jn}_pos" joint="{jn}" gainprm="{spec.kp}" biastype="affine" '
            f'biasprm="0 {-spec.kp} 0"/>'
        )
    for jn in actuated:  # velocity servo: kv (qdot_cmd - qdot)
        lines.append(
            f'    <general name="{jn}_vel" joint="{jn}" gainprm="{spec.kv}" biastype="affine" '
            f'biasprm="0 0 {-spec.kv}"/>'
        )
    lines.append("  </actuator>")
    lines.append("</mujoco>")
    return "\n".join(lines), actuated


def _segment_radius(seg: str) -> float:
    from depthguard.sim.people import SEGMENTS

    return next(s.radius for s in SEGMENTS if s.name == seg)


class Cell:
    """A compiled cell: ``model``, ``data`` and the index maps the rest of the simulator needs.

    Attributes:
        model, data: MuJoCo model and data.
        desc: the robot description the arm was built from.
        qadr, dofadr: (n,) qpos / qvel addresses of the arm joints, in the controller's q order.
        robot_geoms: geom ids of the arm (group 1), with ``robot_geom_body`` their link names.
        obstacle_geoms: geom ids of everything that is not the robot and that the robot could hit.
        cameras: the depth cameras (depthguard :class:`Camera`), same order as MuJoCo cameras depthcam<i>.
    """

    def __init__(self, spec: CellSpec, desc: RobotDesc | None = None) -> None:
        import mujoco

        self.spec = spec
        self.desc = desc or load_robot_desc(spec.robot)
        xml, actuated = cell_xml(spec, self.desc)
        self.xml = xml
        self.mj_spec = mujoco.MjSpec.from_string(xml)
        self.model = self.mj_spec.compile()
        self.data = mujoco.MjData(self.model)
        m = self.model
        self.joint_names = actuated
        jids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n) for n in actuated]
        self.qadr = np.array([m.jnt_qposadr[j] for j in jids])
        self.dofadr = np.array([m.jnt_dofadr[j] for j in jids])
        self.q_lower = np.array([m.jnt_range[j, 0] for j in jids])
        self.q_upper = np.array([m.jnt_range[j, 1] for j in jids])
        self.qd_max = np.array([j.velocity for j in self.desc.actuated])
        self.ee_site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "ee")
        groups = m.geom_group
        self.robot_geoms = np.flatnonzero(groups == GROUP_ROBOT)
        self.robot_geom_body = [
            mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, m.geom_bodyid[g]) for g in self.robot_geoms
        ]
        names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or f"geom{g}" for g in range(m.ngeom)]
        self.geom_names = names
        self.obstacle_geoms = np.array(
            [g for g in range(m.ngeom) if groups[g] != GROUP_ROBOT and not names[g].startswith(("floor", "wall"))]
        )
        self.cameras = list(spec.cameras)
        self.mocap: dict[str, int] = {}
        for b in range(m.nbody):
            if m.body_mocapid[b] >= 0:
                self.mocap[mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b)] = int(m.body_mocapid[b])
        self._carried_offset: dict[str, np.ndarray] = {}
        self.set_q(np.asarray(spec.q0, float))
        self.update_people(0.0)
        mujoco.mj_forward(m, self.data)

    # --------------------------------------------------------------- robot
    @property
    def nq(self) -> int:
        return len(self.qadr)

    def set_q(self, q: np.ndarray) -> None:
        """Put the arm at ``q`` (n,) rad at rest, with the servos holding it there."""
        import mujoco

        self.data.qpos[self.qadr] = q
        self.data.qvel[self.dofadr] = 0.0
        self.data.ctrl[: self.nq] = q
        self.data.ctrl[self.nq : 2 * self.nq] = 0.0
        mujoco.mj_forward(self.model, self.data)

    def q(self) -> np.ndarray:
        return self.data.qpos[self.qadr].copy()

    def qd(self) -> np.ndarray:
        return self.data.qvel[self.dofadr].copy()

    def ee_position(self) -> np.ndarray:
        return self.data.site_xpos[self.ee_site].copy()

    def step(self, q_cmd: np.ndarray, qd_cmd: np.ndarray | None = None, n: int = 1) -> None:
        """Advance the physics ``n`` steps (1 ms each) with the joint command: position ``q_cmd`` (n,) rad (m) and
        velocity ``qd_cmd`` (n,) (servo ``kp (q_cmd - q) + kv (qd_cmd - qd)``)."""
        import mujoco

        self.data.ctrl[: self.nq] = np.clip(q_cmd, self.q_lower, self.q_upper)
        self.data.ctrl[self.nq : 2 * self.nq] = 0.0 if qd_cmd is None else qd_cmd
        mujoco.mj_step(self.model, self.data, n)

    # --------------------------------------------------------------- people
    def update_people(self, t: float) -> None:
        """Pose every person (and what they carry) at time ``t`` s (mocap; call before mj_step/forward)."""
        d = self.data
        for p in self.spec.people:
            segs = p.segments(t)
            for seg, (a, b) in segs.items():
                pos, quat = segment_pose(a, b)
                mid = self.mocap[f"{p.name}_{seg}_body"]
                d.mocap_pos[mid] = pos
                d.mocap_quat[mid] = quat
            _, _, _, _, carry, hand = p.state(t)
            if carry is not None and f"{carry}_body" in self.mocap:
                h = segs[f"{hand[0]}_hand"][0]
                box = next(bx for bx in self.spec.boxes if bx.name == carry)
                d.mocap_pos[self.mocap[f"{carry}_body"]] = h + np.array([0.0, 0.0, -(box.half[2] + 0.03)])

    def forward(self) -> None:
        import mujoco

        mujoco.mj_forward(self.model, self.data)


def build_cell(spec: CellSpec, desc: RobotDesc | None = None) -> Cell:
    """Compile the cell described by ``spec`` (MuJoCo 4, through ``mujoco.MjSpec``)."""
    return Cell(spec, desc)
