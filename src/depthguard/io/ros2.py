"""ROS 2 messages without a ROS installation: built, serialised (CDR) and described with ``rosbags``.

The type store is ROS 2 Jazzy's (``rosbags.typesys.Stores.ROS2_JAZZY``) plus DepthGuard's own messages
(:data:`DEPTHGUARD_MSGS`), so that bags, MCAP recordings and Zenoh payloads carry ordinary ROS 2 types:

* ``sensor_msgs/msg/Image`` (depth as ``16UC1`` millimetres, 0 = no reading, or ``32FC1`` metres, NaN = no
  reading), ``sensor_msgs/msg/CameraInfo``, ``sensor_msgs/msg/JointState``, ``tf2_msgs/msg/TFMessage``;
* ``visualization_msgs/msg/MarkerArray`` for display, ``trajectory_msgs/msg/JointTrajectory`` and
  ``std_msgs/msg/Float64MultiArray`` for ros2_control drivers;
* ``depthguard_msgs/msg/ControlPointDistances`` and ``depthguard_msgs/msg/ControllerStatus`` (definitions
  below: what DepthGuard computes per distance query and per control cycle).

Frames follow ``docs/conventions.md``: the world frame is the robot base frame; a camera's optical frame
has OpenCV axes; its pose is ``P_C = R P_W + t``, so the TF transform world -> camera optical frame has
rotation ``R^T`` and translation ``-R^T t``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from depthguard.io import ros2_types
from depthguard.io.joint_state_cdr import decode_joint_state
from depthguard.io.ros2_images import (  # (re-exported: one module for every message)
    camera_info_msg,
    image_msg,
    image_to_depth,
    image_to_mask,
    mask_msg,
    rgb_image_msg,
)
from depthguard.io.ros2_types import (
    DEPTHGUARD_MSGS,
    _t,
    header,
    msgdef,
    serialize,
    stamp,
    stamp_parts,
    to_seconds,
    typestore,
)

#: The task velocity (``geometry_msgs/msg/Vector3Stamped``, m/s of the end effector): recorded in bags and
#: recordings, published by the ``sim`` node.
TASK_TOPIC = "/depthguard/task_velocity"

__all__ = [
    "TASK_TOPIC",
    "DEPTHGUARD_MSGS",
    "typestore",
    "stamp",
    "stamp_parts",
    "to_seconds",
    "header",
    "image_msg",
    "image_to_depth",
    "mask_msg",
    "image_to_mask",
    "camera_info_msg",
    "joint_state_msg",
    "joints_in_order",
    "vector3_stamped_msg",
    "tf_msg",
    "distances_msg",
    "status_msg",
    "markers_msg",
    "joint_trajectory_msg",
    "cube_list_marker",
    "float64_array_msg",
    "labelled_array_msg",
    "rgb_image_msg",
    "serialize",
    "deserialize",
    "msgdef",
]


def deserialize(data: bytes | memoryview, typename: str):
    """Message from CDR bytes: ``sensor_msgs/msg/JointState`` in its canonical layout through the fast path of
    :mod:`depthguard.io.joint_state_cdr` (the same message as the generic decoder's), anything else through
    ``rosbags``."""
    if typename == "sensor_msgs/msg/JointState":
        msg = decode_joint_state(data)
        if msg is not None:
            return msg
    return ros2_types.deserialize(data, typename)


def joint_state_msg(
    t: float, names: list[str] | tuple[str, ...], q: np.ndarray, qdot: np.ndarray | None = None, frame_id: str = ""
):
    """``sensor_msgs/msg/JointState`` (positions rad or m; velocities optional)."""
    q = np.asarray(q, dtype=float).ravel()
    v = np.zeros(0) if qdot is None else np.asarray(qdot, dtype=float).ravel()
    return _t("sensor_msgs/msg/JointState")(
        header=header(t, frame_id), name=list(names), position=q, velocity=v, effort=np.zeros(0)
    )


def joints_in_order(msg, names: list[str] | tuple[str, ...]) -> tuple[np.ndarray, np.ndarray | None]:
    """``(q, qdot)`` of a ``sensor_msgs/msg/JointState`` in the joint order ``names`` (the robot model's),
    writable float64 copies; ``qdot`` None when the message carries no velocities.

    Joints are matched by name, in any order, and joints the model does not have (a gripper's) are left
    out: a ros2_control ``joint_state_broadcaster`` orders its joints by its own configuration, not by the
    URDF. A message that names no joint is taken by position. Raises ``ValueError`` when a joint of
    ``names`` is missing or a joint is named twice, the positions or velocities do not match the names, or a
    value is not finite.
    (The order found for a list of names is kept: a driver sends the same names at every message.)
    """
    got = tuple(str(x) for x in msg.name)
    q, qd = np.array(msg.position, dtype=float), np.array(msg.velocity, dtype=float)
    if got:
        if len(q) != len(got) or len(qd) not in (0, len(got)):
            raise ValueError(f"JointState: {len(got)} names, {len(q)} positions, {len(qd)} velocities")
        idx = _joint_order(got, tuple(names))
        if idx is not None:
            q, qd = q[idx], (qd[idx] if len(qd) else qd)
    if q.shape != (len(names),) or len(qd) not in (0, len(names)):
        raise ValueError(f"JointState: {q.size} positions and {qd.size} velocities for {len(names)} joints")
    if not (np.isfinite(q).all() and np.isfinite(qd).all()):
        raise ValueError("JointState: positions and velocities must be finite")
    return q, (qd if len(qd) else None)


_JOINT_ORDERS: dict[tuple, np.ndarray | None] = {}


def _joint_order(got: tuple[str, ...], names: tuple[str, ...]) -> np.ndarray | None:
    """Where each of ``names`` lies in a message naming ``got`` (None: the same list, nothing to reorder);
    ``ValueError`` when one is missing. Kept per pair of lists (a few per node)."""
    key = (got, names)
    if key in _JOINT_ORDERS:
        return _JOINT_ORDERS[key]
    where = {n: i for i, n in enumerate(got)}
    if len(where) != len(got):  # (which of two values would hold is anybody's guess: the spheres would move)
        twice = sorted({n for n in got if got.count(n) > 1})
        raise ValueError(f"JointState names {twice[:8]} more than once")
    missing = [n for n in names if n not in where]
    if missing:
        raise ValueError(f"JointState names no {missing[:8]} (it names {list(got[:8])})")
    idx = None if got == names else np.array([where[n] for n in names], dtype=np.intp)
    if len(_JOINT_ORDERS) >= 64:  # (never let it grow without end)
        _JOINT_ORDERS.clear()
    _JOINT_ORDERS[key] = idx
    return idx


def vector3_stamped_msg(t: float, frame_id: str, v: np.ndarray):
    """``geometry_msgs/msg/Vector3Stamped`` of a 3-vector (the task's desired end-effector velocity, m/s)."""
    x, y, z = (float(c) for c in np.asarray(v, dtype=float).reshape(3))
    return _t("geometry_msgs/msg/Vector3Stamped")(
        header=header(t, frame_id), vector=_t("geometry_msgs/msg/Vector3")(x=x, y=y, z=z)
    )


def _quat_xyzw(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w) of a rotation matrix (3, 3)."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(np.asarray(R, dtype=float)).as_quat()


def tf_msg(t: float, transforms: list[tuple[str, str, np.ndarray, np.ndarray]]):
    """``tf2_msgs/msg/TFMessage`` from ``(parent, child, R (3, 3), p (3,))``: child pose in the parent frame."""
    T = _t("geometry_msgs/msg/TransformStamped")
    out = []
    for parent, child, R, p in transforms:
        qx, qy, qz, qw = _quat_xyzw(R)
        tr = _t("geometry_msgs/msg/Transform")(
            translation=_t("geometry_msgs/msg/Vector3")(x=float(p[0]), y=float(p[1]), z=float(p[2])),
            rotation=_t("geometry_msgs/msg/Quaternion")(x=qx, y=qy, z=qz, w=qw),
        )
        out.append(T(header=header(t, parent), child_frame_id=child, transform=tr))
    return _t("tf2_msgs/msg/TFMessage")(transforms=out)


def _point(p) -> Any:
    p = np.asarray(p, dtype=float)
    return _t("geometry_msgs/msg/Point")(x=float(p[0]), y=float(p[1]), z=float(p[2]))


def _vec(v) -> Any:
    v = np.asarray(v, dtype=float)
    return _t("geometry_msgs/msg/Vector3")(x=float(v[0]), y=float(v[1]), z=float(v[2]))


def query_msg(t: float, names, centres: np.ndarray, radii: np.ndarray, res, rho: float = float("nan")):
    """:func:`distances_msg` of a distance query's result ``res`` (a
    :class:`~depthguard.depthspace.PointDistances`: ``distance`` (N,), ``direction`` (N, 3) and, if it has
    one, ``nearest`` (N, 3))."""
    d = np.asarray(res.distance, float)
    near = np.asarray(getattr(res, "nearest", np.full((len(d), 3), np.nan)), float)
    return distances_msg(t, names, centres, radii, d, np.asarray(res.direction, float), near, rho=rho)


def distances_msg(
    t: float,
    names: list[str] | tuple[str, ...],
    centres: np.ndarray,
    radii: np.ndarray,
    distances: np.ndarray,
    directions: np.ndarray,
    nearest: np.ndarray | None = None,
    rho: float = float("nan"),
    frame_id: str = "world",
):
    """``depthguard_msgs/msg/ControlPointDistances`` for N points (arrays (N, 3) / (N,), SI units)."""
    P = _t("depthguard_msgs/msg/ControlPointDistance")
    N = len(names)
    near = np.full((N, 3), np.nan) if nearest is None else np.asarray(nearest, dtype=float)
    pts = [
        P(
            name=str(names[k]),
            centre=_point(centres[k]),
            radius=float(radii[k]),
            distance=float(distances[k]),
            direction=_vec(directions[k]),
            nearest=_point(near[k]),
        )
        for k in range(N)
    ]
    return _t("depthguard_msgs/msg/ControlPointDistances")(header=header(t, frame_id), rho=float(rho), points=pts)


def status_msg(t: float, status: str, scale: float, monitor_state: str = "", ssm_scale: float = 1.0):
    """``depthguard_msgs/msg/ControllerStatus``."""
    return _t("depthguard_msgs/msg/ControllerStatus")(
        header=header(t, ""),
        status=str(status),
        scale=float(scale),
        monitor_state=str(monitor_state),
        ssm_scale=float(ssm_scale),
    )


def _color(r: float, g: float, b: float, a: float = 1.0):
    return _t("std_msgs/msg/ColorRGBA")(r=float(r), g=float(g), b=float(b), a=float(a))


def distance_color(d: float, rho: float) -> tuple[float, float, float]:
    """Red at contact, yellow half way, green at rho and beyond (and for +inf)."""
    f = 1.0 if not np.isfinite(d) else float(np.clip(d / max(rho, 1e-9), 0.0, 1.0))
    return (min(1.0, 2.0 * (1.0 - f)), min(1.0, 2.0 * f), 0.0)


def markers_msg(
    t: float,
    centres: np.ndarray,
    radii: np.ndarray,
    distances: np.ndarray,
    directions: np.ndarray,
    rho: float,
    frame_id: str = "world",
):
    """``visualization_msgs/msg/MarkerArray``: one sphere per control point coloured by distance, and an
    arrow along the repulsive direction (length proportional to ``1 - d/rho``) where ``d < rho``."""
    M = _t("visualization_msgs/msg/Marker")
    dur = _t("builtin_interfaces/msg/Duration")(sec=0, nanosec=200_000_000)
    pose = _t("geometry_msgs/msg/Pose")
    quat = _t("geometry_msgs/msg/Quaternion")(x=0.0, y=0.0, z=0.0, w=1.0)
    markers = []
    for k in range(len(radii)):
        c, d = np.asarray(centres[k], float), float(distances[k])
        common = dict(
            header=header(t, frame_id),
            ns="control_points",
            action=0,
            lifetime=dur,
            frame_locked=False,
            points=[],
            colors=[],
            texture_resource="",
            texture=_t("sensor_msgs/msg/CompressedImage")(header=header(t, ""), format="", data=np.zeros(0, np.uint8)),
            uv_coordinates=[],
            text="",
            mesh_resource="",
            mesh_file=_t("visualization_msgs/msg/MeshFile")(filename="", data=np.zeros(0, np.uint8)),
            mesh_use_embedded_materials=False,
        )
        s = 2.0 * float(radii[k])
        markers.append(
            M(
                **common,
                id=2 * k,
                type=2,  # SPHERE
                pose=pose(position=_point(c), orientation=quat),
                scale=_vec([s, s, s]),
                color=_color(*distance_color(d, rho), 0.6),
            )
        )
        u = np.asarray(directions[k], float)
        if np.isfinite(d) and d < rho and np.all(np.isfinite(u)):
            tip = c + u * 0.3 * (1.0 - max(d, 0.0) / rho)
            m = M(
                **{**common, "points": [_point(c), _point(tip)]},
                id=2 * k + 1,
                type=0,  # ARROW (from points[0] to points[1])
                pose=pose(position=_point([0, 0, 0]), orientation=quat),
                scale=_vec([0.01, 0.02, 0.03]),
                color=_color(1.0, 0.3, 0.0),
            )
            markers.append(m)
    return _t("visualization_msgs/msg/MarkerArray")(markers=markers)


def cube_list_marker(
    t: float, ns: str, marker_id: int, centres: np.ndarray, size: float, rgba, frame_id: str = "world"
):
    """``visualization_msgs/msg/Marker`` of type CUBE_LIST: cubes of edge ``size`` m at ``centres`` (K, 3), one
    colour ``rgba`` (4,) or one per cube (K, 4)."""
    c = np.asarray(centres, dtype=float).reshape(-1, 3)
    col = np.asarray(rgba, dtype=float)
    per = col.ndim == 2
    quat = _t("geometry_msgs/msg/Quaternion")(x=0.0, y=0.0, z=0.0, w=1.0)
    first = col[0] if per and len(col) else (col if not per else np.array([1.0, 1.0, 1.0, 1.0]))
    return _t("visualization_msgs/msg/Marker")(
        header=header(t, frame_id), ns=ns, id=int(marker_id), type=6, action=0,
        pose=_t("geometry_msgs/msg/Pose")(position=_point([0, 0, 0]), orientation=quat),
        scale=_vec([size, size, size]), color=_color(*first),
        lifetime=_t("builtin_interfaces/msg/Duration")(sec=0, nanosec=0), frame_locked=False,
        points=[_point(p) for p in c], colors=[_color(*k) for k in col] if per else [],
        texture_resource="",
        texture=_t("sensor_msgs/msg/CompressedImage")(header=header(t, ""), format="", data=np.zeros(0, np.uint8)),
        uv_coordinates=[], text="", mesh_resource="",
        mesh_file=_t("visualization_msgs/msg/MeshFile")(filename="", data=np.zeros(0, np.uint8)),
        mesh_use_embedded_materials=False,
    )  # fmt: skip


def joint_trajectory_msg(t: float, names: list[str] | tuple[str, ...], q: np.ndarray, qdot: np.ndarray, dt: float):
    """``trajectory_msgs/msg/JointTrajectory`` with one point ``dt`` s ahead (for a ros2_control
    ``joint_trajectory_controller``)."""
    ns = int(round(dt * 1e9))
    pt = _t("trajectory_msgs/msg/JointTrajectoryPoint")(
        positions=np.asarray(q, float),
        velocities=np.asarray(qdot, float),
        accelerations=np.zeros(0),
        effort=np.zeros(0),
        time_from_start=_t("builtin_interfaces/msg/Duration")(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000),
    )
    return _t("trajectory_msgs/msg/JointTrajectory")(header=header(t, ""), joint_names=list(names), points=[pt])


def float64_array_msg(values: np.ndarray):
    """``std_msgs/msg/Float64MultiArray`` (for a ros2_control ``forward_command_controller``)."""
    layout = _t("std_msgs/msg/MultiArrayLayout")(dim=[], data_offset=0)
    return _t("std_msgs/msg/Float64MultiArray")(layout=layout, data=np.asarray(values, dtype=float))


def labelled_array_msg(fields: dict[str, Any]):
    """``std_msgs/msg/Float64MultiArray`` carrying named fields: one layout dimension per field (``label`` =
    the field name, ``size`` = its number of values, ``stride`` = its offset + size), the values flattened
    in that order. Booleans are 0/1; non-finite numbers stay (NaN, inf)."""
    dims, data = [], []
    D = _t("std_msgs/msg/MultiArrayDimension")
    for name, value in fields.items():
        arr = np.asarray(value, dtype=float).ravel()
        data.append(arr)
        dims.append(D(label=str(name), size=int(arr.size), stride=int(sum(a.size for a in data))))
    layout = _t("std_msgs/msg/MultiArrayLayout")(dim=dims, data_offset=0)
    flat = np.concatenate(data) if data else np.zeros(0)
    return _t("std_msgs/msg/Float64MultiArray")(layout=layout, data=flat)
