"""Property tests of what the speed and separation monitor relies on besides the distances: the background
pixel rule (:mod:`depthguard.robot.background`), the background file (:mod:`depthguard.io.background`),
commissioning's background and noise estimate (:mod:`depthguard.runner.commission`) and the camera health
checks (:mod:`depthguard.robot.health`). Safety first: the monitor must never hide a person it should see,
and a faulty camera must not pass as valid. Each check compares against a reference written here from the
documented rules (docs/ssm.md, docs/real-cell.md §7), exact in rationals where rounding matters.

Cases found by these tests (pinned with ``@example``): a reading of 0, negative or ±inf (no reading) hidden
as background; a negative background depth, or an infinite noise coefficient, hiding every reading; float32
rounding of the threshold hiding a reading nearer than the rule's threshold; shapes that broadcast and
integer images accepted; a background file that its own writer wrote (no ``valid_fraction``) refused, damaged
archives and odd members raising other errors than InputError or passing; one commissioning reading nearer
than the camera's near limit becoming the background; CameraHealth without stamps, crashing on another
image shape, and passing a camera with a NaN ``covered_fraction``.
"""

from __future__ import annotations

import math
from fractions import Fraction
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, initialize, invariant, rule

from depthguard.camera import Camera
from depthguard.errors import InputError
from depthguard.io.background import BackgroundFile, read_background, write_background
from depthguard.robot.background import apply_background, background_threshold
from depthguard.robot.health import CameraHealth
from depthguard.runner.commission import _Accumulator, _camera_entry

F32 = np.float32
SPECIAL = [math.nan, math.inf, -math.inf, 0.0, -0.0, -1.0, 5e-324, 1e-45, 1.2e-38, 3.0e38]


# ------------------------------------------------------------------------------------------ the pixel rule
def _rule(d: float, b: float, robot: bool, c: float, q: float, m: float) -> bool:
    """The documented rule for one pixel, in rationals: background iff not a robot pixel, a reading (finite,
    > 0), a background (finite, > 0) and ``d >= b - (3 c b² + q + m)``."""
    if robot or not (math.isfinite(d) and d > 0 and math.isfinite(b) and b > 0):
        return False
    fb = Fraction(b)
    return Fraction(d) >= fb - (3 * Fraction(c) * fb * fb + Fraction(q) + Fraction(m))


def _exact_threshold(b: float, c: float, q: float, m: float) -> Fraction:
    fb = Fraction(b)
    return fb - (3 * Fraction(c) * fb * fb + Fraction(q) + Fraction(m))


values = st.one_of(st.sampled_from(SPECIAL), st.floats(0.0625, 12.0, width=32))
params = st.one_of(st.sampled_from([0.0, 1.4e-3, 1e-3, 0.01]), st.floats(0.0, 0.05))


@st.composite
def pixel_cases(draw):
    h, w = draw(st.integers(1, 3)), draw(st.integers(1, 5))
    b = np.array(draw(st.lists(values, min_size=h * w, max_size=h * w)), np.float32).reshape(h, w)
    d = np.array(draw(st.lists(values, min_size=h * w, max_size=h * w)), np.float32).reshape(h, w)
    robot = np.array(draw(st.lists(st.booleans(), min_size=h * w, max_size=h * w))).reshape(h, w)
    c, q, m = draw(params), draw(params), draw(params)
    # readings within a few float32 steps of the rule's threshold (where rounding decides)
    steps = draw(st.lists(st.integers(-3, 3) | st.none(), min_size=h * w, max_size=h * w))
    for i, k in enumerate(steps):
        bi = float(b.flat[i])
        if k is None or not (math.isfinite(bi) and bi > 0):
            continue
        t = F32(float(_exact_threshold(bi, c, q, m))) if bi < 1e30 else F32(1.0)
        for _ in range(abs(k)):
            t = np.nextafter(t, F32(np.inf if k > 0 else -np.inf))
        d.flat[i] = t
    dtype = draw(st.sampled_from([np.float32, np.float64]))
    return d.astype(dtype), robot, b, c, q, m


@settings(max_examples=250, deadline=None)
@given(pixel_cases())
@example(  # a reading of 0 or +inf (no reading) behind a threshold <= 0: was hidden as background
    (
        np.array([[0.0, np.inf, 1.0]], F32),
        np.zeros((1, 3), bool),
        np.array([[0.005, 2.0, 0.005]], F32),
        1.4e-3,
        1e-3,
        0.01,
    )
)
@example(  # a negative background: threshold below every reading, hid a person at 1 m
    (np.array([[1.0, -np.inf]], F32), np.zeros((1, 2), bool), np.array([[-1.0, 3e38]], F32), 1.4e-3, 1e-3, 0.01)
)
@example(  # float32 rounding of b - tol (4.7151709 < 4.715171017): a reading nearer than the rule's threshold hidden
    (
        np.array([[4.715170860290527]], F32),
        np.zeros((1, 1), bool),
        np.array([[4.726171016693115]], F32),
        0.0,
        1e-3,
        0.01,
    )
)
@example(  # a reading equal to ``far`` (4.5) was taken for "not hidden": the test's own fault
    (np.array([[4.5, np.nan]], F32), np.zeros((1, 2), bool), np.array([[1e-45, np.nan]], F32), 0.0, 0.0, 0.0)
)
def test_pixel_rule_matches_the_exact_rule(case):
    """Every pixel is background exactly when the documented rule (in rationals) says so for float32 readings;
    a float64 reading is never hidden nearer than the rule's threshold (shown up to one float32 step beyond
    it: the safe side). Background pixels read ``far``, every other pixel is unchanged (NaN stays NaN), the
    dtype is kept and the inputs are not modified."""
    d, robot, b, c, q, m = case
    d0, b0 = d.copy(), b.copy()
    thr = background_threshold(b, c, q, m)
    assert thr.dtype == np.float32 and thr.shape == b.shape
    out = apply_background(d, robot, thr, 4.5)
    assert out.dtype == d.dtype and out.shape == d.shape and not np.shares_memory(out, d)
    np.testing.assert_array_equal(d, d0)
    np.testing.assert_array_equal(b, b0)
    for i in range(d.size):
        di, bi = float(d.flat[i]), float(b.flat[i])
        if di == 4.5:  # (a reading of ``far`` itself reads the same, hidden or not)
            assert float(out.flat[i]) == 4.5
            continue
        want = _rule(di, bi, bool(robot.flat[i]), c, q, m)
        hidden = bool(out.flat[i] == 4.5)
        if d.dtype == np.float32:
            assert hidden == want, (i, di, bi, c, q, m, float(thr.flat[i]))
        else:
            assert not (hidden and not want), (i, di, bi, c, q, m)  # never hides a nearer reading
            if want and not hidden:  # shown: within one float32 step of the threshold
                assert di < float(np.nextafter(F32(float(_exact_threshold(bi, c, q, m))), F32(np.inf)))
        if not hidden:
            np.testing.assert_array_equal(out.flat[i], d.flat[i])
    # the same readings in float32 and float64 are classified alike (exactly representable in both)
    if d.dtype == np.float32:
        np.testing.assert_array_equal(apply_background(d.astype(np.float64), robot, thr, 4.5) == 4.5, out == 4.5)


@pytest.mark.parametrize("bad", [-1e-3, math.nan, math.inf, -math.inf, "x", None])
@pytest.mark.parametrize("which", [0, 1, 2])
def test_tolerance_parameters_are_refused(bad, which):
    """A NaN, infinite or negative c, q or margin is refused naming it (an infinite c hid every pixel, a NaN
    one silently none)."""
    args = [1.4e-3, 1e-3, 0.01]
    args[which] = bad
    with pytest.raises(ValueError, match=("noise_coeff", "quantization", "margin")[which]):
        background_threshold(np.full((2, 2), 2.0, F32), *args)


@pytest.mark.parametrize(
    ("depth", "mask", "thr", "far", "needle"),
    [
        (np.ones((1, 4), F32), np.zeros((3, 1), bool), np.zeros((3, 4), F32), 4.5, "shape"),  # broadcast before
        (np.ones((2, 2), F32), np.zeros((2, 2), bool), np.zeros((1, 2), F32), 4.5, "shape"),
        (np.ones(4, F32), np.zeros(4, bool), np.zeros(4, F32), 4.5, "2-D"),
        (np.full((1, 1), 1000, np.uint16), np.zeros((1, 1), bool), np.zeros((1, 1), F32), 4.5, "float"),  # mm
        (np.ones((1, 1), F32), np.full((1, 1), np.nan), np.zeros((1, 1), F32), 4.5, "mask"),
        (np.ones((1, 1), F32), np.zeros((1, 1), bool), np.zeros((1, 1), F32), math.nan, "far"),
        (np.ones((1, 1), F32), np.zeros((1, 1), bool), np.zeros((1, 1), F32), 0.0, "far"),
    ],
)
def test_apply_background_refuses_wrong_inputs(depth, mask, thr, far, needle):
    with pytest.raises(ValueError, match=needle):
        apply_background(depth, mask, thr, far)


# ------------------------------------------------------------------------------------------ the background file
names_st = st.lists(st.text("abcxyz_0123", min_size=1, max_size=8), min_size=1, max_size=3, unique=True)


@st.composite
def background_files(draw):
    names = tuple(draw(names_st))
    depths = []
    for _ in names:
        h, w = draw(st.integers(1, 4)), draw(st.integers(1, 4))
        vals = draw(
            st.lists(
                st.floats(0.015625, 20.0, width=32) | st.just(math.nan) | st.just(math.inf),
                min_size=h * w,
                max_size=h * w,
            )
        )
        depths.append(np.array(vals, F32).reshape(h, w))
    n = len(names)
    num = st.floats(0.0, 1.0)
    return BackgroundFile(
        names,
        tuple(depths),
        tuple(draw(st.lists(num, min_size=n, max_size=n))),
        tuple(draw(st.lists(num, min_size=n, max_size=n))),
        tuple(draw(st.lists(num, min_size=n, max_size=n))),
        draw(st.text(max_size=20).filter(lambda s: "\x00" not in s)),
        draw(st.integers(0, 10**6)),
        draw(st.text(max_size=20).filter(lambda s: "\x00" not in s)),
        tuple(draw(st.lists(num, min_size=n, max_size=n))) if draw(st.booleans()) else (),
    )


def _same_file(a: BackgroundFile, b: BackgroundFile) -> None:
    assert (a.names, a.noise_coeff, a.quantization, a.margin) == (b.names, b.noise_coeff, b.quantization, b.margin)
    assert (a.date, a.frames, a.source) == (b.date, b.frames, b.source)
    for x, y in zip(a.depths, b.depths, strict=True):
        assert x.dtype == y.dtype == np.float32
        np.testing.assert_array_equal(x, y)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(bg=background_files())
def test_background_file_round_trip(bg, tmp_path):
    """write -> read gives the same cameras, depths (bit for bit, NaN and inf kept), tolerance model and
    metadata; a file without ``valid_fraction`` (the dataclass default) reads back as NaN per camera (it was
    written as an empty array that the reader refused)."""
    p = write_background(tmp_path / "bg.npz", bg)
    back = read_background(p)
    _same_file(back, bg)
    if bg.valid_fraction:
        assert back.valid_fraction == bg.valid_fraction
    else:
        assert len(back.valid_fraction) == len(bg.names) and all(math.isnan(v) for v in back.valid_fraction)


def _good_arrays() -> dict[str, np.ndarray]:
    d0 = np.array([[1.0, np.nan, 3.0], [2.0, 2.5, np.inf]], F32)
    return {
        "format": np.array("depthguard-background"),
        "version": np.array(1),
        "names": np.array(["a", "b"]),
        "sizes": np.array([[3, 2], [3, 1]]),
        "noise_coeff": np.array([1e-3, 2e-3]),
        "quantization": np.array([1e-3, 1e-3]),
        "margin": np.array([0.01, 0.01]),
        "date": np.array("d"),
        "frames": np.array(5),
        "source": np.array("s"),
        "valid_fraction": np.array([0.5, 0.5]),
        "depth_0": d0,
        "depth_1": d0[:1].copy(),
    }


#: (member, replacement or None to delete): every one is refused naming the file and the member.
MUTATIONS = [
    ("format", None),
    ("format", np.array("other")),
    ("format", np.array(["depthguard-background"])),
    ("version", None),
    ("version", np.array(2)),
    ("version", np.array("x")),
    ("version", np.array([1, 1])),
    ("version", np.array(1.5)),
    ("version", np.array(np.nan)),
    ("names", None),
    ("names", np.array(["a"])),
    ("names", np.array(["a", "a"])),
    ("names", np.array([1, 2])),
    ("names", np.array([["a", "b"]])),
    ("names", np.array(["a", ""])),
    ("sizes", None),
    ("sizes", np.array([[3, 2]])),
    ("sizes", np.array([[3.7, 2], [3, 1]])),
    ("sizes", np.array([[2, 3], [3, 1]])),
    ("sizes", np.array([[3, 2], [3, 2]])),
    ("depth_1", None),
    ("depth_0", np.ones((2, 3), np.int32)),
    ("depth_0", np.ones((2, 3), np.complex64)),
    ("depth_0", np.ones(6, F32)),
    ("depth_0", np.full((2, 3), -1.0, F32)),
    ("depth_0", np.zeros((2, 3), F32)),
    ("depth_0", np.full((2, 3), -np.inf, F32)),
    ("depth_0", np.array("x")),
    ("noise_coeff", None),
    ("noise_coeff", np.array([np.nan, 1e-3])),
    ("noise_coeff", np.array([-1e-3, 1e-3])),
    ("noise_coeff", np.array([np.inf, 1e-3])),
    ("noise_coeff", np.array([1e-3])),
    ("noise_coeff", np.array("x")),
    ("quantization", np.array([1e-3, -1.0])),
    ("margin", np.array([np.nan, np.nan])),
    ("margin", None),
    ("margin", np.array([True, False])),
    ("valid_fraction", np.array([0.5])),
    ("valid_fraction", np.array([2.0, 0.5])),
    ("valid_fraction", np.array("x")),
    ("frames", np.array("x")),
    ("frames", np.array(np.nan)),
    ("frames", np.array(-3)),
    ("frames", np.array([1, 2])),
    ("date", np.array([1.0, 2.0])),
    ("source", np.array(3)),
]


@pytest.mark.parametrize(("member", "value"), MUTATIONS, ids=[f"{m}-{i}" for i, (m, _) in enumerate(MUTATIONS)])
def test_background_file_member_mutations_are_named(tmp_path, member, value):
    arrays = _good_arrays()
    if value is None:
        del arrays[member]
    else:
        arrays[member] = value
    p = tmp_path / "bg.npz"
    with open(p, "wb") as f:
        np.savez_compressed(f, **arrays)
    with pytest.raises(InputError) as info:
        read_background(p)
    msg = str(info.value)
    assert str(p) in msg and "\n" not in msg
    assert member.split("_")[0] in msg or (member == "format" and "not a background file" in msg), msg


def test_the_unmutated_member_set_is_read(tmp_path):
    p = tmp_path / "bg.npz"
    with open(p, "wb") as f:
        np.savez_compressed(f, **_good_arrays())
    bg = read_background(p)
    assert bg.names == ("a", "b") and bg.size(1) == (3, 1) and bg.frames == 5


@pytest.fixture(scope="module")
def good_bytes(tmp_path_factory) -> bytes:
    p = tmp_path_factory.mktemp("bgfile") / "bg.npz"
    with open(p, "wb") as f:
        np.savez_compressed(f, **_good_arrays())
    return p.read_bytes()


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
@example(data=None)  # (the pinned damages below)
def test_damaged_background_files_are_refused_or_read_whole(data, good_bytes, tmp_path):
    """Random byte changes, insertions and truncations of a good file: either :class:`InputError` naming the
    file, or a file read whole and consistent (a change in a part no reader looks at); never another
    exception (zlib.error and NotImplementedError escaped before)."""
    raw = bytearray(good_bytes)
    if data is None:  # pinned: each raised another exception than InputError before
        i = raw.index(b"PK\x03\x04")
        start = i + 30 + int.from_bytes(raw[i + 26 : i + 28], "little") + int.from_bytes(raw[i + 28 : i + 30], "little")
        method, stream, encrypted = bytearray(raw), bytearray(raw), bytearray(raw)
        j = raw.index(b"PK\x01\x02")  # the central directory's first entry
        method[j + 10 : j + 12] = (99).to_bytes(2, "little")  # unknown compression method: NotImplementedError
        stream[start] ^= 0xFF  # a broken deflate stream: zlib.error
        encrypted[j + 8] |= 1  # "encrypted" in the central directory: RuntimeError
        cases = [bytes(method), bytes(stream), bytes(encrypted), b"", good_bytes[:40]]
    else:
        for _ in range(data.draw(st.integers(1, 4))):
            pos = data.draw(st.integers(0, len(raw) - 1))
            kind = data.draw(st.sampled_from(["set", "flip", "cut", "insert"]))
            if kind == "set":
                raw[pos] = data.draw(st.integers(0, 255))
            elif kind == "flip":
                raw[pos] ^= 1 << data.draw(st.integers(0, 7))
            elif kind == "cut":
                del raw[pos : pos + data.draw(st.integers(1, 64))]
            else:
                raw[pos:pos] = data.draw(st.binary(min_size=1, max_size=8))
            if not raw:
                break
        cases = [bytes(raw)]
    for k, blob in enumerate(cases):
        p = tmp_path / f"damaged{k}.npz"
        p.write_bytes(blob)
        try:
            bg = read_background(p)
        except InputError as exc:
            assert str(p) in str(exc) and "\n" not in str(exc)
            continue
        assert len(bg.names) == len(bg.depths) == len(bg.noise_coeff) == 2
        assert all(math.isfinite(v) and v >= 0 for v in bg.noise_coeff + bg.quantization + bg.margin)
        assert all(np.all(np.isnan(d) | (d > 0)) for d in bg.depths)


def test_writer_refuses_what_the_reader_would(tmp_path):
    d = np.ones((1, 2), F32)
    for bad in (
        BackgroundFile(("a",), (d, d), (0.0,), (0.0,), (0.0,)),  # more depths than names
        BackgroundFile(("a", "a"), (d, d), (0.0, 0.0), (0.0, 0.0), (0.0, 0.0)),  # duplicate names
        BackgroundFile(("a",), (d,), (-1.0,), (0.0,), (0.0,)),
        BackgroundFile(("a",), (-d,), (0.0,), (0.0,), (0.0,)),
    ):
        with pytest.raises(InputError, match="bg.npz"):
            write_background(tmp_path / "bg.npz", bad)
    assert not (tmp_path / "bg.npz").exists()


# --------------------------------------------------------------------------------------------- commissioning
@settings(max_examples=25, deadline=None)
@given(
    frames=st.integers(5, 40),
    c=st.floats(5e-4, 3e-3),
    quant=st.sampled_from([0.0, 1e-4, 1e-3]),
    seed=st.integers(0, 2**31 - 1),
)
def test_noise_estimate_recovers_the_coefficient(frames, c, quant, seed):
    """Frames of a steady scene with noise σ = c z² (quantized by ``quant`` <= σ, with a few missing pixels):
    the estimate ``median(σ / z²)`` is within -20 % / +15 % of c (the small-sample bias of the median sample
    deviation at 5 frames is -8 %, the quantization adds at most +4 %)."""
    rng = np.random.default_rng(seed)
    h, w = 16, 20
    z_lo = max(0.6, math.sqrt(quant / c)) if quant else 0.6
    z = rng.uniform(z_lo, z_lo + 3.0, (h, w))
    acc = _Accumulator((h, w))
    for _ in range(frames):
        d = z + c * z * z * rng.standard_normal((h, w))
        if quant:
            d = np.round(d / quant) * quant
        d = d.astype(F32)
        d[rng.random((h, w)) < 0.03] = np.nan
        acc.add(d, np.zeros((h, w), bool))
    est = acc.noise_coeff(frames)
    assert est is not None and 0.8 * c <= est <= 1.15 * c, (est, c)


@settings(max_examples=40, deadline=None)
@given(frames=st.integers(1, 8), min_depth=st.sampled_from([0.0, 0.5]), seed=st.integers(0, 2**31 - 1))
@example(frames=5, min_depth=0.5, seed=0)  # one reading of 0.1 m (dust) was the background: hid all behind it
def test_commissioned_background_is_the_nearest_valid_non_robot_depth(frames, min_depth, seed):
    """b = the nearest valid (finite, > 0, >= the camera's near limit) non-robot reading over the frames, NaN
    where none: robot pixels, no reading (0, negative, ±inf) and readings nearer than ``min_depth`` never
    enter it. Fewer than 5 frame sets: the noise is not measured, and without a given coefficient
    commissioning refuses naming ``--noise-coeff``."""
    rng = np.random.default_rng(seed)
    shape = (12, 10)
    acc = _Accumulator(shape, min_depth)
    stack, robots = [], []
    choices = np.array([np.nan, np.inf, -np.inf, 0.0, -1.0, 1e-45, 0.1, 0.4999], F32)
    for _ in range(frames):
        d = rng.uniform(0.5, 5.0, shape).astype(F32)
        odd = rng.random(shape) < 0.3
        d[odd] = rng.choice(choices, int(odd.sum()))
        robot = rng.random(shape) < 0.3
        acc.add(d, robot)
        stack.append(d)
        robots.append(robot)
    s = np.stack(stack)
    valid = np.isfinite(s) & (s > 0) & (s >= min_depth) & ~np.stack(robots)
    ref = np.where(valid, s, np.inf).min(axis=0)
    ref = np.where(valid.any(axis=0), ref, np.nan).astype(F32)
    np.testing.assert_array_equal(acc.near, ref)
    assert acc.near.dtype == np.float32
    if frames < 5:
        assert acc.noise_coeff(frames) is None
        cc = SimpleNamespace(name="cam", noise_coeff=0.0, params={})
        cam = SimpleNamespace(width=shape[1], height=shape[0])
        with pytest.raises(ValueError, match="--noise-coeff"):
            _camera_entry(cc, cam, acc, frames, "bag:x", None, None, 0.01)
        assert _camera_entry(cc, cam, acc, frames, "bag:x", None, 1e-3, 0.01)["noise_coeff"] == 1e-3


def test_commissioning_records_at_the_cameras_near_limit(monkeypatch):
    """``_record`` over a fake source (the self-filter stubbed: no robot pixels): a reading nearer than the
    camera's ``min_depth`` in one frame set does not become the background (it did: that pixel then hid
    every reading behind 0.1 m from the monitor); frame sets without a joint state are skipped."""
    import depthguard.robot.selffilter as selffilter
    import depthguard.runner.chain as chain
    from depthguard.runner.commission import _record

    monkeypatch.setattr(selffilter, "self_filter", lambda c, d, q, model, **kw: (np.zeros(c.shape, bool),))
    monkeypatch.setattr(chain, "self_filter_margins", lambda *a: None)
    cam = Camera(width=4, height=3, fx=4.0, fy=4.0, cx=2.0, cy=1.5, min_depth=0.5, max_depth=4.5)
    frames = [np.full(cam.shape, 2.0 + 0.01 * k, F32) for k in range(6)]
    frames[2][1, 1] = 0.1  # dust in front of the lens
    ticks = [
        SimpleNamespace(t=0.1 * k, q=np.zeros(1), frames=[f], faults=(), xdot_d=None) for k, f in enumerate(frames)
    ]
    ticks.insert(1, SimpleNamespace(t=0.05, q=None, frames=[np.full(cam.shape, 0.7, F32)], faults=(), xdot_d=None))
    src = SimpleNamespace(cameras=[cam], ticks=lambda: iter(ticks), close=lambda: None, duration=np.inf)
    acc, taken = _record(src, None, SimpleNamespace(joint_names=("j",)), "bag:x", 6, False, False)
    assert taken == 6
    np.testing.assert_array_equal(acc[0].near, np.full(cam.shape, 2.0, F32))


# --------------------------------------------------------------------------------------------- camera health
CAM = Camera(width=4, height=3, fx=4.0, fy=4.0, cx=2.0, cy=1.5, min_depth=0.5, max_depth=4.5)


class ScriptedHealth(CameraHealth):
    """CameraHealth whose "sees through the arm" verdict is the first joint (1.0: sees through), so that the
    counting is tested without a robot model."""

    def _sees_through(self, d, q):
        return bool(q[0] > 0.5)


class HealthModel:
    """The documented rules (module docstring, docs/real-cell.md §7) as a plain state machine."""

    def __init__(self, h: CameraHealth) -> None:
        self.h, self.fault, self.last, self.stamp = h, None, None, None
        self.same = self.moved = self.healthy = 0

    def latch(self, now):
        if now is not None:
            self.fault, self.healthy = now, 0
        elif self.fault is not None:
            self.healthy += 1
            if self.healthy >= self.h.clear_frames:
                self.fault, self.healthy = None, 0
        return self.fault

    def covered(self, d):
        n = d.size
        missing = sum(1 for v in d.flat if not (math.isfinite(v) and v > 0 and v >= CAM.min_depth))
        return Fraction(missing, n) > Fraction(self.h.covered_fraction)

    def check(self, d, q, stamp):
        a = np.asarray(d)
        if a.dtype.kind != "f" or a.shape != CAM.shape:
            return self.latch("image")
        a = a.astype(F32)
        if stamp is not None:
            if not math.isfinite(stamp):
                return self.latch("stamp")
            if self.stamp is not None and stamp <= self.stamp:  # stale: not a new frame
                if self.covered(a):
                    return self.latch("covered")
                self.healthy = 0
                return self.fault
            self.stamp = stamp
        self.same = self.same + 1 if self.last is not None and np.array_equal(self.last, a, equal_nan=True) else 0
        self.last = a
        if self.same >= self.h.frozen_frames - 1:
            return self.latch("frozen")
        if self.covered(a):
            return self.latch("covered")
        self.moved = self.moved + 1 if q is not None and q[0] > 0.5 else 0
        return self.latch("moved" if self.moved >= self.h.moved_frames else None)


FRAMES = [np.full(CAM.shape, 2.0, F32), np.full(CAM.shape, 2.5, F32), np.full(CAM.shape, np.nan, F32)]
frame_st = st.one_of(
    st.sampled_from(range(len(FRAMES))),  # repeats of a few frames (frozen)
    st.lists(st.sampled_from([2.0, 1.0, 0.2, 0.0, math.nan, math.inf, -1.0]), min_size=12, max_size=12).map(
        lambda v: np.array(v, F32).reshape(CAM.shape)
    ),
    st.sampled_from([np.ones((4, 3), F32), np.ones((3, 4), np.uint16), np.ones((3, 4, 1), F32), np.ones(0, F32)]),
)


class HealthMachine(RuleBasedStateMachine):
    @initialize(
        frozen=st.integers(2, 4),
        covered=st.sampled_from([0.0, 0.25, 0.5, 0.7, 0.8, 1 / 3]),
        moved=st.integers(1, 3),
        clear=st.integers(1, 4),
    )
    def setup(self, frozen, covered, moved, clear):
        self.h = ScriptedHealth(
            CAM,
            "cam",
            model=object(),
            frozen_frames=frozen,
            covered_fraction=covered,
            moved_frames=moved,
            clear_frames=clear,
        )
        self.ref = HealthModel(self.h)
        self.t = 0.0

    @rule(
        frame=frame_st,
        through=st.sampled_from([None, 0.0, 1.0, math.nan]),
        dt=st.sampled_from([0.033, 0.033, 0.033, 0.0, -0.05, math.nan, math.inf, None]),
    )
    def frame(self, frame, through, dt):
        d = FRAMES[frame].copy() if isinstance(frame, int) else frame
        q = None if through is None else np.array([through, 0.0])
        stamp = None
        if dt is not None:
            stamp = self.t + dt
            if math.isfinite(stamp) and dt > 0:
                self.t = stamp
        ref_q = None if q is None or not np.all(np.isfinite(q)) else q
        want = self.ref.check(d, ref_q, stamp)
        got = self.h.check(d, q, stamp=stamp)
        assert got == want, (got, want)

    @invariant()
    def fault_is_named(self):
        if hasattr(self, "h"):
            assert self.h.fault in (None, "frozen", "covered", "moved", "image", "stamp")


HealthMachine.TestCase.settings = settings(max_examples=60, stateful_step_count=30, deadline=None)
test_camera_health_follows_the_documented_rules = HealthMachine.TestCase


@pytest.mark.parametrize("frozen", [2, 3, 5])
def test_frozen_fires_after_exactly_frozen_frames_with_advancing_stamps(frozen):
    h = CameraHealth(CAM, "cam", frozen_frames=frozen)
    out = [h.check(FRAMES[0], stamp=0.1 * k) for k in range(frozen + 1)]
    assert out == [None] * (frozen - 1) + ["frozen", "frozen"]
    # the same frame with the same (or an older) stamp again and again: a re-sent frame, not frozen evidence
    h2 = CameraHealth(CAM, "cam", frozen_frames=frozen)
    assert [h2.check(FRAMES[0], stamp=s) for s in [1.0] * 6 + [0.5] * 3] == [None] * 9


def test_stale_nan_and_misshapen_frames_never_clear_a_fault():
    h = CameraHealth(CAM, "cam", clear_frames=2)
    assert h.check(FRAMES[2], stamp=1.0) == "covered"
    for stale in (0.5, 1.0, 0.9):  # reordered / repeated stamps of healthy frames
        assert h.check(FRAMES[0] + stale, stamp=stale) == "covered"
    assert h.check(np.ones((5, 5), F32), stamp=2.0) == "image"  # no crash (the moved check broadcast before)
    assert h.check(FRAMES[0], stamp=math.nan) == "stamp"
    assert h.check(FRAMES[0], stamp=3.0) == "stamp" and h.check(FRAMES[1], stamp=4.0) is None


@example(n_missing=7, fraction=0.7)
@example(n_missing=2, fraction=1 / 6)  # 2/12 > float(1/6): covered; 1 - 10/12 rounded below it before
@given(n_missing=st.integers(0, 12), fraction=st.floats(0.0, 0.99))
@settings(max_examples=60, deadline=None)
def test_covered_is_exactly_more_than_the_fraction(n_missing, fraction):
    """ "covered": more than ``covered_fraction`` of the pixels missing, compared exactly (in integers)."""
    d = np.full(CAM.shape, 2.0, F32)
    d.flat[:n_missing] = np.nan
    h = CameraHealth(CAM, "cam", covered_fraction=fraction)
    want = Fraction(n_missing, 12) > Fraction(fraction)
    assert (h.check(d) == "covered") == want


@pytest.mark.parametrize(
    "kw",
    [
        {"frozen_frames": 1},
        {"frozen_frames": 0},
        {"covered_fraction": math.nan},
        {"covered_fraction": 1.0},
        {"moved_fraction": -0.1},
        {"clear_frames": 0},
        {"moved_frames": 2.5},
        {"see_through": math.inf},
    ],
)
def test_health_parameters_that_disable_a_check_are_refused(kw):
    """``frozen_frames = 1`` called every frame frozen; a NaN ``covered_fraction`` never called any covered."""
    with pytest.raises(ValueError, match=next(iter(kw))):
        CameraHealth(CAM, "cam", **kw)
