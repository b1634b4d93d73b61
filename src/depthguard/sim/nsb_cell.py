"""The simulated cell of the distributed-proximity experiments (SAPHARI D4.1.1 §5.3): the youBot-like
robot, the box of the place task, the obstacles of the four case studies, and its ten Sharp sensors.

Each sensor's reading comes from a ray along its optical axis (``mj_ray``, every geom except the
sensor's own link, the robot's other links included: a real sensor sees them too), converted to the
sensor's output voltage by its data-sheet curve, updated every ~38 ms and sampled at 300 Hz by a 10-bit
ADC (:class:`~depthguard.sensors.sharp.IRRanger`), and back to the distance it reports (ambiguity
below the minimum range resolved on the safe side). The true clearance is the minimum ``mj_geomDistance``
between the robot's geoms and the obstacles' (box included).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from depthguard.robot.youbot import YOUBOT_SENSORS, youbot_urdf_path
from depthguard.sensors.sharp import GP2D120XJ00F, GP2Y0A21YK, IRRanger
from depthguard.sim.mjcf_robot import GROUP_ROBOT, RaySensors, build_model, urdf_to_mjcf_body

__all__ = ["Obstacle", "case_obstacles", "NSBCell", "BOX_CENTRE"]

#: Centre of the target box's floor (m): the box is 0.36 x 0.36 x 0.20 m, open at the top.
BOX_CENTRE = (1.62, 0.0, 0.0)


@dataclass(frozen=True)
class Obstacle:
    """A static box obstacle: ``centre`` (3,) and ``half`` sizes (3,), m."""

    name: str
    centre: tuple[float, float, float]
    half: tuple[float, float, float]
    rgba: str = "0.55 0.35 0.2 1"


def _box_walls() -> list[Obstacle]:
    cx, cy, _ = BOX_CENTRE
    h, t, z = 0.18, 0.01, 0.10
    return [
        Obstacle("box_near", (cx - h, cy, z), (t, h, z), "0.8 0.6 0.3 1"),
        Obstacle("box_far", (cx + h, cy, z), (t, h, z), "0.8 0.6 0.3 1"),
        Obstacle("box_left", (cx, cy + h, z), (h, t, z), "0.8 0.6 0.3 1"),
        Obstacle("box_right", (cx, cy - h, z), (h, t, z), "0.8 0.6 0.3 1"),
        Obstacle("box_bottom", (cx, cy, 0.005), (h, h, 0.005), "0.8 0.6 0.3 1"),
    ]


def case_obstacles(case: int, with_box: bool = True) -> list[Obstacle]:
    """Obstacles of case study ``case`` (1-4, numbered as in the seed): 1 the box only (or nothing with
    ``with_box=False``); 2 and 3 the box and an unexpected obstacle between the box and the robot, on the
    base's path; 4 a cluttered scene: two obstacles on the base's path (on its sensed, right-hand side: the
    paper's six base sensors leave the left side blind), one beside it, and an overhead beam across it."""
    if case not in (1, 2, 3, 4):
        raise ValueError(f"case must be 1, 2, 3 or 4, got {case!r}")
    obs = _box_walls() if with_box else []
    if case in (2, 3):
        obs.append(Obstacle("obstacle", (0.75, -0.20, 0.35), (0.06, 0.06, 0.35)))
    if case == 4:
        obs.append(Obstacle("obstacle", (0.70, -0.20, 0.35), (0.06, 0.06, 0.35)))
        obs.append(Obstacle("obstacle_2", (1.12, -0.27, 0.25), (0.08, 0.05, 0.25)))
        obs.append(Obstacle("obstacle_left", (0.90, 0.52, 0.35), (0.06, 0.06, 0.35)))
        obs.append(Obstacle("beam", (0.95, 0.0, 0.53), (0.04, 1.0, 0.03), "0.4 0.4 0.45 1"))
        obs.append(Obstacle("beam_post_l", (0.95, 1.0, 0.29), (0.03, 0.03, 0.29), "0.4 0.4 0.45 1"))
        obs.append(Obstacle("beam_post_r", (0.95, -1.0, 0.29), (0.03, 0.03, 0.29), "0.4 0.4 0.45 1"))
    return obs


class NSBCell:
    """MuJoCo model of the robot and a scene, with the ten rangers."""

    def __init__(self, obstacles: list[Obstacle], seed: int = 0) -> None:
        import mujoco

        self._mj = mujoco
        self.obstacles = list(obstacles)
        scene = '<geom name="floor" type="plane" size="4 4 0.1" group="3" rgba="0.85 0.85 0.85 1"/>\n'
        for o in self.obstacles:
            scene += (
                f'<geom name="{o.name}" type="box" pos="{" ".join(map(str, o.centre))}" '
                f'size="{" ".join(map(str, o.half))}" group="0" rgba="{o.rgba}"/>\n'
            )
        self.m, self.d = build_model(urdf_to_mjcf_body(youbot_urdf_path()), scene, timestep=1 / 300)
        # the floor (group 3) is not seen: the sensors are horizontal or look up in this task
        self.rays = RaySensors(self.m, self.d, YOUBOT_SENSORS, groups=(0, GROUP_ROBOT))
        rng = np.random.default_rng(seed)
        self.rangers = [
            IRRanger(
                GP2Y0A21YK if m.kind == GP2Y0A21YK.name else GP2D120XJ00F,
                rng=np.random.default_rng(rng.integers(1 << 31)),
            )
            for m in YOUBOT_SENSORS
        ]
        gt = self.m.geom_group
        self.robot_geoms = [g for g in range(self.m.ngeom) if gt[g] == GROUP_ROBOT]
        self.obstacle_geoms = [mujoco.mj_name2id(self.m, mujoco.mjtObj.mjOBJ_GEOM, o.name) for o in self.obstacles]
        self._fromto = np.zeros(6)
        self._robot_set = set(self.robot_geoms)
        self.last_true = np.full(10, np.inf)
        self.self_hits = 0
        self._rg = np.array(self.robot_geoms, dtype=int)
        self._og = np.array(self.obstacle_geoms, dtype=int)
        self._rb = self.m.geom_rbound[self._rg]
        self._ob = self.m.geom_rbound[self._og]

    def set_q(self, q: np.ndarray) -> None:
        self.d.qpos[:] = q
        self._mj.mj_kinematics(self.m, self.d)

    def true_ranges(self) -> tuple[np.ndarray, np.ndarray]:
        """(10,) true ranges along the optical axes (m, inf = nothing within range), geom ids hit."""
        return self.rays.cast()

    def read(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Sample all rangers at time ``t``: (voltages V, normalised outputs, reported distances m)."""
        true = None
        v = np.zeros(10)
        dist = np.zeros(10)
        if any(r.due(t) for r in self.rangers):
            true, hit = self.true_ranges()
            self.last_true = true
            self.self_hits += int(sum(h in self._robot_set for h in hit))
        for k, r in enumerate(self.rangers):
            v[k], dist[k] = r.sample(t, None if true is None else float(true[k]))
        return v, v / np.array([r.model.v_peak for r in self.rangers]), dist

    def clearance(self) -> tuple[float, str]:
        """True minimum distance (m) between the robot and the obstacles, and the obstacle's name."""
        rg, og = self._rg, self._og
        if og.size == 0:
            return float("inf"), ""
        c = self.d.geom_xpos
        # bounding-sphere lower bounds first; exact distances only for pairs that can beat the best
        lb = np.linalg.norm(c[rg][:, None, :] - c[og][None, :, :], axis=2) - self._rb[:, None] - self._ob[None, :]
        best, name = np.inf, ""
        for i, j in zip(*np.unravel_index(np.argsort(lb, axis=None), lb.shape), strict=True):
            if lb[i, j] >= min(best, 0.5):
                break
            dd = self._mj.mj_geomDistance(self.m, self.d, int(rg[i]), int(og[j]), 0.5, self._fromto)
            if dd < best:
                best, name = dd, self.obstacles[j].name
        if not np.isfinite(best):
            best = float(max(lb.min(), 0.5))
        return float(best), name


def geom_corners(m, d, geoms) -> list[np.ndarray]:
    """(8, 3) world corners of the bounding box of each of ``geoms`` (boxes exact, cylinders bounded)."""
    out = []
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
    for g in geoms:
        size = m.geom_size[g]
        half = size.copy() if m.geom_type[g] == 6 else np.array([size[0], size[0], size[1]])  # 6 = box
        R = d.geom_xmat[g].reshape(3, 3)
        out.append(d.geom_xpos[g] + (signs * half) @ R.T)
    return out


def robot_outlines(obstacles, qs) -> list[list[np.ndarray]]:
    """Corners of the robot's geoms at each configuration of ``qs`` (for snapshot plots)."""
    cell = NSBCell(obstacles)
    out = []
    for q in qs:
        cell.set_q(np.asarray(q))
        out.append(geom_corners(cell.m, cell.d, cell.robot_geoms))
    return out
