"""``depthguard run``: the same chain on the simulated cell and on ROS 2 bags, deterministic replay, bags written
by ``rosbags`` itself, and bad bags that give clear errors."""

import itertools
import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rosbags")
pytest.importorskip("mujoco")
pytest.importorskip("pinocchio")

from depthguard.cli import main  # noqa: E402
from depthguard.io import ros2  # noqa: E402
from depthguard.runner import run_cell  # noqa: E402
from depthguard.runner.run import RunLog  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
HEX_CELL = ROOT / "examples" / "cells" / "sim-hexagon.toml"


def _short_scenario(tmp_path, seconds=0.25):
    from depthguard.sim.scenarios import load_scenario

    sc = load_scenario("ral-hexagon")
    sc.pop("variants", None)
    sc["quick_duration"] = seconds
    lines = []
    for k, v in sc.items():  # a flat TOML writer is enough for this file's shape
        if not isinstance(v, dict | list) or (isinstance(v, list) and not (v and isinstance(v[0], dict))):
            lines.append(f"{k} = {json.dumps(v)}")
    for k, v in sc.items():
        if isinstance(v, dict):
            lines.append(f"[{k}]")
            lines += [f"{kk} = {json.dumps(vv)}" for kk, vv in v.items()]
    for k, v in sc.items():
        if isinstance(v, list) and v and isinstance(v[0], dict):
            for item in v:
                lines.append(f"[[{k}]]")
                for kk, vv in item.items():
                    if isinstance(vv, list) and vv and isinstance(vv[0], dict):
                        rows = ", ".join(
                            "{" + ", ".join(f"{a} = {json.dumps(b)}" for a, b in r.items()) + "}" for r in vv
                        )
                        lines.append(f"{kk} = [{rows}]")
                    else:
                        lines.append(f"{kk} = {json.dumps(vv)}")
    p = tmp_path / "short.toml"
    p.write_text("\n".join(lines) + "\n")
    tomllib.loads(p.read_text())
    return p


def _inputs_only_bag(recording: Path, out: Path, cell_path: Path) -> set[str]:
    """Copy the sensor inputs of ``run``'s ``recording`` (depth images, CameraInfo, TF, joint states, task
    velocity: not one of its outputs) into a rosbag2 folder ``out`` written by ``rosbags``' own writer (raw
    CDR, the same log times); returns the topics copied."""
    from rosbags.highlevel import AnyReader
    from rosbags.rosbag2 import StoragePlugin, Writer

    from depthguard.io.cellfile import read_cell
    from depthguard.runner.bag import TASK_TOPIC

    cell = read_cell(cell_path)
    inputs = {c.topic for c in cell.cameras} | {c.info_topic for c in cell.cameras}
    inputs |= {cell.topics["tf_static"], cell.topics["joint_states"], TASK_TOPIC}
    ts = ros2.typestore()
    with (
        AnyReader([recording], default_typestore=ts) as reader,
        Writer(out, version=9, storage_plugin=StoragePlugin.MCAP) as w,
    ):
        conns = [c for c in reader.connections if c.topic in inputs]
        new = {c.id: w.add_connection(c.topic, c.msgtype, typestore=ts) for c in conns}
        for conn, t_ns, raw in reader.messages(connections=conns):
            w.write(new[conn.id], t_ns, raw)
    return {c.topic for c in conns}


@pytest.mark.slow
def test_replay_of_a_recorded_sim_run_is_bit_exact(tmp_path):
    """Record the simulated run, replay the bag with --fast: same distances and commands; and so does a bag
    of its sensor inputs only (written by rosbags), so nothing of the recorded outputs enters a replay."""
    sc = _short_scenario(tmp_path)
    live, replay, inputs_only = RunLog(), RunLog(), RunLog()
    s1 = run_cell(HEX_CELL, f"sim:{sc}", quick=True, out_dir=tmp_path / "live", log=live)
    s2 = run_cell(HEX_CELL, f"bag:{tmp_path / 'live' / 'recording.mcap'}", log=replay)
    copied = _inputs_only_bag(tmp_path / "live" / "recording.mcap", tmp_path / "inputs", HEX_CELL)
    assert not any(t.startswith("/depthguard/") and t != "/depthguard/task_velocity" for t in copied)
    assert {"/camera0/depth/image_raw", "/camera1/depth/image_raw", "/joint_states"} <= copied
    s3 = run_cell(HEX_CELL, f"bag:{tmp_path / 'inputs'}", log=inputs_only)
    for s, log in ((s2, replay), (s3, inputs_only)):
        assert s1["frames"] == s["frames"] >= 7 and s1["commands"] == s["commands"] == 250
        assert s1["statuses"] == s["statuses"]
        np.testing.assert_allclose(live.t_query, log.t_query, rtol=0, atol=1e-9)  # stamps are whole ns
        np.testing.assert_allclose(np.array(live.distances), np.array(log.distances), rtol=0, atol=1e-12)
        np.testing.assert_allclose(np.array(live.q_cmd), np.array(log.q_cmd), rtol=0, atol=1e-12)
        np.testing.assert_allclose(np.array(live.qdot_cmd), np.array(log.qdot_cmd), rtol=0, atol=1e-12)
    assert any(np.isfinite(d).any() for d in live.distances)  # the scene is not empty


def _scene(encoding):
    """A camera 1.6 m in front of the arm at its zero pose, looking at it, and a wall with a post."""
    from depthguard.camera import Camera, look_at
    from depthguard.robot.model import load_lwr4
    from depthguard.robot.selffilter import self_filter
    from depthguard.sim.depthcam import kinect_camera

    R, t = look_at(np.array([1.6, 0.2, 0.8]), np.array([0.0, 0.0, 0.6]))
    cam = kinect_camera((1.6, 0.2, 0.8), (0.0, 0.0, 0.6), width=160, height=120)
    assert isinstance(cam, Camera)
    np.testing.assert_allclose(cam.R, R, atol=1e-12)
    pts = cam.unproject_image(np.full(cam.shape, 1.0))  # unit-depth rays
    ray = pts - cam.position
    # a wall at x = -0.5 and a post (half-space slab) at 0.25 < x < 0.35, -0.3 < y < -0.2
    s_wall = (-0.5 - cam.position[0]) / ray[..., 0]
    depth = s_wall * 1.0
    s_post = (0.35 - cam.position[0]) / ray[..., 0]
    hit = s_post[..., None] * ray + cam.position
    post = (hit[..., 1] > -0.3) & (hit[..., 1] < -0.2) & (hit[..., 2] < 1.2)
    depth = np.where(post, s_post, depth).astype(np.float32)
    model = load_lwr4()
    q = np.zeros(model.n_dof)
    q[3] = 0.6
    mask = np.asarray(self_filter(cam, depth, q, model)[0])
    if encoding == "16UC1":
        depth = (np.round(depth * 1000) / 1000).astype(np.float32)
    return cam, depth, q, model, mask


def _connections(w, ts, topic_image: str = "/cam/depth", tf_topic: str = "/tf_static"):
    """The bag connections of the test bags: depth images, CameraInfo, joint states, TF (static by default)."""
    return (
        w.add_connection(topic_image, "sensor_msgs/msg/Image", typestore=ts),
        w.add_connection("/cam/info", "sensor_msgs/msg/CameraInfo", typestore=ts),
        w.add_connection("/joint_states", "sensor_msgs/msg/JointState", typestore=ts),
        w.add_connection(tf_topic, "tf2_msgs/msg/TFMessage", typestore=ts),
    )


def _write_tick(w, ts, conns, t: float, cam, frame, q, joint_names) -> None:
    """One tick of a test bag at ``t`` s: the depth ``frame`` (32FC1) and its CameraInfo when not None, then
    the joint state ``q``; ``conns``: the image, info and joint-state connections of :func:`_connections`."""
    c_img, c_info, c_js = conns
    ns = int(round(t * 1e9))
    if frame is not None:
        w.write(c_img, ns, ts.serialize_cdr(ros2.image_msg(t, "cam_optical", frame, "32FC1"), "sensor_msgs/msg/Image"))
        info = ros2.camera_info_msg(t, "cam_optical", cam)
        w.write(c_info, ns, ts.serialize_cdr(info, "sensor_msgs/msg/CameraInfo"))
    js = ros2.joint_state_msg(t, list(joint_names), q, np.zeros(len(q)))
    w.write(c_js, ns, ts.serialize_cdr(js, "sensor_msgs/msg/JointState"))


def _write_bag(
    path,
    cam,
    depth,
    q,
    model,
    encoding,
    *,
    distortion=("plumb_bob", (0.0, 0.0, 0.0, 0.0, 0.0)),
    tf=True,
    info_size=None,
    topic_image="/cam/depth",
    storage="mcap",
    tf_topic="/tf_static",
):
    from rosbags.rosbag2 import StoragePlugin, Writer

    from depthguard.sim.recorder import camera_tf

    ts = ros2.typestore()
    plugin = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}[storage]
    with Writer(path, version=9, storage_plugin=plugin) as w:
        c_img, c_info, c_js, c_tf = _connections(w, ts, topic_image, tf_topic)
        if tf:  # the camera hangs on a link ("mount") that is fixed in the world
            Rw, pw = camera_tf(cam.R, cam.t)
            mount_R, mount_p = np.eye(3), np.array([1.0, 0.0, 0.0])
            tfm = ros2.tf_msg(0.0, [("world", "mount", mount_R, mount_p), ("mount", "cam_optical", Rw, pw - mount_p)])
            w.write(c_tf, 0, ts.serialize_cdr(tfm, "tf2_msgs/msg/TFMessage"))
        names = list(model.joint_names)
        for k in range(40):  # 40 ms of joint states at 1 kHz, one frame at 10 ms
            t = 0.001 * k
            ns = int(round(t * 1e9))
            if k == 10:
                img = ros2.image_msg(t, "cam_optical", depth, encoding)
                w.write(c_img, ns, ts.serialize_cdr(img, "sensor_msgs/msg/Image"))
                info = ros2.camera_info_msg(t, "cam_optical", cam)
                info.distortion_model, info.d = distortion[0], np.asarray(distortion[1], float)
                if info_size:
                    info.width, info.height = info_size
                w.write(c_info, ns, ts.serialize_cdr(info, "sensor_msgs/msg/CameraInfo"))
            js = ros2.joint_state_msg(t, names, q, np.zeros_like(q))
            w.write(c_js, ns, ts.serialize_cdr(js, "sensor_msgs/msg/JointState"))


BAG_CELL = """
[cell]
name = "bag-test"
[robot]
model = "lwr4"
control_points = "ral-9"
ee_radius = 0.12
[[cameras]]
name = "cam"
topic = "/cam/depth"
info_topic = "/cam/info"
frame_id = "cam_optical"
intrinsics = "camera_info"
extrinsics = "tf"
min_depth = 0.5
max_depth = 4.5
[distance]
rho = 0.5
mode = "hybrid"
[controller]
joint_timeout = 0.005
"""


@pytest.mark.parametrize("encoding", ["16UC1", "32FC1"])
def test_bag_from_rosbags_gives_the_distance_command_results(tmp_path, encoding, capsys):
    """A rosbag2 (MCAP) written by rosbags from a built scene runs through ``run`` and gives the same
    distances as ``depthguard distance`` on the same frame (camera pose from TF through a link)."""
    from depthguard.io import write_camera, write_mask, write_points
    from depthguard.io.files import ControlPoint
    from depthguard.robot.control_points import ControlPointSet

    cam, depth, q, model, mask = _scene(encoding)
    bag = tmp_path / "bag"
    _write_bag(bag, cam, depth, q, model, encoding)
    cell = tmp_path / "cell.toml"
    cell.write_text(BAG_CELL)
    log = RunLog()
    summary = run_cell(cell, f"bag:{bag}", out_dir=tmp_path / "out", log=log)
    assert summary["frames"] == 1 and summary["commands"] == 40
    assert set(summary["statuses"]) <= {"OK", "SCALED", "STOP_STALE_DISTANCES", "STOP_RESUME_WAIT"}
    # the same frame through the file-based command
    cps = ControlPointSet.build(model, "ral-9", 0.12).evaluate(q)
    write_camera(tmp_path / "cam.json", cam)
    np.save(tmp_path / "depth.npy", depth)
    write_mask(tmp_path / "mask.png", mask)
    write_points(
        tmp_path / "pts.json",
        [ControlPoint(n, tuple(c), float(r)) for n, c, r in zip(cps.names, cps.centres, cps.radii, strict=True)],
    )
    argv = [
        "distance",
        "--camera",
        str(tmp_path / "cam.json"),
        "--depth",
        str(tmp_path / "depth.npy"),
        "--mask",
        str(tmp_path / "mask.png"),
        "--points",
        str(tmp_path / "pts.json"),
        "--rho",
        "0.5",
        "--mode",
        "hybrid",
        "--json",
    ]
    assert main(argv) == 0
    ref = json.loads(capsys.readouterr().out)["points"]
    ref_d = np.array([np.inf if p["distance"] is None else p["distance"] for p in ref])
    got = log.distances[0]
    assert np.isfinite(ref_d).sum() >= 2  # the post and the wall are within reach of some points
    np.testing.assert_allclose(got, ref_d, atol=1e-6)


@pytest.mark.parametrize("storage, tf_topic", [("sqlite3", "/tf_static"), ("mcap", "/tf")])
def test_sqlite3_bags_and_dynamic_tf_give_the_same_distances(tmp_path, storage, tf_topic):
    """The scene of the rosbags test as a sqlite3 rosbag2, and as MCAP with the camera's TF on the dynamic
    ``/tf``: the same distances as the MCAP bag with ``/tf_static``."""
    cam, depth, q, model, _ = _scene("32FC1")
    cell = tmp_path / "cell.toml"
    cell.write_text(BAG_CELL)
    _write_bag(tmp_path / "ref", cam, depth, q, model, "32FC1")
    _write_bag(tmp_path / "bag", cam, depth, q, model, "32FC1", storage=storage, tf_topic=tf_topic)
    assert (tmp_path / "bag" / f"bag.{'db3' if storage == 'sqlite3' else 'mcap'}").is_file()
    ref, got = RunLog(), RunLog()
    run_cell(cell, f"bag:{tmp_path / 'ref'}", log=ref)
    summary = run_cell(cell, f"bag:{tmp_path / 'bag'}", log=got)
    assert summary["frames"] == 1 and summary["commands"] == 40
    assert np.isfinite(ref.distances[0]).sum() >= 2
    np.testing.assert_array_equal(np.array(got.distances), np.array(ref.distances))
    np.testing.assert_array_equal(np.array(got.qdot_cmd), np.array(ref.qdot_cmd))


@pytest.mark.parametrize(
    "kind, needle",
    [
        ("no_topic", "no depth images on '/cam/depth'"),
        ("encoding", "rgb8"),
        ("info_size", "CameraInfo on '/cam/info' says 100x100"),
        ("no_tf", "TF never connects 'world' to camera frame 'cam_optical'"),
        ("distortion", "unsupported distortion_model 'fisheye'"),
    ],
)
def test_bad_bags_give_clear_errors(tmp_path, kind, needle, capsys):
    cam, depth, q, model, _ = _scene("32FC1")
    bag = tmp_path / "bag"
    kw = {}
    if kind == "no_topic":
        kw["topic_image"] = "/other"
    if kind == "info_size":
        kw["info_size"] = (100, 100)
    if kind == "no_tf":
        kw["tf"] = False
    if kind == "distortion":
        kw["distortion"] = ("fisheye", np.zeros(4))
    if kind == "encoding":
        from rosbags.rosbag2 import StoragePlugin, Writer

        ts = ros2.typestore()
        with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as w:
            c = w.add_connection("/cam/depth", "sensor_msgs/msg/Image", typestore=ts)
            img = ros2.image_msg(0.0, "cam_optical", depth, "16UC1")
            img.encoding = "rgb8"
            w.write(c, 0, ts.serialize_cdr(img, "sensor_msgs/msg/Image"))
            cj = w.add_connection("/joint_states", "sensor_msgs/msg/JointState", typestore=ts)
            w.write(
                cj, 0, ts.serialize_cdr(ros2.joint_state_msg(0.0, model.joint_names, q), "sensor_msgs/msg/JointState")
            )
    else:
        _write_bag(bag, cam, depth, q, model, "32FC1", **kw)
    cell = tmp_path / "cell.toml"
    cell.write_text(BAG_CELL)
    assert main(["run", "--cell", str(cell), "--source", f"bag:{bag}", "--json"]) == 2
    err = capsys.readouterr().err
    assert needle in err and err.count("\n") == 1


def test_plumb_bob_with_coefficients_is_undistorted(tmp_path):
    """A distorted image is remapped: the optical centre stays, off-centre pixels move outwards (k1 > 0)."""
    from depthguard.runner.bag import undistort_map
    from depthguard.sim.depthcam import kinect_camera

    cam = kinect_camera((1.0, 0.0, 0.5), (0.0, 0.0, 0.5), width=160, height=120)
    rows, cols = undistort_map(cam, "plumb_bob", np.zeros(5))
    v, u = np.mgrid[0:120, 0:160]
    np.testing.assert_array_equal(rows, v)
    np.testing.assert_array_equal(cols, u)
    rows, cols = undistort_map(cam, "plumb_bob", np.array([0.2, 0.0, 0.0, 0.0, 0.0]))
    assert rows[60, 80] == 60 and cols[60, 80] == 80
    assert cols[60, 150] > 150 or cols[60, 150] == -1
    with pytest.raises(ValueError, match="fisheye"):
        undistort_map(cam, "fisheye", np.zeros(4))


def test_rational_polynomial_is_undistorted():
    """``rational_polynomial`` (8 coefficients): with k4..k6 = 0 it is ``plumb_bob``; with the denominator
    equal to the numerator (k4..k6 = k1..k3, no tangential terms) the radial factor is 1: the identity."""
    from depthguard.runner.bag import undistort_map
    from depthguard.sim.depthcam import kinect_camera

    cam = kinect_camera((1.0, 0.0, 0.5), (0.0, 0.0, 0.5), width=160, height=120)
    k = np.array([0.2, -0.05, 0.0, 0.0, 0.01])
    plumb = undistort_map(cam, "plumb_bob", k)
    rational = undistort_map(cam, "rational_polynomial", np.concatenate([k, np.zeros(3)]))
    for a, b in zip(plumb, rational, strict=True):
        np.testing.assert_array_equal(a, b)
    v, u = np.mgrid[0:120, 0:160]
    rows, cols = undistort_map(cam, "rational_polynomial", np.array([0.2, -0.05, 0.0, 0.0, 0.01, 0.2, -0.05, 0.01]))
    np.testing.assert_array_equal(rows, v)
    np.testing.assert_array_equal(cols, u)
    rows, cols = undistort_map(cam, "rational_polynomial", np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.2, 0.0, 0.0]))
    assert cols[60, 150] < 150  # a denominator > 1 pulls the source pixels inwards


def test_frozen_camera_stops_the_controller_with_its_name(tmp_path):
    """A bag whose camera repeats one frame with fresh stamps: STOP_SENSOR_FAULT, the camera named."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    cam, depth, q, model, _ = _scene("32FC1")
    bag = tmp_path / "bag"
    ts = ros2.typestore()
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        c_img, c_info, c_js, c_tf = _connections(w, ts)
        from depthguard.sim.recorder import camera_tf

        w.write(
            c_tf,
            0,
            ts.serialize_cdr(
                ros2.tf_msg(0.0, [("world", "cam_optical", *camera_tf(cam.R, cam.t))]), "tf2_msgs/msg/TFMessage"
            ),
        )
        for k in range(200):
            t = 0.001 * k
            ns = int(round(t * 1e9))
            if k % 33 == 0:  # 30 Hz, the very same image every time
                w.write(
                    c_img,
                    ns,
                    ts.serialize_cdr(ros2.image_msg(t, "cam_optical", depth, "32FC1"), "sensor_msgs/msg/Image"),
                )
                w.write(
                    c_info,
                    ns,
                    ts.serialize_cdr(ros2.camera_info_msg(t, "cam_optical", cam), "sensor_msgs/msg/CameraInfo"),
                )
            w.write(
                c_js, ns, ts.serialize_cdr(ros2.joint_state_msg(t, model.joint_names, q), "sensor_msgs/msg/JointState")
            )
    cell = tmp_path / "cell.toml"
    cell.write_text(BAG_CELL)
    log = RunLog()
    summary = run_cell(cell, f"bag:{bag}", log=log)
    assert summary["sensor_faults"].get("cam: frozen", 0) >= 3
    assert log.status[-1] == "STOP_SENSOR_FAULT"
    i = log.status.index("STOP_SENSOR_FAULT")
    assert log.t[i] == pytest.approx(0.066, abs=0.002)  # the third identical frame
    assert np.all(np.abs(log.qdot_cmd[-1]) < np.abs(log.qdot_cmd[i]).max() + 1e-12)


def test_run_chain_corrects_for_the_robots_interior():
    """``run`` (and the distance node) apply the robot-interior corrections of the depth grid, as the
    simulated scenarios do (docs/phantom-zero.md): with the joint state, the cells right behind the arm
    are not unseen space. On the first frames of the simulated ``ral-hexagon`` cell every distance is at
    least the uncorrected one and some are larger (with the "ral" cameras, before the second one was rolled,
    the end effector read 0 without them at 640x480; with the rolled one the gain is 1-3 mm)."""
    from depthguard.io.cellfile import read_cell
    from depthguard.runner import open_source
    from depthguard.runner.chain import Chain, load_cell_robot

    cell = read_cell(HEX_CELL)
    model = load_cell_robot(cell)
    src = open_source("sim:ral-hexagon", cell, model.joint_names, quick=True)
    gain = []
    try:
        chain = Chain(cell, src.cameras, model)
        for tick in itertools.islice((t for t in src.ticks() if t.frames is not None), 12):
            chain.on_frames(tick.frames, tick.q, tick.t)
            corrected = np.asarray(chain.query(tick.t, tick.q).distance)
            chain.stage.update(tick.frames, chain.masks)  # without the joint state: no correction
            plain = np.asarray(chain.query(tick.t, tick.q).distance)
            assert np.all(corrected >= plain - 1e-9)
            gain.append(
                np.max(np.where(np.isfinite(corrected), corrected, 1.0) - np.where(np.isfinite(plain), plain, 1.0))
            )
    finally:
        src.close()
    assert max(gain) > 0.001, gain  # without the corrections both are the same, bit for bit


def _wall_and_post(cam):
    """Depth (H, W) float32 of the wall at x = -0.5 and the post of :func:`_scene`, seen by ``cam``."""
    ray = cam.unproject_image(np.full(cam.shape, 1.0)) - cam.position  # unit-depth rays
    with np.errstate(divide="ignore", invalid="ignore"):
        s_wall = (-0.5 - cam.position[0]) / ray[..., 0]
        s_post = (0.35 - cam.position[0]) / ray[..., 0]
    hit = s_post[..., None] * ray + cam.position
    post = (s_post > 0) & (hit[..., 1] > -0.3) & (hit[..., 1] < -0.2) & (hit[..., 2] < 1.2)
    depth = np.where(post, s_post, s_wall)
    return np.where(np.isfinite(depth) & (depth > 0), depth, np.nan).astype(np.float32)


def test_camera_carried_by_a_link_follows_the_joint_state(tmp_path):
    """A bag whose TF hangs the camera on a robot link (``lwr_link_2``), two frames at two joint states: ``run``
    moves the camera with the link and gives, for each frame, the distances of the same frame seen by a
    camera placed at that pose by hand (the link's pose from pinocchio, composed here)."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    from depthguard.robot.control_points import ControlPointSet
    from depthguard.robot.model import load_lwr4
    from depthguard.robot.selffilter import self_filter
    from depthguard.runner.chain import cell_distance_stage
    from depthguard.sim.depthcam import kinect_camera
    from depthguard.sim.recorder import camera_tf

    model = load_lwr4()
    link = "lwr_link_2"
    qa, qb = np.zeros(7), np.zeros(7)
    qa[3], qb[0], qb[1], qb[3] = 0.6, 0.5, 0.3, 0.9
    cam_a = kinect_camera((1.6, 0.2, 0.8), (0.0, 0.0, 0.6), width=160, height=120)  # its pose at qa
    Rl, pl = model.frame_pose(qa, link)
    Rw, pw = camera_tf(cam_a.R, cam_a.t)  # camera -> world at qa
    R_lc, p_lc = Rl.T @ Rw, Rl.T @ (pw - pl)  # camera -> link: fixed

    def cam_at(q):
        R_l, p_l = model.frame_pose(q, link)
        R_wc, p_wc = R_l @ R_lc, R_l @ p_lc + p_l
        return cam_a.with_pose(R_wc.T, -R_wc.T @ p_wc)

    frames = {10: qa, 30: qb}
    ts = ros2.typestore()
    bag = tmp_path / "bag"
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        c_img, c_info, c_js, c_tf = _connections(w, ts)
        w.write(
            c_tf, 0, ts.serialize_cdr(ros2.tf_msg(0.0, [(link, "cam_optical", R_lc, p_lc)]), "tf2_msgs/msg/TFMessage")
        )
        for k in range(45):
            t = 0.001 * k
            q = qa if k < 20 else qb
            frame = _wall_and_post(cam_at(frames[k])) if k in frames else None
            _write_tick(w, ts, (c_img, c_info, c_js), t, cam_a, frame, q, model.joint_names)
    cell = tmp_path / "cell.toml"
    cell.write_text(BAG_CELL)
    log = RunLog()
    summary = run_cell(cell, f"bag:{bag}", out_dir=tmp_path / "out", log=log)
    assert summary["frames"] == 2
    from depthguard.io.cellfile import read_cell

    cellf = read_cell(cell)
    points = ControlPointSet.build(model, "ral-9", 0.12)
    for k, q in frames.items():  # the last query at this frame's joint state (qa until 20 ms)
        i = max(j for j, t in enumerate(log.t_query) if t < (0.020 if k == 10 else 1.0) - 1e-9)
        assert log.t_query[i] >= 0.001 * k
        cam = cam_at(q)
        depth = _wall_and_post(cam)
        stage = cell_distance_stage(cellf, [cam])
        stage.update([depth], [np.asarray(self_filter(cam, depth, q, model)[0])])
        cps = points.evaluate(q)
        ref = np.asarray(stage.query(cps.centres, cps.radii).distance)
        assert np.isfinite(ref).sum() >= 2
        np.testing.assert_allclose(log.distances[i], ref, atol=1e-6)
    # the two frames really saw the scene from two places
    assert np.linalg.norm(cam_at(qa).position - cam_at(qb).position) > 0.3
    # run's recording hangs the camera on the link too: its replay gives the same distances
    replay = RunLog()
    run_cell(cell, f"bag:{tmp_path / 'out' / 'recording.mcap'}", log=replay)
    np.testing.assert_allclose(np.array(replay.distances), np.array(log.distances), rtol=0, atol=1e-12)


def test_bag_with_non_finite_joint_positions_stops_instead_of_raising(tmp_path):
    """A NaN joint position cannot place the robot: ``run`` skips the frame stage and the queries for it,
    counts the fault, and the controller stops (it raised ``ValueError`` from the self-filter before)."""
    cam, depth, q, model, _ = _scene("32FC1")
    q = q.copy()
    q[2] = np.nan
    _write_bag(tmp_path / "bag", cam, depth, q, model, "32FC1")
    cell = tmp_path / "cell.toml"
    cell.write_text(BAG_CELL)
    log = RunLog()
    summary = run_cell(cell, f"bag:{tmp_path / 'bag'}", log=log)
    assert summary["frames"] == 0 and summary["commands"] == 40
    assert set(summary["statuses"]) == {"STOP_INVALID_INPUT"}
    assert summary["sensor_faults"]["joint state: not finite or wrong size"] == 1


def _one_camera_bag(path: Path, cam, q, model, frames: dict) -> None:
    """A 60-tick bag (1 ms apart) of the test scene's camera at joint positions ``q``: at tick k, the depth
    image ``frames[k]`` (an array, written as 32FC1 with its CameraInfo, or a ready Image message, written as
    it is), then the joint state."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    from depthguard.sim.recorder import camera_tf

    ts = ros2.typestore()
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        c_img, c_info, c_js, c_tf = _connections(w, ts)
        Rw, pw = camera_tf(cam.R, cam.t)
        tfm = ros2.tf_msg(0.0, [("world", "cam_optical", Rw, pw)])
        w.write(c_tf, 0, ts.serialize_cdr(tfm, "tf2_msgs/msg/TFMessage"))
        for k in range(60):
            frame = frames.get(k)
            if frame is not None and not isinstance(frame, np.ndarray):
                w.write(c_img, k * 1_000_000, ts.serialize_cdr(frame, "sensor_msgs/msg/Image"))
                frame = None
            _write_tick(w, ts, (c_img, c_info, c_js), 0.001 * k, cam, frame, q, model.joint_names)


def test_image_of_another_size_mid_run_stops_with_the_camera_named(tmp_path):
    """A driver that changes its resolution mid-run (or a corrupt message): ``STOP_SENSOR_FAULT`` naming the
    camera and the shapes, not an exception from the array arithmetic of the health check."""
    cam, depth, q, model, _ = _scene("32FC1")
    _one_camera_bag(tmp_path / "bag", cam, q, model, {10: depth, 40: depth[:60, :80].copy()})
    cell = tmp_path / "cell.toml"
    cell.write_text(BAG_CELL)
    log = RunLog()
    summary = run_cell(cell, f"bag:{tmp_path / 'bag'}", log=log)
    assert summary["sensor_faults"] == {"cam: image of shape (60, 80), expected (120, 160)": 1}
    i = log.t.index(0.04)
    assert "STOP_SENSOR_FAULT" not in log.status[:i] and set(log.status[i:]) == {"STOP_SENSOR_FAULT"}


def test_undecodable_image_mid_run_is_a_named_fault_not_a_crash(tmp_path):
    """A corrupt image mid-bag (another encoding, fewer bytes than its size says): ``run`` counts a fault
    naming the camera and goes on; the frame is missing (no frame set at that tick), and the frames after it
    are used as before."""
    cam, depth, q, model, _ = _scene("32FC1")
    bad = [ros2.image_msg(0.001 * k, "cam_optical", depth, "32FC1") for k in (20, 30)]
    bad[0].encoding = "rgb8"
    bad[1].data = bad[1].data[:100]
    _one_camera_bag(tmp_path / "bag", cam, q, model, {k: depth for k in range(0, 60, 10)} | {20: bad[0], 30: bad[1]})
    cell = tmp_path / "cell.toml"
    cell.write_text(BAG_CELL)
    log = RunLog()
    summary = run_cell(cell, f"bag:{tmp_path / 'bag'}", log=log)
    # (this synthetic scene does not show the arm where the model puts it: the health check's other faults
    # come from that, not from the corrupt images)
    faults = {k: v for k, v in summary["sensor_faults"].items() if "undecodable" in k}
    assert sorted(faults) == [
        "cam: undecodable image (Image 160x120 32FC1 holds 100 bytes with step 640: too few)",
        "cam: undecodable image (Image encoding 'rgb8' is not a depth encoding (expected 16UC1 or 32FC1))",
    ]
    assert set(faults.values()) == {1}
    assert summary["frames"] == 4 and summary["commands"] == 60  # (k = 0, 10, 40, 50)


def test_run_cell_closes_its_source_when_the_set_up_fails(monkeypatch):
    """A run that fails before its loop (here an unknown transport) closes the source it opened: a live
    camera must not stay streaming, a simulator not stay loaded."""
    import depthguard.runner as runner

    closed = []
    real_open = runner.open_source

    def open_and_watch(*a, **k):
        src = real_open(*a, **k)
        real_close = src.close
        src.close = lambda: (closed.append(True), real_close())
        return src

    monkeypatch.setattr(runner, "open_source", open_and_watch)
    with pytest.raises(ValueError, match="--transport must be"):
        run_cell(ROOT / "examples/cells/sim-hexagon.toml", "sim:ral-hexagon", quick=True, transport="carrier-pigeon")
    assert closed == [True]
