"""The JointState fast path (``io/joint_state_cdr.py``) against ``rosbags``' generic CDR (de)serialiser, and the
joint reordering (``ros2.joints_in_order``) against a plain reference written here."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from depthguard.io import ros2
from depthguard.io.joint_state_cdr import JointStateEncoder, decode_joint_state, joint_state_cdr

_TYPE = "sensor_msgs/msg/JointState"
_names = st.lists(
    st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00"), max_size=12), max_size=9
)
_floats = st.floats(allow_nan=True, allow_infinity=True)


def _rosbags_bytes(msg, little_endian: bool = True) -> bytes:
    return bytes(ros2.typestore().serialize_cdr(msg, _TYPE, little_endian=little_endian))


def _rosbags_msg(data: bytes):
    return ros2.typestore().deserialize_cdr(data, _TYPE)


def _same_floats(a, b) -> bool:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return a.shape == b.shape and a.tobytes() == b.tobytes()  # (bit for bit: NaN, -0.0)


def _same_msg(a, b) -> bool:
    return (
        (a.header.stamp.sec, a.header.stamp.nanosec, a.header.frame_id)
        == (b.header.stamp.sec, b.header.stamp.nanosec, b.header.frame_id)
        and list(a.name) == list(b.name)
        and all(_same_floats(getattr(a, f), getattr(b, f)) for f in ("position", "velocity", "effort"))
    )


@st.composite
def _joint_states(draw):
    names = draw(_names)
    n = len(names)
    q = np.array(draw(st.lists(_floats, min_size=n, max_size=n)), float)
    qd = np.array(draw(st.lists(_floats, min_size=n, max_size=n)), float) if draw(st.booleans()) else None
    t = draw(st.floats(-5.0, 2.0e9))
    frame_id = draw(st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00"), max_size=10))
    return t, names, q, qd, frame_id


@settings(max_examples=300, deadline=None)
@given(_joint_states())
def test_encoder_writes_the_bytes_of_rosbags(js):
    t, names, q, qd, frame_id = js
    ref = _rosbags_bytes(ros2.joint_state_msg(t, names, q, qd, frame_id))
    assert joint_state_cdr(t, names, q, qd, frame_id) == ref
    assert JointStateEncoder(names, qd is not None, frame_id).encode(t, q, qd) == ref


def test_encoder_refuses_values_that_do_not_fit_its_joints():
    enc = JointStateEncoder(["a", "b"])
    with pytest.raises(ValueError, match="positions: expected 2 values"):
        enc.encode(0.0, np.zeros(3), np.zeros(2))
    with pytest.raises(ValueError, match="velocities: expected 2 values"):
        enc.encode(0.0, np.zeros(2), np.zeros(1))
    with pytest.raises(ValueError, match="velocities: this encoder carries velocities"):
        enc.encode(0.0, np.zeros(2))
    with pytest.raises(ValueError, match="carries none"):
        JointStateEncoder(["a"], velocities=False).encode(0.0, np.zeros(1), np.zeros(1))
    with pytest.raises(ValueError, match="NUL"):
        JointStateEncoder(["a\x00b"])


@settings(max_examples=300, deadline=None)
@given(_joint_states(), st.lists(_floats, max_size=4), st.booleans())
def test_decoder_reads_what_rosbags_reads(js, effort, little_endian):
    t, names, q, qd, frame_id = js
    msg = ros2.joint_state_msg(t, names, q, qd, frame_id)
    if len(effort) == len(names):  # (the builder leaves effort empty: give it values when they fit)
        msg.effort = np.array(effort, float)
    data = _rosbags_bytes(msg, little_endian)
    got = decode_joint_state(data)
    assert got is not None, "the canonical layout must take the fast path"
    assert _same_msg(got, _rosbags_msg(data))
    assert _same_msg(ros2.deserialize(data, _TYPE), got)
    got.position[:] = 1.0  # (writable, and a copy: the payload's bytes stay as they were)
    assert _same_msg(decode_joint_state(data), _rosbags_msg(data))


@settings(max_examples=400, deadline=None)
@given(_joint_states(), st.data())
def test_decoder_on_damaged_bytes_agrees_with_rosbags_or_leaves_it_the_payload(js, data):
    """Truncated, lengthened or overwritten payloads: the fast path either declines (None) or returns the
    message that ``rosbags`` decodes from the same bytes; it never raises."""
    t, names, q, qd, frame_id = js
    raw = bytearray(_rosbags_bytes(ros2.joint_state_msg(t, names, q, qd, frame_id)))
    how = data.draw(st.sampled_from(["truncate", "extend", "overwrite"]))
    if how == "truncate":
        raw = raw[: data.draw(st.integers(0, len(raw) - 1))]
    elif how == "extend":
        raw += bytes(data.draw(st.lists(st.integers(0, 255), min_size=1, max_size=9)))
    else:
        for _ in range(data.draw(st.integers(1, 4))):
            raw[data.draw(st.integers(0, len(raw) - 1))] = data.draw(st.integers(0, 255))
    got = decode_joint_state(bytes(raw))
    if got is None:
        return
    try:
        ref = _rosbags_msg(bytes(raw))
    except Exception as exc:  # noqa: BLE001
        pytest.fail(f"the fast path decoded bytes that rosbags refuses ({exc!r})")
    assert _same_msg(got, ref)


def test_decoder_declines_other_encapsulations_and_the_generic_path_takes_them():
    data = _rosbags_bytes(ros2.joint_state_msg(1.0, ["a"], np.ones(1), np.zeros(1)))
    assert decode_joint_state(b"\x00\x01\x00\x00") is None
    assert decode_joint_state(b"\x00\x02" + data[2:]) is None  # (PL_CDR_BE: not the canonical layout)
    assert decode_joint_state(data[:2] + b"\x00\x01" + data[4:]) is None  # (options set)
    with pytest.raises(Exception):  # noqa: B017 - rosbags' own error: the sample filter counts it as malformed
        ros2.deserialize(data[:-3], _TYPE)


def test_decoder_tells_apart_messages_with_other_names():
    """The names of the last message are reused only when their bytes match: alternate lists of equal
    length, and a list whose bytes start like the last one's."""
    for names in (["j1", "j2"], ["k1", "k2"], ["j1", "j2"], ["j1", "j22"], ["j1"], ["j1", "j2", "j3"]):
        data = joint_state_cdr(3.0, names, np.arange(len(names), dtype=float), np.zeros(len(names)))
        assert decode_joint_state(data).name == names


def _reference_order(msg, names):
    """``joints_in_order`` as its docstring says it, written plainly."""
    got = [str(x) for x in msg.name]
    q, qd = list(map(float, msg.position)), list(map(float, msg.velocity))
    if got:
        if len(q) != len(got) or len(qd) not in (0, len(got)):
            raise ValueError("lengths")
        for n in names:
            if n not in got:
                raise ValueError("missing")
        q = [q[got.index(n)] for n in names]
        qd = [qd[got.index(n)] for n in names] if qd else []
    if len(q) != len(names) or len(qd) not in (0, len(names)):
        raise ValueError("count")
    if not all(math.isfinite(x) for x in q + qd):
        raise ValueError("finite")
    return np.array(q), (np.array(qd) if qd else None)


@settings(max_examples=400, deadline=None)
@given(st.data())
def test_joints_in_order_matches_the_reference(data):
    model = ["a1", "a2", "a3", "a4"]
    kept = data.draw(st.lists(st.sampled_from(model), unique=True, min_size=3, max_size=4))
    extra = data.draw(st.lists(st.sampled_from(["gripper", "a5"]), unique=True, max_size=2))
    got = data.draw(st.permutations(kept + extra) | st.just([]))
    n = data.draw(st.sampled_from([len(got), len(got), len(got) + 1, 4]))
    q = [0.5 + i for i in range(n)]  # (distinct values: a wrong order shows)
    nv = data.draw(st.sampled_from([0, n, n, n - 1]))
    assume(nv >= 0)
    qd = [-0.25 - i for i in range(nv)]
    for values in (q, qd):  # a non-finite value somewhere, sometimes
        if values and data.draw(st.booleans()):
            values[data.draw(st.integers(0, len(values) - 1))] = data.draw(st.sampled_from([math.nan, -math.inf]))
    msg = ros2.joint_state_msg(1.0, got, np.array(q), None)
    msg.velocity = np.array(qd, float)
    try:
        want = _reference_order(msg, model)
    except ValueError:
        with pytest.raises(ValueError):
            ros2.joints_in_order(msg, model)
        return
    q_got, qd_got = ros2.joints_in_order(msg, model)
    assert _same_floats(q_got, want[0])
    assert (qd_got is None) == (want[1] is None)
    if want[1] is not None:
        assert _same_floats(qd_got, want[1])
    q_got[:] = 0.0  # (a copy: the message keeps its values)
    assert _same_floats(msg.position, q)
