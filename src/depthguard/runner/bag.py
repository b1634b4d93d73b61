"""A ROS 2 bag as a source (MCAP or sqlite3, read with ``rosbags``: no ROS installation needed).

Topics come from the cell file: per camera its depth ``topic`` (``sensor_msgs/msg/Image``, 16UC1 mm or 32FC1 m)
and ``info_topic`` (``sensor_msgs/msg/CameraInfo``), the ``joint_states`` topic (``sensor_msgs/msg/JointState``,
reordered into the model's joint order by name), ``tf``/``tf_static`` (``tf2_msgs/msg/TFMessage``) for cameras
whose ``extrinsics = "tf"``, and optionally ``/depthguard/task_velocity``
(``geometry_msgs/msg/Vector3Stamped``, the desired end-effector velocity; zero when absent).

Images at a reduced resolution of the cell file's sensor (same aspect ratio) get proportionally scaled
intrinsics. Time synchronisation is by header stamps: one tick per joint-state message; the frames whose stamps are at
or before the tick (one per camera, the newest by stamp) form a frame set when every camera has a new frame; a frame
stamped later than the tick waits for a later tick. A frame stamped at or before the last frame used of its camera
(a duplicate, or out of order) is skipped and named as a fault. The frame set is self-filtered (and a carried camera
placed) with the joint state read so far whose stamp is nearest to the set's newest frame (``Tick.q_frames``); when
that joint state is more than :data:`MAX_JOINT_SKEW` from a frame of the set, the set is skipped and named as a fault
(as the camera and distance nodes do), never paired with a joint state of another time. A CameraInfo whose size or
calibration changes mid-bag is refused (a ValueError naming the bag, the topic and the message's index).
Cameras with lens distortion (``plumb_bob``, ``rational_polynomial``) are undistorted through a remap
computed once (nearest neighbour: depth is never interpolated across edges). A CameraInfo's principal point
has ROS's pixel centres (at integers): half a pixel is added (:func:`depthguard.camera.principal_point_from_opencv`).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from depthguard.camera import Camera, principal_point_from_opencv
from depthguard.io import ros2
from depthguard.io.cellfile import CellCamera, CellFile, refuse_align
from depthguard.io.mcap_ros2 import read_messages
from depthguard.io.ros2 import TASK_TOPIC
from depthguard.nodes.common import MAX_JOINT_SKEW
from depthguard.runner.sources import Tick

__all__ = ["BagSource", "undistort_map", "TASK_TOPIC", "MAX_JOINT_SKEW", "MAX_PENDING"]

#: Joint states kept for pairing frame sets (the latest ones read: 2 s at 1 kHz).
JOINT_HISTORY = 2000

#: Frames of one camera kept waiting for a joint state stamped at or after them; beyond it the oldest is dropped
#: (a fault names it).
MAX_PENDING = 32


def _distort(x: np.ndarray, y: np.ndarray, model: str, D: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Normalised image coordinates -> distorted ones (OpenCV / ROS ``plumb_bob`` and ``rational_polynomial``)."""
    d = np.zeros(8)
    d[: min(len(D), 8)] = D[:8]
    k1, k2, p1, p2, k3 = d[:5]
    k4, k5, k6 = d[5:8] if model == "rational_polynomial" else (0.0, 0.0, 0.0)
    r2 = x * x + y * y
    radial = (1 + k1 * r2 + k2 * r2**2 + k3 * r2**3) / (1 + k4 * r2 + k5 * r2**2 + k6 * r2**3)
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return xd, yd


def undistort_map(camera: Camera, model: str, D: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For every pixel of the undistorted image (``camera``'s pinhole), the source pixel (row, col) in the
    distorted image (-1 where it falls outside). Apply as ``out = img[rows, cols]`` (nearest neighbour)."""
    if model not in ("plumb_bob", "rational_polynomial"):
        raise ValueError(f"CameraInfo distortion_model {model!r} is not supported (plumb_bob, rational_polynomial)")
    v, u = np.mgrid[0 : camera.height, 0 : camera.width].astype(float)
    x = (u + 0.5 - camera.cx) / camera.fx
    y = (v + 0.5 - camera.cy) / camera.fy
    xd, yd = _distort(x, y, model, np.asarray(D, float))
    cols = np.floor(xd * camera.fx + camera.cx).astype(np.int64)
    rows = np.floor(yd * camera.fy + camera.cy).astype(np.int64)
    bad = (cols < 0) | (cols >= camera.width) | (rows < 0) | (rows >= camera.height)
    rows[bad] = -1
    cols[bad] = -1
    return rows, cols


def _apply_map(img: np.ndarray, maps: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    rows, cols = maps
    out = img[np.maximum(rows, 0), np.maximum(cols, 0)].astype(np.float32)
    out[rows < 0] = np.nan
    return out


def _pose_from_tf(
    tf_tree: dict[str, tuple[str, np.ndarray, np.ndarray]],
    frame: str,
    root: str = "world",
    links: frozenset[str] = frozenset(),
):
    """Pose ``(parent, R, p)`` of ``frame`` by chaining TF parents up to ``root``, or up to the first of
    the robot's ``links`` met on the way (a camera carried by the robot: its pose in that link's frame,
    which then follows the joint state, not the bag's first transform of it); None if not connected."""
    R, p = np.eye(3), np.zeros(3)
    seen = set()
    while frame != root:
        if frame not in tf_tree or frame in seen:
            return None
        seen.add(frame)
        parent, Rl, pl = tf_tree[frame]
        R, p = Rl @ R, Rl @ p + pl
        frame = parent
        if frame in links:
            return frame, R, p
    return root, R, p


class BagSource:
    """Replay a ROS 2 bag through the chain (module docstring).

    Args:
        path: the bag (``.mcap`` file or rosbag2 folder).
        cell: the cell file (topics, intrinsics/extrinsics sources).
        joint_names: the model's joint order.
    Raises:
        ValueError: a named topic is missing, a CameraInfo contradicts the image size, an unsupported
            encoding or distortion model, TF that never gives a camera's pose; the message names the bag
            and the topic. A camera with ``align`` (live RealSense only) is refused, naming the key.
    """

    def __init__(
        self, path: str | Path, cell: CellFile, joint_names: tuple[str, ...], links: frozenset[str] = frozenset()
    ) -> None:
        refuse_align(
            cell,
            f"a bag ({path})",
            " (a recording of an aligned run holds the aligned depth and, in its CameraInfo, the colour intrinsics:"
            " drop align to replay it; for depth aligned by the RealSense ROS driver, name its aligned_depth_to_color"
            " topics and drop align)",
        )
        self.path = Path(path)
        self.cell = cell
        self.joint_names = tuple(joint_names)
        self.links = frozenset(links)
        self._scan()

    # ------------------------------------------------------------------ set-up pass: topics, intrinsics, TF
    def _scan(self) -> None:
        cams: list[CellCamera] = list(self.cell.cameras)
        topics = self.cell.topics
        seen, infos, sizes, tf_tree = self._index(cams)
        name = self.path
        if not seen.get(topics["joint_states"]):
            raise ValueError(
                f"{name}: no sensor_msgs/JointState on '{topics['joint_states']}' (cell topics.joint_states)"
            )
        self.cameras: list[Camera] = []
        self.camera_parents: list[str] = []  # "world" or the robot link that carries the camera
        self._maps: list[tuple[np.ndarray, np.ndarray] | None] = []
        for c in cams:
            if not seen.get(c.topic):
                raise ValueError(f"{name}: no depth images on '{c.topic}' (camera '{c.name}' topic)")
            info = infos.get(c.info_topic)
            params = _camera_params(name, c, *sizes[c.topic], info)
            parent = c.parent
            if c.extrinsics == "tf":
                pose = _pose_from_tf(tf_tree, c.frame_id, links=self.links)
                if pose is None:
                    raise ValueError(
                        f"{name}: TF never connects 'world' to camera frame '{c.frame_id}' (topics"
                        f" {topics['tf']}, {topics['tf_static']}); known frames: {sorted(tf_tree)}"
                    )
                parent, Rw, pw = pose
            try:
                cam = c.build(**params)
                if c.extrinsics == "tf":
                    cam = cam.with_pose(Rw.T, -Rw.T @ pw)
            except ValueError as exc:  # (a CameraInfo of an uncalibrated camera has K = 0; TF may be broken)
                source = f"the CameraInfo on '{c.info_topic}'" if params.get("fx") is not None else "the cell file"
                if c.extrinsics == "tf":
                    source += f" or the TF of '{c.frame_id}'"
                raise ValueError(f"{name}: camera '{c.name}' from {source}: {exc}") from None
            self.cameras.append(cam)
            self.camera_parents.append(parent)
            self._maps.append(_undistortion(name, c, cam, info))
        self.has_task = bool(seen.get(TASK_TOPIC))

    def _index(self, cams: list[CellCamera]) -> tuple[dict, dict, dict, dict]:
        """One pass over the bag's topics of interest: ``(messages per topic, first CameraInfo per topic,
        first image size per topic, TF tree child -> (parent, R, t))``; sets :attr:`duration`."""
        topics = self.cell.topics
        wanted = {c.topic for c in cams} | {c.info_topic for c in cams} | {topics["joint_states"], TASK_TOPIC}
        wanted |= {topics["tf"], topics["tf_static"]}
        seen: dict[str, int] = {}
        infos: dict[str, object] = {}
        sizes: dict[str, tuple[int, int]] = {}
        tf_tree: dict[str, tuple[str, np.ndarray, np.ndarray]] = {}
        t0 = t = None
        for topic, _, t, msg in read_messages(self.path, topics=sorted(wanted)):
            t0 = t if t0 is None else t0
            seen[topic] = seen.get(topic, 0) + 1
            if topic in (topics["tf"], topics["tf_static"]):
                for tr in msg.transforms:
                    q = tr.transform.rotation
                    from scipy.spatial.transform import Rotation

                    Rl = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
                    tl = tr.transform.translation
                    tf_tree.setdefault(tr.child_frame_id, (tr.header.frame_id, Rl, np.array([tl.x, tl.y, tl.z])))
            elif any(topic == c.info_topic for c in cams):
                if topic not in infos:
                    infos[topic] = msg
                else:  # (one camera, one calibration: a CameraInfo that changes is refused, not half followed)
                    _same_camera_info(self.path, topic, seen[topic] - 1, infos[topic], msg)
            elif any(topic == c.topic for c in cams) and topic not in sizes:
                sizes[topic] = (int(msg.width), int(msg.height))
                try:  # encoding check now: a clear error rather than mid-run
                    ros2.image_to_depth(msg)
                except ValueError as exc:
                    raise ValueError(f"{self.path}: the first image on '{topic}' (message 0): {exc}") from None
        self.duration = 0.0 if t0 is None else float(t - t0)
        return seen, infos, sizes, tf_tree

    # ------------------------------------------------------------------ replay
    def _reorder(self, msg) -> tuple[np.ndarray | None, np.ndarray | None]:
        names = list(msg.name)
        pos = np.asarray(msg.position, float)
        vel = np.asarray(msg.velocity, float)
        idx = []
        for jn in self.joint_names:
            if jn not in names:
                return None, None  # a missing joint: invalid input for this tick (the controller stops)
            idx.append(names.index(jn))
        q = pos[idx] if len(pos) == len(names) else None
        qd = vel[idx] if len(vel) == len(names) else np.zeros(len(idx))
        return q, qd

    def ticks(self) -> Iterator[Tick]:
        cams = self.cell.cameras
        topics = self.cell.topics
        cam_of = {c.topic: i for i, c in enumerate(cams)}
        # per camera: the frames (stamp, depth) read and not yet used, and the stamp of the last one used
        self._pending: list[list[tuple[float, np.ndarray]]] = [[] for _ in cams]
        self._used: list[float] = [-np.inf] * len(cams)
        self._joints: deque[tuple[float, np.ndarray]] = deque(maxlen=JOINT_HISTORY)  # (stamp, q) of the latest
        self._xdot = np.zeros(3)
        self._faults: dict[str, str] = {}  # camera name -> fault, reported with the next tick
        wanted = sorted(set(cam_of) | {topics["joint_states"], TASK_TOPIC})
        group: list[tuple[str, object]] = []
        t_group = None
        for topic, _, t_log, msg in read_messages(self.path, topics=wanted):
            if t_group is not None and t_log != t_group:
                yield from self._flush(group, cam_of)
                group = []
            t_group = t_log
            group.append((topic, msg))
        yield from self._flush(group, cam_of)

    def _add_frame(self, i: int, msg) -> None:
        """Camera ``i``'s image ``msg`` to its pending frames, or a fault naming why it is not used."""
        name = self.cell.cameras[i].name
        try:
            depth = ros2.image_to_depth(msg)
        except ValueError as exc:  # (a corrupt message mid-run: a named fault, the frame missing)
            self._faults[name] = f"undecodable image ({exc})"
            return
        s = ros2.to_seconds(msg.header.stamp)
        if not s > self._used[i]:  # (NaN too)
            self._faults[name] = "frame stamped at or before the last frame used (duplicate or out of order): skipped"
            return
        if self._maps[i] is not None:
            depth = _apply_map(depth, self._maps[i])
        pend = self._pending[i]
        pend.append((s, depth))
        if len(pend) > MAX_PENDING:  # (stamps ahead of every joint state: keep the newest ones)
            pend.remove(min(pend, key=lambda p: p[0]))
            self._faults[name] = f"more than {MAX_PENDING} frames stamped after every joint state: oldest dropped"

    def _frame_set(self, t: float) -> tuple[list[np.ndarray] | None, float, np.ndarray | None]:
        """The frame set at a tick stamped ``t``: per camera the newest pending frame stamped at or before ``t``
        when every camera has one, its oldest frame's stamp and the joint positions to filter it with (the joint
        state read so far nearest to its newest frame); ``(None, -inf, None)`` when there is none or it is
        skipped."""
        chosen = []
        for pend in self._pending:
            ready = [p for p in pend if p[0] <= t + 1e-9]
            if not ready:
                return None, -np.inf, None
            chosen.append(max(ready, key=lambda p: p[0]))
        for i, (s, _) in enumerate(chosen):  # (used: it and every older frame of its camera)
            self._used[i] = s
            self._pending[i] = [p for p in self._pending[i] if p[0] > s]
        tf = max(s for s, _ in chosen)
        tj, qj = min(self._joints, key=lambda j: abs(j[0] - tf)) if self._joints else (np.inf, None)
        skew = [abs(tj - s) for s, _ in chosen]
        if not max(skew) <= MAX_JOINT_SKEW:
            worst = self.cell.cameras[int(np.argmax(skew))].name
            self._faults[worst] = f"no joint state within {MAX_JOINT_SKEW} s of the frame: frame set skipped"
            return None, -np.inf, None
        # the set's stamp is its oldest frame's, as the distance node's: its distances never look fresher than
        # the data they come from
        return [d for _, d in chosen], min(s for s, _ in chosen), qj

    def _flush(self, group: list, cam_of: dict[str, int]) -> Iterator[Tick]:
        """Messages logged at one instant: images and the task first, then the joint states (ticks)."""
        for topic, msg in group:
            if topic in cam_of:
                self._add_frame(cam_of[topic], msg)
            elif topic == TASK_TOPIC:
                self._xdot = np.array([msg.vector.x, msg.vector.y, msg.vector.z], float)
        for topic, msg in group:
            if topic in cam_of or topic == TASK_TOPIC:
                continue
            t = ros2.to_seconds(msg.header.stamp)
            q, qd = self._reorder(msg)
            if q is not None and np.isfinite(t):  # (a non-finite q too: run names it and skips the set)
                self._joints.append((t, q))
            frames, tf, q_frames = self._frame_set(t)
            faults, self._faults = self._faults, {}
            yield Tick(t, q, qd, t, self._xdot.copy(), frames, tf, faults, q_frames)

    def command(self, q_cmd: np.ndarray, qdot_cmd: np.ndarray) -> None:  # a recording cannot move
        pass

    def close(self) -> None:
        pass


def _camera_params(name: str, c: CellCamera, w: int, h: int, info) -> dict:
    """Intrinsics that override the cell file's for camera ``c`` whose images are ``w`` x ``h``: the
    CameraInfo's (``intrinsics = "camera_info"``, or ``"device"`` with a CameraInfo), or the cell file's scaled
    to a reduced resolution of the same sensor; ``{}`` when the cell file's apply as they are."""
    if c.intrinsics == "camera_info" or (c.intrinsics == "device" and info is not None):
        if info is None:
            raise ValueError(f"{name}: camera '{c.name}' takes its intrinsics from '{c.info_topic}', which is empty")
        if (int(info.width), int(info.height)) != (w, h):
            raise ValueError(
                f"{name}: CameraInfo on '{c.info_topic}' says {info.width}x{info.height} but the images on"
                f" '{c.topic}' are {w}x{h}"
            )
        K = np.asarray(info.k, float)
        cx, cy = principal_point_from_opencv(K[2], K[5])  # (ROS puts pixel centres at integers)
        return dict(width=w, height=h, fx=K[0], fy=K[4], cx=cx, cy=cy)
    if c.params.get("width") not in (None, w) or c.params.get("height") not in (None, h):
        sx, sy = w / c.params["width"], h / c.params["height"]
        if abs(sx - sy) > 1e-9:
            raise ValueError(
                f"{name}: camera '{c.name}' is {c.params['width']}x{c.params['height']} in the cell file but"
                f" the images on '{c.topic}' are {w}x{h} (not the same sensor at a reduced resolution)"
            )
        p = c.params  # the same sensor at a reduced resolution: scale the intrinsics
        return dict(width=w, height=h, fx=p["fx"] * sx, fy=p["fy"] * sx, cx=p["cx"] * sx, cy=p["cy"] * sx)
    return {}


def _same_camera_info(name: str, topic: str, index: int, first, msg) -> None:
    """Refuse a CameraInfo (``index``: its message on ``topic``) whose size, calibration or distortion differs
    from the first one on that topic: the bag source reads one calibration per camera."""
    what = None
    if (int(msg.width), int(msg.height)) != (int(first.width), int(first.height)):
        what = f"{msg.width}x{msg.height}, the first one {first.width}x{first.height}"
    elif str(msg.distortion_model) != str(first.distortion_model):
        what = f"distortion_model {msg.distortion_model!r}, the first one {first.distortion_model!r}"
    else:
        for key in ("k", "d"):
            a, b = np.asarray(getattr(msg, key), float), np.asarray(getattr(first, key), float)
            if a.shape != b.shape or not np.allclose(a, b, rtol=1e-9, atol=1e-12, equal_nan=True):
                what = f"{key.upper()} = {a.tolist()}, the first one {b.tolist()}"
                break
    if what is not None:
        raise ValueError(
            f"{name}: CameraInfo on '{topic}' changes mid-bag (message {index} says {what}): one calibration per"
            " camera is read; split the bag where the camera changes"
        )


def _undistortion(name: str, c: CellCamera, cam: Camera, info) -> tuple[np.ndarray, np.ndarray] | None:
    """The undistortion map of camera ``c`` from its CameraInfo's distortion (None when there is none)."""
    dm = str(getattr(info, "distortion_model", "")) if info is not None else ""
    D = np.asarray(getattr(info, "d", np.zeros(0)), float) if info is not None else np.zeros(0)
    if info is not None and np.any(D != 0):
        return undistort_map(cam, dm, D)
    if info is not None and dm not in ("", "plumb_bob", "rational_polynomial", "equidistant"):
        raise ValueError(f"{name}: CameraInfo on '{c.info_topic}': unsupported distortion_model {dm!r}")
    return None
