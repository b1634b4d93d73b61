"""Recording of a simulated run as ROS 2 messages in MCAP (:mod:`depthguard.io.mcap_ros2`).

Open it in Foxglove, replay it with ``ros2 bag play recording.mcap`` or read it with ``rosbags``. Topics:

* ``/camera<k>/depth/image_raw`` (``sensor_msgs/msg/Image``, ``16UC1`` mm, 0 = no reading): every third
  frame (10 Hz); images 640 pixels wide or more are subsampled (every ``W // 320``-th pixel) and recorded
  every sixth frame (5 Hz);
* ``/camera<k>/depth/camera_info`` (``sensor_msgs/msg/CameraInfo``, of the recorded image size), with each image;
* ``/tf_static`` (``tf2_msgs/msg/TFMessage``): ``world`` -> ``camera<k>_optical`` once;
* ``/joint_states`` (``sensor_msgs/msg/JointState``): measured joint positions, 100 Hz;
* ``/depthguard/distances`` (``depthguard_msgs/msg/ControlPointDistances``): the evaluated distances;
* ``/depthguard/markers`` (``visualization_msgs/msg/MarkerArray``): control spheres coloured by distance
  and repulsive arrows, 20 Hz;
* ``/depthguard/status`` (``depthguard_msgs/msg/ControllerStatus``);
* ``/depthguard/repulsion`` (``geometry_msgs/msg/Vector3Stamped``): the end effector's repulsive velocity;
* ``/depthguard/true_clearance`` and ``/depthguard/evaluated_min`` (``std_msgs/msg/Float64``): ground
  truth from the simulator and the pipeline's minimum, m.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from depthguard.io import ros2
from depthguard.io.mcap_ros2 import Ros2McapWriter

__all__ = ["record_run", "camera_tf"]


def camera_tf(R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pose of a camera's optical frame in the world (R_wc (3, 3), p_wc (3,)) from ``P_C = R P_W + t``."""
    R = np.asarray(R, dtype=float)
    return R.T, -R.T @ np.asarray(t, dtype=float)


def _f64(x: float):
    return ros2.typestore().types["std_msgs/msg/Float64"](data=float(x))


def record_run(path: str | Path, cell, log, rho: float = 0.4, extra=None) -> Path:
    """Write the run's recording to ``path`` (.mcap). Returns the path.

    ``extra(writer)``, if given, adds a scenario's own topics through the
    :class:`~depthguard.io.mcap_ros2.Ros2McapWriter` (e.g. the octree and the reachability grid of
    ``saphari-octree`` as ``visualization_msgs/MarkerArray`` cube lists)."""
    path = Path(path)
    with Ros2McapWriter(path) as w:
        tfs = []
        infos = []
        for k, cam in enumerate(cell.cameras):
            tfs.append(("world", f"camera{k}_optical", *camera_tf(cam.R, cam.t)))
            st = max(1, cam.width // 320)  # the recorded images are subsampled by this step (loop._to_mm)
            small = cam.strided(st)  # (every st-th pixel: loop._to_mm)
            infos.append(small)
        w.write("/tf_static", "tf2_msgs/msg/TFMessage", ros2.tf_msg(0.0, tfs), 0.0)
        for t, depths in log.frames:
            for k, d in enumerate(depths):
                frame = f"camera{k}_optical"
                w.write(f"/camera{k}/depth/image_raw", "sensor_msgs/msg/Image", ros2.image_msg(t, frame, d), t)
                info = ros2.camera_info_msg(t, frame, infos[k])
                w.write(f"/camera{k}/depth/camera_info", "sensor_msgs/msg/CameraInfo", info, t)
        names = list(cell.joint_names)
        for i, t in enumerate(log.t):
            w.write("/joint_states", "sensor_msgs/msg/JointState", ros2.joint_state_msg(t, names, log.q[i]), t)
            centres = np.asarray(log.centres[i], float)
            dist = np.asarray(log.eval_points[i], float)
            radii = np.asarray(log.radii, float) if len(getattr(log, "radii", ())) else np.full(len(dist), np.nan)
            logged_dirs = getattr(log, "directions", ())
            dirs = np.asarray(logged_dirs[i], float) if len(logged_dirs) > i else np.zeros((len(dist), 3))
            msg = ros2.distances_msg(t, list(log.point_names), centres, radii, dist, dirs, rho=rho)
            w.write("/depthguard/distances", "depthguard_msgs/msg/ControlPointDistances", msg, t)
            if i % 5 == 0:
                r = np.where(np.isfinite(radii), radii, 0.05)
                mk = ros2.markers_msg(t, centres, r, dist, dirs, rho)
                w.write("/depthguard/markers", "visualization_msgs/msg/MarkerArray", mk, t)
            stt = log.status[i] if i < len(log.status) else {}
            sm = ros2.status_msg(t, str(stt.get("status", "")), float(stt.get("scale", 0.0)))
            w.write("/depthguard/status", "depthguard_msgs/msg/ControllerStatus", sm, t)
            vec = ros2.vector3_stamped_msg(t, "world", log.v_ee[i])
            w.write("/depthguard/repulsion", "geometry_msgs/msg/Vector3Stamped", vec, t)
            w.write("/depthguard/true_clearance", "std_msgs/msg/Float64", _f64(log.true_min[i]), t)
            w.write("/depthguard/evaluated_min", "std_msgs/msg/Float64", _f64(log.eval_min[i]), t)
        if extra is not None:
            extra(w)
    return path
