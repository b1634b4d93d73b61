"""The cell file: one TOML file that describes a work cell (robot, cameras, distance backend, controller,
topics), validated with errors that name the key; unknown keys are rejected.

This docstring is the key reference (``docs/real-cell.md`` walks through a cell; ``examples/cells/`` has
complete files). Relative paths in a cell file are relative to the file's folder. Sections:

* ``[cell]``: ``name``, ``description``;
* ``[robot]``: ``model`` (a shipped model: ``"lwr4"``) or ``urdf`` (a path), ``ee_frame``, ``joint_names``
  (the order of ``q``; a JointState is reordered into it), ``control_points`` (a preset name such as
  ``"ral-9"`` or ``"auto"``), ``ee_radius`` (m), ``[[robot.spheres]]`` (explicit control spheres, added to
  the preset's: ``link``, ``position`` in the link frame, ``radius``) and ``[[robot.attachments]]`` (tools and
  payloads: ``name``, ``link``, ``shape`` = box | cylinder | sphere | mesh, ``size`` (box: full sizes x y z;
  cylinder: radius, length; sphere: radius; metres, at most 10), ``mesh`` (path), ``xyz``, ``rpy`` (pose in
  the link frame)): the self-filter removes them, and control spheres cover each one (``depthguard.runner.chain``);
* ``[[cameras]]``: ``name``, ``topic`` and ``info_topic`` (recorded or live sources), ``frame_id``,
  intrinsics (``width``, ``height``, ``fx``, ``fy``, ``cx``, ``cy``; or ``intrinsics = "camera_info"`` to
  take them from the CameraInfo topic, ``"device"`` from a live device), ``min_depth``, ``max_depth``,
  ``depth_scale``, ``rate`` (Hz), extrinsics as ``R`` + ``t`` (``P_C = R P + t``) or ``matrix`` (4x4, the
  same map), or ``eye`` + ``target`` (+ ``up``: the camera centre and a point on its optical axis, m), or
  ``extrinsics = "tf"`` (from the bag's TF, read once), in the frame ``parent``: ``"world"`` or a link of
  the robot (a camera carried by the robot, e.g. on the wrist: its extrinsics map points of that link's
  frame, ``P_C = R P_link + t``, and ``depthguard run`` moves it with the link at every frame's joint
  state, as the camera and distance nodes do; the link is checked against the robot when the chain is
  built; the simulated cell and ``calibrate`` take world cameras only and say so), ``align`` (``"none"``, the
  default, or ``"color"``: the live RealSense source aligns the depth stream to the device's colour stream
  with ``pyrealsense2``'s ``rs.align``, so that depth pixels are colour pixels; the camera then has the
  colour stream's intrinsics at the colour resolution, and the extrinsics place the **colour** camera's
  optical frame; needs ``intrinsics = "device"``; bag and simulated sources refuse it, see
  :mod:`depthguard.runner.realsense`), ``noise_coeff`` (the depth noise, σ = c z², m⁻¹; default 0: the
  self-filter's margin is its 3 cm; with c > 0 the margin covers 5 σ at the robot's farthest depth in that
  camera, as in the simulated cell: a simulated Kinect has c = 0.0014);
* ``[distance]``: ``backend`` (``depthspace`` | ``octree``; ``run`` and the nodes refuse ``octree`` for now),
  ``rho`` (m), ``mode`` (min | all | hybrid),
  ``invalid`` (conservative | ignore), ``fill_radius`` (px), ``grid_dd`` (m), ``workspace`` (6 numbers, m),
  ``octree_res`` (m), ``period`` (s between distance queries in ``--fast`` runs), ``direction_stride``
  (``"auto"`` or an integer >= 1: the direction lattice of modes all / hybrid, docs/conventions.md);
* ``[controller]``: ``rate`` (Hz), ``distance_timeout``, ``joint_timeout``, ``resume_time`` (s),
  ``velocity_scale``, ``a_max``, ``j_max``, ``rho_ee``, ``rho_body``, ``alpha``, ``v_rep_max``, ``ssm`` (bool:
  speed and separation monitoring with the repulsion, controller mode "both", docs/ssm.md), ``ssm_range``
  (m, default 0.6: with ``ssm``, the distances reach max(``rho``, ``ssm_range``) for the monitor; the
  repulsion keeps ``rho``), ``background`` (a path: the background file of ``depthguard commission``, the
  empty cell; applied to the depth images before the distances when ``ssm`` is on, not otherwise: the
  repulsion must still see the table; docs/ssm.md);
* ``calibration = "FILE"`` (top level): extrinsics from ``depthguard calibrate`` override the cameras' own;
* ``[topics]``: ``joint_states``, ``tf``, ``tf_static``, ``command`` (JointTrajectory), ``command_array``
  (Float64MultiArray), ``distances``, ``monitor_distances`` (SSM's own distances, published with a
  ``[controller] background``: the same frames without the empty cell), ``status``, ``markers``;
* ``[network]`` (nodes on Zenoh, see ``docs/nodes.md``): ``domain`` (ROS domain id), ``host`` (the address the
  nodes listen on: ``127.0.0.1`` by default), ``base_port`` (node *k* listens on ``base_port + k``; the ports
  stay in [1024, 65535] and off the router's 7447), ``connect`` (extra endpoints ``PROTOCOL/HOST:PORT``,
  default the ROS 2 router ``tcp/127.0.0.1:7447``), ``publishers`` (node names
  allowed to publish distances and joint commands; default: DepthGuard's own ``distance`` and
  ``controller``), ``tls_root_ca``, ``tls_certificate``, ``tls_private_key`` (paths, all three or none: Zenoh TLS
  for a network endpoint; required when ``host`` is not a loopback address; with ``{node}`` in the certificate and key
  paths, each node has its own certificate, whose common name is its node name, and Zenoh's access control
  lets only the ``publishers`` publish distances and joint commands: ``docs/nodes.md``).
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from depthguard.camera import Camera
from depthguard.io.cell_network import PER_NODE, network_section, node_tls_files, per_node_certificates
from depthguard.io.cell_robot import (  # (re-exported: the [robot] section)
    CONTROL_POINT_CHOICES,
    MAX_ATTACHMENT_SIZE,
    MODEL_EE_FRAMES,
    Attachment,
    CellRobot,
    Sphere,
    robot_section,
)
from depthguard.io.cell_schema import (
    _TOP,
    NODE_ROLES,
    CellError,
    _is_matrix,
    _section,
    _vector,
    apply_calibration,
    check_background,
    check_names,
    distance_section,
)

__all__ = [
    "CONTROL_POINT_CHOICES",
    "MAX_ATTACHMENT_SIZE",
    "MODEL_EE_FRAMES",
    "CellFile",
    "CellCamera",
    "CellRobot",
    "Attachment",
    "Sphere",
    "read_cell",
    "refuse_align",
    "node_names",
    "PER_NODE",
    "per_node_certificates",
    "node_tls_files",
]


@dataclass(frozen=True)
class CellCamera:
    """One camera. ``camera`` holds the intrinsics and extrinsics when the file gives both; ``intrinsics``
    and ``extrinsics`` say where they come from otherwise (``"file"``, ``"camera_info"``, ``"device"``;
    ``"file"``, ``"tf"``). ``parent`` is the frame the extrinsics are given in. ``align``: ``"none"`` or
    ``"color"`` (the live RealSense's depth aligned to its colour stream: colour intrinsics, and the
    extrinsics are the colour camera's)."""

    name: str
    topic: str
    info_topic: str
    frame_id: str
    intrinsics: str
    extrinsics: str
    parent: str
    rate: float
    params: dict[str, Any]
    R: np.ndarray | None
    t: np.ndarray | None
    noise_coeff: float = 0.0
    align: str = "none"

    def build(self, width: int | None = None, **intrinsics: float) -> Camera:
        """The :class:`Camera` (extrinsics in ``parent``), with intrinsics from the file or the arguments."""
        p = dict(self.params)
        p.update({k: v for k, v in intrinsics.items() if v is not None})
        if width is not None:
            p["width"] = width
        R = np.eye(3) if self.R is None else self.R
        t = np.zeros(3) if self.t is None else self.t
        return Camera(R=R, t=t, **p)


@dataclass(frozen=True)
class CellFile:
    path: Path
    name: str
    description: str
    robot: CellRobot
    cameras: tuple[CellCamera, ...]
    distance: dict[str, Any]
    controller: dict[str, Any]
    topics: dict[str, str]
    raw: dict[str, Any] = field(repr=False, default_factory=dict)
    network: dict[str, Any] = field(default_factory=dict)


def _camera(src: Path, i: int, table: Any) -> CellCamera:
    where = f"cameras[{i}]"
    c = _section(src, where, "camera", table)
    empty = [k for k in ("topic", "info_topic", "frame_id") if k in table and not c[k].strip()]
    if empty:  # (an empty one would be taken for the default)
        raise CellError(f"{src}: {where}.{empty[0]} must not be empty: leave it out for the default")
    intr = {k: c[k] for k in ("width", "height", "fx", "fy", "cx", "cy")}
    if c["intrinsics"] == "file":
        missing = [k for k, v in intr.items() if v is None]
        if missing:
            raise CellError(f'{src}: {where} needs {missing} (or intrinsics = "camera_info" | "device")')
    R = t = None
    given = [k for k in ("R", "t", "matrix", "eye", "target") if c[k] is not None]
    if c["extrinsics"] != "file" and given:  # (they would be ignored)
        raise CellError(f'{src}: {where}: extrinsics = "{c["extrinsics"]}" takes no {given}: give one or the other')
    if "up" in table and c["eye"] is None:  # (it would be ignored)
        raise CellError(f"{src}: {where}.up goes with 'eye' + 'target' only: remove it or give them")
    if c["extrinsics"] == "file":
        if c["eye"] is not None or c["target"] is not None:
            if c["matrix"] is not None or c["R"] is not None or c["t"] is not None:
                raise CellError(f"{src}: {where}: give one form of extrinsics: 'eye' + 'target', 'R' + 't' or 'matrix'")
            from depthguard.camera import look_at

            eye = _vector(src, f"{where}.eye", c["eye"], 3)
            target = _vector(src, f"{where}.target", c["target"], 3)
            try:
                R, t = look_at(np.array(eye), np.array(target), np.array(_vector(src, f"{where}.up", c["up"], 3)))
            except ValueError as exc:
                raise CellError(f"{src}: {where}: {exc}") from None
        elif c["matrix"] is not None:
            if c["R"] is not None or c["t"] is not None:
                raise CellError(f"{src}: {where}: give either 'matrix' or 'R' and 't', not both")
            M = np.asarray(c["matrix"], dtype=float) if _is_matrix(c["matrix"], 4, 4) else None
            if M is None or not np.allclose(M[3], [0, 0, 0, 1]):
                raise CellError(f"{src}: {where}.matrix must be a 4x4 homogeneous matrix (last row 0 0 0 1)")
            R, t = M[:3, :3], M[:3, 3]
        else:
            if c["R"] is None or c["t"] is None or not _is_matrix(c["R"], 3, 3):
                raise CellError(f"{src}: {where} needs extrinsics: 'R' (3x3) and 't' (3), or 'matrix' (4x4)")
            R = np.asarray(c["R"], dtype=float)
            t = np.asarray(_vector(src, f"{where}.t", c["t"], 3))
        from depthguard.validation import check_rotation

        try:
            R = check_rotation(R, f"{where}.R")
        except ValueError as exc:
            raise CellError(f"{src}: {exc}") from None
    if c["align"] != "none" and c["intrinsics"] != "device":
        raise CellError(
            f'{src}: {where}.align = "{c["align"]}" needs intrinsics = "device" (got "{c["intrinsics"]}"): the'
            " aligned depth has the intrinsics of the RealSense's colour stream, read from the device"
        )
    if c["noise_coeff"] < 0:
        raise CellError(f"{src}: {where}.noise_coeff must be >= 0 (sigma = c z^2, m^-1), got {c['noise_coeff']}")
    params = {k: v for k, v in intr.items() if v is not None}
    params.update(min_depth=float(c["min_depth"]), max_depth=float(c["max_depth"]), depth_scale=float(c["depth_scale"]))
    # the depth range and scale are the file's whatever the intrinsics' source (stand-ins for those not given)
    stand_in = {} if c["intrinsics"] == "file" else dict(width=1, height=1, fx=1.0, fy=1.0, cx=0.5, cy=0.5)
    try:
        Camera(R=np.eye(3) if R is None else R, t=np.zeros(3) if t is None else t, **{**stand_in, **params})
    except ValueError as exc:
        raise CellError(f"{src}: {where}: {exc}") from None
    name = c["name"]
    return CellCamera(
        name=name,
        topic=c["topic"] or f"/{name}/depth/image_raw",
        info_topic=c["info_topic"] or f"/{name}/depth/camera_info",
        frame_id=c["frame_id"] or f"{name}_optical",
        intrinsics=c["intrinsics"],
        extrinsics=c["extrinsics"],
        parent=c["parent"],
        rate=float(c["rate"]),
        params=params,
        R=R,
        t=t,
        align=c["align"],
        noise_coeff=float(c["noise_coeff"]),
    )


def refuse_align(cell: CellFile, source: str, hint: str = "") -> None:
    """``ValueError`` naming ``cameras[i].align`` when a camera of ``cell`` asks for alignment and the source
    (``source``: its description, e.g. ``"a bag"``) is not the live RealSense, the only one that can align;
    ``hint`` ends the message."""
    for i, c in enumerate(cell.cameras):
        if c.align != "none":
            raise CellError(
                f"{cell.path}: cameras[{i}].align = \"{c.align}\" (camera '{c.name}') is for the live RealSense source"
                f" (--source realsense) only, not for {source}: its depth images are used as they come{hint}"
            )


def read_cell(path: str | Path) -> CellFile:
    """Read and validate a cell file. Raises ``ValueError`` (:class:`CellError`) naming the file and key."""
    src = Path(path)
    if src.is_dir():
        raise CellError(f"{src}: is a directory, expected a cell file (.toml)")
    if not src.is_file():
        raise CellError(f"{src}: no such cell file")
    try:
        data = tomllib.loads(src.read_text(encoding="utf-8"))
    except UnicodeDecodeError as exc:
        raise CellError(f"{src}: not UTF-8 text ({exc.reason})") from None
    except tomllib.TOMLDecodeError as exc:
        raise CellError(f"{src}: not valid TOML ({exc})") from None
    except OSError as exc:  # (permission denied, an I/O error)
        raise CellError(f"{src}: cannot be read ({exc.strerror or exc})") from None
    unknown = sorted(set(data) - _TOP)
    if unknown:
        raise CellError(f"{src}: unknown section(s) {unknown}; known: {sorted(_TOP)}")
    for req in ("robot", "cameras"):
        if req not in data:
            raise CellError(f"{src}: the cell file needs a [{req}] section" + (" ([[cameras]])" * (req == "cameras")))
    cell = _section(src, "cell", "cell", data.get("cell", {}))
    cams_raw = data["cameras"]
    if not isinstance(cams_raw, list) or not cams_raw:
        raise CellError(f"{src}: [[cameras]] must hold at least one camera table")
    cams = tuple(_camera(src, i, c) for i, c in enumerate(cams_raw))
    names = [c.name for c in cams]
    if len(set(names)) != len(names):
        raise CellError(f"{src}: camera names must be unique, got {names}")
    if "calibration" in data:
        cams = apply_calibration(src, data["calibration"], cams)
    dist = distance_section(src, data.get("distance", {}))
    ctrl = _section(src, "controller", "controller", data.get("controller", {}))
    if not 0 < ctrl["velocity_scale"] <= 1:
        raise CellError(f"{src}: controller.velocity_scale must be in (0, 1], got {ctrl['velocity_scale']}")
    if not 0 < ctrl["ssm_range"] < float("inf"):
        raise CellError(f"{src}: controller.ssm_range must be a finite number of metres > 0, got {ctrl['ssm_range']}")
    check_background(src, ctrl, cams)
    topics = _section(src, "topics", "topics", data.get("topics", {}))
    check_names(src, cams, topics)
    net = network_section(src, data.get("network", {}), nodes=len(cams) + len(NODE_ROLES))
    robot = robot_section(src, data["robot"])
    return CellFile(src, cell["name"], cell["description"], robot, cams, dist, ctrl, topics, data, net)


def node_names(cell: CellFile) -> list[str]:
    """The names of a cell's nodes on Zenoh, in port order (node *k* listens on ``network.base_port + k``):
    ``sim``, one per camera (the camera's name), ``distance``, ``controller``, ``monitor``, ``run``, ``view``."""
    return [NODE_ROLES[0], *[c.name for c in cell.cameras], *NODE_ROLES[1:]]


def ssm_range(cell: CellFile) -> float | None:
    """The range (m) of the distances that the SSM monitor gets, ``max(rho, ssm_range)``; None without SSM."""
    if not cell.controller["ssm"]:
        return None
    return max(float(cell.controller["ssm_range"]), float(cell.distance["rho"]))
