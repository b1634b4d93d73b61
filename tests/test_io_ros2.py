"""ROS 2 messages and MCAP recordings, checked with decoders independent of the encoder: ``mcap_ros2``
(its own CDR parser driven by the embedded ``ros2msg`` schema text) and a plain Jazzy type store."""

import math
import struct

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

pytest.importorskip("rosbags")
pytest.importorskip("mcap")

from depthguard.camera import Camera  # noqa: E402
from depthguard.io import ros2  # noqa: E402
from depthguard.io.mcap_ros2 import Ros2McapWriter, read_messages  # noqa: E402


def _write_sample(path):
    cam = Camera.kinect_v1(width=8, height=6, fx=5.0, fy=5.0, cx=4.0, cy=3.0)
    depth = np.linspace(0.5, 3.0, 48, dtype=np.float32).reshape(6, 8)
    depth[0, 0] = np.nan
    with Ros2McapWriter(path) as w:
        w.write("/cam/depth", "sensor_msgs/msg/Image", ros2.image_msg(0.1, "cam", depth), 0.1)
        w.write("/cam/depth32", "sensor_msgs/msg/Image", ros2.image_msg(0.1, "cam", depth, "32FC1"), 0.1)
        w.write("/cam/info", "sensor_msgs/msg/CameraInfo", ros2.camera_info_msg(0.1, "cam", cam), 0.1)
        w.write("/joint_states", "sensor_msgs/msg/JointState", ros2.joint_state_msg(0.2, ["a", "b"], [0.1, -0.2]), 0.2)
        msg = ros2.distances_msg(
            0.3, ["ee", "l1"], np.eye(3)[:2], np.array([0.06, 0.1]), np.array([0.25, np.inf]), np.eye(3)[1:], rho=0.4
        )
        w.write("/depthguard/distances", "depthguard_msgs/msg/ControlPointDistances", msg, 0.3)
    return depth


def test_mcap_profile_schema_and_encoding(tmp_path):
    from mcap.reader import make_reader

    _write_sample(tmp_path / "r.mcap")
    with open(tmp_path / "r.mcap", "rb") as fh:
        reader = make_reader(fh)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
        assert {c.message_encoding for c in summary.channels.values()} == {"cdr"}
        names = {s.name for s in summary.schemas.values()}
        assert "sensor_msgs/msg/Image" in names and "depthguard_msgs/msg/ControlPointDistances" in names


def test_independent_decoder_reads_every_message(tmp_path):
    """mcap_ros2 parses CDR from the embedded definitions: values must round-trip."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    depth = _write_sample(tmp_path / "r.mcap")
    got = {}
    with open(tmp_path / "r.mcap", "rb") as fh:
        for _, channel, _, msg in make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            got[channel.topic] = msg
    img = got["/cam/depth"]
    assert (img.encoding, img.width, img.height, img.step) == ("16UC1", 8, 6, 16)
    mm = np.frombuffer(bytes(img.data), dtype="<u2").reshape(6, 8)
    assert mm[0, 0] == 0  # no reading
    np.testing.assert_allclose(mm[1:, :] / 1000.0, depth[1:, :], atol=5e-4)
    f32 = np.frombuffer(bytes(got["/cam/depth32"].data), dtype="<f4").reshape(6, 8)
    np.testing.assert_array_equal(f32[1:], depth[1:])
    info = got["/cam/info"]
    assert list(info.k) == [5.0, 0.0, 3.5, 0.0, 5.0, 2.5, 0.0, 0.0, 1.0]  # ROS's principal point: cx - 0.5, cy - 0.5
    assert list(got["/joint_states"].position) == [0.1, -0.2]
    d = got["/depthguard/distances"]
    assert d.rho == 0.4 and [p.name for p in d.points] == ["ee", "l1"]
    assert d.points[0].distance == 0.25 and d.points[1].distance == float("inf")
    assert (d.points[0].direction.x, d.points[0].direction.y) == (0.0, 1.0)
    assert d.header.stamp.sec == 0 and d.header.stamp.nanosec == 300_000_000


def test_rosbags_reads_custom_types_from_the_file(tmp_path):
    """A reader with only the stock Jazzy type store learns depthguard_msgs from the file's schemas."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    _write_sample(tmp_path / "r.mcap")
    with AnyReader([tmp_path / "r.mcap"], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        conns = [c for c in reader.connections if c.topic == "/depthguard/distances"]
        (conn, _, raw) = next(reader.messages(connections=conns))
        msg = reader.deserialize(raw, conn.msgtype)
    assert msg.points[0].name == "ee" and msg.points[0].radius == 0.06


def test_read_messages_and_depth_round_trip(tmp_path):
    depth = _write_sample(tmp_path / "r.mcap")
    msgs = list(read_messages(tmp_path / "r.mcap", topics=["/cam/depth32"]))
    assert len(msgs) == 1 and msgs[0][1] == "sensor_msgs/msg/Image" and msgs[0][2] == pytest.approx(0.1)
    back = ros2.image_to_depth(msgs[0][3])
    assert np.isnan(back[0, 0])
    np.testing.assert_array_equal(back[1:], depth[1:])


def test_bad_bag_and_bad_image_errors_name_the_problem(tmp_path):
    bad = tmp_path / "x.mcap"
    bad.write_bytes(b"not an mcap")
    with pytest.raises(ValueError, match="x.mcap"):
        list(read_messages(bad))
    with pytest.raises(ValueError, match="no such bag"):
        list(read_messages(tmp_path / "missing.mcap"))
    msg = ros2.image_msg(0.0, "c", np.ones((2, 2)))
    msg.encoding = "rgb8"
    with pytest.raises(ValueError, match="rgb8"):
        ros2.image_to_depth(msg)
    msg = ros2.image_msg(0.0, "c", np.ones((2, 2)))
    msg.height = 5
    with pytest.raises(ValueError, match="too few"):
        ros2.image_to_depth(msg)


def test_tf_of_a_camera_pose_matches_the_projection():
    """TF world -> camera optical: a world point mapped by the TF inverse equals R P + t."""
    from scipy.spatial.transform import Rotation

    from depthguard.camera import look_at
    from depthguard.sim.recorder import camera_tf

    R, t = look_at(np.array([2.0, 1.0, 1.5]), np.zeros(3))
    Rw, pw = camera_tf(R, t)
    tf = ros2.tf_msg(0.0, [("world", "cam", Rw, pw)]).transforms[0].transform
    q = [tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w]
    Rq = Rotation.from_quat(q).as_matrix()
    p = np.array([tf.translation.x, tf.translation.y, tf.translation.z])
    P = np.array([0.3, -0.2, 0.5])
    np.testing.assert_allclose(Rq.T @ (P - p), R @ P + t, atol=1e-9)


_SPECIAL = np.array([0.0, -0.0, -1.0, np.nan, np.inf, -np.inf, 1e-40, 3.4e38, 0.5, 7.25], np.float32)


@settings(deadline=None)  # (the first example compiles the decoding kernel on a cold cache)
@given(
    h=st.integers(1, 7),
    w=st.integers(1, 9),
    pad=st.integers(0, 5),
    big=st.booleans(),
    mm=st.booleans(),
    seed=st.integers(0, 2**31 - 1),
)
def test_image_to_depth_reads_every_layout_as_metres_with_nan_for_no_reading(h, w, pad, big, mm, seed):
    """Depth decoding on raw bytes laid out by hand (row padding, both byte orders, 16UC1 millimetres and
    32FC1 metres with 0, negative, NaN, inf and subnormal samples): the metres where the sample is a reading
    (> 0, finite), NaN elsewhere; the expected values come from Python floats, not from the decoder."""
    rng = np.random.default_rng(seed)
    if mm:
        vals = rng.integers(0, 65536, (h, w)).astype(np.uint16)
        vals[rng.random((h, w)) < 0.3] = 0
        want = [[np.float32(x) / np.float32(1000.0) if x > 0 else np.nan for x in row] for row in vals.tolist()]
        enc, item, fmt = "16UC1", 2, "H"
    else:
        vals = rng.choice(_SPECIAL, (h, w)).astype(np.float32)
        want = [[x if (x > 0 and math.isfinite(x)) else np.nan for x in row] for row in vals.tolist()]
        enc, item, fmt = "32FC1", 4, "f"
    order = ">" if big else "<"
    rows = [struct.pack(f"{order}{w}{fmt}", *row) + b"\xab" * pad for row in vals.tolist()]
    msg = ros2.image_msg(0.0, "c", np.ones((h, w)))
    msg.encoding, msg.is_bigendian, msg.step = enc, int(big), w * item + pad
    msg.data = np.frombuffer(b"".join(rows), np.uint8)
    got = ros2.image_to_depth(msg)
    assert got.dtype == np.float32 and got.shape == (h, w) and got.flags.writeable
    np.testing.assert_array_equal(got, np.array(want, np.float32))


@settings(max_examples=200, deadline=None)
@given(t=st.one_of(st.floats(0.0, 2.0**31, exclude_max=True), st.floats(1.6e9, 1.8e9), st.floats(-1e12, 0.0)))
@example(t=1.9999999995)  # (a near-tie that the float product decided the wrong way)
def test_stamps_are_the_nanosecond_nearest_to_the_float(t: float) -> None:
    """Every stamp DepthGuard writes (headers, MCAP log times, the joint-state fast path) comes from
    ``stamp_parts``: the exact value of the float, rounded to the nanosecond (ties either way), negative -> 0.
    Before, ``round(t * 1e9)`` rounded twice: epoch-scale stamps up to 128 ns off."""
    from fractions import Fraction

    from depthguard.io.ros2_types import stamp_parts

    sec, ns = stamp_parts(t)
    assert 0 <= ns < 1_000_000_000 and sec >= 0
    exact = Fraction(max(t, 0.0)) * 10**9
    assert abs(Fraction(sec * 1_000_000_000 + ns) - exact) <= Fraction(1, 2)


@pytest.mark.parametrize("t", [float("nan"), float("inf"), 2.0**31, 1e300])
def test_stamps_beyond_int32_seconds_or_nan_are_refused(t: float) -> None:
    from depthguard.io.ros2_types import stamp_parts

    with pytest.raises(ValueError, match="2\\*\\*31"):
        stamp_parts(t)
    assert stamp_parts(float("-inf")) == (0, 0)
