"""What the nodes do with messages that pass the wire format but that they cannot use (the wave's hardening).

Any peer that mutual TLS admits may publish images and joint states (only distances and joint commands are
protected), and a ROS 2 camera driver may send any ``sensor_msgs/Image``. So:

* a header stamp far in the future must not poison a subscription's stamp order (one such sample made every
  later joint state "stale" until the wall clock caught up: an arm held for an hour by one message);
* a node callback that raises (an image of another encoding...) is counted as a drop, never raised into
  Zenoh's thread (which printed a traceback per sample and counted nothing);
* the distance node's work on a frame set and the camera node's preparation of a frame either answer or
  raise ``ValueError`` whatever the image's size, encoding, layout or content (a 100x100 image once stopped
  the distance node: the camera scaling raised outside the node's guard), and a good frame set after bad
  ones gets exactly the answer of a fresh node.

Real processes under the same faults: ``tests/test_nodes_faults.py``.
"""

from __future__ import annotations

import random
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from depthguard.io import rmw_zenoh as rz
from depthguard.io import ros2
from depthguard.io.sample_filter import MAX_FUTURE_S, SampleFilter

ROOT = Path(__file__).resolve().parents[1]
NOW = 1.8e9  # the receiver's clock in the filter tests (s since the epoch)


def _js(stamp: float) -> bytes:
    return ros2.serialize(ros2.joint_state_msg(stamp, ["a"], [0.0]), "sensor_msgs/msg/JointState")


def test_a_stamp_in_the_future_is_dropped_and_does_not_hold_later_samples():
    f = SampleFilter("sensor_msgs/msg/JointState")
    gid = b"\x01" * 16
    assert f.accept(rz.encode_attachment(1, 0, gid), _js(NOW), now=NOW) is not None
    assert f.accept(rz.encode_attachment(2, 0, gid), _js(NOW + 3600.0), now=NOW) is None  # an hour ahead
    assert f.dropped == {"stamp in the future": 1}
    assert f.accept(rz.encode_attachment(3, 0, gid), _js(NOW + 0.001), now=NOW + 0.001) is not None
    # within the allowance it is taken (the controller's own check then refuses it for a moment)
    assert f.accept(rz.encode_attachment(4, 0, gid), _js(NOW + 0.9 * MAX_FUTURE_S), now=NOW + 0.002) is not None


@given(
    st.lists(
        st.tuples(st.integers(0, 3), st.integers(-5, 60), st.floats(-100.0, 7200.0), st.booleans()),
        min_size=1,
        max_size=40,
    )
)
def test_no_sample_sequence_holds_a_subscription_past_the_future_allowance(samples):
    """Random publishers, sequence numbers and stamps up to two hours ahead of the receiver's clock: what
    passes is never more than ``MAX_FUTURE_S`` ahead and strictly increasing, every drop is counted, and
    ``MAX_FUTURE_S`` later a fresh sample stamped with the receiver's clock is taken, whatever came before."""
    f = SampleFilter("sensor_msgs/msg/JointState")
    passed = []
    for pub, seq, ahead, corrupt in samples:
        cdr = _js(NOW + ahead)
        got = f.accept(rz.encode_attachment(seq, 0, bytes([pub]) * 16), cdr[:9] if corrupt else cdr, now=NOW)
        if got is not None:
            passed.append(ros2.to_seconds(got[0].header.stamp))
    assert all(s <= NOW + MAX_FUTURE_S for s in passed)
    assert all(a < b for a, b in zip(passed, passed[1:], strict=False))
    assert sum(f.dropped.values()) == len(samples) - len(passed)
    later = NOW + MAX_FUTURE_S + 0.01
    assert f.accept(rz.encode_attachment(1, 0, b"\x09" * 16), _js(later), now=later) is not None


def test_a_callback_error_is_counted_and_never_raised_into_zenoh(capfd):
    pytest.importorskip("zenoh")
    from depthguard.io.zenoh_transport import ZenohNode

    pa = random.randint(21000, 29000)
    rx = ZenohNode("rx", domain=7, listen=[f"tcp/127.0.0.1:{pa}"], connect=[])
    tx = ZenohNode("tx", domain=7, listen=[], connect=[f"tcp/127.0.0.1:{pa}"])
    try:
        got = []
        sub = rx.subscribe("/img", "sensor_msgs/msg/Image", lambda m, a, t: got.append(ros2.image_to_depth(m)))
        pub = tx.publisher("/img", "sensor_msgs/msg/Image")
        time.sleep(1.5)
        rgb = ros2.image_msg(time.time(), "c", np.ones((4, 6)))
        rgb.encoding = "rgb8"
        pub.publish(rgb)
        pub.publish(ros2.image_msg(time.time(), "c", np.ones((4, 6), np.float32), "32FC1"))
        end = time.time() + 5.0
        while not got and time.time() < end:
            time.sleep(0.05)
        assert len(got) == 1 and got[0].shape == (4, 6)  # the good image after the bad one
        assert sub.dropped == {"refused by the node (ValueError)": 1}
        assert "not a depth encoding" in sub.filter.last_refusal
        rgb.header = ros2.header(time.time(), "c")
        pub.publish(rgb)  # the same refusal again: counted, not said again
        end = time.time() + 5.0
        while sub.dropped["refused by the node (ValueError)"] < 2 and time.time() < end:
            time.sleep(0.05)
        assert sub.dropped == {"refused by the node (ValueError)": 2}
    finally:
        tx.close()
        rx.close()
    err = capfd.readouterr().err
    assert "Traceback" not in err
    said = [x for x in err.splitlines() if "refused a message on /img" in x]
    assert len(said) == 1 and "not a depth encoding" in said[0] and said[0].startswith("depthguard rx:")


# ---------------------------------------------------------------- images of every kind through the nodes' work

_SIZES = [(160, 120), (320, 240), (100, 100), (0, 0), (1, 1), (4, 3), (8, 6), (161, 120), (120, 160), (2, 1)]
_ENCODINGS = ["32FC1", "16UC1", "mono16", "mono8", "rgb8", "32FC3", "", "32fc1"]
_VALUES = np.array([0.0, -1.0, np.nan, np.inf, -np.inf, 1e-30, 3e38, 0.3, 1.2, 2.5, 6.0], np.float32)


@st.composite
def images(draw, stamp: float, mask: bool = False, size: tuple[int, int] | None = None):
    """A ``sensor_msgs/Image`` that the wire format accepts: any size (``size`` (width, height) more often
    than not), encoding, byte order, row step and data length, samples from readings to NaN, inf, negative
    and huge values; more often a usable one than not."""
    scaled = st.sampled_from([(160, 120), (320, 240), (640, 480), (8, 6), (4, 3), (32, 24)])  # (the cell's 4:3)
    sizes = st.one_of(scaled, st.sampled_from(_SIZES), st.tuples(st.integers(0, 40), st.integers(0, 40)))
    w, h = draw(sizes if size is None else st.one_of(st.just(size), st.just(size), sizes))
    rng = np.random.default_rng(draw(st.integers(0, 2**31 - 1)))
    if mask:
        msg = ros2.image_msg(stamp, "c", np.zeros((1, 1)), "16UC1")
        data = (rng.random((h, w)) < 0.3).astype(np.uint8) * 255
        msg.height, msg.width, msg.encoding, msg.step = h, w, draw(st.sampled_from(["mono8", "mono8", "rgb8"])), w
        msg.data = data.ravel()
    else:
        enc = draw(st.one_of(st.sampled_from(["32FC1", "16UC1"]), st.sampled_from(_ENCODINGS)))
        vals = rng.choice(_VALUES, (h, w))
        if enc.upper() in ("16UC1", "MONO16"):  # (millimetres; 0 = no reading)
            mm = np.nan_to_num(vals.astype(float) * 1000.0, nan=0.0, posinf=65535.0, neginf=0.0)
            mm = mm.clip(0, 65535).astype(np.uint16)
            msg = ros2.image_msg(stamp, "c", mm, "16UC1")
        else:
            msg = ros2.image_msg(stamp, "c", np.ones((max(h, 1), max(w, 1))), "32FC1")
            msg.height, msg.width, msg.step = h, w, 4 * w
            msg.data = np.frombuffer(vals.astype("<f4").tobytes(), np.uint8)  # (NaN, inf, negative as they are)
        msg.encoding = enc
        msg.is_bigendian = int(draw(st.booleans()))
    raw = bytes(np.asarray(msg.data, np.uint8))
    cut = draw(st.sampled_from(["exact"] * 6 + ["short", "long", "step0", "step_short"]))
    if cut == "short" and raw:
        raw = raw[: rng.integers(0, len(raw))]
    elif cut == "long":
        raw = raw + bytes(rng.integers(0, 256, rng.integers(1, 64), dtype=np.uint8))
    elif cut == "step0":
        msg.step = 0
    elif cut == "step_short":
        msg.step = max(0, int(msg.step) - 1)
    msg.data = np.frombuffer(raw, np.uint8)
    return msg


@pytest.fixture(scope="module")
def hexagon():
    """The simulated hexagon cell at 160x120: one good frame set, its joint state and a fresh node's answer."""
    pytest.importorskip("mujoco")
    from depthguard.io.cellfile import read_cell
    from depthguard.nodes.bench import _frames
    from depthguard.nodes.distance import FrameSetWork
    from depthguard.runner.carried import check_camera_parents
    from depthguard.runner.chain import cell_control_points, load_cell_robot

    cell = read_cell(ROOT / "examples/cells/sim-hexagon.toml")
    _, sets = _frames(True, cell, 1)
    q, depths, masks = sets[0]
    model = load_cell_robot(cell)
    points = cell_control_points(cell, model)
    carried = check_camera_parents(cell, model)

    def work():
        return FrameSetWork(cell, [c.build() for c in cell.cameras], points, carried)

    ref = work().distances(list(depths), list(masks), q, {}, q)
    return {"cell": cell, "model": model, "q": q, "depths": depths, "masks": masks, "work": work, "ref": ref}


def _feed(fs, n: str, msg, mask: bool) -> bool:
    """One message into the distance node's pairing, as its subscription delivers it; False when the node
    refuses it (the subscription counts that)."""
    att = rz.Attachment(1, int(time.time_ns()), b"\x00" * 16)
    try:
        (fs.on_mask if mask else fs.on_depth)(n)(msg, att, time.time_ns())
    except ValueError:
        return False
    return True


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_distance_node_work_answers_or_refuses_any_frame_set(hexagon, data):
    """Random images for camera0 (depth and mask) beside camera1's good frame, through the node's pairing
    and :class:`FrameSetWork`: a ``ValueError`` (the node skips the set) or distances that are never NaN nor
    negative; and the good frame set next gets exactly the answer of a fresh node (no state of the bad set
    lingers in the reused distance stage)."""
    from depthguard.nodes.distance import _FrameSets

    h = hexagon
    work = h.setdefault("shared", h["work"]())  # (one node for all examples, as in a long run)
    stamp = h.setdefault("stamp", [100.0])
    stamp[0] += 1.0
    fs = _FrameSets(["camera0", "camera1"], h["model"].joint_names)
    depth = data.draw(images(stamp[0]))
    ok_d = _feed(fs, "camera0", depth, False)
    ok_m = _feed(fs, "camera0", data.draw(images(stamp[0], mask=True, size=(depth.width, depth.height))), True)
    good = ros2.image_msg(stamp[0], "camera1", h["depths"][1], "32FC1")
    assert _feed(fs, "camera1", good, False) and _feed(fs, "camera1", ros2.mask_msg(stamp[0], "c", h["masks"][1]), True)
    if ok_d and ok_m:
        assert set(fs.ready) == {"camera0", "camera1"}
        sets = [fs.ready.pop(n) for n in ("camera0", "camera1")]
        try:
            got = work.distances([s[1] for s in sets], [s[2] for s in sets], h["q"], {}, h["q"])
        except ValueError:
            got = None
        if got is not None:
            d = np.asarray(got[1].distance)
            assert not np.isnan(d).any() and (d >= 0).all(), d
    again = work.distances(list(h["depths"]), list(h["masks"]), h["q"], {}, h["q"])
    for a, b in zip(again[1], h["ref"][1], strict=True):
        np.testing.assert_array_equal(a, b)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_camera_node_prepares_or_refuses_any_image(hexagon, data):
    """The camera node's preparation of a raw image (decoding, camera scaling, self-filter) on random
    images: a ``ValueError`` (the node logs ``bad_frame`` and skips it) or a depth and a robot mask of the
    same size, the mask boolean."""
    from depthguard.nodes.camera import prepare_frame

    cc = hexagon["cell"].cameras[0]
    msg = data.draw(images(10.0))
    try:
        depth, mask = prepare_frame(msg, cc.build(), cc, hexagon["model"], hexagon["q"])
    except ValueError:
        return
    assert depth.shape == mask.shape == (int(msg.height), int(msg.width)) and mask.dtype == np.bool_


@settings(deadline=None)  # (the first example loads the image decoding kernel)
@given(
    st.lists(st.floats(0.0, 10.0), min_size=2, max_size=2),
    st.lists(st.floats(0.0, 10.0), min_size=1, max_size=5),
)
def test_distances_carry_the_age_of_the_joint_state_they_were_computed_at(frame_stamps, joint_stamps):
    """The distance node places the control spheres at the newest joint state; its distances are stamped with
    the oldest of the frames' stamps and that joint state's, so distances from joint states that stopped
    coming (while frames still come) age and go stale at the controller like distances from old frames."""
    from depthguard.nodes.distance import _FrameSets

    fs = _FrameSets(["camera0", "camera1"], ["a", "b"])
    att = rz.Attachment(1, 0, b"\x00" * 16)
    for t in joint_stamps:  # (in arrival order; the subscription has already dropped stamps going back)
        fs.on_js(ros2.joint_state_msg(100.0 + t, ["a", "b"], [t, t], [0.0, 0.0]), att, 0)
    for n, t in zip(fs.names, frame_stamps, strict=True):
        fs.on_depth(n)(ros2.image_msg(100.0 + t, n, np.ones((3, 4)), "32FC1"), att, 0)
        fs.on_mask(n)(ros2.mask_msg(100.0 + t, n, np.zeros((3, 4), bool)), att, 0)
    sets, q, t_data, _, _ = fs.take([])
    newest = joint_stamps[-1]
    assert q.tolist() == [newest, newest]
    assert t_data == pytest.approx(100.0 + min(*frame_stamps, newest), abs=1e-6)
    assert fs.take([]) is None  # (each frame set is used once)


@given(st.integers(0, 9), st.integers(0, 9), st.integers(0, 4), st.integers(0, 2**31 - 1))
def test_robot_masks_cross_the_wire_bit_for_bit(h, w, pad, seed):
    """``mask_msg`` then ``image_to_mask`` (rows padded to ``step`` by another writer, non-zero bytes of any
    value as robot pixels) gives the mask back; a row step shorter than a row is refused, not misread."""
    mask = np.random.default_rng(seed).random((h, w)) < 0.4
    np.testing.assert_array_equal(ros2.image_to_mask(ros2.mask_msg(1.0, "c", mask)), mask)
    msg = ros2.mask_msg(1.0, "c", mask)
    rows = np.zeros((h, w + pad), np.uint8)
    rows[:, :w] = np.where(mask, np.random.default_rng(seed).integers(1, 256, (h, w)), 0)
    msg.step, msg.data = w + pad, rows.ravel()
    np.testing.assert_array_equal(ros2.image_to_mask(msg), mask)
    if w > 1 and h > 0:
        msg.step = w - 1
        with pytest.raises(ValueError, match="step"):
            ros2.image_to_mask(msg)


@settings(deadline=None)  # (the first example loads the image decoding kernel)
@given(
    st.lists(st.tuples(st.integers(0, 1), st.booleans(), st.integers(0, 3), st.booleans()), max_size=120),
    st.integers(0, 2**31 - 1),
    st.integers(0, 60),
)
def test_frame_sets_pair_depth_and_mask_of_one_stamp_whatever_the_arrival_order(events, seed, lone):
    """The distance node's pairing under any interleaving of the two cameras' depth and mask topics (each
    topic's stamps increasing, as its subscription lets them through, with gaps: dropped messages), with
    frame sets taken at random moments: every camera's depth and mask in a taken set carry the same stamp
    (each image encodes its stamp), no frame is used twice (stamps strictly increase per camera), and the
    messages waiting for their partner stay bounded (``lone`` depths of camera1 first: its masks lost).
    """
    from depthguard.nodes.distance import _UNPAIRED_MAX, _FrameSets

    fs = _FrameSets(["camera0", "camera1"], ["a"])
    fs.on_js(ros2.joint_state_msg(0.0, ["a"], [0.0]), rz.Attachment(1, 0, b"\x00" * 16), 0)
    rng = np.random.default_rng(seed)
    next_stamp = {(c, m): 1 for c in (0, 1) for m in (False, True)}
    last_taken = {0: 0.0, 1: 0.0}
    att = rz.Attachment(1, 0, b"\x00" * 16)
    events = [(1, False, 0, False)] * lone + list(events)
    for cam, is_mask, gap, take in events:
        n = fs.names[cam]
        t = next_stamp[cam, is_mask] + gap  # (gap > 0: the messages in between were lost)
        next_stamp[cam, is_mask] = t + 1
        if is_mask:
            fs.on_mask(n)(ros2.mask_msg(float(t), n, (np.arange(12).reshape(3, 4) % (t % 5 + 2)) == 0), att, 0)
        else:
            fs.on_depth(n)(ros2.image_msg(float(t), n, np.full((3, 4), float(t), np.float32), "32FC1"), att, 0)
        for d in (fs.depth[n], fs.mask[n], fs.recv[n]):
            assert len(d) <= _UNPAIRED_MAX
        if take or rng.random() < 0.1:
            got = fs.take([])
            if got is None:
                continue
            sets, _, t_data, _, _ = got
            for k, (stamp, depth, mask, _, _) in enumerate(sets):
                assert np.all(depth == np.float32(stamp)), "a depth paired with another stamp's mask"
                want = (np.arange(12).reshape(3, 4) % (int(stamp) % 5 + 2)) == 0
                np.testing.assert_array_equal(mask, want)
                assert stamp > last_taken[k], "a frame used twice, or an older one after a newer"
                last_taken[k] = stamp
            assert t_data <= min(s[0] for s in sets)


@given(st.permutations(list(range(5))), st.integers(0, 2**31 - 1), st.sampled_from(["ok", "short", "nan", "extra"]))
def test_the_simulated_driver_maps_joint_commands_by_name(order, seed, kind):
    """The ``sim`` node's driver takes a joint command by joint names in any order (as ros2_control does); a
    command that lacks a joint or holds a non-finite value is refused (``ValueError``: counted, the watchdog
    then holds the arm), one with extra joints takes only its own."""
    from depthguard.nodes.sim import joint_command

    names = [f"j{i}" for i in range(5)]
    rng = np.random.default_rng(seed)
    q, qd = rng.normal(size=5), rng.normal(size=5)
    sent = [names[i] for i in order]
    pos, vel = q[order], qd[order]
    if kind == "short":
        sent, pos, vel = sent[1:], pos[1:], vel[1:]
    elif kind == "nan":
        pos = pos.copy()
        pos[int(rng.integers(5))] = np.nan
    elif kind == "extra":
        sent, pos, vel = [*sent, "gripper"], np.append(pos, 0.5), np.append(vel, 0.0)
    msg = ros2.joint_state_msg(1.0, sent, pos, vel)
    if kind in ("short", "nan"):
        with pytest.raises(ValueError, match="JointState"):
            joint_command(msg, names)
        return
    got_q, got_qd = joint_command(msg, names)
    np.testing.assert_array_equal(got_q, q)
    np.testing.assert_array_equal(got_qd, qd)
    assert got_q.flags.writeable
    # without names, by position
    plain = ros2.joint_state_msg(1.0, names, q, qd)
    plain.name = []
    np.testing.assert_array_equal(joint_command(plain, names)[0], q)
    plain.velocity = np.zeros(0)  # (a command must say how fast)
    with pytest.raises(ValueError, match="no velocities"):
        joint_command(plain, names)


@given(
    st.permutations(list(range(4))),
    st.lists(st.sampled_from(["gripper_a", "gripper_b", "head_pan"]), unique=True, max_size=3),
    st.booleans(),
    st.integers(0, 2**31 - 1),
)
def test_joint_states_in_any_order_reach_every_node_in_the_models_order(order, extra, with_velocity, seed):
    """A joint state as a ros2_control ``joint_state_broadcaster`` may send it (its own joint order, joints the
    model does not have, velocities or none): the distance node and the controller take the positions in
    the model's order; the controller refuses one without velocities (it needs them), never taking the
    positions by place."""
    from depthguard.nodes.controller import _Inputs
    from depthguard.nodes.distance import _FrameSets

    names = ["shoulder", "elbow", "wrist_1", "wrist_2"]
    rng = np.random.default_rng(seed)
    q, qd = rng.normal(size=4), rng.normal(size=4)
    sent = [names[i] for i in order] + extra
    pos = np.append(q[order], rng.normal(size=len(extra)))
    vel = np.append(qd[order], rng.normal(size=len(extra))) if with_velocity else None
    msg = ros2.joint_state_msg(2.0, sent, pos, vel)
    got_q, got_qd = ros2.joints_in_order(msg, names)
    np.testing.assert_array_equal(got_q, q)
    assert (got_qd is None) != with_velocity and (got_qd is None or np.array_equal(got_qd, qd))
    fs = _FrameSets(["camera0"], names)
    fs.on_js(msg, None, 0)
    np.testing.assert_array_equal(fs.joint["q"], q)
    inp = _Inputs(names, 1)
    if with_velocity:
        inp.on_js(msg, None, 0)
        np.testing.assert_array_equal(inp.st["q"], q)
        np.testing.assert_array_equal(inp.st["qd"], qd)
    else:
        with pytest.raises(ValueError, match="velocities"):
            inp.on_js(msg, None, 0)
        assert inp.st["q"] is None
    short = ros2.joint_state_msg(2.0, sent[1:], pos[1:], None if vel is None else vel[1:])  # (a model joint lost)
    for f in (lambda m: ros2.joints_in_order(m, names), lambda m: fs.on_js(m, None, 0)):
        with pytest.raises(ValueError, match="names no"):
            f(short)


@given(st.lists(st.tuples(st.floats(0.0, 0.2), st.booleans(), st.booleans()), min_size=1, max_size=30))
@example([(6.103515625e-05, False, False), (0.05, True, True)])  # (a wait of exactly the watchdog: fresh seeds)
def test_the_simulated_drivers_watchdog_holds_the_arm_whenever_commands_are_late(steps):
    """The ``sim`` driver's command latch under any sequence of commands (good or refused) and waits: it
    follows the newest good command while that is at most ``watchdog`` old, and otherwise holds the arm
    where it is with zero velocity, whatever came before."""
    from depthguard.nodes.sim import _CommandLatch

    names, wd = ["a", "b"], 0.05
    latch = _CommandLatch(names, wd)
    now, last_good, q_now = 100.0, None, np.array([0.3, -0.2])
    for k, (wait, send, good) in enumerate(steps):
        if send:
            v = float(k) if good else np.nan
            msg = ros2.joint_state_msg(now, names, [v, v], [1.0, 1.0])
            try:
                latch.on_cmd(msg, None, int(now * 1e9))
                last_good = (now, v)
            except ValueError:
                assert not good
        now += wait
        q, qd, held = latch.command(now, q_now)
        if last_good is not None and abs(now - last_good[0] - wd) < 1e-6:
            continue  # (exactly at the watchdog either way: the stamps travel in ns, and the last bit decides)
        if last_good is not None and now - last_good[0] <= wd:
            assert not held and q.tolist() == [last_good[1]] * 2 and qd.tolist() == [1.0, 1.0]
        else:
            assert held and q is q_now and not qd.any()
