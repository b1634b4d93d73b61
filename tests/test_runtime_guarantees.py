"""The runtime guarantees of the node and runner layer, attacked with property tests (pure, in process).

Each test drives the in-process logic that a node runs on every sample (:class:`SampleFilter`, the node
callbacks, the decoders, the controller node's inputs and cycle) with random sample streams: duplicates,
reordering, receiver clock jumps, int64 extremes, NaN / inf payload values, truncated, oversized or random
CDR payloads and attachments, images whose fields contradict their data, joint states in any order. Every
claim is checked against a small reference model written here from the docstrings (not from the code):

* what a subscription lets through (``io/sample_filter.py``) and what it counts (``dropped``, ``missed``);
* every decoder returns the right value or raises ``ValueError`` (never ``IndexError``, ``struct.error``,
  ``OverflowError`` or numpy garbage), a node callback either takes a message or refuses it with
  ``ValueError``;
* the controller node: a distance message older than the applied one never replaces it, distances for other
  points are refused, the stale-data timeout holds at its boundary, the resume latch is not shortened by a
  burst of fresh messages, NaN distances stop the arm;
* the side thread's ``run_parts`` gives every part once or raises the part's error.

Real processes under the same faults: ``tests/test_nodes_faults.py``.
"""

from __future__ import annotations

import math
import struct
import threading

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from depthguard.io import rmw_zenoh as rz
from depthguard.io import ros2, ros2_types
from depthguard.io.joint_state_cdr import decode_joint_state
from depthguard.io.sample_filter import MAX_FUTURE_S, SampleFilter

JS = "sensor_msgs/msg/JointState"
DIST = "depthguard_msgs/msg/ControlPointDistances"
IMG = "sensor_msgs/msg/Image"
NOW_MS = 1_800_000_000_000  # the receiver's clock in the filter tests, ms since the epoch
FAST = settings(deadline=None, max_examples=60, suppress_health_check=[HealthCheck.too_slow])
I64 = (-(2**63), 2**63 - 1)


def _time(sec: int, nanosec: int):
    return ros2_types._t("builtin_interfaces/msg/Time")(sec=sec, nanosec=nanosec)


def _js_cdr(ms: int, names=("a",), q=(0.0,)) -> bytes:
    """A JointState stamped ``ms`` milliseconds since the epoch (exact in sec/nanosec)."""
    msg = ros2.joint_state_msg(0.0, list(names), np.asarray(q, float))
    msg.header.stamp = _time(ms // 1000, (ms % 1000) * 1_000_000)
    return ros2.serialize(msg, JS)


def _reference_decode(payload: bytes, typename: str):
    """The generic decoder (rosbags): the oracle of "malformed CDR"."""
    try:
        return ros2_types.deserialize(payload, typename)
    except Exception:  # noqa: BLE001
        return None


# ====================================================================== the sample filter against a reference
class FilterModel:
    """What a subscription must do with a sample, from the docstring of :class:`SampleFilter`: an attachment
    that is not 33 bytes with a 16-byte GID is dropped; a sequence number not above the last *accepted* one
    of its publisher is dropped; a payload the generic decoder refuses is dropped; a stamp more than
    ``max_future`` after the receiver's clock is dropped; a stamp not newer than the last accepted one is
    dropped; the rest is accepted. ``missed``: per publisher, the sequence numbers between the first and the
    highest that reached the filter and that never reached it (a sample that arrives and is dropped counts
    in ``dropped`` only)."""

    def __init__(self) -> None:
        self.last_seq: dict[bytes, int] = {}
        self.reached: dict[bytes, list[int]] = {}
        self.last_stamp = -math.inf
        self.dropped: dict[str, int] = {}

    def _drop(self, why: str) -> None:
        self.dropped[why] = self.dropped.get(why, 0) + 1

    def accept(self, att: bytes, payload: bytes, now: float):
        if len(att) != 33 or att[16] != 16:
            return self._drop("bad attachment")
        seq = int.from_bytes(att[:8], "little", signed=True)
        gid = att[17:]
        self.reached.setdefault(gid, []).append(seq)
        if gid in self.last_seq and seq <= self.last_seq[gid]:
            return self._drop("duplicate or reordered sequence number")
        msg = _reference_decode(payload, JS)
        if msg is None:
            return self._drop("malformed CDR")
        stamp = float(msg.header.stamp.sec) + 1e-9 * float(msg.header.stamp.nanosec)
        if stamp > now + MAX_FUTURE_S:
            return self._drop("stamp in the future")
        if stamp <= self.last_stamp:
            return self._drop("stale or reordered stamp")
        self.last_stamp = stamp
        self.last_seq[gid] = seq
        return stamp

    @property
    def missed(self) -> int:
        total = 0
        for seqs in self.reached.values():
            first, top = seqs[0], max(seqs)
            total += len({s for s in range(first + 1, top) if s not in seqs}) if top - first < 10_000 else 0
        return total


_SEQ = st.one_of(st.integers(-3, 14), st.sampled_from(I64), st.sampled_from([I64[1] - 1, I64[0] + 1]))
_ATT = st.sampled_from(["good"] * 8 + ["short", "long", "gidlen"])
_PAYLOAD = st.one_of(
    st.just(("good", 0)) | st.just(("good", 0)) | st.just(("good", 0)),
    st.tuples(st.just("cut"), st.integers(0, 60)),
    st.tuples(st.just("extra"), st.integers(1, 9)),
    st.tuples(st.just("flip"), st.integers(0, 60)),
)
_SAMPLE = st.tuples(
    st.integers(0, 2),  # publisher
    _SEQ,
    st.one_of(st.integers(-3000, 3000), st.sampled_from([3_600_000, -3_600_000, 499, 500, 501])),  # stamp (ms)
    _ATT,
    _PAYLOAD,
    st.one_of(st.just(None), st.integers(-5000, 5000)),  # receiver's clock jump (ms)
)


def _attachment(kind: str, seq: int, gid: bytes) -> bytes:
    a = rz.encode_attachment(seq, 0, gid)
    return {"good": a, "short": a[:32], "long": a + b"\x00", "gidlen": a[:16] + b"\x0f" + a[17:]}[kind]


def _payload(kind: tuple, cdr: bytes) -> bytes:
    what, k = kind
    if what == "cut":
        return cdr[: min(k, len(cdr) - 1)]
    if what == "extra":
        return cdr + bytes(range(k))
    if what == "flip":
        b = bytearray(cdr)
        b[k % len(b)] ^= 0xA5
        return bytes(b)
    return cdr


def _run_filter(samples):
    f, m = SampleFilter(JS), FilterModel()
    now = NOW_MS
    got, want = [], []
    for pub, seq, stamp_ms, att_kind, pay_kind, jump in samples:
        if jump is not None:
            now += jump  # (the receiver's clock steps, forwards or backwards)
        now += 1
        att = _attachment(att_kind, seq, bytes([0x10 + pub]) * 16)
        payload = _payload(pay_kind, _js_cdr(NOW_MS + stamp_ms))
        r = f.accept(att, payload, now=now * 1e-3)
        got.append(None if r is None else ros2.to_seconds(r[0].header.stamp))
        want.append(m.accept(att, payload, now * 1e-3))
    return f, m, got, want, now


@FAST
@given(st.lists(_SAMPLE, min_size=1, max_size=40))
@example(  # a reordered sample (2 after 3) reached the filter: it is a drop, not a missed sample
    [(0, 1, 0, "good", ("good", 0), None), (0, 3, 1, "good", ("good", 0), None), (0, 2, 2, "good", ("good", 0), None)]
)
@example(  # 3 came corrupt first, then 2: both reached the filter, none is missed
    [(0, 1, 0, "good", ("good", 0), None), (0, 3, 1, "good", ("cut", 5), None), (0, 2, 2, "good", ("good", 0), None)]
)
@example([(0, I64[0], 0, "good", ("good", 0), None), (0, I64[1], 1, "good", ("good", 0), None)])
def test_the_filter_takes_and_counts_what_the_reference_model_does(samples):
    """Random publishers, sequence numbers (int64 extremes too), stamps (an hour either way), damaged
    attachments and payloads, and a receiver clock that steps back and forth: the filter accepts exactly the
    samples of the reference model, with their stamps, counts the same drops by reason and the same missed
    samples; afterwards a fresh sample from a new publisher is taken."""
    f, m, got, want, now = _run_filter(samples)
    assert got == want
    assert f.dropped == m.dropped
    assert sum(f.dropped.values()) + sum(x is not None for x in got) == len(samples)
    if all(s[1] in range(-3, 15) for s in samples):  # (the reference counts gaps of a few only)
        assert f.missed == m.missed
    fresh = max(now, math.floor(f.last_stamp * 1e3) if f.last_stamp > -math.inf else now) + 1
    r = f.accept(rz.encode_attachment(1, 0, b"\x99" * 16), _js_cdr(fresh), now=fresh * 1e-3)
    assert r is not None and ros2.to_seconds(r[0].header.stamp) == pytest.approx(fresh * 1e-3, abs=1e-6)


@FAST
@given(
    st.binary(max_size=80),
    st.binary(max_size=300),
    st.sampled_from([JS, DIST, IMG, "geometry_msgs/msg/Vector3Stamped"]),
)
@example(rz.encode_attachment(1, 0, b"\x01" * 16), b"\x00\x01\x00\x00" + b"\xff" * 16, IMG)
def test_the_filter_never_raises_on_arbitrary_bytes(att, payload, typename):
    """Arbitrary attachment and payload bytes for every type the nodes subscribe: the filter returns a
    message or None and counts the drop; it never raises into Zenoh's thread."""
    f = SampleFilter(typename)
    r = f.accept(att, payload, now=NOW_MS * 1e-3)
    assert (r is None) == (sum(f.dropped.values()) == 1)
    if r is None:
        assert f.dropped.keys() <= {
            "bad attachment",
            "malformed CDR",
            "stamp in the future",
            "stale or reordered stamp",
        }


@FAST
@given(st.lists(st.tuples(st.integers(0, 3), st.integers(1, 30), st.booleans()), min_size=1, max_size=30))
def test_an_allow_list_passes_only_the_named_publishers_even_when_the_graph_changes(samples):
    """``allowed``: the publisher is named by ``who`` at the moment its sample comes (the graph may learn of
    a publisher late); a sample whose publisher is not named, or named but not allowed, never passes."""
    names = {0: "distance", 1: "intruder", 2: None, 3: "distance"}
    known: set[int] = set()
    f = SampleFilter(JS, who=lambda gid: names[gid[0]] if gid[0] in known else None, allowed={"distance"})
    stamp = NOW_MS
    for pub, seq, learn in samples:
        if learn:
            known.add(pub)
        stamp += 1
        ok_pub = pub in known and names[pub] == "distance"
        r = f.accept(rz.encode_attachment(seq, 0, bytes([pub]) * 16), _js_cdr(stamp), now=stamp * 1e-3)
        if not ok_pub:
            assert r is None
    assert f.rejected_publishers <= {"None", "intruder"}


@FAST
@given(st.lists(st.text(max_size=4), min_size=1, max_size=60))
def test_the_filter_says_a_refusal_once_per_text_and_counts_every_one(texts):
    """``reject``: every refusal is counted by the error's type; the first time a text comes it is to be said
    (at most 20 kinds are remembered; later new texts are counted but not said)."""
    f = SampleFilter(JS)
    said: set[str] = set()
    for t in texts:
        says = f.reject(ValueError(t))
        assert says == (t not in said and len(said) < 20)
        if says:
            said.add(t)
        assert f.last_refusal == t
    assert f.dropped == {"refused by the node (ValueError)": len(texts)}


def test_a_refused_message_stamped_ahead_does_not_hold_the_next_good_ones():
    """A message that passes the filter but that the node refuses (NaN joint positions from an open peer,
    stamped 0.4 s ahead, within the future allowance) is never applied: it must not make the good messages
    of the next 0.4 s "stale" (a controller fed by them would stop the arm for that long on one message)."""
    f = SampleFilter(JS)
    t0 = NOW_MS
    assert f.accept(rz.encode_attachment(1, 0, b"\x01" * 16), _js_cdr(t0), now=t0 * 1e-3) is not None
    bad = f.accept(rz.encode_attachment(1, 0, b"\x02" * 16), _js_cdr(t0 + 400, q=(math.nan,)), now=t0 * 1e-3)
    assert bad is not None
    with pytest.raises(ValueError):
        ros2.joints_in_order(bad[0], ["a"])
    f.reject(ValueError("JointState: positions and velocities must be finite"))
    for k in range(1, 5):
        r = f.accept(rz.encode_attachment(1 + k, 0, b"\x01" * 16), _js_cdr(t0 + k), now=(t0 + k) * 1e-3)
        assert r is not None, f.dropped
    # a replay of what was applied is still refused, and so is one older than it
    assert f.accept(rz.encode_attachment(9, 0, b"\x03" * 16), _js_cdr(t0 + 4), now=(t0 + 5) * 1e-3) is None
    assert f.accept(rz.encode_attachment(10, 0, b"\x03" * 16), _js_cdr(t0 + 3), now=(t0 + 5) * 1e-3) is None


def test_the_filters_memory_is_bounded_whatever_gids_an_open_peer_sends():
    """An open topic takes samples from anyone; a peer that sends every sample with another GID must not
    grow the filter's per-publisher state without end (a node must not die of many bogus samples)."""
    f = SampleFilter(JS)
    cdr = _js_cdr(NOW_MS)
    for k in range(5000):
        f.accept(rz.encode_attachment(k, 0, k.to_bytes(16, "little")), cdr, now=NOW_MS * 1e-3)
    assert len(f.last_seq) <= 1024 and len(f.seen_seq) <= 1024
    # a legitimate publisher that keeps sending is still served (its stamps order its samples)
    for k in range(1, 4):
        r = f.accept(rz.encode_attachment(k, 0, b"\xee" * 16), _js_cdr(NOW_MS + k), now=(NOW_MS + k) * 1e-3)
        assert r is not None


# ================================================================================= decoders on arbitrary bytes
@FAST
@given(st.binary(max_size=40), st.sampled_from([bytes, bytearray, memoryview]))
def test_an_attachment_decodes_or_is_refused_with_a_value_error(raw, kind):
    try:
        a = rz.decode_attachment(kind(raw))
    except ValueError:
        assert len(raw) != 33 or raw[16] != 16
        return
    assert rz.encode_attachment(*a) == raw and len(a.gid) == 16 and I64[0] <= a.seq <= I64[1]


def _js_payload(data, big: bool) -> bytes:
    """A canonical JointState CDR (little- or big-endian, written here) with random fields."""
    o = ">" if big else "<"
    names = data.draw(st.lists(st.text(max_size=5).filter(lambda s: "\x00" not in s), max_size=4))
    n = len(names)
    body = bytearray(
        struct.pack(o + "iI", data.draw(st.integers(-(2**31), 2**31 - 1)), data.draw(st.integers(0, 2**32 - 1)))
    )

    def string(s: str) -> None:
        raw = s.encode()
        body.extend(bytes(-len(body) % 4) + struct.pack(o + "I", len(raw) + 1) + raw + b"\x00")

    string(data.draw(st.text(max_size=6).filter(lambda s: "\x00" not in s)))
    body.extend(bytes(-len(body) % 4) + struct.pack(o + "I", n))
    for s in names:
        string(s)
    for count in (n, data.draw(st.sampled_from([0, n])), data.draw(st.sampled_from([0, n]))):
        body.extend(bytes(-len(body) % 4) + struct.pack(o + "I", count))
        if count:
            body.extend(bytes(-len(body) % 8))
            vals = data.draw(st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=count, max_size=count))
            body.extend(struct.pack(o + "d" * count, *vals))
    return (b"\x00\x00\x00\x00" if big else b"\x00\x01\x00\x00") + bytes(body)


def _same_js(a, b) -> bool:
    def arr(x):
        return np.asarray(x, float).tobytes()

    return (
        a.header.stamp.sec == b.header.stamp.sec
        and a.header.stamp.nanosec == b.header.stamp.nanosec
        and a.header.frame_id == b.header.frame_id
        and list(a.name) == list(b.name)
        and all(arr(getattr(a, k)) == arr(getattr(b, k)) for k in ("position", "velocity", "effort"))
    )


@FAST
@given(st.data(), st.booleans(), st.sampled_from(["none", "cut", "grow", "flip", "count"]))
def test_the_joint_state_fast_path_agrees_with_rosbags_or_declines(data, big, damage):
    """A JointState in the canonical layout (either byte order), then damaged: the fast decoder returns the
    message of the generic decoder or None, never another message and never an exception; the decoder
    behind :func:`ros2.deserialize` gives what the generic one gives or raises."""
    cdr = bytearray(_js_payload(data, big))
    if damage == "cut":
        del cdr[data.draw(st.integers(4, len(cdr) - 1)) :]
    elif damage == "grow":
        cdr += data.draw(st.binary(min_size=1, max_size=12))
    elif damage == "flip":
        cdr[data.draw(st.integers(4, len(cdr) - 1))] ^= data.draw(st.integers(1, 255))
    elif damage == "count":  # a sequence length field set to a huge value
        pos = data.draw(st.integers(4, len(cdr) - 4))
        cdr[pos : pos + 4] = data.draw(st.sampled_from([b"\xff\xff\xff\xff", b"\xff\xff\xff\x7f", b"\x00\x00\x00\x80"]))
    cdr = bytes(cdr)
    ref = _reference_decode(cdr, JS)
    fast = decode_joint_state(cdr)
    if fast is not None:
        assert ref is not None and _same_js(fast, ref)
    try:
        got = ros2.deserialize(cdr, JS)
    except Exception:  # noqa: BLE001 - the generic decoder's refusal
        assert ref is None
    else:
        assert ref is not None and _same_js(got, ref)
    if damage == "none":
        assert fast is not None


@FAST
@given(st.binary(max_size=200))
@example(b"\x00\x01\x00\x00" + b"\x00" * 8 + b"\x01\x00\x00\x00\x00" + b"\x00" * 3 + b"\xff\xff\xff\xff")
def test_the_joint_state_fast_path_on_arbitrary_bytes_never_raises(raw):
    for head in (b"", b"\x00\x01\x00\x00", b"\x00\x00\x00\x00"):
        fast = decode_joint_state(head + raw)
        if fast is not None:
            ref = _reference_decode(head + raw, JS)
            assert ref is not None and _same_js(fast, ref)


# ========================================================================================= images and masks
_DEPTH_ENC = {"16UC1": ("u2", 1000.0), "mono16": ("u2", 1000.0), "32FC1": ("f4", 1.0)}


def _reference_depth(enc: str, h: int, w: int, step: int, big: int, data: bytes, pixels: bool = True):
    """The depth image as the docs define it, pixel by pixel, or None where the fields contradict the data."""
    kind = {k.upper(): v for k, v in _DEPTH_ENC.items()}.get(enc.upper())
    if kind is None:
        return None
    typ, div = kind
    item = 2 if typ == "u2" else 4
    step = step or w * item
    if step < w * item or len(data) < step * h:
        return None
    if not pixels:
        return "valid"
    out = np.full((h, w), np.nan, np.float32)
    dt = np.dtype((">" if big else "<") + typ)
    for r in range(h if w else 0):
        for c in range(w):
            v = float(np.frombuffer(data, dt, 1, r * step + c * item)[0])
            m = np.float32(np.float32(v) / np.float32(div))
            if math.isfinite(m) and m > 0:
                out[r, c] = m
    return out


_IMG_DIM = st.one_of(st.integers(0, 5), st.sampled_from([2**31, 2**32 - 1, 2**16]))


@FAST
@given(
    st.sampled_from(["16UC1", "32FC1", "mono16", "32fc1", "mono8", "rgb8", "", "16UC1\x01", "32FC2"]),
    _IMG_DIM,
    _IMG_DIM,
    st.one_of(st.integers(0, 24), st.sampled_from([2**32 - 1, 2**31])),
    st.integers(0, 255),
    st.binary(max_size=120),
)
@example("32FC1", 0, 2**32 - 1, 0, 0, b"")
@example("16UC1", 2**32 - 1, 0, 0, 1, b"")
@example("16UC1", 2, 3, 7, 1, bytes(range(14)))
def test_a_depth_image_off_the_wire_is_its_samples_in_metres_or_a_value_error(enc, h, w, step, big, data):
    """Any ``sensor_msgs/Image`` through the CDR round trip: ``image_to_depth`` gives the documented metres
    (16UC1 / mono16 mm, 32FC1 m, in the message's byte order, rows of ``step`` bytes, NaN for no reading) or
    raises ``ValueError`` when the encoding is not a depth one or the fields contradict the data; a mask
    (mono8) likewise."""
    msg = ros2_types._t(IMG)(
        header=ros2.header(1.0, "c"), height=h, width=w, encoding=enc, is_bigendian=big, step=step,
        data=np.frombuffer(data, np.uint8),
    )  # fmt: skip
    msg = ros2.deserialize(ros2.serialize(msg, IMG), IMG)
    small = h * w <= 64
    want = _reference_depth(enc, h, w, step, big, data, pixels=small)
    try:
        got = ros2.image_to_depth(msg)
    except ValueError:
        assert want is None, (enc, h, w, step)
    else:
        assert want is not None, (enc, h, w, step, len(data))
        assert got.shape == (h, w) and got.dtype == np.float32
        if isinstance(want, np.ndarray):
            assert np.array_equal(got, want, equal_nan=True)
    try:
        mask = ros2.image_to_mask(msg)
    except ValueError:
        ok = enc == "mono8" and w <= (step or w) and len(data) >= (step or w) * h
        assert not ok
    else:
        assert enc == "mono8" and mask.shape == (h, w) and mask.dtype == bool
        if small and h * w:
            s = step or w
            for r in range(h):
                for c in range(w):
                    assert mask[r, c] == (data[r * s + c] != 0)


# ============================================================================== the controller node's inputs
@pytest.fixture(scope="module")
def lwr():
    pytest.importorskip("pinocchio")  # (only the tests with the robot need it)
    from depthguard.robot.control_points import ControlPointSet
    from depthguard.robot.model import load_lwr4

    model = load_lwr4()
    return model, ControlPointSet.build(model, "ral-9")


class _Sub:
    """What :meth:`Subscription._on_sample` does with one sample, without Zenoh."""

    def __init__(self, typename: str, callback) -> None:
        self.filter, self.callback = SampleFilter(typename), callback

    def on_sample(self, att: bytes, payload: bytes, now: float) -> str:
        got = self.filter.accept(att, payload, now)
        if got is None:
            return "dropped"
        try:
            self.callback(got[0], got[1], int(now * 1e9))
        except Exception as exc:  # noqa: BLE001
            assert isinstance(exc, ValueError), repr(exc)  # (the callbacks refuse with ValueError only)
            self.filter.reject(exc)
            return "refused"
        return "taken"


def _dist_cdr(t: float, names, d, rho: float = 0.5) -> bytes:
    n = len(names)
    dirs = np.tile([0.0, 0.0, 1.0], (n, 1))
    msg = ros2.distances_msg(t, list(names), np.zeros((n, 3)), np.full(n, 0.05), np.asarray(d, float), dirs, rho=rho)
    return ros2.serialize(msg, DIST)


_NAME_EDIT = st.sampled_from(["same"] * 4 + ["swap", "drop", "extra", "rename"])
_DIST_VALUE = st.sampled_from([0.3, 0.0, 1.5, math.inf, math.nan, -math.inf, -0.01, 1e300])


@FAST
@given(
    st.lists(
        st.tuples(st.integers(0, 1), st.integers(0, 12), st.integers(-40, 40), _NAME_EDIT, _DIST_VALUE),
        min_size=1,
        max_size=25,
    )
)
def test_the_controller_applies_only_newer_distances_for_its_own_points(lwr, msgs):
    """Distance messages through the controller node's subscription and callback in any order, with
    duplicates, other point lists and non-finite values: the applied distances are always those of the
    newest-stamped message taken so far (a message older than the applied one never replaces it), a
    message for other points (another number, order or names) is refused with ``ValueError`` and changes
    nothing, and the stamp the controller sees never goes back."""
    from depthguard.nodes.controller import _Inputs

    model, points = lwr
    names = list(points.names)
    inp = _Inputs(model.joint_names, points.n_points, names)
    sub = _Sub(DIST, inp.on_dist)
    applied_t = -math.inf
    applied_d = None
    for k, (pub, seq, ms, edit, value) in enumerate(msgs):
        nm = list(names)
        if edit == "swap":
            nm[1], nm[2] = nm[2], nm[1]
        elif edit == "drop":
            nm = nm[:-1]
        elif edit == "extra":
            nm = [*nm, "gripper"]
        elif edit == "rename":
            nm[0] = "ee2"
        d = np.full(len(nm), 0.8)
        d[k % len(nm)] = value
        t_ms = NOW_MS + ms
        what = sub.on_sample(
            rz.encode_attachment(seq, t_ms, bytes([pub]) * 16), _dist_cdr(t_ms * 1e-3, nm, d), (NOW_MS + 50) * 1e-3
        )
        if what == "taken":
            assert edit == "same" and t_ms * 1e-3 > applied_t
            applied_t, applied_d = t_ms * 1e-3, d
        elif what == "refused":
            assert edit != "same"
        assert inp.st["td"] == pytest.approx(applied_t, abs=1e-6) if applied_d is not None else inp.st["d"] is None
        if applied_d is not None:
            assert np.array_equal(inp.st["d"], applied_d, equal_nan=True)
            dirs = inp.st["dirs"]
            assert np.all(dirs[~np.isfinite(applied_d)] == 0.0)


@FAST
@given(
    st.lists(st.sampled_from(["a1", "a2", "a3", "a4", "a5", "a6", "a7", "gripper"]), min_size=0, max_size=9),
    st.booleans(),
    st.sampled_from([None, math.nan, math.inf]),
)
@example(["a1", "a2", "a3", "a4", "a5", "a6", "a7", "a4"], True, None)  # a4 named twice: which one?
@example(["a7", "a6", "a5", "a4", "a3", "a2", "a1", "gripper", "gripper"], True, None)
def test_joint_states_reach_the_controller_by_name_or_are_refused(lwr, order, velocities, bad):
    """Joint states naming the model's joints in any order, with extra joints, missing ones or duplicates
    (the names mapped on the model's ``a1..a7`` here), and non-finite values: the controller's inputs get the
    positions of the model's joints by name, or the message is refused with ``ValueError`` and the last
    good joint state stays (it then goes stale and the arm stops)."""
    from depthguard.nodes.controller import _Inputs

    model, points = lwr
    jn = list(model.joint_names)
    alias = {f"a{i + 1}": jn[i] for i in range(7)}
    names = [alias.get(n, n) for n in order]
    inp = _Inputs(jn, points.n_points, points.names)
    good = {n: 0.1 * (i + 1) for i, n in enumerate(jn)}
    q = np.array([good.get(n, 9.0) + (0.5 if names[:i].count(n) else 0.0) for i, n in enumerate(names)])
    if bad is not None and len(q):
        q[len(q) // 2] = bad
    msg = ros2.joint_state_msg(1.0, names, q, q * 0.5 if velocities else None)
    before = dict(inp.st)
    try:
        inp.on_js(ros2.deserialize(ros2.serialize(msg, JS), JS), None, 0)
    except ValueError:
        assert inp.st["q"] is before["q"] and inp.st["tj"] == before["tj"]
        ok = (
            set(jn) <= set(names)
            and len(set(names)) == len(names)  # (the model's joints each named once)
            and velocities
            and np.all(np.isfinite(q))
        )
        assert not ok or not names
        return
    assert velocities and np.all(np.isfinite(inp.st["q"]))
    if names:
        assert set(jn) <= set(names)
        assert len({n for n in names if n in jn}) == sum(n in jn for n in names), "a joint named twice was taken"
        assert np.array_equal(inp.st["q"], [good[n] for n in jn])
    assert np.array_equal(inp.st["qd"], inp.st["q"] * 0.5)


# ============================================================================= the controller node's cycles
DT = 2.0**-10  # (a control period exact in binary: the stale-data boundary is exact)
T0 = 2.0**20  # the controller's clock at the first cycle (s), exact with DT
Q0 = np.array([0.0, 0.5, 0.0, -1.2, 0.0, 0.8, 0.0])


def _cycle_config(timeout_cycles: int, resume_cycles: int):
    from depthguard.control.types import ControllerConfig

    return ControllerConfig(
        dt=DT, distance_timeout=timeout_cycles * DT, joint_timeout=0.02, resume_time=resume_cycles * DT
    )


_EVENT = st.one_of(
    st.just(("fresh", 1)),
    st.tuples(st.just("fresh"), st.integers(2, 6)),  # a burst of fresh messages in one period
    st.tuples(st.just("none"), st.integers(1, 12)),  # no distances for that many periods
    st.tuples(st.just("nan"), st.just(1)),
    st.tuples(st.just("old"), st.integers(1, 30)),  # a message stamped that many periods ago
)


@settings(deadline=None, max_examples=25, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(_EVENT, min_size=1, max_size=25), st.integers(2, 6), st.integers(0, 8))
@example([("none", 4), ("fresh", 6), ("fresh", 6)], 3, 8)
def test_the_controller_node_stops_on_stale_or_nan_distances_and_waits_out_its_latch(lwr, events, timeout_c, resume_c):
    """The controller node's path (subscription, ``_Inputs``, one cycle per period) under random distance
    streams: gaps, bursts, NaN distances, messages older than the applied ones. Against the documented rules:
    distances age past ``distance_timeout`` (strictly: at exactly the timeout they still count) -> stop; a NaN
    distance -> stop; after any stop the arm moves again only once the inputs have been valid for
    ``resume_time`` in a row, counted in cycles, however many fresh messages came meanwhile; and it does move
    again then."""
    from depthguard.control import AvoidanceController
    from depthguard.control.types import CycleStatus
    from depthguard.nodes.controller import _Inputs

    model, points = lwr
    cfg = _cycle_config(timeout_c, resume_c)
    ctrl = AvoidanceController(points, cfg)
    names = list(points.names)
    inp = _Inputs(model.joint_names, points.n_points, names)
    sub_d, sub_j = _Sub(DIST, inp.on_dist), _Sub(JS, inp.on_js)
    q, qd = Q0.copy(), np.zeros(7)
    seq = {"d": 0, "j": 0}
    far = np.full(points.n_points, 2.0)

    def send_d(t: float, d) -> None:
        seq["d"] += 1
        sub_d.on_sample(rz.encode_attachment(seq["d"], 0, b"\x0d" * 16), _dist_cdr(t, names, d), t)

    k = 0
    applied: list[tuple[float, bool]] = []  # per cycle: the applied distance stamp, whether it holds a NaN
    statuses = []
    # the reference: the cycle's inputs are valid iff the applied distances are not NaN and not older than the
    # timeout; a stop latches until the inputs have been valid for resume_c cycles in a row after it
    plan = [e for ev in events for e in ([ev] if ev[0] != "none" else [("none", 1)] * ev[1])]
    plan += [("fresh", 1)] * (timeout_c + resume_c + 3)  # then good data long enough to resume
    for kind, n in plan:
        t = T0 + k * DT
        if kind == "fresh":
            for i in range(n):  # (the burst: several messages within the period, the newest stamped t)
                send_d(t - (n - 1 - i) * DT / n, far)
        elif kind == "nan":
            d = far.copy()
            d[3] = math.nan
            send_d(t, d)
        elif kind == "old":
            send_d(t - n * DT, far)
        seq["j"] += 1
        sub_j.on_sample(
            rz.encode_attachment(seq["j"], 0, b"\x0a" * 16),
            ros2.serialize(ros2.joint_state_msg(t, model.joint_names, q, qd), JS),
            t,
        )
        with inp.lock:
            s = dict(inp.st)
        out = ctrl.step(inp.cycle_input(s, t))
        statuses.append(out.status)
        applied.append((s["td"], s["d"] is not None and bool(np.isnan(s["d"]).any())))
        q, qd = out.q_cmd, out.qdot_cmd
        k += 1
    valid = [not nan and t_d >= T0 + i * DT - timeout_c * DT for i, (t_d, nan) in enumerate(applied)]
    run = 0
    latched = False  # (the latch follows a stop; the start is none)
    for i, (ok, status) in enumerate(zip(valid, statuses, strict=True)):
        if not ok:
            assert status.stopping and status != CycleStatus.STOP_RESUME_WAIT, (i, status)
            nan, never = applied[i][1], applied[i][0] == -math.inf
            # (before any distances came the node's stamp is -inf, "not a finite number" for the input check:
            # STOP_INVALID_INPUT, not STOP_STALE_DISTANCES; either stops the arm, and the docs allow both)
            want = {CycleStatus.STOP_INVALID_INPUT} if nan else {CycleStatus.STOP_STALE_DISTANCES}
            if never:
                want.add(CycleStatus.STOP_INVALID_INPUT)
            assert status in want, (i, status)
            latched, run = True, 0
            continue
        run += 1
        if latched and run <= resume_c:  # (still inside the latch: the arm must not move)
            assert status == CycleStatus.STOP_RESUME_WAIT, (i, status, run)
        elif latched:
            latched = False
        if not latched:
            assert not status.stopping, (i, status)
    assert not statuses[-1].stopping


# ================================================================================================ side thread
@FAST
@given(st.integers(0, 40), st.sets(st.integers(0, 39), max_size=3), st.booleans())
def test_run_parts_gives_every_part_once_or_raises_a_parts_error(n, failing, with_side):
    """``run_parts(fn, n, side)``: every part computed once and returned in order; when parts raise, one of
    their errors comes out, from either thread, and no part runs twice."""
    from depthguard.sidethread import SideThread, run_parts

    calls: list[int] = []
    lock = threading.Lock()

    def fn(k: int) -> int:
        with lock:
            calls.append(k)
        if k in failing:
            raise KeyError(k)
        return k * k

    side = SideThread() if with_side else None
    try:
        if with_side:
            with side.beside() as ex:
                try:
                    out = run_parts(fn, n, ex)
                except KeyError as exc:
                    assert exc.args[0] in failing and exc.args[0] < n
                    out = None
        else:
            try:
                out = run_parts(fn, n)
            except KeyError as exc:
                assert exc.args[0] in failing and exc.args[0] < n
                out = None
    finally:
        if side is not None:
            side.shutdown()
    assert len(calls) == len(set(calls))
    if out is not None:
        assert not (failing & set(range(n)))
        assert out == [k * k for k in range(n)] and sorted(calls) == list(range(n))
    else:
        assert failing & set(range(n))


# ============================================================================================ liveliness tokens
_TOKEN_PART = st.sampled_from(["@ros2_lv", "0", "232", "x", "", "NN", "MP", "%", "12ab", "node", "a%b", "9" * 5000])


@FAST
@given(
    st.lists(st.lists(_TOKEN_PART, min_size=1, max_size=14).map("/".join), max_size=8),
    st.lists(st.text(max_size=30), max_size=4),
)
def test_the_monitor_reads_any_liveliness_keys_without_raising(keys, junk):
    """Whatever liveliness keys a peer declares, ``live_nodes`` names the nodes of the well-formed ``NN``
    tokens and counts the other ``NN`` ones; it never raises."""
    from depthguard.nodes.monitor import live_nodes

    good = rz.liveliness_token(0, "abc", 0, 0, "NN", "distance")
    names, malformed = live_nodes([good, *keys, *junk])
    assert "distance" in names and names == sorted(set(names))
    assert 0 <= malformed <= sum("/NN/" in k for k in [*keys, *junk])


@pytest.mark.parametrize("node", ["distance", "sim"])
def test_every_node_refuses_a_joint_state_that_names_a_joint_twice(lwr, node):
    """The distance node's joint states and the simulated driver's joint commands are taken by name as the
    controller's are: a message naming a joint twice (with two values) is refused, not read either way."""
    from depthguard.nodes.distance import _FrameSets
    from depthguard.nodes.sim import joint_command

    model, _ = lwr
    jn = list(model.joint_names)
    names = [*jn, jn[2]]
    q = np.array([0.1 * (i + 1) for i in range(len(names))])
    msg = ros2.deserialize(ros2.serialize(ros2.joint_state_msg(1.0, names, q, q), JS), JS)
    with pytest.raises(ValueError, match="more than once"):
        if node == "distance":
            _FrameSets(["cam"], jn).on_js(msg, None, 0)
        else:
            joint_command(msg, jn)
    ok = ros2.deserialize(ros2.serialize(ros2.joint_state_msg(1.0, jn[::-1], q[:7], q[:7]), JS), JS)
    got = _FrameSets(["cam"], jn).on_js(ok, None, 0) if node == "distance" else joint_command(ok, jn)
    assert got is None or np.array_equal(got[0], q[:7][::-1])
