"""The rmw_zenoh wire format, checked against reference values from outside the project.

References (not computed by DepthGuard's encoder):
* the key expression of ``std_msgs/msg/String`` on ``/chatter`` in domain 0 (issue 15);
* type hashes printed by ``ros2 topic info -v`` on ROS 2 Jazzy for ``sensor_msgs/msg/Image`` and
  ``sensor_msgs/msg/JointState``;
* the liveliness tokens quoted in rmw_zenoh's ``docs/design.md`` (talker / listener in domain 2).

No ROS 2 installation was available: the live test decodes what a :class:`ZenohNode` publishes with a bare
Zenoh session, the ``struct`` module and a fresh rosbags Jazzy type store, exactly as rmw_zenoh would read it.
"""

from __future__ import annotations

import json
import random
import struct
import time

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from depthguard.io import rmw_zenoh as rz
from depthguard.io import ros2

STRING_KEY = (
    "0/chatter/std_msgs::msg::dds_::String_/RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
)
IMAGE_HASH = "RIHS01_d31d41a9a4c4bc8eae9be757b0beed306564f7526c88ea6a4588fb9582527d47"
JOINT_STATE_HASH = "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e"
TALKER_PUB = (
    "@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/std_msgs::msg::dds_::String_/"
    "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18/::,7:,:,:,,"
)
LISTENER_NODE = "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"


def test_key_expressions_match_references():
    assert rz.topic_keyexpr(0, "/chatter", "std_msgs/msg/String") == STRING_KEY
    assert rz.type_hash("sensor_msgs/msg/Image") == IMAGE_HASH
    assert rz.type_hash("sensor_msgs/msg/JointState") == JOINT_STATE_HASH
    k = rz.topic_keyexpr(3, "/camera0/depth/image_raw/", "sensor_msgs/msg/Image")
    assert k == f"3/camera0/depth/image_raw/sensor_msgs::msg::dds_::Image_/{IMAGE_HASH}"
    p = rz.parse_topic_keyexpr(k)
    assert (p.domain, p.topic, p.typename, p.type_hash) == (
        3,
        "/camera0/depth/image_raw",
        "sensor_msgs/msg/Image",
        IMAGE_HASH,
    )


def test_liveliness_tokens_match_rmw_zenoh_design_doc():
    tok = rz.liveliness_token(
        2, "8b20917502ee955ac4476e0266340d5c", 0, 10, "MP", "talker",
        topic="/chatter", typename="std_msgs/msg/String", qos=rz.QoS(depth=7),
    )  # fmt: skip
    assert tok == TALKER_PUB
    assert rz.liveliness_token(2, "aac3178e146ba6f1fc6e6a4085e77f21", 0, 0, "NN", "listener") == LISTENER_NODE
    t = rz.parse_liveliness_token(TALKER_PUB)
    assert (t.kind, t.node, t.topic, t.typename, t.namespace) == (
        "MP",
        "talker",
        "/chatter",
        "std_msgs/msg/String",
        "/",
    )
    # rmw_zenoh's defaults (reliable, volatile, keep last 42) leave the fields empty; best effort is 2.
    assert rz.qos_keyexpr(rz.QoS(depth=42)) == "::,:,:,:,,"
    assert rz.qos_keyexpr(rz.QOS_SENSOR_DATA) == "2::,5:,:,:,,"


@pytest.mark.parametrize(
    "bad",
    ["", "/", "a//b", "cam*", "has space"],
)
def test_bad_topic_names_are_refused(bad):
    with pytest.raises(ValueError, match="topic name"):
        rz.topic_keyexpr(0, bad, "std_msgs/msg/String")


def test_bad_inputs_are_refused():
    with pytest.raises(ValueError, match="domain"):
        rz.topic_keyexpr(-1, "/a", "std_msgs/msg/String")
    with pytest.raises(ValueError, match="pkg/msg/Type"):
        rz.dds_type_name("String")
    with pytest.raises(ValueError, match="33 bytes"):
        rz.decode_attachment(b"\x00" * 32)
    with pytest.raises(ValueError, match="16 bytes"):
        rz.encode_attachment(1, 2, b"\x00" * 15)
    with pytest.raises(ValueError, match="liveliness"):
        rz.parse_liveliness_token("@ros2_lv/0/x")


def test_the_monitor_counts_malformed_node_tokens_and_keeps_going():
    """One malformed ``NN`` token from another participant used to raise out of the monitor's loop."""
    from depthguard.nodes.monitor import live_nodes

    keys = [LISTENER_NODE, "@ros2_lv/x/NN/bad", "@ros2_lv/0/a/0/0/NN/%/%/", TALKER_PUB]
    assert live_nodes(keys) == (["listener"], 2)


@given(st.integers(-(2**63), 2**63 - 1), st.integers(-(2**63), 2**63 - 1), st.binary(min_size=16, max_size=16))
def test_attachment_layout(seq, ts, gid):
    b = rz.encode_attachment(seq, ts, gid)
    assert len(b) == 33
    # the layout read with struct, independently of decode_attachment
    assert struct.unpack("<q", b[0:8])[0] == seq and struct.unpack("<q", b[8:16])[0] == ts
    assert b[16] == 16 and b[17:] == gid
    assert rz.decode_attachment(b) == (seq, ts, gid)


def _ports(n):
    base = random.randint(21000, 29000)
    return [base + i for i in range(n)]


def test_live_publisher_decoded_as_rmw_zenoh_would():
    zenoh = pytest.importorskip("zenoh")
    from rosbags.typesys import Stores, get_typestore

    from depthguard.io import ros2
    from depthguard.io.zenoh_transport import ZenohNode, session_config

    pa, pb = _ports(2)
    node = ZenohNode("cam_test", domain=7, listen=[f"tcp/127.0.0.1:{pa}"], connect=[f"tcp/127.0.0.1:{pb}"])
    raw = zenoh.open(session_config([f"tcp/127.0.0.1:{pb}"], [f"tcp/127.0.0.1:{pa}"]))
    got = []
    key = f"7/cam/depth/sensor_msgs::msg::dds_::Image_/{IMAGE_HASH}"
    sub = raw.declare_subscriber(key, lambda s: got.append((s.payload.to_bytes(), s.attachment.to_bytes())))
    try:
        pub = node.publisher("/cam/depth", "sensor_msgs/msg/Image", rz.QOS_SENSOR_DATA)
        depth = np.array([[0.5, np.nan, 1.25], [2.0, 3.0, 0.75]], dtype=np.float32)
        t_end = time.time() + 8.0
        while len(got) < 2 and time.time() < t_end:
            pub.publish(ros2.image_msg(12.5, "cam_optical", depth, "32FC1"))
            time.sleep(0.1)
        assert len(got) >= 2, "nothing arrived over Zenoh"
        payload, att = got[-1]
        assert payload[:4] == b"\x00\x01\x00\x00"  # CDR little endian encapsulation
        msg = get_typestore(Stores.ROS2_JAZZY).deserialize_cdr(payload, "sensor_msgs/msg/Image")
        assert (msg.height, msg.width, msg.encoding, msg.header.frame_id) == (2, 3, "32FC1", "cam_optical")
        img = np.frombuffer(bytes(msg.data), "<f4").reshape(2, 3)
        np.testing.assert_array_equal(np.isnan(img), np.isnan(depth))
        np.testing.assert_array_equal(img[~np.isnan(img)], depth[~np.isnan(depth)])
        seq0 = struct.unpack("<q", got[0][1][:8])[0]
        seq1, ts = struct.unpack("<qq", att[:16])
        assert len(att) == 33 and att[16] == 16 and seq1 > seq0
        assert abs(ts / 1e9 - time.time()) < 10.0
        # the liveliness tokens seen in the graph, parsed as rmw_zenoh's graph cache does
        toks = [str(r.ok.key_expr) for r in raw.liveliness().get("@ros2_lv/7/**") if r.ok is not None]
        zid = node.zid
        assert f"@ros2_lv/7/{zid}/0/0/NN/%/%/cam_test" in toks
        mp = [t for t in toks if "/MP/" in t]
        assert mp == [
            f"@ros2_lv/7/{zid}/0/1/MP/%/%/cam_test/%cam%depth/sensor_msgs::msg::dds_::Image_/{IMAGE_HASH}/2::,5:,:,:,,"
        ]
        assert att[17:] == rz.entity_gid(mp[0])
    finally:
        sub.undeclare()
        node.close()
        raw.close()


def test_subscription_drops_duplicates_reordered_and_unlisted():
    pytest.importorskip("zenoh")
    from depthguard.io import ros2
    from depthguard.io.zenoh_transport import ZenohNode

    pa, pb = _ports(2)
    rx = ZenohNode("rx", domain=9, listen=[f"tcp/127.0.0.1:{pa}"], connect=[f"tcp/127.0.0.1:{pb}"])
    tx = ZenohNode("friend", domain=9, listen=[f"tcp/127.0.0.1:{pb}"], connect=[f"tcp/127.0.0.1:{pa}"])
    try:
        seen = []
        sub = rx.subscribe(
            "/js", "sensor_msgs/msg/JointState", lambda m, a, t: seen.append(ros2.to_seconds(m.header.stamp))
        )
        pub = tx.publisher("/js", "sensor_msgs/msg/JointState")
        time.sleep(1.5)
        cdr = [ros2.serialize(ros2.joint_state_msg(t, ["a"], [0.0]), "sensor_msgs/msg/JointState") for t in (1, 2, 3)]
        pub.put_cdr(cdr[0])  # seq 1, stamp 1
        pub.put_cdr(cdr[0], seq=1)  # duplicate sequence number
        pub.put_cdr(cdr[2])  # seq 3, stamp 3
        pub.put_cdr(cdr[1])  # seq 4, stamp 2: reordered stamp
        time.sleep(1.0)
        assert seen == [1.0, 3.0]
        assert sub.dropped == {"duplicate or reordered sequence number": 1, "stale or reordered stamp": 1}
        assert sub.missed == 1  # (number 2 never came: the duplicate went out under number 1)
        # a subscription that only accepts node "camera0" ignores "friend" and names it
        sub2 = rx.subscribe("/js2", "sensor_msgs/msg/JointState", lambda m, a, t: seen.append(-1), allowed={"camera0"})
        pub2 = tx.publisher("/js2", "sensor_msgs/msg/JointState")
        time.sleep(1.0)
        pub2.put_cdr(cdr[0])
        time.sleep(0.5)
        assert -1 not in seen and sub2.dropped == {"publisher not allowed": 1}
        assert sub2.rejected_publishers == {"friend"}
    finally:
        tx.close()
        rx.close()


def test_a_pull_subscription_waits_for_drain_keeps_the_newest_and_filters_alike():
    """``pull``: nothing runs until :meth:`drain`, which runs the callback in the caller's thread on the newest
    ``pull`` samples, oldest first, through the same filter (a duplicate and a reordered stamp dropped)."""
    pytest.importorskip("zenoh")
    import threading

    from depthguard.io.zenoh_transport import ZenohNode

    pa, pb = _ports(2)
    rx = ZenohNode("rx", domain=12, listen=[f"tcp/127.0.0.1:{pa}"], connect=[f"tcp/127.0.0.1:{pb}"])
    tx = ZenohNode("tx", domain=12, listen=[f"tcp/127.0.0.1:{pb}"], connect=[f"tcp/127.0.0.1:{pa}"])
    try:
        seen, threads = [], set()

        def on_js(m, a, t):
            seen.append(ros2.to_seconds(m.header.stamp))
            threads.add(threading.get_ident())

        sub = rx.subscribe("/js", "sensor_msgs/msg/JointState", on_js, pull=5)
        pub = tx.publisher("/js", "sensor_msgs/msg/JointState")
        time.sleep(1.5)
        cdr = {
            t: ros2.serialize(ros2.joint_state_msg(t, ["a"], [0.0]), "sensor_msgs/msg/JointState") for t in range(1, 9)
        }
        pub.put_cdr(cdr[1])
        pub.put_cdr(cdr[2])
        time.sleep(0.5)
        assert seen == []  # (waiting in the ring)
        assert sub.drain() == 2 and seen == [1.0, 2.0] and threads == {threading.get_ident()}
        assert sub.drain() == 0
        for t in (3, 4, 5, 6, 7):
            pub.put_cdr(cdr[t])
        pub.put_cdr(cdr[7], seq=pub.seq)  # a duplicate sequence number
        pub.put_cdr(cdr[6])  # a reordered stamp
        time.sleep(0.5)
        assert sub.drain() == 5  # the ring's five newest: 5, 6, 7, the duplicate, the reordered one
        assert seen == [1.0, 2.0, 5.0, 6.0, 7.0]
        assert sub.dropped == {"duplicate or reordered sequence number": 1, "stale or reordered stamp": 1}
        assert sub.missed == 3  # (3 and 4, pushed out of the full ring; 8: the duplicate went out under 7)
        plain = rx.subscribe("/js3", "sensor_msgs/msg/JointState", on_js)
        assert plain.drain() == 0  # (a callback subscription has nothing to drain)
    finally:
        tx.close()
        rx.close()


@given(
    st.lists(
        st.tuples(st.integers(0, 3), st.integers(-5, 30), st.integers(0, 40), st.booleans()), min_size=1, max_size=40
    )
)
def test_filter_never_passes_duplicates_reordered_or_stale(samples):
    """Random interleavings of publishers, sequence numbers, stamps and corrupt payloads: what passes has
    strictly increasing stamps and, per publisher, strictly increasing sequence numbers."""
    from depthguard.io import ros2
    from depthguard.io.zenoh_transport import SampleFilter

    f = SampleFilter("sensor_msgs/msg/JointState")
    passed = []
    for pub, seq, stamp, corrupt in samples:
        gid = bytes([pub]) * 16
        cdr = ros2.serialize(ros2.joint_state_msg(float(stamp), ["a"], [0.0]), "sensor_msgs/msg/JointState")
        got = f.accept(rz.encode_attachment(seq, 0, gid), cdr[:7] if corrupt else cdr)
        if got is not None:
            passed.append((pub, seq, ros2.to_seconds(got[0].header.stamp)))
    stamps = [s for _, _, s in passed]
    assert all(a < b for a, b in zip(stamps, stamps[1:], strict=False))
    for p in {p for p, _, _ in passed}:
        seqs = [s for q, s, _ in passed if q == p]
        assert all(a < b for a, b in zip(seqs, seqs[1:], strict=False))
    assert sum(f.dropped.values()) == len(samples) - len(passed)
    # an allow-list with no way to name the publisher lets nothing through
    g = SampleFilter("sensor_msgs/msg/JointState", who=lambda gid: None, allowed={"controller"})
    assert g.accept(rz.encode_attachment(1, 0, b"\x00" * 16), cdr) is None
    assert g.rejected_publishers == {"None"}


@given(
    delivered=st.lists(st.booleans(), min_size=1, max_size=60),
    corrupt=st.lists(st.booleans(), min_size=60, max_size=60),
    resent=st.lists(st.integers(0, 59), max_size=10),
)
def test_missed_counts_the_samples_that_never_came(delivered, corrupt, resent):
    """One publisher sends sequence numbers 1..N; some never arrive, some arrive corrupt, some arrive twice.
    ``missed`` is the number that never arrived between the first and the last that did; a corrupt or repeated
    sample counts in ``dropped`` only."""
    from depthguard.io import ros2
    from depthguard.io.zenoh_transport import SampleFilter

    f = SampleFilter("sensor_msgs/msg/JointState")
    gid = b"\x07" * 16
    came = [i + 1 for i, d in enumerate(delivered) if d]
    arrivals = list(came)
    for k in resent:  # (a copy of an earlier sample right after a later one)
        if k < len(arrivals):
            arrivals.insert(k + 1, arrivals[k])
    for seq in arrivals:
        cdr = ros2.serialize(ros2.joint_state_msg(float(seq), ["a"], [0.0]), "sensor_msgs/msg/JointState")
        f.accept(rz.encode_attachment(seq, 0, gid), cdr[:7] if corrupt[seq - 1] else cdr)
    expected = (came[-1] - came[0] + 1 - len(came)) if came else 0
    assert f.missed == expected


def test_large_images_cross_in_shared_memory_and_arrive_intact():
    """Two nodes on one host: Zenoh carries a 640x480 depth image (1.2 MB of CDR) through its shared memory
    (its default transport optimisation for messages over 3 KB), bit for bit; a joint state (small) goes
    over the socket. The node latency figures (BENCHMARKS.md) rely on this."""
    pytest.importorskip("zenoh")
    from depthguard.io import ros2
    from depthguard.io.zenoh_transport import ZenohNode

    pa, pb = _ports(2)
    rx = ZenohNode("rx", domain=11, listen=[f"tcp/127.0.0.1:{pa}"], connect=[f"tcp/127.0.0.1:{pb}"])
    tx = ZenohNode("tx", domain=11, listen=[f"tcp/127.0.0.1:{pb}"], connect=[f"tcp/127.0.0.1:{pa}"])
    try:
        images, joints = [], []
        sub_i = rx.subscribe("/img", "sensor_msgs/msg/Image", lambda m, a, t: images.append(ros2.image_to_depth(m)))
        sub_j = rx.subscribe("/js", "sensor_msgs/msg/JointState", lambda m, a, t: joints.append(m))
        pub_i = tx.publisher("/img", "sensor_msgs/msg/Image")
        pub_j = tx.publisher("/js", "sensor_msgs/msg/JointState")
        depth = np.random.default_rng(3).uniform(0.5, 4.5, (480, 640)).astype(np.float32)
        depth[::7, ::5] = np.nan
        t_end = time.time() + 8.0
        k = 0
        while (len(images) < 4 or len(joints) < 3) and time.time() < t_end:
            k += 1
            pub_i.publish(ros2.image_msg(float(k), "cam", depth, "32FC1"))
            pub_j.publish(ros2.joint_state_msg(float(k), ["a"], [0.0]))
            time.sleep(0.1)
        assert len(images) >= 4 and len(joints) >= 3, "nothing arrived over Zenoh"
        np.testing.assert_array_equal(images[-1], depth)  # NaN where NaN, every other value exact
        assert sub_i.received - 1 <= sub_i.shm_received  # (the first may precede the lazily created pool)
        assert sub_j.shm_received == 0
    finally:
        tx.close()
        rx.close()


def test_depthguard_msgs_package_builds_the_types_the_nodes_publish(tmp_path, capsys):
    """``depthguard ros2-msgs``: the ROS 2 interface package that a workspace builds to echo the nodes' own
    topics. Its ``.msg`` files, parsed by a fresh rosbags Jazzy store (as rosidl would read them), give the
    same fields and so the same RIHS01 type hashes as the key expressions the nodes publish on; its
    package.xml and CMakeLists.txt name every message and dependency. (No ROS 2 here: not built by colcon.)"""
    import xml.etree.ElementTree as ET

    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    from depthguard.cli import main
    from depthguard.io.ros2 import DEPTHGUARD_MSGS

    assert main(["ros2-msgs", "--out", str(tmp_path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    pkg = tmp_path / "depthguard_msgs"
    ts = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    for f in sorted((pkg / "msg").glob("*.msg")):
        types.update(get_types_from_msg(f.read_text(), f"depthguard_msgs/msg/{f.stem}"))
    ts.register(types)
    assert set(types) == set(DEPTHGUARD_MSGS)
    for name in DEPTHGUARD_MSGS:
        assert ts.hash_rihs01(name) == rz.type_hash(name) == out["type_hashes"][name]
        assert rz.topic_keyexpr(0, "/x", name).endswith(out["type_hashes"][name])
    root = ET.parse(pkg / "package.xml").getroot()
    assert root.get("format") == "3" and root.findtext("name") == "depthguard_msgs"
    assert {e.text for e in root.findall("depend")} == {"std_msgs", "geometry_msgs"}
    assert root.findtext("member_of_group") == "rosidl_interface_packages"
    cmake = (pkg / "CMakeLists.txt").read_text()
    assert all(f'"msg/{n.rsplit("/", 1)[1]}.msg"' in cmake for n in DEPTHGUARD_MSGS)
    assert "DEPENDENCIES std_msgs geometry_msgs" in cmake
    assert main(["ros2-msgs", "--out", str(tmp_path)]) == 2  # (an existing package is not overwritten)
    assert "--overwrite" in capsys.readouterr().err
    assert main(["ros2-msgs", "--out", str(tmp_path), "--overwrite", "--json"]) == 0
