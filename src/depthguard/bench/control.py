"""Benchmarks of the control stage and of the self-filter (BENCHMARKS.md).

``run_control_benchmark`` times one 1 kHz control cycle for the shipped 7-DOF LWR and the 9 RA-L'16
control points (distance query excluded): forward kinematics + Jacobians, control points, body bounds,
SNS, Ruckig, the input checks, the joint bounds (v_max, position limits) and the bound enforcement,
and the whole cycle, in free space and with obstacles that make SNS scale the task. The
budget is 200 µs p99. A plain pseudo-inverse with clipping is timed in the same run as the peer. The
same run times the cycle with speed and separation monitoring (``avoidance="both"``: monitor +
controller, ``full_cycle_ssm``, target 150 µs p99) and the monitor's update alone (``ssm_monitor``).

``run_selffilter_benchmark`` times the self-filter on 640x480 frames (target 3 ms) with the exact
numpy ray caster of :mod:`depthguard.scene` as the peer, and counts, against exact ground truth, the
robot pixels left in and the obstacle (hand) pixels wrongly removed.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from depthguard.bench.timing import machine_info, reference_speed, time_calls, with_reference


def _machine() -> dict:
    """machine_info (it includes the 1-minute load average: p99s on a busy machine measure preemption)."""
    return dict(machine_info())


__all__ = ["run_control_benchmark", "run_selffilter_benchmark"]

Q_BENCH = np.array([0.3, 0.6, 0.0, -1.3, 0.2, 0.9, 0.0])


def _inputs(points, q: np.ndarray, constrained: bool):
    N = points.n_points
    dist, dirs = np.full(N, np.inf), np.zeros((N, 3))
    if constrained:
        st = points.evaluate(q)
        obstacle = st.centres[4] + np.array([0.0, 0.0, -0.25])  # below the forearm
        diff = st.centres - obstacle
        norm = np.linalg.norm(diff, axis=1)
        dist, dirs = np.maximum(norm - st.radii - 0.05, 0.0), diff / norm[:, None]
    return dist, dirs


def run_control_benchmark(quick: bool = False) -> dict:
    """Time the control cycle and its parts; returns a JSON-able dict (µs, median and p99)."""
    from depthguard.control.body import body_bounds_inplace
    from depthguard.control.bounded import enforce_bounds_kernel
    from depthguard.control.cycle import AvoidanceController, ControllerConfig, CycleInput, joint_bounds
    from depthguard.control.endeffector import dls_damping
    from depthguard.control.inputs import check_inputs
    from depthguard.control.otg import OtgState
    from depthguard.control.sns import sns_velocity_unchecked
    from depthguard.robot.control_points import ControlPointSet
    from depthguard.robot.model import load_lwr4

    repeat = 300 if quick else 5000
    reference = reference_speed()  # machine-speed reference, same run (see depthguard.bench.timing)
    model = load_lwr4()
    points = ControlPointSet.build(model, "ral-9")
    cfg = ControllerConfig()
    q = Q_BENCH.copy()
    xdot_d = np.array([0.0, 0.0, -0.15])
    results: dict[str, dict] = {}
    for scenario in ("free", "constrained"):
        dist, dirs = _inputs(points, q, scenario == "constrained")
        ctrl = AvoidanceController(points, cfg)
        ctrl_ssm = AvoidanceController(points, replace(cfg, avoidance="both"))
        state = {"t": 0.0}
        inp0 = CycleInput(0.0, q, np.zeros(7), 0.0, xdot_d, dist, dirs, 0.0)
        ctrl.step(inp0)
        # SSM: the obstacle 0.2 m farther, so that the monitor scales the task (REDUCED: its bisection runs)
        # instead of stopping at once
        d_ssm = dist + 0.2
        ctrl_ssm.step(inp0._replace(distances=d_ssm))
        states: dict[str, int] = {}

        def cycle(ctrl=ctrl, dist=dist, dirs=dirs, state=state) -> None:
            state["t"] += 0.001
            t = state["t"]
            ctrl.step(CycleInput(t, q, np.zeros(7), t, xdot_d, dist, dirs, t))

        def cycle_ssm(ctrl=ctrl_ssm, dist=d_ssm, dirs=dirs, state={"t": 0.0}, states=states) -> None:  # noqa: B006
            state["t"] += 0.001
            t = state["t"]
            m = ctrl.step(CycleInput(t, q, np.zeros(7), t, xdot_d, dist, dirs, t)).ssm
            name = m.state.name if m is not None else "none"
            states[name] = states.get(name, 0) + 1

        st = points.evaluate(q)
        J = np.ascontiguousarray(st.jacobians[0])
        lo, hi = -ctrl.v_max.copy(), ctrl.v_max.copy()
        body_bounds_inplace(st.jacobians, dist, dirs, ctrl.body_use, ctrl.v_max, 0.4, 6.0, 0.0, 1e-6, lo, hi)
        lam = dls_damping(J)
        xc = xdot_d.copy()
        otg_state = OtgState(q.copy(), np.zeros(7), np.zeros(7))
        target, scale = sns_velocity_unchecked(J, xc, lo, hi, lam)

        def body(st=st, dist=dist, dirs=dirs, ctrl=ctrl) -> None:
            a, b = -ctrl.v_max.copy(), ctrl.v_max.copy()
            body_bounds_inplace(st.jacobians, dist, dirs, ctrl.body_use, ctrl.v_max, 0.4, 6.0, 0.0, 1e-6, a, b)

        def pinv_clip(J=J, lo=lo, hi=hi, xc=xc) -> None:
            np.clip(np.linalg.pinv(J) @ xc, lo, hi)

        parts = {
            "forward_kinematics_and_jacobians": lambda: model.joint_kinematics(q),
            "control_points": lambda: points.evaluate(q),
            "body_bounds": body,
            "sns": lambda J=J, lo=lo, hi=hi, lam=lam, xc=xc: sns_velocity_unchecked(J, xc, lo, hi, lam),
            "ruckig": lambda ctrl=ctrl, s=otg_state, tg=target: ctrl.otg.step(s, tg),
            "input_checks": lambda ctrl=ctrl, i=inp0: check_inputs(i, 7, points.n_points, 3, cfg, -np.inf),
            "joint_bounds": lambda ctrl=ctrl, s=otg_state: joint_bounds(ctrl, s),
            "bound_enforcement": lambda ctrl=ctrl, s=otg_state, lo=lo, hi=hi: enforce_bounds_kernel(
                *s, *s, lo, hi, ctrl.otg.a_max, ctrl.otg.j_max, cfg.dt
            ),
            "full_cycle": cycle,
            "full_cycle_ssm": cycle_ssm,
            "ssm_monitor": lambda m=ctrl_ssm.monitor, st=st, dist=d_ssm, dirs=dirs: m.update(
                st.jacobians, np.full(7, 0.2), np.zeros(7), np.full(7, 0.3), dist, dirs
            ),
            "peer_pinv_clip": pinv_clip,
        }
        timings = {name: with_reference(time_calls(fn, repeat, warmup=20), reference) for name, fn in parts.items()}
        full = timings["full_cycle"]
        results[scenario] = {
            "sns_scale": float(scale),
            "timings_us": timings,
            "full_cycle_p99_over_budget": full["us_p99"] / 200.0,
            "full_cycle_over_peer_pinv_clip_median": full["us_median"] / timings["peer_pinv_clip"]["us_median"],
            "full_cycle_ssm_p99_over_target": timings["full_cycle_ssm"]["us_p99"] / 150.0,
            "ssm_cycle_over_plain_median": timings["full_cycle_ssm"]["us_median"] / full["us_median"],
            "ssm_states_timed": states,
        }
    return {
        "benchmark": "control",
        "machine": _machine(),
        "reference": reference,
        "parameters": {
            "robot": "lwr4 (7 DOF)",
            "control_points": "ral-9 (9 points incl. end effector)",
            "task_dim": 3,
            "dt_s": cfg.dt,
            "repeat": repeat,
            "budget_us_p99": 200.0,
            "ssm_target_us_p99": 150.0,
            "ssm": "avoidance='both', SsmConfig() defaults; constrained: obstacle 0.2 m farther for the SSM cycle",
            "distance_query": "excluded",
            "q": Q_BENCH.tolist(),
        },
        "results": results,
    }


def _selffilter_scene(model, q, eye):
    from depthguard.camera import Camera, look_at
    from depthguard.scene import Capsule, HalfSpace, Scene, Sphere

    R, t = look_at(np.asarray(eye, dtype=float), np.array([0.0, 0.0, 0.6]))
    cam = Camera.kinect_v1(R, t, min_depth=0.3)
    a, b, r = model.link_capsules(q)
    robot = tuple(Capsule(a[k], b[k], r[k]) for k in range(len(r)))
    k = [c.link for c in model.capsules].index("lwr_link_4")
    mid = 0.5 * (a[k] + b[k])
    axis = (b[k] - a[k]) / np.linalg.norm(b[k] - a[k])
    side = cam.position - mid
    side -= (side @ axis) * axis
    side /= np.linalg.norm(side)
    hand = Sphere(mid + side * (r[k] + 0.05 + 0.05), 0.05)  # 5 cm from the forearm surface
    wall = HalfSpace(np.array([-1.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0]))
    env = (wall, HalfSpace(np.zeros(3), np.array([0, 0, 1.0])))
    return cam, Scene(robot), Scene((hand,)), Scene(robot + (hand,) + env)


def run_selffilter_benchmark(quick: bool = False, margin: float = 0.03, pad_px: int = 0) -> dict:
    """Time the self-filter per 640x480 frame and count errors against exact ground truth."""
    from depthguard.robot.model import load_lwr4
    from depthguard.robot.selffilter import self_filter
    from depthguard.scene import render_depth

    repeat = 20 if quick else 300
    reference = reference_speed()  # machine-speed reference, same run (see depthguard.bench.timing)
    model = load_lwr4()
    q = Q_BENCH.copy()
    views = {"icra_2m": (2.0, 0.3, 1.2), "near_1.2m": (1.2, 0.3, 1.0)}
    out: dict[str, dict] = {}
    for name, eye in views.items():
        cam, robot, hand, full = _selffilter_scene(model, q, eye)
        measured = render_depth(cam, full)
        robot_only = render_depth(cam, robot)
        hand_only = render_depth(cam, hand)
        res = self_filter(cam, measured, q, model, margin=margin, pad_px=pad_px)
        robot_vis = np.isfinite(robot_only) & (np.abs(measured - robot_only) < 1e-9)
        hand_vis = np.isfinite(hand_only) & (np.abs(measured - hand_only) < 1e-9) & ~robot_vis
        other = np.isfinite(measured) & ~robot_vis & ~hand_vis
        t = time_calls(lambda cam=cam, m=measured: self_filter(cam, m, q, model, margin=margin, pad_px=pad_px), repeat)
        peer = time_calls(lambda cam=cam, s=robot: render_depth(cam, s), max(3, repeat // 20), warmup=1)
        out[name] = {
            "robot_pixels_visible": int(robot_vis.sum()),
            "robot_pixels_left_in": int(np.sum(robot_vis & ~res.mask)),
            "hand_pixels_visible": int(hand_vis.sum()),
            "hand_pixels_wrongly_removed": int(np.sum(hand_vis & res.mask)),
            "background_pixels_removed_within_margin": int(np.sum(other & res.mask)),
            "ms_median": t["us_median"] / 1e3,
            "ms_p99": t["us_p99"] / 1e3,
            "peer_numpy_raycast_ms_median": peer["us_median"] / 1e3,
            "speedup_over_peer": peer["us_median"] / t["us_median"],
            "vs_reference": with_reference(t, reference)["vs_reference"],
        }
    return {
        "benchmark": "selffilter",
        "machine": _machine(),
        "reference": reference,
        "parameters": {
            "image": "640x480 (Kinect v1 intrinsics)",
            "robot": "lwr4 capsules",
            "margin_m": margin,
            "pad_px": pad_px,
            "repeat": repeat,
            "target_ms": 3.0,
            "scene": "robot + 5 cm ball 5 cm from the forearm + wall + floor, exact ray casting",
        },
        "results": out,
        "mesh_robots": _mesh_robots(quick, margin),
    }


def _mesh_robots(quick: bool, margin: float) -> dict:
    """Panda and UR5 from their meshes vs the capsule filter (:mod:`depthguard.bench.selffilter_meshes`)."""
    try:
        from depthguard.bench.selffilter_meshes import run_mesh_selffilter

        return run_mesh_selffilter(quick=quick, margin=margin)
    except ImportError as e:  # needs the robot and sim extras (example-robot-data, trimesh, mujoco)
        return {"skipped": f"needs the robot and sim extras: {e}"}


if __name__ == "__main__":  # pragma: no cover
    import json

    print(json.dumps({"control": run_control_benchmark(), "selffilter": run_selffilter_benchmark()}, indent=2))
