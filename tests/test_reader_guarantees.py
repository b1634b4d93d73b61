"""The readers' documented guarantees, attacked as a sceptical reviewer would (README: "every reader rejects bad
input with one line naming the file and key"; ``depthguard.io.files``, ``depthguard.io.cellfile``,
``depthguard.camera``, ``depthguard.io.ros2_images``, ``depthguard.io.rmw_zenoh``, ``depthguard.runner.bag``).

Unlike ``tests/test_input_fuzz.py`` (whatever the bytes, an error names the file), these properties check
that the error names the *key* too, that values of the wrong type are refused rather than converted (numpy
takes ``"1.5"`` and ``true`` for numbers), and that what a reader returns is what the file holds, computed
here independently (``json``, ``struct``, ``pypng``, ``tomllib``), never with another output of the reader.
"""

from __future__ import annotations

import io
import json
import math
import struct
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import png
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from depthguard.camera import Camera
from depthguard.errors import InputError
from depthguard.io import read_camera, read_depth, read_mask, read_points
from depthguard.io.cellfile import read_cell
from depthguard.io.rmw_zenoh import (
    dds_type_name,
    decode_attachment,
    encode_attachment,
    parse_topic_keyexpr,
    ros_type_name,
    topic_keyexpr,
)

SOME = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
FEW = settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])

CAMERA_KEYS = ("width", "height", "fx", "fy", "cx", "cy", "R", "t", "min_depth", "max_depth", "depth_scale")
CAMERA = {
    "width": 4,
    "height": 3,
    "fx": 2.0,
    "fy": 2.5,
    "cx": 2.0,
    "cy": 1.5,
    "R": [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
    "t": [0.0, 0.0, 1.0],
}


def _tmp() -> Path:
    return Path(tempfile.mkdtemp(prefix="depthguard-guarantees-"))


def _one_line_naming(exc: BaseException, *needles: str) -> str:
    msg = str(exc)
    assert "\n" not in msg, msg
    for n in needles:
        assert n in msg, (n, msg)
    return msg


def _rotation(qw: float, qx: float, qy: float, qz: float) -> np.ndarray:
    """A rotation matrix from a (non-zero) quaternion, by the textbook formula."""
    n = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    w, x, y, z = qw / n, qx / n, qy / n, qz / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


quaternions = st.tuples(*[st.floats(-1, 1)] * 4).filter(lambda q: sum(c * c for c in q) > 0.1)
finite = st.floats(-1e6, 1e6, allow_nan=False)


# ------------------------------------------------------------------------------------------- camera JSON
@SOME
@given(
    w=st.integers(1, 5000),
    h=st.integers(1, 5000),
    fx=st.floats(1e-3, 1e5),
    fy=st.floats(1e-3, 1e5),
    cx=finite,
    cy=finite,
    q=quaternions,
    t=st.lists(finite, min_size=3, max_size=3),
    near=st.floats(1e-3, 10),
    span=st.floats(1e-3, 100),
    scale=st.floats(1e-6, 1.0),
)
def test_a_camera_file_reads_back_as_the_numbers_it_holds(w, h, fx, fy, cx, cy, q, t, near, span, scale):
    """The camera of a valid file holds the file's numbers: nothing rescaled, defaulted or reordered."""
    R = _rotation(*q)
    obj = dict(width=w, height=h, fx=fx, fy=fy, cx=cx, cy=cy, R=R.tolist(), t=t)
    obj.update(min_depth=near, max_depth=near + span, depth_scale=scale)
    assume(obj["max_depth"] > near)
    path = _tmp() / "cam.json"
    path.write_text(json.dumps(obj))
    cam = read_camera(path)
    back = json.loads(path.read_text())  # the file, read independently
    assert (cam.width, cam.height, cam.shape) == (back["width"], back["height"], (back["height"], back["width"]))
    for k in ("fx", "fy", "cx", "cy", "min_depth", "max_depth", "depth_scale"):
        assert getattr(cam, k) == back[k], k
    assert cam.R.tolist() == back["R"] and cam.t.tolist() == back["t"]
    Rb, tb = np.array(back["R"]), np.array(back["t"])
    np.testing.assert_allclose(cam.position, -Rb.T @ tb, rtol=1e-12, atol=1e-6)
    np.testing.assert_array_equal(cam.K, [[back["fx"], 0, back["cx"]], [0, back["fy"], back["cy"]], [0, 0, 1]])


# values that no field of a camera file may hold, by field; each must be refused naming the field
_SCALAR_BAD = [None, True, False, "2.0", "", [2.0], {"v": 2.0}, 10**400, -(10**400), "NaN"]
_POSITIVE_BAD = [0, 0.0, -1.0, -1e-300, float("nan"), float("inf"), float("-inf")]
CAMERA_BAD = {
    "width": [*_SCALAR_BAD, 0, -3, 2.5, 2**31, 1e300, float("nan"), float("inf")],
    "height": [*_SCALAR_BAD, 0, -1, 0.5, 2**40],
    "fx": _SCALAR_BAD + _POSITIVE_BAD,
    "fy": _SCALAR_BAD + _POSITIVE_BAD,
    "cx": [*_SCALAR_BAD, float("nan"), float("inf"), float("-inf")],
    "cy": [*_SCALAR_BAD, float("nan"), float("inf")],
    "min_depth": _SCALAR_BAD + _POSITIVE_BAD + [100.0],
    "max_depth": _SCALAR_BAD + _POSITIVE_BAD + [1e-3],
    "depth_scale": _SCALAR_BAD + _POSITIVE_BAD,
    "R": [
        None,
        "eye",
        1.0,
        [],
        [[1, 0, 0], [0, 1, 0]],
        [[1, 0, 0], [0, 1, 0], [0, 0]],
        [[1, 0, 0], [0, 1, 0], [0, 0, 1, 0]],
        [[1, 0, 0], [0, 1, 0], [0, 0, -1]],  # a reflection
        [[2, 0, 0], [0, 1, 0], [0, 0, 1]],
        [[1, 0, 0], [0, 1, 0], [0, 0, float("nan")]],
        [[1, 0, 0], [0, 1, 0], [0, 0, float("inf")]],
        [["1", 0, 0], [0, "1", 0], [0, 0, "1"]],  # strings numpy would convert
        [[True, False, False], [False, True, False], [False, False, True]],  # booleans likewise
        [[1e300, 1e300, 0], [1e300, -1e300, 0], [0, 0, 1]],
        {"rows": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]},
        [[[1, 0, 0]], [[0, 1, 0]], [[0, 0, 1]]],
    ],
    "t": [
        None,
        "0 0 1",
        1.0,
        [],
        [0, 0],
        [0, 0, 1, 0],
        [0, 0, float("nan")],
        [0, float("inf"), 0],
        [0, 0, 10**400],
        ["0", "0", "1"],
        [True, False, True],
        [[0, 0, 1]],
        [None, 0, 1],
    ],
}


@pytest.mark.parametrize("key, value", [(k, v) for k in sorted(CAMERA_BAD) for v in CAMERA_BAD[k]], ids=repr)
def test_a_camera_field_of_a_wrong_type_or_value_is_refused_naming_it(key, value):
    """Every bad value of every field, exhaustively (a few ms each)."""
    obj = dict(CAMERA, min_depth=0.3, max_depth=8.0, depth_scale=0.001)
    obj[key] = value
    path = _tmp() / "cam.json"
    path.write_text(json.dumps(obj))  # (NaN and Infinity are the JSON extensions Python writes and reads)
    with pytest.raises(InputError) as exc:
        read_camera(path)
    # min_depth above max_depth: either may be the wrong one; the message names both
    _one_line_naming(exc.value, str(path), f"'{key}'")


@SOME
@given(
    drop=st.sets(st.sampled_from(sorted(CAMERA)), min_size=1),
    extra=st.dictionaries(st.text(min_size=1, max_size=8).filter(lambda k: k not in CAMERA_KEYS), finite, max_size=2),
)
def test_missing_and_unknown_camera_fields_are_named(drop, extra):
    obj = {k: v for k, v in CAMERA.items() if k not in drop}
    obj.update(extra)
    path = _tmp() / "cam.json"
    path.write_text(json.dumps(obj))
    with pytest.raises(InputError) as exc:
        read_camera(path)
    msg = _one_line_naming(exc.value, str(path))
    assert any(repr(k) in msg for k in drop) or any(repr(k) in msg for k in extra), msg


def _valid_png() -> bytes:
    buf = io.BytesIO()
    png.Writer(width=4, height=3, greyscale=True, bitdepth=16).write(buf, [[1000] * 4] * 3)
    return buf.getvalue()


def _valid_npy() -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.full((3, 4), 1.0, np.float32))
    return buf.getvalue()


OTHER_FORMATS = {
    "empty": b"",
    "png": _valid_png(),
    "npy": _valid_npy(),
    "toml": b'[robot]\nmodel = "lwr4"\n',
    "utf16 json": json.dumps(CAMERA).encode("utf-16"),
    "utf8 bom json": b"\xef\xbb\xbf" + json.dumps(CAMERA).encode(),
    "latin-1 text": '{"width": "\xe9"}'.encode("latin-1"),
    "json number": b"3",
    "json string": b'"camera"',
    "json null": b"null",
    "json list": b"[1, 2, 3]",
    "deep nesting": b"[" * 100_000 + b"]" * 100_000,
    "nul bytes": b"\x00" * 64,
}


@pytest.mark.parametrize("kind", sorted(OTHER_FORMATS))
def test_files_of_another_format_are_refused_by_every_reader(tmp_path, kind):
    """Whatever another format's bytes land in a reader, it raises InputError naming the file."""
    content = OTHER_FORMATS[kind]
    readers = {
        "cam.json": read_camera,
        "pts.json": read_points,
        "depth.png": read_depth,
        "depth.npy": read_depth,
        "mask.png": read_mask,
        "mask.npy": read_mask,
    }
    for name, read in readers.items():
        path = tmp_path / name
        path.write_bytes(content)
        if (kind, name) in {("png", "depth.png"), ("png", "mask.png"), ("npy", "depth.npy"), ("npy", "mask.npy")}:
            read(path)  # (its own format: readable)
            continue
        with pytest.raises(InputError) as exc:
            read(path)
        _one_line_naming(exc.value, str(path))


# ------------------------------------------------------------------------------------------- points JSON
names = st.text(max_size=12)


@SOME
@given(st.lists(st.tuples(names, st.lists(finite, min_size=3, max_size=3), st.floats(0, 1e3)), max_size=6))
def test_points_read_back_as_the_file_holds_them(items):
    path = _tmp() / "pts.json"
    path.write_text(json.dumps([{"name": n, "position": p, "radius": r} for n, p, r in items]))
    back = json.loads(path.read_text())
    got = read_points(path)
    assert [p.name for p in got] == [b["name"] for b in back]
    for p, b in zip(got, back, strict=True):
        assert p.position.tolist() == b["position"] and p.radius == b["radius"]


POINT_BAD = {
    "position": [
        None,
        "0 0 1",
        [0, 0],
        [0, 0, 1, 2],
        [0, 0, float("nan")],
        [0, float("-inf"), 0],
        ["0", "0", "1"],
        [True, 0, 0],
        [[0, 0, 1]],
        {"x": 0},
        [0, 0, 10**400],
    ],
    "radius": [None, "0.1", -0.1, float("nan"), float("inf"), True, [0.1], 10**400],
    "name": [None, 3, ["a"], {"a": 1}, True],
}


@pytest.mark.parametrize("key, value", [(k, v) for k in sorted(POINT_BAD) for v in POINT_BAD[k]], ids=repr)
def test_a_point_field_of_a_wrong_type_or_value_is_refused_naming_the_entry_and_field(key, value):
    n, i = 3, 1
    items = [{"name": f"p{j}", "position": [0.0, 0.0, 1.0], "radius": 0.1} for j in range(n)]
    items[i][key] = value
    path = _tmp() / "pts.json"
    path.write_text(json.dumps(items))
    with pytest.raises(InputError) as exc:
        read_points(path)
    _one_line_naming(exc.value, str(path), f"points[{i}]", key)


# ----------------------------------------------------------------------------------------------- depth
def _png_bytes(rows, width, height, **kw) -> bytes:
    buf = io.BytesIO()
    png.Writer(width=width, height=height, **kw).write(buf, rows)
    return buf.getvalue()


@SOME
@given(
    h=st.integers(1, 6),
    w=st.integers(1, 6),
    seed=st.integers(0, 2**32 - 1),
    scale=st.one_of(st.floats(1e-6, 1.0), st.floats(1e-300, 1e300)),
)
def test_a_16_bit_depth_png_reads_as_its_values_times_the_scale(h, w, seed, scale):
    """Each pixel is ``value * depth_scale`` metres (float32) and 0 is NaN (no reading); a scale that takes the
    values out of float32 metres is refused naming it, never read as inf or 0."""
    raw = np.random.default_rng(seed).integers(0, 65536, size=(h, w))
    raw[0, 0] = 0
    raw[-1, -1] = 65535
    path = _tmp() / "d.png"
    path.write_bytes(_png_bytes(raw.tolist(), w, h, greyscale=True, bitdepth=16))
    cam = Camera(width=w, height=h, fx=1.0, fy=1.0, cx=0.5, cy=0.5, depth_scale=scale)
    try:
        depth = read_depth(path, cam)
    except InputError as exc:
        _one_line_naming(exc, str(path), "depth_scale")
        f32 = np.finfo(np.float32)
        assert scale * 65535 > float(f32.max) or scale < float(f32.smallest_subnormal), scale
        return
    assert depth.dtype == np.float32 and depth.shape == (h, w)
    assert np.array_equal(np.isnan(depth), raw == 0)
    valid = raw > 0
    assert np.all(np.isfinite(depth[valid])) and np.all(depth[valid] > 0)
    np.testing.assert_allclose(depth[valid], raw[valid] * scale, rtol=2e-7 * 4)


FLOAT_DTYPES = ["<f2", ">f2", "<f4", ">f4", "<f8", ">f8"]
specials = st.sampled_from([0.0, -0.0, np.nan, np.inf, -np.inf, -1.0, 1e-50, 1e39, 1e300, 5e-324])


@SOME
@given(
    dtype=st.sampled_from(FLOAT_DTYPES),
    values=st.lists(st.one_of(st.floats(-10, 10), specials), min_size=1, max_size=12),
    fortran=st.booleans(),
)
def test_a_float_npy_depth_is_metres_with_nan_for_no_reading(dtype, values, fortran):
    """NaN exactly where the stored value is no usable depth (0, negative, NaN, inf, or beyond float32)."""
    n = len(values)
    with np.errstate(over="ignore"):
        arr = np.array(values, dtype=np.float64).astype(dtype).reshape(1, n)
    arr = np.asfortranarray(np.repeat(arr, 2, axis=0)) if fortran else np.repeat(arr, 2, axis=0)
    path = _tmp() / "d.npy"
    np.save(path, arr)
    with np.errstate(over="ignore"):
        # the stored values, read with the struct module (not numpy's loader)
        stored = np.array(
            struct.unpack(dtype[0] + {"2": "e", "4": "f", "8": "d"}[dtype[2]] * n, arr[0].astype(dtype).tobytes())
        )
        expect32 = stored.astype(np.float32)
    depth = read_depth(path)
    assert depth.dtype == np.float32 and depth.shape == (2, n)
    usable = np.isfinite(expect32) & (expect32 > 0)
    assert np.array_equal(~np.isnan(depth[0]), usable) and np.array_equal(~np.isnan(depth[1]), usable)
    assert np.array_equal(depth[0][usable], expect32[usable])


@FEW
@given(h=st.integers(1, 5), w=st.integers(1, 5), dh=st.integers(-1, 2), dw=st.integers(-1, 2))
def test_an_image_of_another_size_than_the_camera_names_both_files(h, w, dh, dw):
    assume((dh, dw) != (0, 0) and h + dh > 0 and w + dw > 0)
    d = _tmp()
    cam_path = d / "cam.json"
    cam_path.write_text(json.dumps(dict(CAMERA, width=w + dw, height=h + dh)))
    cam = read_camera(cam_path)
    np.save(d / "depth.npy", np.ones((h, w), np.float32))
    (d / "depth.png").write_bytes(_png_bytes([[1] * w] * h, w, h, greyscale=True, bitdepth=16))
    (d / "mask.png").write_bytes(_png_bytes([[1] * w] * h, w, h, greyscale=True, bitdepth=8))
    for name, read in (("depth.npy", read_depth), ("depth.png", read_depth), ("mask.png", read_mask)):
        with pytest.raises(InputError) as exc:
            read(d / name, cam, cam_path)
        _one_line_naming(exc.value, str(d / name), str(cam_path), "shape")


# ------------------------------------------------------------------------------------------------ masks
@SOME
@given(
    mode=st.sampled_from(["L", "LA", "RGB", "RGBA", "P"]),
    bitdepth=st.sampled_from([1, 2, 4, 8, 16]),
    h=st.integers(1, 5),
    w=st.integers(1, 5),
    seed=st.integers(0, 2**32 - 1),
)
def test_a_png_mask_is_robot_wherever_the_pixel_is_nonzero(mode, bitdepth, h, w, seed):
    """ "nonzero = robot pixel" for every PNG the reader takes: any colour channel (an alpha plane is no
    colour: a transparent black pixel is 0); a palette pixel is its palette colour."""
    if mode in ("LA", "RGB", "RGBA"):
        bitdepth = max(bitdepth, 8)
    if mode == "P":
        bitdepth = min(bitdepth, 8)
    rng = np.random.default_rng(seed)
    planes = {"L": 1, "LA": 2, "RGB": 3, "RGBA": 4, "P": 1}[mode]
    top = 2**bitdepth - 1
    px = rng.integers(0, top + 1, size=(h, w, planes)) * rng.integers(0, 2, size=(h, w, planes))
    kw: dict = {"bitdepth": bitdepth}
    if mode == "P":
        palette = [(0, 0, 0), (0, 9, 0), (0, 0, 1), (7, 0, 0)] * (2**bitdepth // 4 + 1)
        kw["palette"] = palette[: 2**bitdepth]
        colour = np.array([palette[i] for i in px[..., 0].ravel()]).reshape(h, w, 3)
        expect = colour.any(axis=-1)
    else:
        kw.update(greyscale=mode.startswith("L"), alpha=mode.endswith("A"))
        colour_planes = planes - (1 if mode.endswith("A") else 0)
        expect = px[..., :colour_planes].any(axis=-1)
    path = _tmp() / "m.png"
    path.write_bytes(_png_bytes(px.reshape(h, w * planes).tolist(), w, h, **kw))
    assert np.array_equal(read_mask(path), expect)


@SOME
@given(
    dtype=st.sampled_from(["|b1", "|u1", "<i2", ">u2", "<i8", "<f4", ">f8"]),
    seed=st.integers(0, 2**32 - 1),
)
def test_a_npy_mask_is_robot_wherever_the_value_is_nonzero(dtype, seed):
    raw = np.random.default_rng(seed).integers(-2, 3, size=(3, 5))
    arr = raw.astype(np.float64).astype(dtype) if dtype != "|b1" else raw != 0
    path = _tmp() / "m.npy"
    np.save(path, arr)
    assert np.array_equal(read_mask(path), raw != 0)


# ------------------------------------------------------------------------------------------------- cells
CELL = """
[robot]
model = "lwr4"

[[cameras]]
name = "cam"
width = 64
height = 48
fx = 52.0
fy = 52.0
cx = 32.0
cy = 24.0
R = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
t = [0.0, 0.0, 2.0]
"""


def _toml(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return {math.inf: "inf", -math.inf: "-inf"}.get(v, "nan" if math.isnan(v) else repr(v))
    if isinstance(v, int):
        return str(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(_toml(x) for x in v) + "]"
    return "{" + ", ".join(f"{k} = {_toml(x)}" for k, x in v.items()) + "}"


def _cell_with(section: str, key: str, value) -> str:
    """The base cell with ``key = value`` in ``section`` (``cameras``, ``robot``, a table, or an array of
    tables ``robot.spheres`` / ``robot.attachments`` with one valid entry)."""
    line = f"{key} = {_toml(value)}\n"
    if section == "cameras":
        text = CELL
        start = text.index(f"\n{key} = ") if f"\n{key} = " in text else -1
        if start >= 0:  # replace the key's line
            end = text.index("\n", start + 1)
            return text[: start + 1] + line + text[end + 1 :]
        return text + line
    if section == "robot":
        return CELL.replace('model = "lwr4"\n', 'model = "lwr4"\n' + line)
    if section == "robot.spheres":
        entry = {"link": "lwr_link_7", "position": [0.0, 0.0, 0.0], "radius": 0.1}
    elif section == "robot.attachments":
        entry = {"name": "tool", "link": "lwr_link_7", "shape": "box", "size": [0.1, 0.1, 0.1]}
    else:
        return CELL + f"\n[{section}]\n{line}"
    entry[key] = value
    return CELL + f"\n[[{section}]]\n" + "".join(f"{k} = {_toml(v)}\n" for k, v in entry.items())


_NUM_BAD = ["0.4", True, [0.4], float("nan"), float("inf"), float("-inf")]
_VEC3_BAD = [[0, 0], [0, 0, 0, 0], ["0", "0", "1"], [True, False, True], [0, 0, float("nan")], "0 0 1", [[0, 0, 1]]]
CELL_BAD: dict[tuple[str, str], list] = {
    ("cameras", "fx"): [*_NUM_BAD, 0.0, -52.0],
    ("cameras", "cx"): _NUM_BAD,
    ("cameras", "width"): [0, -64, 64.0, "64", True],
    ("cameras", "min_depth"): [*_NUM_BAD, 0.0, -0.3, 9.0],
    ("cameras", "max_depth"): [*_NUM_BAD, 0.0, 0.1],
    ("cameras", "depth_scale"): [*_NUM_BAD, 0.0, -0.001],
    ("cameras", "rate"): [*_NUM_BAD, 0.0, -30.0],
    ("cameras", "noise_coeff"): [*_NUM_BAD, -0.001],
    ("cameras", "t"): _VEC3_BAD,
    ("cameras", "R"): [
        [[1, 0, 0], [0, 1, 0], [0, 0, -1]],
        [["1", "0", "0"], ["0", "1", "0"], ["0", "0", "1"]],
        [[True, False, False], [False, True, False], [False, False, True]],
        [[1, 0, 0], [0, 1, 0]],
        [[1, 0, 0], [0, 1, 0], [0, 0, float("nan")]],
    ],
    ("cameras", "intrinsics"): ["File", "", "tf", 1],
    ("cameras", "parent"): [1, True, ["world"]],
    ("robot", "ee_radius"): [*_NUM_BAD, -0.06],
    ("robot", "control_points"): ["ral9", "RAL-9", "", "icra", 9],
    ("robot", "joint_names"): [[1, 2], "a", [True]],
    ("robot.spheres", "position"): _VEC3_BAD,
    ("robot.spheres", "radius"): [*_NUM_BAD, -0.1],
    ("robot.attachments", "size"): [
        [0.1, 0.1],
        [0.1, 0.1, 0.0],
        [0.1, 0.1, -0.1],
        [0.1, 0.1, float("nan")],
        [0.1, 0.1, float("inf")],
        [True, True, True],
        ["0.1", "0.1", "0.1"],
    ],
    ("robot.attachments", "xyz"): _VEC3_BAD,
    ("robot.attachments", "shape"): ["cube", "Box", 3],
    ("distance", "rho"): [*_NUM_BAD, 0.0, -0.4],
    ("distance", "fill_radius"): [-1, 2.5, True, "4"],
    ("distance", "workspace"): [[0, 1, 0, 1, 0], [1, 0, 0, 1, 0, 1], ["-1", "1", "-1", "1", "0", "1"]],
    ("distance", "mode"): ["nearest", "MIN", 1],
    ("distance", "direction_stride"): [0, -2, "two", 1.5, True],
    ("controller", "rho_ee"): [*_NUM_BAD, 0.0, -0.4],
    ("controller", "rho_body"): [*_NUM_BAD, 0.0, -0.4],
    ("controller", "alpha"): [*_NUM_BAD, 0.0, -6.0],
    ("controller", "v_rep_max"): [*_NUM_BAD, 0.0, -2.0],
    ("controller", "resume_time"): [*_NUM_BAD, -0.1],
    ("controller", "velocity_scale"): [*_NUM_BAD, 0.0, 1.5],
    ("controller", "a_max"): [*_NUM_BAD, 0.0],
    ("controller", "ssm"): [1, "true"],
    ("controller", "ssm_range"): [*_NUM_BAD, 0.0, -0.6],
    ("topics", "joint_states"): [1, True, ["/js"]],
    ("network", "domain"): [-1, 233, True, 1.0],
    ("network", "base_port"): [80, 7447, 70000],
}


@pytest.mark.parametrize("section, key, value", [(*sk, v) for sk in sorted(CELL_BAD) for v in CELL_BAD[sk]], ids=repr)
def test_a_cell_key_of_a_wrong_type_or_value_is_refused_naming_it(section, key, value):
    """Every documented key, given a value of the wrong type or out of its range (for the controller's
    repulsion: a value that would silently disable or reverse it), is refused by ``read_cell`` naming the file
    and the key, before any robot or camera is built. Exhaustive: a few ms per case."""
    path = _tmp() / "cell.toml"
    path.write_text(_cell_with(section, key, value))
    with pytest.raises(ValueError) as exc:
        read_cell(path)
    msg = _one_line_naming(exc.value, str(path), key)
    assert section.split(".")[-1].rstrip("s") in msg, msg


@SOME
@given(
    section=st.sampled_from(["cameras", "robot", "robot.spheres", "robot.attachments", "distance", "controller"]),
    key=st.text("abcdefghijklmnopqrstuvwxyz_", min_size=1, max_size=10),
)
def test_an_unknown_cell_key_is_refused_naming_it(section, key):
    known = {
        "cameras": "name topic info_topic frame_id intrinsics width height fx fy cx cy min_depth max_depth "
        "depth_scale rate extrinsics R t matrix eye target up parent align noise_coeff",
        "robot": "model urdf ee_frame joint_names control_points ee_radius spheres attachments",
        "robot.spheres": "link position radius",
        "robot.attachments": "name link shape size mesh xyz rpy",
        "distance": "backend rho mode invalid fill_radius grid_dd workspace octree_res period direction_stride",
        "controller": "rate distance_timeout joint_timeout resume_time velocity_scale a_max j_max rho_ee rho_body "
        "alpha v_rep_max ssm ssm_range background",
    }[section].split()
    assume(key not in known)
    path = _tmp() / "cell.toml"
    path.write_text(_cell_with(section, key, 1.0))
    with pytest.raises(ValueError) as exc:
        read_cell(path)
    _one_line_naming(exc.value, str(path), repr(key))


@SOME
@given(
    q=quaternions,
    t=st.lists(st.floats(-10, 10), min_size=3, max_size=3),
    fx=st.floats(1, 2000),
    cx=st.floats(-100, 100),
    w=st.integers(1, 4000),
    near=st.floats(0.01, 1),
    far=st.floats(2, 50),
    use_matrix=st.booleans(),
)
def test_a_cell_camera_is_built_with_the_numbers_of_the_file(q, t, fx, cx, w, near, far, use_matrix):
    R = _rotation(*q)
    intr = f"width = {w}\nheight = 48\nfx = {fx!r}\nfy = 52.0\ncx = {cx!r}\ncy = 24.0\n"
    intr += f"min_depth = {near!r}\nmax_depth = {far!r}\n"
    if use_matrix:
        M = np.eye(4)
        M[:3, :3], M[:3, 3] = R, t
        ext = f"matrix = {_toml(M.tolist())}\n"
    else:
        ext = f"R = {_toml(R.tolist())}\nt = {_toml(list(t))}\n"
    path = _tmp() / "cell.toml"
    path.write_text('[robot]\nmodel = "lwr4"\n[[cameras]]\nname = "c"\n' + intr + ext)
    import tomllib

    raw = tomllib.loads(path.read_text())["cameras"][0]  # the file, read independently
    cam = read_cell(path).cameras[0].build()
    assert (cam.width, cam.fx, cam.cx, cam.min_depth, cam.max_depth) == (
        raw["width"],
        raw["fx"],
        raw["cx"],
        raw["min_depth"],
        raw["max_depth"],
    )
    Rf = np.array(raw["matrix"])[:3, :3] if use_matrix else np.array(raw["R"])
    tf = np.array(raw["matrix"])[:3, 3] if use_matrix else np.array(raw["t"])
    assert np.array_equal(cam.R, Rf) and np.array_equal(cam.t, tf)


def test_cell_keys_that_another_source_would_silently_override_are_refused(tmp_path):
    """``extrinsics = "tf"`` with R / t (or matrix, eye, target): the file's numbers would be dropped for the
    bag's TF; ``intrinsics = "camera_info"`` keeps the file's depth range and scale, so they are checked too."""
    no_intr = CELL.replace("width = 64\nheight = 48\nfx = 52.0\nfy = 52.0\ncx = 32.0\ncy = 24.0\n", "")
    for text, needle in (
        (CELL + 'extrinsics = "tf"\n', "extrinsics"),
        (no_intr + 'intrinsics = "camera_info"\nmin_depth = 5.0\nmax_depth = 1.0\n', "max_depth"),
        (no_intr + 'intrinsics = "device"\ndepth_scale = 0.0\n', "depth_scale"),
    ):
        (tmp_path / "cell.toml").write_text(text)
        with pytest.raises(ValueError) as exc:
            read_cell(tmp_path / "cell.toml")
        _one_line_naming(exc.value, str(tmp_path / "cell.toml"), needle)


CALIBRATION_BAD = {
    "cameras = 3\n": "cameras",
    "cameras = [1, 2]\n": "cameras",
    "cameras = []\ncamera = []\n": "camera",
    '[[camera]]\nname = "cam"\nR = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\nt = [0, 0, 5]\n': "camera",
    '[cameras]\nname = "cam"\n': "cameras",
    "[[cameras]]\nname = [1]\n": "cameras[0]",
    '[[cameras]]\nname = "other"\n': "cameras[0]",
    '[[cameras]]\nname = "cam"\nR = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\nt = ["0", "0", "5"]\n': "cameras[0].t",
    '[[cameras]]\nname = "cam"\nR = [[1, 0, 0], [0, 1, 0], [0, 0, -1]]\nt = [0, 0, 5]\n': "cameras[0].R",
    '[[cameras]]\nname = "cam"\nt = [0, 0, 5]\n': "cameras[0].R",
    '[[cameras]]\nname = "cam"\nR = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\nt = [0, 0, 5]\nrsme = 0.1\n': "rsme",
}


@pytest.mark.parametrize("text", sorted(CALIBRATION_BAD))
def test_a_broken_calibration_file_is_refused_naming_it_and_the_key(tmp_path, text):
    """The calibration file (``calibration = "..."``) is a reader too: its structure and keys are checked;
    a typo such as ``[[camera]]`` never leaves the cell's own extrinsics silently in use."""
    (tmp_path / "cal.toml").write_text(text)
    (tmp_path / "cell.toml").write_text('calibration = "cal.toml"\n' + CELL)
    with pytest.raises(ValueError) as exc:
        read_cell(tmp_path / "cell.toml")
    _one_line_naming(exc.value, "cal.toml", CALIBRATION_BAD[text])


@SOME
@given(data=st.data())
def test_cell_byte_mutations_give_a_cell_or_an_error_naming_the_file(data):
    src = (CELL + "\n[distance]\nrho = 0.4\nworkspace = [-1, 1, -1, 1, 0, 1]\n").encode()
    b = bytearray(src)
    for _ in range(data.draw(st.integers(1, 3))):
        i = data.draw(st.integers(0, max(len(b) - 1, 0)))
        op = data.draw(st.sampled_from(["truncate", "flip", "insert", "delete"]))
        if op == "truncate":
            del b[i:]
        elif op == "flip" and b:
            b[i] ^= data.draw(st.integers(1, 255))
        elif op == "insert":
            b[i:i] = data.draw(st.binary(min_size=1, max_size=4))
        else:
            del b[i : i + data.draw(st.integers(1, 8))]
    path = _tmp() / "cell.toml"
    path.write_bytes(bytes(b))
    try:
        read_cell(path)
    except ValueError as exc:
        _one_line_naming(exc, str(path))


def test_cli_cell_check_refuses_broken_cells_with_one_line(tmp_path):
    """The command line (a real process: nothing on stderr but the one line, no traceback, exit code 2)."""
    from depthguard.robot.model import lwr4_urdf_path

    urdf = lwr4_urdf_path().read_bytes()
    (tmp_path / "cut.urdf").write_bytes(urdf[: len(urdf) // 2])
    cases = {
        "a.toml": (CELL.replace('model = "lwr4"', 'model = "lwr4"\ncontrol_points = "ral9"'), "robot.control_points"),
        "b.toml": (CELL + "\n[controller]\nv_rep_max = -2.0\n", "controller.v_rep_max"),
        "c.toml": (CELL.replace('model = "lwr4"', 'urdf = "cut.urdf"'), "cut.urdf"),
    }
    for name, (text, needle) in cases.items():
        (tmp_path / name).write_text(text)
        r = subprocess.run(
            [sys.executable, "-m", "depthguard.cli", "cell", "check", str(tmp_path / name)],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert r.returncode == 2 and r.stdout == "", (name, r)
        assert r.stderr.count("\n") == 1 and needle in r.stderr and str(tmp_path) in r.stderr, (name, r.stderr)


# --------------------------------------------------------------------------------------------- ROS 2
@SOME
@given(
    enc=st.sampled_from(["16UC1", "mono16", "32FC1", "16uc1", "8UC1", "rgb8", "", "32FC3"]),
    h=st.integers(0, 4),
    w=st.integers(0, 4),
    step_extra=st.integers(-3, 5),
    size_extra=st.integers(-8, 8),
    big=st.booleans(),
    seed=st.integers(0, 2**32 - 1),
)
def test_image_to_depth_decodes_the_samples_or_refuses_with_a_value_error(enc, h, w, step_extra, size_extra, big, seed):
    """Any combination of encoding, size, step, byte order and data length: a ValueError, or the samples where
    the header says they are (read here with ``struct``), in metres, with NaN for no reading."""
    from depthguard.io.ros2 import _t, header, image_to_depth

    item = {"16UC1": 2, "MONO16": 2, "32FC1": 4}.get(enc.upper(), 1)
    step = max(w * item + step_extra, 0)
    n = max(step * h + size_extra, 0)
    data = np.random.default_rng(seed).integers(0, 256, size=n).astype(np.uint8)
    msg = _t("sensor_msgs/msg/Image")(
        header=header(0.0, "c"), height=h, width=w, encoding=enc, is_bigendian=int(big), step=step, data=data
    )
    try:
        depth = image_to_depth(msg)
    except ValueError:
        ok = enc.upper() in ("16UC1", "MONO16", "32FC1") and (step or w * item) >= w * item
        assert not ok or n < (step or w * item) * h
        return
    assert enc.upper() in ("16UC1", "MONO16", "32FC1")
    rowstep = step or w * item
    fmt = (">" if big else "<") + ("H" if item == 2 else "f")
    raw = bytes(data)
    expect = np.full((h, w), np.nan, np.float32)
    for v in range(h):
        for u in range(w):
            (x,) = struct.unpack_from(fmt, raw, v * rowstep + u * item)
            x = x / 1000.0 if item == 2 else x
            if math.isfinite(x) and x > 0:
                expect[v, u] = x
    assert depth.shape == (h, w) and depth.dtype == np.float32
    np.testing.assert_array_equal(depth, expect)


def _bag_with_camera_info(path: Path, k0: float, quat=(0.0, 0.0, 0.0, 1.0)) -> None:
    from depthguard.io import ros2
    from depthguard.io.mcap_ros2 import Ros2McapWriter

    cam = Camera(width=4, height=3, fx=2.0, fy=2.0, cx=2.0, cy=1.5)
    info = ros2.camera_info_msg(0.0, "cam_optical", cam)
    info.k[0] = k0
    tf = ros2.tf_msg(0.0, [("world", "cam_optical", np.eye(3), np.zeros(3))])
    tf.transforms[0].transform.rotation.x, tf.transforms[0].transform.rotation.y = quat[0], quat[1]
    tf.transforms[0].transform.rotation.z, tf.transforms[0].transform.rotation.w = quat[2], quat[3]
    with Ros2McapWriter(path) as w:
        w.write("/tf_static", "tf2_msgs/msg/TFMessage", tf, 0.0)
        w.write("/cam/depth/camera_info", "sensor_msgs/msg/CameraInfo", info, 0.0)
        w.write("/cam/depth/image_raw", "sensor_msgs/msg/Image", ros2.image_msg(0.0, "c", np.ones((3, 4))), 0.0)
        w.write("/joint_states", "sensor_msgs/msg/JointState", ros2.joint_state_msg(0.0, ["a"], np.zeros(1)), 0.0)


@pytest.mark.parametrize("k0", [0.0, float("nan"), -2.0, float("inf")])
def test_a_bag_whose_camera_info_is_not_a_calibration_names_the_bag_and_topic(tmp_path, k0):
    """An uncalibrated camera publishes K = 0: the bag reader names the bag and the CameraInfo topic (it said
    only "camera field 'fx' must be a positive finite number")."""
    from depthguard.runner.bag import BagSource

    cell_text = '[robot]\nmodel = "lwr4"\n[[cameras]]\nname = "cam"\nintrinsics = "camera_info"\nextrinsics = "tf"\n'
    (tmp_path / "cell.toml").write_text(cell_text)
    cell = read_cell(tmp_path / "cell.toml")
    _bag_with_camera_info(tmp_path / "ok.mcap", 2.0)
    assert BagSource(tmp_path / "ok.mcap", cell, ("a",)).cameras[0].fx == 2.0
    _bag_with_camera_info(tmp_path / "b.mcap", k0)
    with pytest.raises(ValueError) as exc:
        BagSource(tmp_path / "b.mcap", cell, ("a",))
    _one_line_naming(exc.value, str(tmp_path / "b.mcap"), "/cam/depth/camera_info", "'fx'")


@SOME
@given(st.binary(max_size=40), st.integers(0, 40), st.integers(0, 255))
def test_an_attachment_decodes_to_what_reencodes_to_its_bytes_or_is_refused(raw, i, byte):
    b = bytearray(encode_attachment(7, 8, bytes(range(16))) if len(raw) % 3 else raw)
    if b and i < len(b):
        b[i] = byte
    try:
        att = decode_attachment(bytes(b))
    except ValueError:
        assert len(b) != 33 or b[16] != 16
        return
    assert encode_attachment(*att) == bytes(b)
    assert att.seq == struct.unpack_from("<q", b, 0)[0] and att.stamp_ns == struct.unpack_from("<q", b, 8)[0]


_part = st.text("abcXYZ_09/", min_size=0, max_size=6)  # (':' inside a part: see the report, dds_type_name)


@SOME
@given(pkg=_part, kind=st.sampled_from(["msg", "srv", "action", "foo", ""]), name=_part)
def test_ros_type_name_is_the_inverse_of_dds_type_name(pkg, kind, name):
    """``ros_type_name`` is documented as the inverse of ``dds_type_name``, refusing anything else: what it
    returns maps back to the same DDS name (it returned '/msg/T' for '::msg::dds_::T_', 'a/b/msg/T' for
    'a/b::msg::dds_::T_', which no type name gives)."""
    dds = f"{pkg}::{kind}::dds_::{name}_"
    try:
        ros = ros_type_name(dds)
    except ValueError:
        typename = f"{pkg}/{kind}/{name}"
        with pytest.raises(ValueError):
            assert dds_type_name(typename) == dds  # (no type name gives this DDS name)
        return
    assert dds_type_name(ros) == dds


@FEW
@given(
    domain=st.integers(0, 232),
    topic=st.lists(st.text("abc_019", min_size=1, max_size=5), min_size=1, max_size=3),
    typename=st.sampled_from(["sensor_msgs/msg/Image", "sensor_msgs/msg/JointState", "tf2_msgs/msg/TFMessage"]),
)
def test_topic_key_expressions_parse_back_to_their_parts(domain, topic, typename):
    name = "/" + "/".join(topic)
    key = topic_keyexpr(domain, name, typename, hash_="RIHS01_" + "0" * 64)
    assert key.split("/")[0] == str(domain)
    parsed = parse_topic_keyexpr(key)
    assert (parsed.domain, parsed.topic, parsed.typename) == (domain, name, typename)


# ------------------------------------------------------------------------------------------ robot model
@settings(FEW, suppress_health_check=[HealthCheck.function_scoped_fixture])  # (capfd is emptied per example)
@given(cut=st.floats(0.05, 0.95))
def test_a_truncated_urdf_is_refused_in_one_line_naming_it(cut, capfd):
    """Before pinocchio's URDF parser (which logs its own multi-line errors on the process's stderr) sees it."""
    from depthguard.robot.model import RobotModel, lwr4_urdf_path

    src = lwr4_urdf_path().read_bytes()
    path = _tmp() / "arm.urdf"
    path.write_bytes(src[: int(len(src) * cut)])
    capfd.readouterr()
    with pytest.raises(ValueError) as exc:
        RobotModel.from_urdf(path)
    _one_line_naming(exc.value, str(path))
    assert capfd.readouterr().err == ""


def test_the_cell_file_s_control_point_choices_are_the_presets() -> None:
    """``robot.control_points`` is checked against a list kept in the reader (free of pinocchio): it must be
    the presets of :mod:`depthguard.robot.control_points`, plus "auto" and "ee"."""
    from depthguard.io.cellfile import CONTROL_POINT_CHOICES
    from depthguard.robot.control_points import PRESETS

    assert sorted(CONTROL_POINT_CHOICES) == sorted([*PRESETS, "auto", "ee"])


def test_an_unreadable_cell_file_is_named(tmp_path, monkeypatch) -> None:
    """An OSError while reading (here: permission denied, raised by a stand-in, since root reads any file)
    is a CellError naming the file, not a traceback."""
    from pathlib import Path

    from depthguard.io.cellfile import CellError, read_cell

    cell = tmp_path / "cell.toml"
    cell.write_text("[cell]\n")

    def denied(self, *a, **k):
        raise PermissionError(13, "Permission denied", str(self))

    monkeypatch.setattr(Path, "read_text", denied)
    with pytest.raises(CellError, match=r"cell\.toml: cannot be read \(Permission denied\)"):
        read_cell(cell)
