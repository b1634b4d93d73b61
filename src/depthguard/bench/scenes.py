"""The benchmark and demo scene: a person reaching towards an arm, seen by one or two Kinect-like cameras.

World frame = robot base frame (z up). Camera 1 (the principal one) stands as in ICRA'12 §VI-A: 2 m away
horizontally, 1.2 m high. Camera 2 stands about 4 m from camera 1 (RA-L'16 §VIII). The person's torso
is about 2 m from camera 1; a wall stands 3.5 m in front of camera 1 and another one faces camera 2.
"""

from __future__ import annotations

import numpy as np

from depthguard.camera import Camera, look_at
from depthguard.scene import Box, Capsule, HalfSpace, Scene, Sphere, render_depth

__all__ = ["person_scene", "bench_cameras", "arm_chain_points", "kinect_noise", "noisy_depth", "shadow_frames"]

SHADOW_WORKSPACE = (-1.2, 1.2, -1.2, 1.2, -0.3, 1.5)  # the simulated scenarios' default (sim/scenarios.py)
SHADOW_Q = (0.0, -0.3, 0.0, 1.6, 0.0, -0.8, 0.0)  # the ral-shadow scenario's q0


def person_scene(reach: float = 0.0) -> Scene:
    """A standing person (legs, torso, head, two arms), one arm reaching towards the robot, and two walls.

    Args:
        reach: how far (m) the reaching hand is moved from its default pose towards -y (the robot).
    """
    px, py = 0.15, 0.95  # person's ground position (world)
    shoulder_r = np.array([px, py - 0.20, 1.38])
    elbow_r = np.array([px + 0.02, py - 0.45 - reach / 2, 1.22])
    hand_r = np.array([px + 0.05, py - 0.66 - reach, 1.12])
    prims = [
        Capsule(np.array([px, py - 0.1, 0.05]), np.array([px, py - 0.1, 0.85]), 0.08),  # legs
        Capsule(np.array([px, py + 0.1, 0.05]), np.array([px, py + 0.1, 0.85]), 0.08),
        Capsule(np.array([px, py, 0.95]), np.array([px, py, 1.35]), 0.17),  # torso
        Sphere(np.array([px, py, 1.62]), 0.11),  # head
        Capsule(shoulder_r, elbow_r, 0.05),  # reaching upper arm
        Capsule(elbow_r, hand_r, 0.045),  # forearm
        Sphere(hand_r + np.array([0.0, -0.05, 0.0]), 0.06),  # hand
        Capsule(np.array([px, py + 0.2, 1.38]), np.array([px, py + 0.25, 0.95]), 0.05),  # other arm
        HalfSpace(np.array([-1.5, 0.0, 0.0]), np.array([1.0, 0.0, 0.0])),  # wall 3.5 m from camera 1
        HalfSpace(np.array([0.0, -0.5, 0.0]), np.array([0.0, 1.0, 0.0])),  # wall facing camera 2
    ]
    return Scene(tuple(prims))


def bench_cameras(width: int = 640, height: int = 480, f: float = 525.0) -> list[Camera]:
    """Two Kinect-like cameras about 4 m apart; the first one is the principal camera."""
    cams = []
    for eye, target in (([2.0, 0.0, 1.2], [0.0, 0.2, 0.8]), ([-0.3, 2.9, 1.5], [0.0, 0.2, 0.8])):
        R, t = look_at(eye, target)
        cams.append(
            Camera(
                width=width,
                height=height,
                fx=f,
                fy=f,
                cx=width / 2 - 0.5,
                cy=height / 2 - 0.5,
                R=R,
                t=t,
                min_depth=0.5,
                max_depth=4.5,
            )
        )
    return cams


def arm_chain_points() -> tuple[list[str], np.ndarray, np.ndarray]:
    """9 control spheres along an arm-like chain (base -> end effector), several within 0.4 m of the hand.

    Returns:
        names (9,), centres (9, 3) world metres, radii (9,) metres.
    """
    joints = np.array([[0.0, 0.0, 0.35], [0.0, 0.0, 0.65], [0.05, 0.05, 0.95], [0.22, 0.05, 1.10], [0.30, 0.06, 1.05]])
    # two points per segment, base to end effector: s = 0, 0.5, ..., 4 along the polyline
    s = np.arange(9) * 0.5
    k = np.minimum(s.astype(int), 3)
    centres = joints[k] + (s - k)[:, None] * (joints[k + 1] - joints[k])
    radii = np.array([0.09, 0.09, 0.08, 0.08, 0.07, 0.07, 0.06, 0.06, 0.05])
    names = [f"cp{i}" for i in range(8)] + ["ee"]
    return names, centres, radii


def kinect_noise(
    depth: np.ndarray,
    rng: np.random.Generator,
    sigma_per_m2: float = 0.0014,
    quantum: float = 0.001,
    missing: float = 0.02,
) -> np.ndarray:
    """Kinect v1-like measurement: axial noise ``sigma = 1.4 mm z^2``, 1 mm quantisation, random dropouts.

    Args:
        depth: (H, W) exact depth in metres (NaN = no surface).
        rng: random generator (fixed seed for reproducibility).
        missing: fraction of pixels without a reading.
    Returns:
        (H, W) float32 noisy depth, NaN = no reading.
    """
    d = depth + rng.standard_normal(depth.shape) * sigma_per_m2 * depth**2
    d = np.round(d / quantum) * quantum
    d[rng.random(depth.shape) < missing] = np.nan
    return d.astype(np.float32)


def noisy_depth(camera: Camera, scene: Scene, seed: int = 0) -> np.ndarray:
    """Exact ray-cast depth of ``scene`` with :func:`kinect_noise` applied."""
    return kinect_noise(render_depth(camera, scene), np.random.default_rng(seed))


def shadow_frames(width: int = 640, height: int = 480) -> dict:
    """The ``ral-shadow`` situation (RA-L'16 Figs. 8 and 12) as two analytic frames, for ``bench distance``.

    The two Kinect-like cameras of the ``"ral"`` placement (:func:`depthguard.sim.depthcam.placement`), the
    shipped LWR at the scenario's ``q0`` (its link capsules, masked in both images as the self-filter
    would), a person 1.5 m from the robot holding a 40x30 cm panel up between the principal camera and the
    robot (the scenario's keyframe at t = 1 s), the floor and two walls. Kinect-like noise, no random
    drop-outs (the simulated sensor drops pixels only at depth edges). The robot's 9 ``ral-9`` control
    spheres (end-effector radius 0.12 m) are the query points, as in the scenario.

    Returns:
        ``{"cameras", "depths", "masks", "centres", "radii", "workspace", "q", "model"}`` (``q``, ``model``:
        the joint positions and the robot, for the frame stage's robot corrections).
    """
    from depthguard.robot.control_points import ControlPointSet
    from depthguard.robot.model import load_lwr4
    from depthguard.sim.depthcam import placement

    cams = placement("ral", width, height)
    model = load_lwr4()
    q = np.array(SHADOW_Q)
    a, b, r = model.link_capsules(q)
    robot = Scene(tuple(Capsule(a[k], b[k], r[k]) for k in range(len(r))))
    floor = -0.8
    base = np.array([1.3, -0.62])
    hand = np.array([1.15, -0.58, 1.12])
    yaw = np.radians(145.0)
    side = np.array([-np.sin(yaw), np.cos(yaw), 0.0])  # the person's left, in the floor plane
    hip = np.array([base[0], base[1], floor + 0.95])
    neck = np.array([base[0], base[1], floor + 1.45])
    shoulder = neck - 0.2 * side
    person = (
        Capsule(hip + 0.1 * side, np.array([*base, floor + 0.08]) + 0.1 * side, 0.07),  # legs
        Capsule(hip - 0.1 * side, np.array([*base, floor + 0.08]) - 0.1 * side, 0.07),
        Capsule(hip, neck, 0.16),  # torso
        Sphere(neck + np.array([0.0, 0.0, 0.22]), 0.11),  # head
        Capsule(shoulder, hand, 0.05),  # the arm holding the panel up
        Box(hand + np.array([-0.06, 0.0, 0.0]), np.array([0.05, 0.2, 0.15])),  # the panel
    )
    room = (
        HalfSpace(np.array([0.0, 0.0, floor]), np.array([0.0, 0.0, 1.0])),
        HalfSpace(np.array([-1.1, 0.0, 0.0]), np.array([1.0, 0.0, 0.0])),
        HalfSpace(np.array([0.0, -1.1, 0.0]), np.array([0.0, 1.0, 0.0])),
    )
    full = Scene((*robot.primitives, *person, *room))
    rng = np.random.default_rng(7)
    depths, masks = [], []
    for cam in cams:
        exact = render_depth(cam, full)
        robot_d = render_depth(cam, robot)
        masks.append(np.isfinite(robot_d) & (robot_d <= exact + 1e-9))
        depths.append(kinect_noise(exact, rng, missing=0.0))
    pts = ControlPointSet.build(model, "ral-9", ee_radius=0.12).evaluate(q)
    return {
        "cameras": cams,
        "depths": depths,
        "masks": masks,
        "centres": np.asarray(pts.centres),
        "radii": np.asarray(pts.radii),
        "workspace": SHADOW_WORKSPACE,
        "q": q,
        "model": model,
    }
