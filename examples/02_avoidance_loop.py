"""02 - The whole loop without a simulator: depth image -> distances -> controller -> joints.

A 7-DOF LWR moves its end effector towards a goal on the other side of a box that one camera sees. Every
1 ms cycle: control points (forward kinematics), depth-space distances to the box (and its gray area),
the avoidance controller (end-effector repulsion eqs. 10-11, body constraints eqs. 12-14, SNS, Ruckig).
The joints follow the command exactly (a kinematic robot). The true clearance to the box is printed.
Run: ``.venv/bin/python examples/02_avoidance_loop.py``.
"""

import numpy as np

from depthguard.camera import Camera, look_at
from depthguard.control import AvoidanceController, ControllerConfig, CycleInput
from depthguard.depthspace import prepare_frame, query_distances
from depthguard.robot.control_points import ControlPointSet
from depthguard.robot.model import load_lwr4
from depthguard.scene import Box, HalfSpace, Scene, render_depth

model = load_lwr4()
points = ControlPointSet.build(model, "ral-9")
ctrl = AvoidanceController(points, ControllerConfig(rho_ee=0.3, v_rep_max=0.5, rho_body=0.3))

R, t = look_at([1.6, 0.0, 2.2], [0.3, 0.0, 0.3])  # above and in front, so that shadows fall away from the arm
camera = Camera.kinect_v1(R=R, t=t)
box = Box(np.array([0.6, 0.0, 0.4]), np.array([0.05, 0.05, 0.05]))
scene = Scene((box, HalfSpace(np.zeros(3), np.array([0, 0, 1.0]))))  # the box on a table at z = 0
frame = prepare_frame(camera, render_depth(camera, scene))  # the robot is not in this image: as self-filtered

q = np.array([0.6 - np.pi, 0.7, 0.0, -1.2, 0.0, 0.8, 0.0])
qdot = np.zeros(7)
goal = model.frame_pose(q)[1] * np.array([1.0, -1.0, 1.0]) + [0.0, 0.0, 0.2]  # across the box, a bit higher
min_clearance = np.inf
for k in range(5000):
    t_now = k * 1e-3
    cps = points.evaluate(q)
    res = query_distances(frame, cps.centres, cps.radii, rho=0.3, mode="all")
    ee = model.frame_pose(q)[1]
    xdot_d = np.clip(2.0 * (goal - ee), -0.3, 0.3)
    out = ctrl.step(CycleInput(t_now, q, qdot, t_now, xdot_d, res.distance, res.direction, t_now))
    q, qdot = out.q_cmd, out.qdot_cmd
    min_clearance = min(min_clearance, float(np.min(box.distance(cps.centres) - cps.radii)))
    if k % 500 == 0:
        near = cps.names[int(np.argmin(res.distance))]
        print(f"t={t_now:4.1f} s  ee={np.round(ee, 3)}  d_min={np.min(res.distance):.3f} m ({near}) {out.status.name}")
print(
    f"end effector {np.linalg.norm(goal - model.frame_pose(q)[1]):.3f} m from the goal; "
    f"true minimum clearance to the box {min_clearance:.3f} m"
)
