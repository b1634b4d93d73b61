"""What DepthGuard writes for other tools, read back by readers that share no code with the writers:
OctoMap files (``io/octomap.py``) by ``pyoctomap`` and OctoMap's own ``convert_octree``; MCAP recordings of
ROS 2 messages (``io/mcap_ros2.py``, ``sim/mcap_log.py``) by ``mcap`` + ``mcap_ros2`` (their own CDR parser
driven by the embedded schema text) and by ``rosbags``; the JointState fast path (``io/joint_state_cdr.py``)
against ``rosbags``' serialiser. References are written here (node keys, stamps in exact arithmetic)."""

from __future__ import annotations

import atexit
import io
import math
import shutil
import struct
import subprocess
import sys
import tempfile
from collections import Counter
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

pyoctomap = pytest.importorskip("pyoctomap")
pytest.importorskip("mcap")
pytest.importorskip("mcap_ros2")
pytest.importorskip("rosbags")

from mcap.reader import make_reader  # noqa: E402
from mcap.records import Message  # noqa: E402
from mcap.stream_reader import StreamReader  # noqa: E402
from mcap_ros2.decoder import DecoderFactory  # noqa: E402

from depthguard.io import ros2  # noqa: E402
from depthguard.io.joint_state_cdr import joint_state_cdr  # noqa: E402
from depthguard.io.mcap_ros2 import Ros2McapWriter, read_messages  # noqa: E402
from depthguard.io.octomap import COLORS, write_octomap  # noqa: E402
from depthguard.octree.fusion import OctreeFrame  # noqa: E402
from depthguard.octree.grid import VoxelBox  # noqa: E402
from depthguard.sim.mcap_log import write_mcap  # noqa: E402

TMP = Path(tempfile.mkdtemp(prefix="depthguard-export-"))  # (hypothesis examples share it; removed at exit)
atexit.register(shutil.rmtree, TMP, True)
_SETTINGS = {"deadline": None, "suppress_health_check": [HealthCheck.function_scoped_fixture, HealthCheck.too_slow]}


def _tmp(name: str) -> Path:
    d = TMP / name
    d.mkdir(parents=True, exist_ok=True)
    return d


# --------------------------------------------------------------------------------------------- OctoMap


def _frame(origin_cells, res: float, kind: np.ndarray) -> OctreeFrame:
    box = VoxelBox(np.asarray(origin_cells, float) * res, res, kind.shape)
    mask = np.ones(kind.shape, bool)
    return OctreeFrame(box, kind != 0, kind, mask, np.zeros((1, *kind.shape), np.uint8), "conservative")


def _expected(origin_cells, kind: np.ndarray, kinds) -> set:
    """OctoMap keys (node index ``floor(x / res)`` per axis) of the nodes of ``kinds``."""
    idx = np.argwhere(np.isin(kind, kinds)) + np.asarray(origin_cells, int)
    return {tuple(int(v) for v in row) for row in idx}


def _leaves(tree, res: float) -> dict:
    """``{node key at the finest depth: colour or None}`` of the leaves of a tree read back, pruned leaves
    expanded; every leaf must be occupied (free space is not written)."""
    out = {}
    for it in tree.begin_leafs():
        assert tree.isNodeOccupied(it), "a free leaf in the file"
        size = float(it.getSize())
        n = round(size / res)
        assert n >= 1 and n & (n - 1) == 0 and math.isclose(n * res, size, rel_tol=1e-6)
        lo = np.round((np.asarray(it.getCoordinate(), float) - size / 2) / res).astype(int)
        colour = tuple(it.getColor()) if hasattr(it, "getColor") and isinstance(tree, pyoctomap.ColorOcTree) else None
        for i in range(n):
            for j in range(n):
                for k in range(n):
                    key = (int(lo[0]) + i, int(lo[1]) + j, int(lo[2]) + k)
                    assert key not in out, f"two leaves hold the node {key}"
                    out[key] = colour
    return out


@st.composite
def _octree_frames(draw):
    res = draw(st.sampled_from([0.02, 0.025, 0.05, 0.07, 0.1]) | st.integers(2000, 10000).map(lambda k: k / 1e5))
    shape = tuple(draw(st.integers(1, 5)) for _ in range(3))
    origin = [
        draw(st.sampled_from([0, -1, -3, -32768, 32767 - s + 1, -20000]) | st.integers(-32768, 32767 - s + 1))
        for s in shape
    ]
    pattern = draw(st.sampled_from(["random", "empty", "full"]))
    if pattern == "random":
        kind = np.array(
            draw(st.lists(st.sampled_from([0, 1, 2, 3]), min_size=math.prod(shape), max_size=math.prod(shape)))
        )
        kind = kind.astype(np.uint8).reshape(shape)
    else:
        kind = np.full(shape, 0 if pattern == "empty" else draw(st.sampled_from([1, 2, 3])), np.uint8)
    return origin, res, kind


_MIXED_BLOCK = np.ones((2, 2, 2), np.uint8)
_MIXED_BLOCK[0, 0, 0], _MIXED_BLOCK[1, 1, 1] = 2, 3


@settings(max_examples=60, **_SETTINGS)
@given(_octree_frames())
# eight siblings of three kinds: OctoMap pruned them into one grey leaf of the .ot (a ColorOcTree prunes by
# occupancy alone), losing the red and the orange nodes
@example(([0, 0, 0], 0.05, _MIXED_BLOCK))
@example(([-2, 4, -32768], 0.02, np.concatenate([_MIXED_BLOCK, _MIXED_BLOCK[::-1]], axis=0)))
# no node at all: pyoctomap's ColorOcTree.updateInnerOccupancy crashed the process (SIGSEGV) on the empty tree
@example(([0, 0, 0], 0.05, np.zeros((2, 3, 1), np.uint8)))
@example(([32766, -32768, 0], 0.1, np.full((2, 1, 1), 2, np.uint8)))  # (the key range's very edges)
def test_octomap_files_hold_exactly_the_frame_s_nodes_on_octomap_s_lattice(case):
    origin, res, kind = case
    paths = write_octomap(_frame(origin, res, kind), _tmp("octo"))
    occ = pyoctomap.OcTree(res)
    assert occ.readBinary(str(paths["occupied.bt"]))
    hid = pyoctomap.OcTree(res)
    assert hid.readBinary(str(paths["occluded.bt"]))
    col = pyoctomap.ColorOcTree(res).read(str(paths["octree.ot"]))
    assert col is not None
    assert set(_leaves(occ, res)) == _expected(origin, kind, (1,))
    assert set(_leaves(hid, res)) == _expected(origin, kind, (2, 3))
    got = _leaves(col, res)
    want = {key: COLORS[k] for k in COLORS for key in _expected(origin, kind, (k,))}
    assert got == want
    for t in (occ, hid, col):
        assert t.getResolution() == pytest.approx(res, rel=1e-12)


def test_octomap_s_own_tool_reads_the_files(tmp_path):
    tool = Path(sys.executable).parent / "convert_octree"
    if not tool.exists():
        pytest.skip("OctoMap's convert_octree (cmeel-octomap) is not installed")
    kind = np.zeros((6, 5, 4), np.uint8)
    kind[:2, :2, :2] = _MIXED_BLOCK
    kind[3:5, 1:4, 2] = 2
    kind[5, 4, 3] = 1
    paths = write_octomap(_frame([-7, 3, 0], 0.05, kind), tmp_path / "o")
    for name, path in paths.items():
        out = tmp_path / f"{name}.converted.ot"
        run = subprocess.run([str(tool), str(path), str(out)], capture_output=True, text=True, timeout=60)
        assert run.returncode == 0 and out.is_file(), (name, run.stdout, run.stderr)
        tree = pyoctomap.OcTree(0.05).read(str(out)) if name.endswith(".bt") else None
        if tree is not None:  # (.bt -> .ot: the same nodes through OctoMap's C++ reader and writer)
            kinds = (1,) if name == "occupied.bt" else (2, 3)
            assert set(_leaves(tree, 0.05)) == _expected([-7, 3, 0], kind, kinds)


@settings(max_examples=20, **_SETTINGS)
@given(st.floats(0.02, 0.1).filter(lambda r: float(f"{r:.6g}") != r))
# OctoMap writes the resolution as text to 6 digits: the file said 0.0585938, its lattice not the frame's
@example(0.05859375)
def test_a_resolution_that_octomap_s_header_cannot_hold_is_refused(res):
    out = _tmp("res") / repr(res)
    with pytest.raises(ValueError, match="6 significant digits"):
        write_octomap(_frame([0, 0, 0], res, _MIXED_BLOCK), out)
    assert not out.exists() or not any(out.iterdir())


@settings(max_examples=25, **_SETTINGS)
@given(st.integers(2000, 10000).map(lambda k: k / 1e5), st.integers(-500, 500), st.floats(0.001, 0.999))
def test_a_box_off_octomap_s_lattice_is_refused_and_nothing_written(res, i0, frac):
    out = _tmp("offlattice") / f"{i0}-{frac}"
    kind = np.ones((2, 2, 2), np.uint8)
    frame = OctreeFrame(
        VoxelBox(np.array([i0 + frac, 0.0, 0.0]) * res, res, kind.shape), kind != 0, kind, kind != 0, kind[None], "x"
    )
    with pytest.raises(ValueError, match="lattice"):
        write_octomap(frame, out)
    assert not out.exists() or not any(out.iterdir())


@settings(max_examples=25, **_SETTINGS)
@given(st.sampled_from([0.02, 0.05, 0.1]), st.sampled_from([-1, 1]), st.integers(0, 10**6), st.integers(0, 2))
@example(0.02, 1, 0, 0)  # one node just past key 32767 (655.36 m at 0.02 m): silently missing from the files
@example(0.1, -1, 0, 2)  # one node just before key -32768: silently missing
def test_nodes_beyond_octomap_s_key_range_are_refused(res, side, beyond, axis):
    """OctoMap's keys are 16 bits per axis; a node beyond was dropped from the .bt files without a word."""
    kind = np.zeros((3, 3, 3), np.uint8)
    kind[1, 1, 1] = 1
    origin = [0, 0, 0]
    origin[axis] = 32767 + beyond if side > 0 else -32768 - 2 - beyond  # (node 1 on that axis beyond the range)
    out = _tmp("keyrange") / f"{res}-{side}-{beyond}-{axis}"
    with pytest.raises(ValueError, match="key range"):
        write_octomap(_frame(origin, res, kind), out)
    assert not out.exists() or not any(out.iterdir())


def test_unknown_node_kinds_and_a_wrong_shape_are_refused(tmp_path):
    kind = np.zeros((2, 2, 2), np.uint8)
    kind[0, 1, 0] = 4
    with pytest.raises(ValueError, match="kind 4"):
        write_octomap(_frame([0, 0, 0], 0.05, kind), tmp_path / "a")
    frame = _frame([0, 0, 0], 0.05, np.ones((2, 2, 2), np.uint8))._replace(kind=np.ones((2, 2, 3), np.uint8))
    with pytest.raises(ValueError, match="shape"):
        write_octomap(frame, tmp_path / "b")


def test_an_unwritable_destination_is_an_error_naming_it(tmp_path):
    frame = _frame([0, 0, 0], 0.05, _MIXED_BLOCK)
    (tmp_path / "file").write_text("x")
    with pytest.raises(OSError, match="file"):
        write_octomap(frame, tmp_path / "file")
    # OctoMap only prints "Filestream ... not open" and returns False: the files must not be claimed written
    for name in ("occupied.bt", "occluded.bt", "octree.ot"):
        (tmp_path / name / name).mkdir(parents=True)
        with pytest.raises(OSError, match=name):
            write_octomap(frame, tmp_path / name)
    # an existing folder with earlier files: they are replaced
    first = write_octomap(_frame([0, 0, 0], 0.05, np.full((2, 2, 2), 2, np.uint8)), tmp_path / "again")
    write_octomap(frame, tmp_path / "again")
    tree = pyoctomap.OcTree(0.05)
    assert tree.readBinary(str(first["occupied.bt"]))
    assert set(_leaves(tree, 0.05)) == _expected([0, 0, 0], _MIXED_BLOCK, (1,))


# ------------------------------------------------------------------------------------------------ MCAP

_TEXT = st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00"), max_size=12)
_LONG_TEXT = st.text(
    st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00"), min_size=200, max_size=2000
)
_FLOATS = st.floats(allow_nan=True, allow_infinity=True, width=64)
# stamps at and around second boundaries, 0, far in the past and near the int32 seconds' end
_SECONDS = st.sampled_from([0, 1, 59, 1_700_000_000, 2**31 - 2]) | st.integers(0, 2**31 - 2)
_FRACTIONS = st.sampled_from([0.0, 1e-9, 4e-10, 5e-10, 6e-10, 1 - 1e-9, 0.9999999995, 0.5, 0.123456789]) | st.floats(
    0.0, 0.999999999
)
_TIMES = st.builds(lambda s, f: s + f, _SECONDS, _FRACTIONS) | st.sampled_from([-0.5, -1e-9, 0.0])
_F64 = ros2.typestore().types["std_msgs/msg/Float64"]


@st.composite
def _messages(draw):
    """``(topic, typename, msg, t)``: a message of one of several types at a drawn log time."""
    t = draw(_TIMES)
    what = draw(st.sampled_from(["f64", "js", "img", "status", "array"]))
    if what == "f64":
        return "/f64", "std_msgs/msg/Float64", _F64(data=draw(_FLOATS)), t
    if what == "js":
        names = draw(st.lists(_TEXT, max_size=5))
        q = np.array(draw(st.lists(_FLOATS, min_size=len(names), max_size=len(names))), float)
        qd = np.array(draw(st.lists(_FLOATS, min_size=len(names), max_size=len(names))), float)
        msg = ros2.joint_state_msg(t, names, q, qd if draw(st.booleans()) else None, draw(_TEXT))
        return draw(st.sampled_from(["/joint_states", "/ジョイント"])), "sensor_msgs/msg/JointState", msg, t
    if what == "img":
        h, w = draw(st.integers(0, 4)), draw(st.integers(0, 5))
        bits = draw(st.lists(st.integers(0, 2**32 - 1), min_size=h * w, max_size=h * w))
        depth = np.array(bits, dtype="<u4").view("<f4").reshape(h, w)
        return "/cam/depth", "sensor_msgs/msg/Image", ros2.image_msg(t, draw(_TEXT), depth, "32FC1"), t
    if what == "status":
        msg = ros2.status_msg(t, draw(_LONG_TEXT | _TEXT), draw(_FLOATS), draw(_TEXT), draw(_FLOATS))
        return "/depthguard/status", "depthguard_msgs/msg/ControllerStatus", msg, t
    values = np.array(draw(st.lists(_FLOATS, max_size=6)), float)
    return "/array", "std_msgs/msg/Float64MultiArray", ros2.float64_array_msg(values), t


def _same(decoded, written, path: str = "msg") -> None:
    """``decoded`` (an ``mcap_ros2`` or ``rosbags`` message) holds the values of the ``rosbags`` message
    ``written``, floats bit for bit."""
    if hasattr(written, "__dataclass_fields__"):
        for name in written.__dataclass_fields__:
            if name != "__msgtype__":
                _same(getattr(decoded, name), getattr(written, name), f"{path}.{name}")
    elif isinstance(written, np.ndarray):
        got = np.frombuffer(decoded, np.uint8) if isinstance(decoded, bytes | bytearray) else np.asarray(decoded)
        assert got.shape == written.shape and got.astype(written.dtype).tobytes() == written.tobytes(), path
    elif isinstance(written, list):
        assert len(decoded) == len(written), path
        for i, (a, b) in enumerate(zip(decoded, written, strict=True)):
            _same(a, b, f"{path}[{i}]")
    elif isinstance(written, float):
        assert struct.pack("<d", decoded) == struct.pack("<d", written), (path, decoded, written)
    else:
        assert decoded == written and type(decoded) is type(written), (path, decoded, written)


def _exact_ns_bound(t: float, ns: int) -> bool:
    """``ns`` is ``t`` seconds to the nearest nanosecond (the float's exact value)."""
    exact = Fraction(max(t, 0.0)) * 10**9
    return abs(Fraction(ns) - exact) <= Fraction(1, 2)


@settings(max_examples=40, **_SETTINGS)
@given(st.lists(_messages(), max_size=12), st.sampled_from(["zstd", "lz4", "none"]))
@example(
    [("/js", "sensor_msgs/msg/JointState", ros2.joint_state_msg(1.9999999995, [], np.zeros(0)), 1.9999999995)], "zstd"
)
def test_a_recording_reads_back_equal_with_the_independent_readers(msgs, compression):
    path = _tmp("mcap") / "r.mcap"
    with Ros2McapWriter(path, compression=compression) as w:
        for topic, typename, msg, t in msgs:
            w.write(topic, typename, msg, t)
    with open(path, "rb") as fh:
        reader = make_reader(fh, validate_crcs=True, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        assert header.profile == "ros2"
        summary = reader.get_summary()
        assert summary is not None and summary.statistics.message_count == len(msgs)
        assert (len(summary.chunk_indexes) > 0) == (len(msgs) > 0)
        counts = Counter(topic for topic, *_ in msgs)
        assert {summary.channels[c].topic: n for c, n in summary.statistics.channel_message_counts.items()} == counts
        for ch in summary.channels.values():
            assert ch.message_encoding == "cdr"
            schema = summary.schemas[ch.schema_id]
            assert schema.encoding == "ros2msg"
            assert {m[1] for m in msgs if m[0] == ch.topic} == {schema.name}
        seen = set()
        last = -1
        for schema, channel, record, decoded in reader.iter_decoded_messages(log_time_order=True):
            topic, typename, msg, t = msgs[record.sequence]  # (the writer numbers its messages)
            seen.add(record.sequence)
            assert (channel.topic, schema.name) == (topic, typename)
            assert record.log_time == record.publish_time and record.log_time >= last
            last = record.log_time
            assert _exact_ns_bound(t, record.log_time), (t, record.log_time)
            stamp = getattr(getattr(decoded, "header", None), "stamp", None)
            if stamp is not None:  # (built with the same t: the header says what the log time says)
                assert 0 <= stamp.nanosec < 10**9 and 0 <= stamp.sec < 2**31
                assert stamp.sec * 10**9 + stamp.nanosec == record.log_time
            _same(decoded, msg)
        assert seen == set(range(len(msgs)))
    from rosbags.highlevel import AnyReader

    with AnyReader([path]) as ar:
        got = Counter()
        last = -1
        for conn, t_ns, raw in ar.messages():
            assert t_ns >= last
            last = t_ns
            got[(conn.topic, conn.msgtype, t_ns, bytes(raw))] += 1
        want = Counter()
        for topic, typename, msg, t in msgs:
            want[(topic, typename, round(Fraction(max(t, 0.0)) * 10**9), ros2.serialize(msg, typename))] += 1
        assert got == want
        for conn, _, raw in ar.messages():  # (decoded from the file's own schema text)
            matches = [m for tp, _, m, _ in msgs if tp == conn.topic and ros2.serialize(m, conn.msgtype) == bytes(raw)]
            _same(ar.deserialize(raw, conn.msgtype), matches[0])


def test_writer_lifecycle_and_refused_messages(tmp_path):
    path = tmp_path / "w.mcap"
    w = Ros2McapWriter(path)
    w.write("/f64", "std_msgs/msg/Float64", _F64(data=1.5), 1.0)
    # a log time that is not a time: refused naming the topic, the file unchanged
    for t in (math.nan, math.inf):
        with pytest.raises(ValueError, match="'/f64'.*finite"):
            w.write("/f64", "std_msgs/msg/Float64", _F64(data=2.0), t)
    with pytest.raises(ValueError, match="'/f64'.*2\\*\\*31 s"):
        w.write("/f64", "std_msgs/msg/Float64", _F64(data=2.0), 2.0e10)
    # a header stamp beyond int32 seconds: rosbags' struct.error before; now a ValueError naming topic and type
    with pytest.raises(ValueError, match="2\\*\\*31"):  # (DepthGuard's own stamps refuse it first)
        ros2.joint_state_msg(2.0**31, ["a"], np.zeros(1))
    late = ros2.joint_state_msg(1.0, ["a"], np.zeros(1))
    late.header.stamp.sec = 2**31
    with pytest.raises(ValueError, match="'/js'.*sensor_msgs/msg/JointState"):
        w.write("/js", "sensor_msgs/msg/JointState", late, 1.0)
    with pytest.raises(ValueError, match="already carries"):
        w.write("/f64", "sensor_msgs/msg/JointState", ros2.joint_state_msg(1.0, [], np.zeros(0)), 1.0)
    w.write("/js", "sensor_msgs/msg/JointState", ros2.joint_state_msg(2**31 - 1, ["a"], np.ones(1)), 2**31 - 1)
    w.close()
    w.close()  # (twice: nothing happens)
    # after close: refused, never silently lost
    with pytest.raises(ValueError, match="closed"):
        w.write("/f64", "std_msgs/msg/Float64", _F64(data=3.0), 3.0)
    got = [(m[0], m[2]) for m in read_messages(path)]
    assert got == [("/f64", 1.0), ("/js", float(2**31 - 1))]  # (2147483647.0000002 before: ns * 1e-9)
    # an exception inside the with block still leaves a complete file
    with pytest.raises(RuntimeError), Ros2McapWriter(tmp_path / "x.mcap") as w2:
        w2.write("/f64", "std_msgs/msg/Float64", _F64(data=1.0), 0.25)
        raise RuntimeError("boom")
    assert [m[2] for m in read_messages(tmp_path / "x.mcap")] == [0.25]


@settings(max_examples=30, **_SETTINGS)
@given(st.lists(st.integers(0, 2**51) | st.sampled_from([7_500_000_000, 10**9 - 1, 10**9, 10**9 + 1]), max_size=8))
@example([7_500_000_000])  # read back as 7.500000000000001 s (ns * 1e-9 instead of ns / 1e9)
def test_log_times_of_whole_nanoseconds_read_back_exactly(ns_list):
    path = _tmp("times") / "t.mcap"
    with Ros2McapWriter(path) as w:
        for ns in ns_list:
            w.write("/f64", "std_msgs/msg/Float64", _F64(data=float(ns)), ns / 1e9)
    got = [(m[2], m[3].data) for m in read_messages(path)]
    assert got == sorted((ns / 1e9, float(ns)) for ns in ns_list)


def _big_recording() -> tuple[bytes, list[bytes]]:
    """An uncompressed recording of several chunks and the CDR bytes of its messages, in write order."""
    path = _tmp("big") / "big.mcap"
    rng = np.random.default_rng(7)
    raws = []
    with Ros2McapWriter(path, compression="none") as w:
        for i in range(14):
            msg = ros2.image_msg(0.1 * i, "cam", rng.random((240, 320)).astype(np.float32) + 0.5, "32FC1")
            w.write("/cam/depth", "sensor_msgs/msg/Image", msg, 0.1 * i)
            raws.append(ros2.serialize(msg, "sensor_msgs/msg/Image"))
            js = ros2.joint_state_msg(0.1 * i, ["a", "b"], rng.random(2))
            w.write("/joint_states", "sensor_msgs/msg/JointState", js, 0.1 * i)
            raws.append(ros2.serialize(js, "sensor_msgs/msg/JointState"))
    return path.read_bytes(), raws


_BIG: list = []


def _stream_messages(raw: bytes, skip_magic: bool = False) -> list:
    """The messages that MCAP's stream reader reads from ``raw`` before it ends or breaks off."""
    out = []
    try:
        for record in StreamReader(io.BytesIO(raw), skip_magic=skip_magic).records:
            if isinstance(record, Message):
                out.append(record)
    except Exception:  # noqa: BLE001 - (the cut record: where the stream ends)
        pass
    return out


@settings(max_examples=12, **_SETTINGS)
@given(st.floats(0.0, 1.0, exclude_max=True))
@example(0.999)
def test_a_recording_cut_short_keeps_its_complete_chunks_readable(where):
    """A process killed mid-write leaves a file without summary: our reader refuses it naming the file, and
    MCAP's stream reader reads the messages of every chunk complete before the cut, unchanged."""
    if not _BIG:
        _BIG.append(_big_recording())
    raw, raws = _BIG[0]
    cut = int(where * len(raw))
    with open(_tmp("big") / "big.mcap", "rb") as fh:
        chunks = make_reader(fh).get_summary().chunk_indexes
    assert len(chunks) >= 3
    complete = 0
    for c in chunks:
        if c.chunk_start_offset + c.chunk_length <= cut:
            part = raw[c.chunk_start_offset : c.chunk_start_offset + c.chunk_length]
            complete += len(_stream_messages(part, skip_magic=True))
    got = _stream_messages(raw[:cut])
    assert complete > 0 or cut < chunks[0].chunk_start_offset + chunks[0].chunk_length
    assert len(got) >= complete
    assert [r.sequence for r in got] == list(range(len(got)))
    assert all(r.data == raws[r.sequence] for r in got)
    cut_path = _tmp("big") / "cut.mcap"
    cut_path.write_bytes(raw[:cut])
    with pytest.raises(ValueError, match="cut.mcap"):
        list(read_messages(cut_path))


@st.composite
def _experiment_channels(draw):
    n = draw(st.integers(0, 4))
    names = draw(st.none() | st.lists(_TEXT, min_size=n, max_size=n))
    states = []
    for _ in range(draw(st.integers(0, 4))):
        msg = {"position": draw(st.lists(_FLOATS, min_size=n, max_size=n))}
        if names is not None:
            msg["name"] = names
        for k in ("velocity", "effort"):
            if draw(st.booleans()):
                msg[k] = np.array(draw(st.lists(_FLOATS, min_size=n, max_size=n)))
        states.append((draw(_TIMES), msg))
    other = [
        (
            draw(_TIMES),
            {"a": draw(_FLOATS), "b": draw(st.lists(_FLOATS, max_size=3)), "on": draw(st.booleans()), "s": "x"},
        )
        for _ in range(draw(st.integers(0, 3)))
    ]
    return {"/joint_states": states, "/other": other}


@settings(max_examples=30, **_SETTINGS)
@given(_experiment_channels())
# velocities and efforts were dropped from the joint states without a word
@example({"/joint_states": [(0.5, {"name": ["a"], "position": [1.0], "velocity": [2.0], "effort": [3.0]})]})
def test_experiment_recordings_keep_every_field(channels):
    path = write_mcap(_tmp("explog") / "e.mcap", channels)
    with open(path, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        got = {}
        for schema, channel, record, decoded in reader.iter_decoded_messages(log_time_order=False):
            got.setdefault(channel.topic, []).append((schema.name, record.log_time, decoded))
    for topic, msgs in channels.items():
        assert len(got.get(topic, [])) == len(msgs)
        for (t, want), (typename, ns, msg) in zip(msgs, got.get(topic, []), strict=True):
            assert _exact_ns_bound(t, ns)
            if topic == "/joint_states":
                assert typename == "sensor_msgs/msg/JointState"
                n = len(want["position"])
                assert list(msg.name) == list(want.get("name") or [f"joint{i + 1}" for i in range(n)])
                for k in ("position", "velocity", "effort"):
                    values = np.asarray(want.get(k, []), float)
                    assert np.asarray(msg.__getattribute__(k), float).tobytes() == values.tobytes(), k
            else:
                assert typename == "std_msgs/msg/Float64MultiArray"
                assert [d.label for d in msg.layout.dim] == ["a", "b", "on"]
                flat = np.concatenate([[want["a"]], np.asarray(want["b"], float), [float(want["on"])]])
                assert np.asarray(msg.data, float).tobytes() == flat.tobytes()


def test_experiment_joint_states_of_mismatched_lengths_are_refused(tmp_path):
    for bad in ({"name": ["a", "b"], "position": [1.0]}, {"position": [1.0, 2.0], "velocity": [1.0]}):
        with pytest.raises(ValueError, match="/joint_states message 1"):
            write_mcap(tmp_path / "e.mcap", {"/joint_states": [(0.0, {"position": [0.0]} | {}), (0.1, bad)]})


# ------------------------------------------------------------------------------------ JointState CDR


@settings(max_examples=40, **_SETTINGS)
@given(
    st.sampled_from([math.nan, math.inf, 2.0**31, 1e300]) | st.floats(2.0**31, 1e18),
    st.lists(st.sampled_from(["a", "b", "ü"]), max_size=3),
)
def test_joint_state_stamps_beyond_int32_seconds_are_a_value_error(t, names):
    """The fast encoder raised struct.error (or a bare 'cannot convert float NaN') for these."""
    with pytest.raises(ValueError, match="JointState stamp"):
        joint_state_cdr(t, names, np.zeros(len(names)))


@settings(max_examples=60, **_SETTINGS)
@given(_TIMES, st.lists(_TEXT, max_size=4), _TEXT, st.data())
def test_joint_state_fast_path_at_second_boundaries_is_rosbags_byte_for_byte(t, names, frame_id, data):
    q = np.array(data.draw(st.lists(_FLOATS, min_size=len(names), max_size=len(names))), float)
    qd = np.array(data.draw(st.lists(_FLOATS, min_size=len(names), max_size=len(names))), float)
    ref = ros2.typestore().serialize_cdr(ros2.joint_state_msg(t, names, q, qd, frame_id), "sensor_msgs/msg/JointState")
    got = joint_state_cdr(t, names, q, qd, frame_id)
    assert got == bytes(ref)
    sec, nanosec = struct.unpack_from("<iI", got, 4)
    assert 0 <= nanosec < 10**9 and _exact_ns_bound(t, sec * 10**9 + nanosec)
