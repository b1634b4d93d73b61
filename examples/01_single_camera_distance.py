"""01 - Distances and repulsive vectors from one depth image.

Build a scene (a person reaching towards an arm), render what a Kinect-like camera sees, prepare the frame
once (hole filling, tile minima) and query 9 control spheres many times, as the distance stage of a robot
controller would between two camera frames. Run: ``.venv/bin/python examples/01_single_camera_distance.py``.
"""

import numpy as np

from depthguard.bench.scenes import arm_chain_points, bench_cameras, noisy_depth, person_scene
from depthguard.depthspace import prepare_frame, query_distances
from depthguard.repulsion import repulsive_vectors

camera = bench_cameras()[0]  # 640x480, fx = fy = 525, 2 m from the robot, 1.2 m high
scene = person_scene()
depth = noisy_depth(camera, scene, seed=0)  # (480, 640) metres, NaN = no reading

frame = prepare_frame(camera, depth)  # once per camera frame (30 Hz)
names, centres, radii = arm_chain_points()
for step in range(3):  # many times per frame while the robot moves
    moved = centres + np.array([0.0, -0.02 * step, 0.0])
    res = query_distances(frame, moved, radii, rho=0.4, mode="all")
    V = repulsive_vectors(res, vmax=2.0, rho=0.4, alpha=6.0)
    i = int(np.argmin(res.distance))
    print(f"step {step}: closest point {names[i]} at {res.distance[i]:.3f} m, repulsion {np.round(V[i], 2)} m/s")
