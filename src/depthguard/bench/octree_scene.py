"""The SAPHARI §3.3 scene without a simulator: the mobile manipulator, a person reaching for it from its left,
static obstacles on the other sides, sensed by the platform's two depth cameras and two 2-D scanners.

Depth images and scans are exact ray casts (:mod:`depthguard.scene`) of the obstacles *and* the robot's
capsules; the robot is then removed by the project's self-filter (cameras) and by
:func:`depthguard.octree.scanner.scan_robot_rays` (scanners), as on the real platform.
"""

from __future__ import annotations

from functools import lru_cache
from importlib import resources
from pathlib import Path

import numpy as np

from depthguard.bench.scenes import kinect_noise
from depthguard.octree.fusion import CameraObservation, ScanObservation
from depthguard.octree.grid import VoxelBox
from depthguard.octree.scanner import scan_robot_rays
from depthguard.robot.platform import platform_sensors
from depthguard.robot.selffilter import self_filter
from depthguard.scene import Box, Capsule, HalfSpace, Scene, Sphere, render_depth

__all__ = ["omni_model", "omni_urdf_path", "Q_BENCH", "obstacle_scene", "robot_scene", "sense", "platform_box"]

# base (x, y, yaw), then the arm reaching forward and to the left
Q_BENCH = np.array([0.0, 0.0, 0.0, 0.5, -0.7, 0.0, 1.1, 0.0, -0.6, 0.0])


def omni_urdf_path() -> Path:
    return Path(str(resources.files("depthguard.robot") / "data" / "omni_lwr4" / "omni_lwr4.urdf"))


@lru_cache(maxsize=1)
def omni_model():
    """The shipped mobile manipulator (10 coordinates: base x, y, yaw, then the 7 arm joints)."""
    from depthguard.robot.model import RobotModel

    return RobotModel.from_urdf(omni_urdf_path(), ee_frame="lwr_ee")


def person(base_xy, reach: float, yaw_to_robot: float = -np.pi / 2) -> list:
    """A standing person at ``base_xy`` reaching ``reach`` metres towards -y of its own frame (the robot)."""
    px, py = base_xy
    d = np.array([np.cos(yaw_to_robot), np.sin(yaw_to_robot), 0.0])
    side = np.array([-d[1], d[0], 0.0])
    c = np.array([px, py, 0.0])
    shoulder = c + 0.2 * d + 0.0 * side + np.array([0, 0, 1.38])
    hand = shoulder + (0.45 + reach) * d + np.array([0, 0, -0.2])
    elbow = 0.5 * (shoulder + hand) + np.array([0, 0, -0.08])
    return [
        Capsule(c + 0.1 * side + [0, 0, 0.05], c + 0.1 * side + [0, 0, 0.85], 0.08),
        Capsule(c - 0.1 * side + [0, 0, 0.05], c - 0.1 * side + [0, 0, 0.85], 0.08),
        Capsule(c + [0, 0, 0.95], c + [0, 0, 1.35], 0.17),
        Sphere(c + [0, 0, 1.62], 0.11),
        Capsule(shoulder, elbow, 0.05),
        Capsule(elbow, hand, 0.045),
        Capsule(c - 0.2 * side + [0, 0, 1.38], c - 0.25 * side + [0, 0, 0.95], 0.05),
    ]


def obstacle_scene(reach: float = 0.3, person_xy=(0.55, 1.05)) -> Scene:
    """A person on the platform's left reaching for the arm; a shelf behind, a crate on the right, a pillar in
    front, the floor (z = 0) and walls."""
    prims = [
        *person(person_xy, reach),
        Box(np.array([-1.5, 0.0, 0.9]), np.array([0.25, 0.8, 0.9]), np.eye(3)),  # shelf behind
        Box(np.array([0.2, -1.3, 0.35]), np.array([0.35, 0.3, 0.35]), np.eye(3)),  # crate on the right
        Capsule(np.array([1.7, 0.3, 0.0]), np.array([1.7, 0.3, 2.2]), 0.15),  # pillar in front
        HalfSpace(np.array([0.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])),  # floor
        HalfSpace(np.array([3.0, 0.0, 0.0]), np.array([-1.0, 0.0, 0.0])),
        HalfSpace(np.array([0.0, 2.6, 0.0]), np.array([0.0, -1.0, 0.0])),
        HalfSpace(np.array([-3.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0])),
        HalfSpace(np.array([0.0, -2.6, 0.0]), np.array([0.0, 1.0, 0.0])),
    ]
    return Scene(tuple(prims))


def robot_scene(model, q: np.ndarray) -> list:
    """The robot's capsules as scene primitives (what the sensors see of it)."""
    a, b, r = model.link_capsules(q)
    return [Capsule(a[i], b[i], float(r[i])) for i in range(len(a))]


def platform_box(q_base: np.ndarray, res: float = 0.05) -> VoxelBox:
    """The octree's bounding box around the platform (SAPHARI §3.2): 4.2 x 4.2 m, from 0.1 m to 2.1 m high
    (the floor itself stays out)."""
    x, y = float(q_base[0]), float(q_base[1])
    return VoxelBox.around([x - 2.1, y - 2.1, 0.1], [x + 2.1, y + 2.1, 2.1], res)


def sense(model, q: np.ndarray, scene: Scene, width: int = 640, height: int = 480, seed: int | None = 0):
    """One frame of the four platform sensors at robot state ``q``: exact ray casts of ``scene`` plus the robot,
    Kinect-like noise and dropouts on the cameras (``seed=None``: exact), robot removed.

    Returns:
        (observations, cameras, scanners, raw depths): observations for :func:`depthguard.octree.fusion.fuse`.
    """
    full = Scene(tuple(scene.primitives) + tuple(robot_scene(model, q)))
    cams, scanners = platform_sensors(q[:3], width, height)
    obs, depths = [], []
    for i, cam in enumerate(cams):
        d = render_depth(cam, full)
        if seed is not None:
            d = kinect_noise(d, np.random.default_rng(seed + i))
        d = np.nan_to_num(d, nan=0.0).astype(np.float32)
        mask = self_filter(cam, d, q, model, with_depth=False).mask
        obs.append(CameraObservation(cam, d, mask))
        depths.append(d)
    a, b, r = model.link_capsules(q)
    for sc in scanners:
        s = full.ray_hit(sc.position, sc.directions())
        ranges = np.where(s <= sc.range_max, s, np.inf)
        obs.append(ScanObservation(sc, ranges, scan_robot_rays(sc, ranges, a, b, r)))
    return obs, cams, scanners, depths
