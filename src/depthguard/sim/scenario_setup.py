"""A scenario's set-up from its data file: the simulated cell (cameras, robot, boxes, people), the start
configuration (inverse kinematics to ``ee_start``) and the end-effector task (:mod:`depthguard.sim.scenarios`
runs them)."""

from __future__ import annotations

import numpy as np

__all__ = ["build_scenario_cell", "solve_ik", "scenario_task"]


def with_ssm_cameras(sc: dict, ssm: bool) -> dict:
    """Scenario ``sc`` as run with speed and separation monitoring (``ssm``): its ``ssm_cameras`` placement,
    where it has one, whose views hold the protective zone (docs/ssm.md); ``sc`` itself otherwise."""
    return {**sc, "cameras": sc["ssm_cameras"]} if ssm and "ssm_cameras" in sc else sc


def build_scenario_cell(sc: dict, *, quick: bool, cameras: int | None, demo: bool = False):
    """The simulated cell of scenario ``sc`` (a loaded scenario dict): its cameras (resolution of the full,
    ``quick`` or ``demo`` form; the first ``cameras`` of the placement), robot, boxes and people. Returns
    ``(cell, kinematics, end-effector start (3,) m)``."""
    from depthguard.sim.cell import BoxSpec, CellSpec, build_cell
    from depthguard.sim.depthcam import RAL_TWO, placement
    from depthguard.sim.people import Keyframe, PersonScript
    from depthguard.sim.pipeline import Kinematics

    res = sc.get("quick_resolution", [160, 120]) if quick else sc.get("resolution", [640, 480])
    if demo:
        res = sc.get("demo_resolution", res)
    cams = placement(sc["cameras"], int(res[0]), int(res[1]))
    if sc["cameras"] in RAL_TWO and cameras is not None and cameras > len(cams):
        cams = cams + placement("ral3", int(res[0]), int(res[1]))[2:]  # the third camera (docs/phantom-zero.md)
    n_cams = cameras if cameras is not None else sc.get("camera_count", len(cams))
    if n_cams < 1 or n_cams > len(cams):
        raise ValueError(f"scenario {sc['name']}: cameras must be 1..{len(cams)} for placement {sc['cameras']!r}")
    cams = cams[:n_cams]
    q0 = np.array(sc.get("q0", [0.0, -0.3, 0.0, 1.6, 0.0, -0.8, 0.0]), float)
    robot = str(sc.get("robot", "lwr4"))  # the arm, simulated from its own meshes (depthguard.robot.robots)
    kin = Kinematics(
        sc.get("control_points", "ral-9"), float(sc.get("ee_radius", 0.12)), robot, int(sc.get("auto_spheres", 3))
    )
    if "ee_start" in sc:
        q0 = solve_ik(kin, q0, np.asarray(sc["ee_start"], float))
    ee0 = kin.evaluate(q0).centres[0]
    floor_z = float(sc.get("floor_z", -0.8))

    def hand(kf: dict, side: str):
        if f"{side}_hand" in kf:
            return tuple(kf[f"{side}_hand"])
        if f"{side}_hand_rel_ee" in kf:
            return tuple(ee0 + np.asarray(kf[f"{side}_hand_rel_ee"], float))
        return None

    people = []
    for p in sc.get("people", []):
        kfs = [
            Keyframe(
                t=float(k["t"]),
                base=tuple(k["base"]),
                yaw=float(k.get("yaw", 0.0)),
                left_hand=hand(k, "left"),
                right_hand=hand(k, "right"),
                carry=k.get("carry"),
                carry_hand=k.get("carry_hand", "right"),
            )
            for k in p["keyframes"]
        ]
        people.append(PersonScript(p["name"], kfs, floor_z=floor_z))
    boxes = [
        BoxSpec(b["name"], tuple(b["center"]), tuple(b["half"]), bool(b.get("movable", False)))
        for b in sc.get("boxes", [])
    ]
    room = tuple(sc.get("room", (-1.1, 2.0, -1.1, 2.0) if sc["cameras"].startswith("ral") else (-1.5, 2.3, -1.6, 2.3)))
    spec = CellSpec(cameras=cams, boxes=boxes, people=people, q0=tuple(q0), floor_z=floor_z, room=room, robot=robot)
    cell = build_cell(spec)
    return cell, kin, ee0


def solve_ik(kin, q: np.ndarray, target: np.ndarray, iters: int = 200) -> np.ndarray:
    """Joint positions putting the end effector at ``target`` (damped least squares from ``q``)."""
    q = q.copy()
    for _ in range(iters):
        s = kin.evaluate(q)
        e = target - s.centres[0]
        if np.linalg.norm(e) < 1e-5:
            break
        J = s.jacobians[0]
        q += J.T @ np.linalg.solve(J @ J.T + 1e-4 * np.eye(3), e) * 0.5
        q = np.clip(q, kin.q_min + 0.05, kin.q_max - 0.05)
    return q


def scenario_task(sc: dict, ee0: np.ndarray):
    """The end-effector task of scenario ``sc`` (:class:`depthguard.sim.loop.Task`); ``ee0`` (3,) m is the
    start, for "hold" tasks and relative waypoints."""
    from depthguard.sim.loop import Task

    t = sc["task"]
    kind = t.get("kind", "points")
    if kind not in ("points", "cycle", "hold"):
        raise ValueError(f"scenario {sc['name']}: task.kind must be points, cycle or hold, got {kind!r}")
    if kind == "hold":
        wps = np.array([ee0])
    else:
        wps = np.array(t["waypoints"], float)
        if t.get("relative", False):
            wps = wps + ee0
    return Task(
        kind=kind,
        waypoints=wps,
        speed=float(t.get("speed", 0.4)),
        tol=float(t.get("tol", 0.02)),
        kp=float(t.get("kp", 3.0)),
    )
