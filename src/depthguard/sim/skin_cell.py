"""The simulated cell of the skin experiment (SAPHARI D4.1.1 §4.3): a UR5 with a 49-element skin on its
forearm and a hand that approaches the skin, touches it and withdraws.

* Robot: the UR5 of the ``example-robot-data`` package (any offline 6-DOF URDF works; the paper's
  IRB 140 is not required). Its mesh-only links get primitive capsules for MuJoCo; the forearm carries the
  skin, a cylindrical sleeve (:class:`~depthguard.sensors.skin.SkinLayout`).
* Hand: a mocap palm (box, 8 x 12 x 2 cm) that moves in the sensorised link's frame: it starts
  ``start_gap`` from the skin above one module, approaches along the module's normal at ``approach_speed``
  (0.25 m/s relative to the link), presses ``press`` into the skin, holds, and withdraws at the same speed.
* Readings: each element casts a ray along its normal with ``mj_ray`` (only the environment and the hand;
  the robot's own links are excluded, as a skin whose range is limited to 5 cm is mounted so that it
  does not see them, §4.1). Proximity elements convert the range to ADC counts, contact elements the
  penetration of the silicone layer to a force and counts. The true clearance is ``mj_geomDistance``
  between palm and sleeve.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from depthguard.sensors.skin import SkinLayout
from depthguard.sim.mjcf_robot import GROUP_ENV, GROUP_HUMAN, RaySensors, build_model, urdf_to_mjcf_body

__all__ = ["ur5_urdf_path", "SkinCell", "HandScript"]

_UR5_GEOMS = {
    "shoulder_link": ['<geom type="capsule" fromto="0 0 -0.05 0 0 0.05" size="0.06" group="1"/>'],
    "upper_arm_link": [
        '<geom type="capsule" fromto="0 0 0 0 0 0.425" size="0.055" group="1"/>',
        '<geom type="capsule" fromto="0 0 0.425 0 -0.12 0.425" size="0.05" group="1"/>',
    ],
    "forearm_link": ['<geom type="capsule" fromto="0 0 0 0 0 0.39225" size="0.042" group="1"/>'],
    "wrist_1_link": ['<geom type="sphere" size="0.045" group="1"/>'],
    "wrist_2_link": ['<geom type="sphere" size="0.045" group="1"/>'],
    "wrist_3_link": ['<geom type="cylinder" size="0.04 0.02" pos="0 0.06 0" quat="0.7071 0.7071 0 0" group="1"/>'],
}


def ur5_urdf_path() -> Path:
    """The UR5 URDF of ``example-robot-data`` (``ValueError`` with an install hint when missing)."""
    import sys

    for sp in sys.path:
        p = Path(sp) / "cmeel.prefix/share/example-robot-data/robots/ur_description/urdf/ur5_robot.urdf"
        if p.is_file():
            return p
    raise ValueError("the UR5 URDF of example-robot-data is not installed: pip install 'depthguard[robot]'")


@dataclass(frozen=True)
class HandScript:
    """Relative approach of the hand to the skin: gap (m) between palm and skin over time (s).

    Approach starts at ``t0`` from ``start_gap``; the palm presses ``press`` into the skin, holds ``hold``
    and withdraws to ``start_gap`` at ``approach_speed``; before and after it is far (``far_gap``)."""

    t0: float = 0.2
    start_gap: float = 0.10
    approach_speed: float = 0.25
    press: float = 0.002
    hold: float = 0.3
    far_gap: float = 0.5

    def times(self) -> tuple[float, float, float, float]:
        """(start, contact, withdraw start, end) instants, s."""
        t_touch = self.t0 + self.start_gap / self.approach_speed
        t_w = t_touch + self.press / self.approach_speed + self.hold
        t_end = t_w + (self.press + self.start_gap) / self.approach_speed
        return self.t0, t_touch, t_w, t_end

    def gap(self, t: float) -> float:
        t0, _, t_w, t_end = self.times()
        if t < t0 or t > t_end:
            return self.far_gap
        down = self.start_gap - self.approach_speed * (t - t0)
        if t < t_w:
            return max(down, -self.press)
        return -self.press + self.approach_speed * (t - t_w)


class SkinCell:
    """MuJoCo model of the UR5 with the skin and the hand.

    Args:
        layout: the skin on ``forearm_link``.
        hand_module, hand_element: where the palm's centre comes down.
    """

    PALM_HALF = (0.04, 0.06, 0.01)

    def __init__(self, layout: SkinLayout | None = None, hand_module: int = 2, hand_element: int = 3) -> None:
        import mujoco

        self._mj = mujoco
        self.layout = layout or SkinLayout(link="forearm_link")
        L = self.layout
        zc = L.z0 + 0.5 * (L.per_module - 1) * L.pitch
        half = 0.5 * (L.per_module - 1) * L.pitch + 0.02
        geoms = {k: list(v) for k, v in _UR5_GEOMS.items()}
        geoms[L.link] = geoms.get(L.link, []) + [
            f'<geom name="skin" type="cylinder" size="{L.radius} {half}" pos="0 0 {zc}" group="1" '
            'rgba="0.3 0.3 0.35 1"/>'
        ]
        bodies = urdf_to_mjcf_body(ur5_urdf_path(), geoms, rgba="0.6 0.7 0.8 1")
        ph = self.PALM_HALF
        scene = (
            '<geom name="floor" type="plane" size="3 3 0.1" pos="0 0 -0.01" group="0" rgba="0.8 0.8 0.8 1"/>\n'
            f'<body name="hand" mocap="true" pos="1 1 1"><geom name="palm" type="box" size="{ph[0]} {ph[1]} {ph[2]}" '
            f'group="{GROUP_HUMAN}" rgba="0.95 0.75 0.6 1"/></body>'
        )
        self.m, self.d = build_model(bodies, scene)
        self.mounts = L.mounts()
        self.rays = RaySensors(self.m, self.d, self.mounts, groups=(GROUP_ENV, GROUP_HUMAN))
        self.is_prox = L.kinds() == "P"
        self.hand_index = hand_module * L.per_module + hand_element
        self.palm = mujoco.mj_name2id(self.m, mujoco.mjtObj.mjOBJ_GEOM, "palm")
        self.skin = mujoco.mj_name2id(self.m, mujoco.mjtObj.mjOBJ_GEOM, "skin")
        self.tool = mujoco.mj_name2id(self.m, mujoco.mjtObj.mjOBJ_BODY, "tool0")
        self._fromto = np.zeros(6)

    def set_state(self, q: np.ndarray, gap: float) -> None:
        """Pose the robot at ``q`` (6,) and the palm ``gap`` m above the skin (negative = pressed in)."""
        mj = self._mj
        self.d.qpos[:] = q
        mj.mj_kinematics(self.m, self.d)
        pos, ax = self.rays.poses()
        p, n = pos[self.hand_index], ax[self.hand_index]
        body = self.rays.body[self.hand_index]
        y = self.d.xmat[body].reshape(3, 3)[:, 2]  # the link's axis
        x = np.cross(y, n)
        R = np.column_stack([x, y, n])
        quat = np.zeros(4)
        mj.mju_mat2Quat(quat, R.ravel())
        self.d.mocap_pos[0] = p + n * (gap + self.PALM_HALF[2])
        self.d.mocap_quat[0] = quat
        mj.mj_kinematics(self.m, self.d)

    def ranges(self) -> np.ndarray:
        """(49,) signed range of each element's ray, m (negative = surface pressed into the skin)."""
        return self.rays.cast(back=0.01)[0]

    def clearance(self) -> float:
        """True palm-skin distance, m (negative = penetration)."""
        return float(self._mj.mj_geomDistance(self.m, self.d, self.palm, self.skin, 1.0, self._fromto))

    def tcp(self) -> np.ndarray:
        """(3,) tool0 position, m."""
        return self.d.xpos[self.tool].copy()
