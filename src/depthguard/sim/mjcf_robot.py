"""A MuJoCo model of any URDF chain with primitive geometry, plus a scene, and robot-mounted ray sensors.

:func:`urdf_to_mjcf_body` writes one MJCF body per URDF link (frames identical to the URDF's, so that
pinocchio frames and MuJoCo bodies agree), a hinge or slide joint per revolute/prismatic joint, and the
URDF's ``box``/``cylinder``/``sphere`` collision primitives (meshes are skipped; pass primitives for them
in ``extra_geoms``). :func:`build_model` wraps it in a world with a scene and compiles it; the robot is
posed kinematically (``qpos``) by the experiments, so no actuators are written.

:class:`RaySensors` casts each mounted sensor's ray along its optical axis with ``mj_ray`` (excluding the
sensor's own body): the range ``d_k`` such a sensor measures (SAPHARI eq. 5.14).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from depthguard.sensors.mount import SensorMount

__all__ = ["urdf_to_mjcf_body", "build_model", "RaySensors", "rpy_quat"]

GROUP_ENV, GROUP_ROBOT, GROUP_HUMAN = 0, 1, 2


def rpy_quat(rpy: tuple[float, float, float]) -> tuple[float, float, float, float]:
    """URDF roll-pitch-yaw (fixed axes x, y, z) -> MuJoCo quaternion (w, x, y, z)."""
    r, p, y = (0.5 * a for a in rpy)
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def _f(v) -> str:
    return " ".join(f"{float(x):.12g}" for x in v)


def _origin(e: ET.Element | None) -> tuple[list[float], list[float]]:
    if e is None:
        return [0.0] * 3, [0.0] * 3
    return [float(x) for x in e.get("xyz", "0 0 0").split()], [float(x) for x in e.get("rpy", "0 0 0").split()]


def _geoms(link: ET.Element, rgba: str) -> list[str]:
    out = []
    for col in link.findall("collision"):
        g = col.find("geometry")
        if g is None:
            continue
        xyz, rpy = _origin(col.find("origin"))
        pose = f'pos="{_f(xyz)}" quat="{_f(rpy_quat(tuple(rpy)))}"'
        if (b := g.find("box")) is not None:
            half = [0.5 * float(x) for x in b.get("size").split()]
            out.append(f'<geom type="box" size="{_f(half)}" {pose} group="{GROUP_ROBOT}" rgba="{rgba}"/>')
        elif (c := g.find("cylinder")) is not None:
            size = f"{c.get('radius')} {0.5 * float(c.get('length'))}"
            out.append(f'<geom type="cylinder" size="{size}" {pose} group="{GROUP_ROBOT}" rgba="{rgba}"/>')
        elif (s := g.find("sphere")) is not None:
            out.append(f'<geom type="sphere" size="{s.get("radius")}" {pose} group="{GROUP_ROBOT}" rgba="{rgba}"/>')
    return out


def urdf_to_mjcf_body(
    urdf_path: str | Path, extra_geoms: dict[str, list[str]] | None = None, rgba: str = "0.9 0.55 0.1 1"
) -> str:
    """MJCF bodies (to go inside ``<worldbody>``) of the URDF's link tree; see the module docstring."""
    root = ET.parse(urdf_path).getroot()
    links = {e.get("name"): e for e in root.findall("link")}
    children: dict[str, list[ET.Element]] = {}
    child_names = set()
    for j in root.findall("joint"):
        children.setdefault(j.find("parent").get("link"), []).append(j)
        child_names.add(j.find("child").get("link"))
    extra = extra_geoms or {}

    def body(joint: ET.Element, indent: str) -> str:
        name = joint.find("child").get("link")
        xyz, rpy = _origin(joint.find("origin"))
        s = f'{indent}<body name="{name}" pos="{_f(xyz)}" quat="{_f(rpy_quat(tuple(rpy)))}">\n'
        s += f'{indent}  <inertial pos="0 0 0" mass="0.5" diaginertia="0.01 0.01 0.01"/>\n'
        typ = joint.get("type")
        if typ in ("revolute", "continuous", "prismatic"):
            axis = joint.find("axis")
            ax = axis.get("xyz", "1 0 0") if axis is not None else "1 0 0"
            kind = "slide" if typ == "prismatic" else "hinge"
            s += f'{indent}  <joint name="{joint.get("name")}" type="{kind}" axis="{ax}" limited="false"/>\n'
        for g in _geoms(links[name], rgba) + list(extra.get(name, [])):
            s += f"{indent}  {g}\n"
        for cj in children.get(name, []):
            s += body(cj, indent + "  ")
        return s + f"{indent}</body>\n"

    out = ""
    for root_name in [n for n in links if n not in child_names]:
        for g in _geoms(links[root_name], rgba) + list(extra.get(root_name, [])):
            out += f"    {g}\n"
        for j in children.get(root_name, []):
            out += body(j, "    ")
    return out


def build_model(robot_bodies: str, scene: str = "", timestep: float = 0.001, assets: str = ""):
    """Compile a world with the robot bodies and ``scene`` (MJCF inside ``<worldbody>``). Gravity off,
    contacts off: collisions are measured, not simulated. Returns (MjModel, MjData)."""
    import mujoco

    xml = f"""<mujoco model="depthguard-saphari">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{timestep}" gravity="0 0 0"><flag contact="disable"/></option>
  <visual><global offwidth="800" offheight="600"/></visual>
  {assets}
  <worldbody>
    <light pos="0 0 4" dir="0 0 -1" diffuse="0.8 0.8 0.8"/>
{robot_bodies}
{scene}
  </worldbody>
</mujoco>"""
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d)
    return m, d


class RaySensors:
    """Rays along mounted sensors' optical axes in a MuJoCo model whose bodies are named after links.

    Args:
        model, data: the compiled MuJoCo model and its data.
        mounts: the sensors (link = MuJoCo body name).
        groups: geom groups the rays see (default all).
    """

    def __init__(self, model, data, mounts: tuple[SensorMount, ...], groups: tuple[int, ...] | None = None) -> None:
        import mujoco

        self._mj = mujoco
        self.m, self.d = model, data
        self.mounts = tuple(mounts)
        self.body = np.array([mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, mt.link) for mt in self.mounts])
        if np.any(self.body < 0):
            bad = [mt.link for mt, b in zip(self.mounts, self.body, strict=True) if b < 0]
            raise ValueError(f"sensor links not in the MuJoCo model: {bad}")
        self.p = np.array([mt.position for mt in self.mounts], float)
        self.a = np.array([mt.axis for mt in self.mounts], float)
        self.range = np.array([mt.max_range for mt in self.mounts], float)
        self.groups = None
        if groups is not None:
            self.groups = np.zeros(6, np.uint8)
            self.groups[list(groups)] = 1
        self._gid = np.zeros(1, np.int32)
        self._body_list = [int(b) for b in self.body]

    def poses(self) -> tuple[np.ndarray, np.ndarray]:
        """World origins (N, 3) and unit axes (N, 3) of the sensors (after ``mj_kinematics``)."""
        R = self.d.xmat[self.body].reshape(-1, 3, 3)
        o = self.d.xpos[self.body]
        return np.einsum("kij,kj->ki", R, self.p) + o, np.einsum("kij,kj->ki", R, self.a)

    def cast(self, back: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Ranges (N,), m, along each axis from the sensor point (inf = nothing within max_range), and the
        geom ids hit (-1 = none). ``back`` starts each ray that far behind the sensor (inside its own
        body) and subtracts it, so that a surface pressed into the sensor reads negative."""
        pos, ax = self.poses()
        starts = pos - back * ax
        n = len(self.mounts)
        out = np.full(n, np.inf)
        hit = np.full(n, -1)
        ray, m, d, g, gid, body, rng = (
            self._mj.mj_ray,
            self.m,
            self.d,
            self.groups,
            self._gid,
            self._body_list,
            self.range,
        )
        for k in range(n):
            r = ray(m, d, starts[k], ax[k], g, 1, body[k], gid)
            if r >= 0 and r - back <= rng[k]:
                out[k] = r - back
                hit[k] = int(gid[0])
        return out, hit
