"""Fuzzing the file readers and the command line with broken files (issue 8 §2).

Byte-level mutations (truncation, flipped, inserted and deleted bytes) and structured mutations (fields
dropped, renamed, retyped or added; PNG chunks corrupted with a correct CRC; ``.npy`` files of other dtypes
and shapes; scenario tables broken) of valid camera JSON, points JSON, depth PNG / ``.npy``, masks and
scenario TOML. Whatever the bytes, a reader either returns or raises :class:`InputError` naming the file, and
``depthguard.cli.main`` (run in-process) returns 0 with JSON on stdout or 2 with one line on stderr that
names the file. Derandomized like every property test here; ``make test-random`` draws fresh examples.
"""

from __future__ import annotations

import contextlib
import copy
import io
import json
import struct
import tempfile
import tomllib
import zlib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from depthguard.camera import Camera, look_at
from depthguard.cli import main
from depthguard.errors import InputError
from depthguard.io import (
    ControlPoint,
    read_camera,
    read_depth,
    read_mask,
    read_points,
    write_camera,
    write_depth,
    write_mask,
    write_points,
)

FUZZ = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
W, H = 32, 24

# ------------------------------------------------------------------------------------------- valid files
_R, _T = look_at([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], up=[0.0, -1.0, 0.0])
CAMERA = Camera(width=W, height=H, fx=26.0, fy=26.0, cx=16.0, cy=12.0, R=_R, t=_T)
DEPTH = np.full((H, W), 2.0, dtype=np.float32)
DEPTH[5:15, 8:20] = 1.2
MASK = np.zeros((H, W), dtype=bool)
MASK[0:4, 0:4] = True
POINTS = [ControlPoint("ee", np.array([0.0, 0.0, 1.0]), 0.05), ControlPoint("elbow", np.array([0.1, 0.0, 0.8]), 0.1)]
WORK = Path(tempfile.mkdtemp(prefix="depthguard-fuzz-"))


def _valid_bytes(kind: str) -> bytes:
    p = WORK / f"valid.{kind}"
    if kind == "cam.json":
        write_camera(p, CAMERA)
    elif kind == "pts.json":
        write_points(p, POINTS)
    elif kind in ("depth.png", "depth.npy"):
        write_depth(p, DEPTH)
    elif kind == "mask.png":
        write_mask(p, MASK)
    elif kind == "mask.npy":
        np.save(p, MASK.astype(np.uint8))
    return p.read_bytes()


VALID = {k: _valid_bytes(k) for k in ("cam.json", "pts.json", "depth.png", "depth.npy", "mask.png", "mask.npy")}
for _k, _b in VALID.items():
    (WORK / _k).write_bytes(_b)


def _run_cli(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(argv)
    return rc, out.getvalue(), err.getvalue()


def _distance_argv(**replace: Path) -> list[str]:
    files = {"camera": WORK / "cam.json", "depth": WORK / "depth.png", "points": WORK / "pts.json"}
    files.update({k: v for k, v in replace.items() if k in files})
    argv = ["distance", "--json", "--rho", "0.5"]
    for k, v in files.items():
        argv += [f"--{k}", str(v)]
    if "mask" in replace:
        argv += ["--mask", str(replace["mask"])]
    return argv


def _check_reader(read, path: Path) -> None:
    try:
        read(path)
    except InputError as exc:
        msg = str(exc)
        assert str(path) in msg and "\n" not in msg, msg


def _check_cli(argv: list[str], path: Path) -> None:
    rc, out, err = _run_cli(argv)
    if rc == 0:
        json.loads(out)
        assert err == ""
    else:
        assert rc == 2, (rc, err)
        assert out == "" and err.count("\n") == 1, err
        assert str(path) in err, err


# --------------------------------------------------------------------------------------- byte mutations
@st.composite
def mutated_bytes(draw, valid: bytes) -> bytes:
    """The valid file with a few random edits, or random bytes."""
    if draw(st.integers(0, 9)) == 0:
        return draw(st.binary(max_size=200))
    b = bytearray(valid)
    for _ in range(draw(st.integers(1, 3))):
        op = draw(st.sampled_from(["truncate", "flip", "insert", "delete", "empty"]))
        i = draw(st.integers(0, max(len(b) - 1, 0)))
        if op == "truncate":
            del b[i:]
        elif op == "flip" and b:
            b[i] ^= draw(st.integers(1, 255))
        elif op == "insert":
            b[i:i] = draw(st.binary(min_size=1, max_size=8))
        elif op == "delete":
            del b[i : i + draw(st.integers(1, 16))]
        elif op == "empty":
            b.clear()
    return bytes(b)


READERS = {
    "cam.json": (read_camera, "camera"),
    "pts.json": (read_points, "points"),
    "depth.png": (lambda p: read_depth(p, CAMERA), "depth"),
    "depth.npy": (lambda p: read_depth(p, CAMERA), "depth"),
    "mask.png": (lambda p: read_mask(p, CAMERA), "mask"),
    "mask.npy": (lambda p: read_mask(p, CAMERA), "mask"),
}


@pytest.mark.parametrize("kind", list(READERS))
@FUZZ
@given(data=st.data())
def test_byte_mutations_give_input_error_naming_the_file(kind, data):
    read, role = READERS[kind]
    path = WORK / f"fuzz-bytes.{kind}"
    path.write_bytes(data.draw(mutated_bytes(VALID[kind])))
    _check_reader(read, path)
    _check_cli(_distance_argv(**{role: path}), path)


def test_a_camera_file_of_another_size_is_named_with_the_image():
    """A camera file whose width or height is not the image's: the wrong number may be in either file, so the
    error names both (found by the byte fuzz above: "width": 32 became 22 and only the image was named)."""
    for field in ("width", "height"):
        cam = json.loads(VALID["cam.json"])
        cam[field] += 7
        path = WORK / f"other-{field}.cam.json"
        path.write_text(json.dumps(cam))
        for kind in ("depth.png", "depth.npy"):
            rc, out, err = _run_cli(_distance_argv(camera=path, depth=WORK / kind))
            assert rc == 2 and out == "" and err.count("\n") == 1, (kind, err)
            assert str(path) in err and str(WORK / kind) in err and "shape" in err, err
        for kind in ("mask.png", "mask.npy"):  # (the CLI reads the depth images first)
            with pytest.raises(InputError, match="shape") as exc:
                read_mask(WORK / kind, read_camera(path), path)
            assert str(path) in str(exc.value) and str(WORK / kind) in str(exc.value)


# ---------------------------------------------------------------------------------- structured mutations
json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=5),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=5), inner, max_size=3),
    max_leaves=8,
)


@st.composite
def mutated_object(draw, obj):
    """Drop, retype or add fields somewhere in a JSON-like object (or a TOML document)."""
    obj = copy.deepcopy(obj)
    for _ in range(draw(st.integers(1, 3))):
        node = obj
        while isinstance(node, dict | list) and node and draw(st.booleans()):
            keys = list(node) if isinstance(node, dict) else list(range(len(node)))
            child = node[draw(st.sampled_from(keys))]
            if not isinstance(child, dict | list) or not child:
                break
            node = child
        if not isinstance(node, dict | list) or not node:
            continue
        keys = list(node) if isinstance(node, dict) else list(range(len(node)))
        key = draw(st.sampled_from(keys))
        op = draw(st.sampled_from(["drop", "retype", "add", "rename"]))
        if op == "drop":
            del node[key]
        elif op == "retype":
            node[key] = draw(json_values)
        elif op == "add" and isinstance(node, dict):
            node[draw(st.text(min_size=1, max_size=8))] = draw(json_values)
        elif op == "rename" and isinstance(node, dict):
            node[str(key).upper() + "_"] = node.pop(key)
    return obj


@pytest.mark.parametrize("kind", ["cam.json", "pts.json"])
@FUZZ
@given(data=st.data())
def test_json_field_mutations(kind, data):
    read, role = READERS[kind]
    obj = data.draw(mutated_object(json.loads(VALID[kind])))
    path = WORK / f"fuzz-fields.{kind}"
    path.write_text(json.dumps(obj))
    _check_reader(read, path)
    _check_cli(_distance_argv(**{role: path}), path)


def test_typos_in_field_names_are_rejected(tmp_path):
    """Unknown keys name the key and list the known ones: a typo never runs with the default."""
    cam = json.loads(VALID["cam.json"])
    cam["min_Depth"] = cam.pop("min_depth")
    (tmp_path / "c.json").write_text(json.dumps(cam))
    with pytest.raises(InputError, match=r"c\.json: .*unknown field 'min_Depth'; known fields: .*'min_depth'"):
        read_camera(tmp_path / "c.json")
    pts = json.loads(VALID["pts.json"])
    pts[1]["raduis"] = 0.3
    (tmp_path / "p.json").write_text(json.dumps(pts))
    with pytest.raises(InputError, match=r"p\.json: points\[1\]: unknown field 'raduis'; known fields: .*'radius'"):
        read_points(tmp_path / "p.json")


def _png_chunks(b: bytes) -> list[tuple[bytes, bytes]]:
    out, i = [], 8
    while i + 8 <= len(b):
        (n,) = struct.unpack(">I", b[i : i + 4])
        out.append((b[i + 4 : i + 8], b[i + 8 : i + 8 + n]))
        i += 12 + n
    return out


def _png_build(chunks: list[tuple[bytes, bytes]]) -> bytes:
    body = b"".join(struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d)) for t, d in chunks)
    return b"\x89PNG\r\n\x1a\n" + body


@pytest.mark.parametrize("kind", ["depth.png", "mask.png"])
@FUZZ
@given(data=st.data())
def test_png_chunk_mutations_with_valid_crc(kind, data):
    """Corrupt header fields and compressed data behind a correct CRC: the decoder's own errors surface."""
    chunks = _png_chunks(VALID[kind])
    i = data.draw(st.integers(0, len(chunks) - 1))
    ctype, payload = chunks[i]
    if ctype == b"IHDR" and data.draw(st.booleans()):
        w, h, bd, ct, comp, filt, inter = struct.unpack(">IIBBBBB", payload)
        w, h = data.draw(st.sampled_from([(w, h), (h, w), (0, h), (2**31 - 1, h), (w, 1), (w * 2, h * 2)]))
        bd = data.draw(st.sampled_from([bd, 1, 2, 4, 8, 16, 3, 32]))
        ct = data.draw(st.sampled_from([ct, 0, 2, 3, 4, 6, 5]))
        inter = data.draw(st.sampled_from([inter, 0, 1, 2]))
        payload = struct.pack(">IIBBBBB", w, h, bd, ct, comp, filt, inter)
    elif ctype == b"IDAT" and data.draw(st.booleans()):
        raw = bytearray(zlib.decompress(payload))
        for _ in range(data.draw(st.integers(1, 4))):
            j = data.draw(st.integers(0, len(raw) - 1))
            raw[j] = data.draw(st.integers(0, 255))  # filter-type bytes included
        payload = zlib.compress(bytes(raw[: data.draw(st.integers(0, len(raw)))]))
    else:
        payload = data.draw(mutated_bytes(payload))
    chunks[i] = (ctype, payload)
    if data.draw(st.integers(0, 4)) == 0:
        del chunks[data.draw(st.integers(0, len(chunks) - 1))]
    path = WORK / f"fuzz-chunks.{kind}"
    path.write_bytes(_png_build(chunks))
    read, role = READERS[kind]
    _check_reader(read, path)
    _check_cli(_distance_argv(**{role: path}), path)


NPY_DTYPES = ["<f4", ">f8", "<f2", "<i4", "|u1", "|b1", "<c8", "<U3", "<M8[s]", "|V4"]


@pytest.mark.parametrize("kind", ["depth.npy", "mask.npy"])
@FUZZ
@given(
    dtype=st.sampled_from(NPY_DTYPES),
    shape=st.sampled_from([(H, W), (W, H), (0,), (H, W, 1), (), (H * W,), (0, W)]),
    fortran=st.booleans(),
    header_edit=st.sampled_from([None, "shape", "descr", "garbage"]),
)
def test_npy_of_other_dtypes_shapes_and_headers(kind, dtype, shape, fortran, header_edit):
    arr = np.ones(shape, dtype=np.float64).astype(dtype)
    if fortran and arr.ndim > 1:
        arr = np.asfortranarray(arr)
    buf = io.BytesIO()
    np.save(buf, arr)
    b = buf.getvalue()
    if header_edit == "shape":
        b = b.replace(repr(tuple(shape)).encode(), b"(100000, 100000)", 1)
    elif header_edit == "descr":
        b = b.replace(np.dtype(dtype).str.encode(), b"|O", 1)
    elif header_edit == "garbage":
        b = b[:10] + b"{'descr': <f4, ]" + b[26:]
    path = WORK / f"fuzz-header.{kind}"
    path.write_bytes(b)
    read, role = READERS[kind]
    _check_reader(read, path)
    _check_cli(_distance_argv(**{role: path}), path)


def test_directories_missing_files_and_output_paths(tmp_path):
    """A directory is not reported as missing; an --out under a file is refused before the run starts."""
    rc, _, err = _run_cli(_distance_argv(camera=tmp_path))
    assert rc == 2 and f"'{tmp_path}' is a directory" in err
    rc, _, err = _run_cli(_distance_argv(points=tmp_path / "nope.json"))
    assert rc == 2 and "nope.json' does not exist" in err
    (tmp_path / "file").write_text("x")
    rc, out, err = _run_cli(["scenario", "pivot", "--json", "--out", str(tmp_path / "file" / "x")])
    assert rc == 2 and out == "" and str(tmp_path / "file" / "x") in err and err.count("\n") == 1
    rc, _, err = _run_cli(["distance", "--camera"])
    assert rc == 2 and err.count("\n") == 1 and "--camera" in err


# ----------------------------------------------------------------------------------------- scenario TOML
def _toml_dump(obj, prefix: str = "") -> str:
    """A small TOML writer (tables, arrays of tables, inline values) for the mutated scenarios."""

    def val(v) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, int | float):
            return repr(v)  # nan, inf and -inf are TOML too
        if isinstance(v, str):
            return json.dumps(v)
        if v is None:
            return '""'
        if isinstance(v, list):
            return "[" + ", ".join(val(x) for x in v) + "]"
        return "{" + ", ".join(f"{json.dumps(str(k))} = {val(x)}" for k, x in v.items()) + "}"

    lines, tables = [], []
    for k, v in obj.items():
        if isinstance(v, dict) and v:
            tables.append((k, v, False))
        elif isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
            tables.append((k, v, True))
        else:
            lines.append(f"{json.dumps(str(k))} = {val(v)}")
    for k, v, many in tables:
        name = f"{prefix}{json.dumps(str(k))}"
        for item in v if many else [v]:
            lines.append(f"\n[[{name}]]" if many else f"\n[{name}]")
            lines.extend(f"{json.dumps(str(kk))} = {val(x)}" for kk, x in item.items())
    return "\n".join(lines) + "\n"


def _scenario_bytes(name: str) -> bytes:
    from importlib import resources

    return resources.files("depthguard").joinpath(f"data/scenarios/{name}.toml").read_bytes()


SCENARIOS = ["icra-exp4", "ral-hexagon", "icra-exp3"]


def _check_scenario_load(path: Path) -> None:
    from depthguard.sim.scenarios import load_scenario

    _check_reader(load_scenario, path)


@FUZZ
@given(name=st.sampled_from(SCENARIOS), data=st.data())
def test_scenario_byte_mutations(name, data):
    path = WORK / "fuzz-bytes.toml"
    path.write_bytes(data.draw(mutated_bytes(_scenario_bytes(name))))
    _check_scenario_load(path)


@FUZZ
@given(name=st.sampled_from(SCENARIOS), data=st.data())
def test_scenario_field_mutations_fail_before_the_run(name, data, monkeypatch_module):
    """Broken scenario files: ``load_scenario`` raises :class:`InputError`, and the CLI exits 2 before any
    simulation starts (the run itself is replaced by a stub that records whether it was reached)."""
    valid = tomllib.loads(_scenario_bytes(name).decode())
    mutated = data.draw(mutated_object(valid))
    path = WORK / "fuzz-fields.toml"
    path.write_text(_toml_dump(mutated))
    try:
        from depthguard.sim.scenarios import load_scenario

        load_scenario(path)
    except InputError as exc:
        assert str(path) in str(exc) and "\n" not in str(exc)
        monkeypatch_module.calls.clear()
        rc, out, err = _run_cli(["scenario", str(path), "--json"])
        assert rc == 2 and out == "" and str(path) in err and err.count("\n") == 1, err
        assert monkeypatch_module.calls == []


@pytest.fixture(scope="module")
def monkeypatch_module():
    """Replace the simulation run by a stub: these tests check input handling, not the simulator."""
    pytest.importorskip("mujoco")
    import depthguard.sim.scenarios as scenarios

    mp = pytest.MonkeyPatch()
    calls: list = []

    def stub(*args, **kwargs):
        calls.append(args)
        raise AssertionError("the simulation started (stub)")

    mp.setattr(scenarios, "_run_one", stub)
    mp.calls = calls
    yield mp
    mp.undo()


def test_scenario_files_missing_keyframes_or_waypoints(tmp_path):
    from depthguard.sim.scenarios import load_scenario

    sc = tomllib.loads(_scenario_bytes("icra-exp4").decode())
    del sc["people"][0]["keyframes"]
    (tmp_path / "a.toml").write_text(_toml_dump(sc))
    with pytest.raises(InputError, match=r"a\.toml: field 'people\[0\]\.keyframes' is missing"):
        load_scenario(tmp_path / "a.toml")
    sc = tomllib.loads(_scenario_bytes("icra-exp4").decode())
    del sc["task"]["waypoints"]
    sc["avoidance"]["rho_bdy"] = 0.3
    (tmp_path / "b.toml").write_text(_toml_dump(sc))
    with pytest.raises(InputError, match=r"b\.toml: unknown field 'rho_bdy' in 'avoidance'; known fields: .*rho_body"):
        load_scenario(tmp_path / "b.toml")
    del sc["avoidance"]["rho_bdy"]
    (tmp_path / "b.toml").write_text(_toml_dump(sc))
    with pytest.raises(InputError, match=r"b\.toml: field 'task\.waypoints' is missing"):
        load_scenario(tmp_path / "b.toml")
    (tmp_path / "c.toml").write_bytes(b'name = "\xff"\n')
    with pytest.raises(InputError, match=r"c\.toml: not UTF-8"):
        load_scenario(tmp_path / "c.toml")
    # every shipped scenario survives the round trip through the writer used above
    for name in SCENARIOS:
        (tmp_path / "d.toml").write_text(_toml_dump(tomllib.loads(_scenario_bytes(name).decode())))
        assert load_scenario(tmp_path / "d.toml")["name"] == name


def test_simulated_scenario_checks_out_before_the_run(tmp_path, monkeypatch_module):
    """``--out`` under a file fails at once, naming the path, for the simulated scenarios too (library and CLI)."""
    from depthguard.sim.scenarios import run_scenario

    (tmp_path / "file").write_text("x")
    bad = tmp_path / "file" / "run"
    monkeypatch_module.calls.clear()
    with pytest.raises(InputError, match="file' is a file, not a folder"):
        run_scenario("icra-exp1", quick=True, out_dir=bad)
    rc, out, err = _run_cli(["scenario", "ral-hexagon", "--quick", "--json", "--out", str(bad)])
    assert rc == 2 and out == "" and str(bad) in err and err.count("\n") == 1
    assert monkeypatch_module.calls == []
    with pytest.raises(AssertionError, match="the simulation started"):  # the stub, reached with a good --out
        main(["scenario", "icra-exp1", "--quick", "--json", "--out", str(tmp_path / "new" / "run")])
    assert (tmp_path / "new" / "run").is_dir()  # created before the (stubbed) run started
    assert len(monkeypatch_module.calls) == 1


@pytest.mark.parametrize("placement", ["ral3", "ral-rolled", "ral-rolled-far"])
def test_scenario_files_take_every_ral_placement(tmp_path, placement):
    """A scenario file may name any of the ral cell's placements (``ral3`` used to raise a KeyError in the
    camera-count check); a camera count beyond the placement is refused with the field's name."""
    from depthguard.sim.depthcam import placement as cameras_of
    from depthguard.sim.scenarios import load_scenario

    sc = tomllib.loads(_scenario_bytes("ral-shadow").decode())
    sc["cameras"] = placement
    (tmp_path / "a.toml").write_text(_toml_dump(sc))
    assert load_scenario(tmp_path / "a.toml")["cameras"] == placement
    sc["camera_count"] = len(cameras_of(placement)) + 1
    (tmp_path / "b.toml").write_text(_toml_dump(sc))
    with pytest.raises(InputError, match=r"field 'camera_count'"):
        load_scenario(tmp_path / "b.toml")
