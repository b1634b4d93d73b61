"""``depthguard bench contact``: the contact-handling costs of SAPHARI D4.1.1 §6 (DESIGN.md §7).

* ``residual_cycle``: one control cycle of the 7-DOF LWR: momentum residual (pinocchio ``crba``,
  ``computeCoriolisMatrix``, ``computeGeneralizedGravity``, the observer's default), detection, contact
  Jacobian and force estimate F̂ = (J_cᵀ)^# r. Target 50 µs p99. ``dynamics_terms`` times M, C, g alone;
  ``residual_cycle_compiled_terms`` the same cycle with ``MomentumObserver(terms="compiled")``.
* ``contact_point_search``: from a 640×480 Kinect frame (simulated: a hand on link 6, the robot
  self-filtered) to the contact point: foreground, the robot's vertices posed by forward kinematics,
  the depth-space hand search and Algorithm 1 (nearest vertex, vectorised). Target 2 ms.
* Baseline in the same run: Algorithm 1 as the literal per-vertex Python loop
  (:func:`~depthguard.robot.contact_point.nearest_vertex_loop`) over the same vertices, and the
  vectorised nearest-vertex step alone for the ratio.
* ``reference_matmul_us``: a fixed 200×200 matrix product, the machine-speed reference.
"""

from __future__ import annotations

import numpy as np

from depthguard.bench.timing import machine_info, time_calls

__all__ = ["run_contact_benchmark"]


def _machine() -> dict:
    return dict(machine_info())  # includes the load average


def _frame():
    """A simulated Kinect frame with a hand pressing link 6, and what the search needs."""
    from depthguard.robot.selffilter import self_filter
    from depthguard.sim.contact_cell import ContactCell, HandScript
    from depthguard.sim.contact_experiment import CAMERA_EYE, CAMERA_TARGET, Q0, _background
    from depthguard.sim.depthcam import KinectSim, kinect_camera

    cam = kinect_camera(CAMERA_EYE, CAMERA_TARGET)
    hand = HandScript("hand0", "lwr_link_6", 0.5, (0.0, 1.0, 0.0), 15.0, 0.2, 1.0, approach=0.05, v_approach=0.25)
    cell = ContactCell([hand], cam, np.array(Q0))
    sim = KinectSim(cell.model, cam, seed=0)
    bg = _background(cell, sim)
    for _ in range(40):
        cell.step(np.zeros(7), 10)
    q = cell.q()
    with np.errstate(invalid="ignore"):
        depth = sim.capture(cell.data)
    mask = self_filter(cam, depth, q, cell.robot, with_depth=False).mask
    return cell, cam, depth, bg, mask, q, cell.contacts()[0][1]


def run_contact_benchmark(quick: bool = False) -> dict:
    """Time the residual cycle and the contact-point search; returns a JSON-able dict (µs)."""
    from depthguard.robot.contact_force import estimate_contact_forces, point_jacobian
    from depthguard.robot.contact_point import (
        RobotSurface,
        contact_from_hand,
        foreground_mask,
        image_box,
        locate_hands,
        nearest_vertex,
        nearest_vertex_loop,
    )
    from depthguard.robot.residual import ContactDetector, MomentumObserver, RigidBodyDynamics

    repeat = 300 if quick else 5000
    cell, cam, depth, bg, mask, q, p_true = _frame()
    robot = cell.robot
    dyn = RigidBodyDynamics(robot, armature=np.full(7, cell.armature), damping=cell.damping)
    obs = MomentumObserver(dyn, gain=100.0, dt=0.005, tau_mode="average")
    det = ContactDetector(r_th=1.0)
    rng = np.random.default_rng(0)
    qd, tau = rng.uniform(-1, 1, 7), rng.uniform(-5, 5, 7)
    obs.update(q, qd, tau)
    link, point = "lwr_link_6", robot.frame_pose(q, "lwr_link_6")[1] + np.array([0.0, -0.06, 0.0])

    def residual_cycle() -> None:
        r = obs.update(q, qd, tau)
        det.step(r, 0.005)
        estimate_contact_forces(point_jacobian(robot, q, link, point), r)

    out: dict = {
        "machine": _machine(),
        "parameters": {"dof": 7, "width": cam.width, "height": cam.height, "repeat": repeat, "quick": quick},
    }
    out["residual_cycle"] = time_calls(residual_cycle, repeat)
    obs_c = MomentumObserver(dyn, gain=100.0, dt=0.005, tau_mode="average", terms="compiled")
    obs_c.update(q, qd, tau)

    def residual_cycle_compiled() -> None:  # the same cycle with the observer's compiled terms (opt-in)
        r = obs_c.update(q, qd, tau)
        det.step(r, 0.005)
        estimate_contact_forces(point_jacobian(robot, q, link, point), r)

    out["residual_cycle_compiled_terms"] = time_calls(residual_cycle_compiled, repeat)
    out["dynamics_terms"] = time_calls(lambda: dyn.terms(q, qd), repeat)
    surf = RobotSurface(robot, spacing=0.01)
    margin = 0.03 + 4 * 1.4e-3 * np.nan_to_num(bg, nan=cam.max_depth) ** 2

    def search():
        V, S = surf.pose(q)
        fg = foreground_mask(depth, bg, mask, margin, box=image_box(cam, S, surf.axis_radii + 0.2))
        hands = locate_hands(cam, depth, fg, S, surf.axis_radii, 1)
        return contact_from_hand(surf, q, V, hands[0].position) if hands else None

    cp = search()
    n_search = max(20, repeat // 10)
    out["contact_point_search"] = time_calls(search, n_search)
    V, _ = surf.pose(q)
    p_h = cp.position if cp is not None else V[0]
    per_link = [V[surf.link == k] for k in range(len(surf.link_names))]
    out["nearest_vertex_vectorised"] = time_calls(lambda: nearest_vertex(V, p_h), repeat)
    out["nearest_vertex_python_loop"] = time_calls(lambda: nearest_vertex_loop(per_link, p_h), 5 if quick else 30, 1)
    A = rng.normal(size=(200, 200))
    out["reference_matmul_us"] = time_calls(lambda: A @ A, repeat)["us_median"]
    out["vertices"] = surf.n_vertices
    out["contact_point_error_m"] = float(np.linalg.norm(cp.position - p_true)) if cp is not None else None
    loop = out["nearest_vertex_python_loop"]["us_median"]
    out["ratios"] = {
        "loop_over_vectorised_nearest_vertex": loop / out["nearest_vertex_vectorised"]["us_median"],
        "loop_over_whole_search": loop / out["contact_point_search"]["us_median"],
    }
    out["targets"] = {"residual_cycle_us_p99": 50.0, "contact_point_search_us": 2000.0}
    return out
