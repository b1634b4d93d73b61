"""Property tests of the cell file's guarantees (``depthguard.io.cellfile``, docs/real-cell.md, docs/nodes.md).

Byte-level mutations of the shipped cell files, structured mutations through ``tomllib`` (keys dropped,
renamed, retyped; numbers replaced by NaN, infinities, huge integers, booleans, strings), rotations that are
not rotations, referenced files that are missing or folders, and the ``[network]`` table (endpoints, node ports,
TLS files). Whatever the file, :func:`read_cell` returns or raises :class:`InputError` naming the file and the
key, and ``depthguard cell check`` returns 0 with what was loaded or 2 with one line on stderr, never a
traceback. Derandomized like every property test here; ``make test-random`` draws fresh examples. Each fault
that these tests found is pinned with ``@example``.
"""

from __future__ import annotations

import contextlib
import copy
import io
import json
import math
import tempfile
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from depthguard.cli import main
from depthguard.errors import InputError
from depthguard.io.cell_describe import describe_cell
from depthguard.io.cellfile import read_cell

FUZZ = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
EXAMPLES = sorted((Path(__file__).resolve().parents[1] / "examples" / "cells").glob("*.toml"))
WORK = Path(tempfile.mkdtemp(prefix="depthguard-cellfuzz-"))
BIG = 10**400  # an integer that TOML allows and no float holds


# ------------------------------------------------------------------------------------------------ helpers
def _value(v: Any) -> str:
    """One TOML value (inline tables and arrays: any nesting fits on one line)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(float(v))
    if isinstance(v, int):
        return str(v)
    if isinstance(v, str):
        return json.dumps(v)  # (ASCII with \\uXXXX escapes: a TOML basic string)
    if isinstance(v, list):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{json.dumps(k)} = {_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(f"no TOML form for {v!r}")


def _dumps(data: dict[str, Any]) -> str:
    return "".join(f"{json.dumps(k)} = {_value(v)}\n" for k, v in data.items())


def _write(name: str, data: dict[str, Any] | str | bytes, folder: Path = WORK) -> Path:
    p = folder / name
    if isinstance(data, dict):
        data = _dumps(data)
    p.write_bytes(data if isinstance(data, bytes) else data.encode())
    return p


def _load(i: int) -> dict[str, Any]:
    return tomllib.loads(EXAMPLES[i].read_text(encoding="utf-8"))


def _cli(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(list(argv))
    return rc, out.getvalue(), err.getvalue()


def _refused(path: Path, *needles: str) -> str:
    """``read_cell(path)`` raises InputError naming ``path`` (or a file it references) and each needle; and
    ``cell check`` says the same on one line with code 2."""
    with pytest.raises(InputError) as info:
        read_cell(path)
    msg = str(info.value)
    assert "\n" not in msg and (path.name in msg or ".toml" in msg), msg
    for n in needles:
        assert n in msg, (n, msg)
    rc, out, err = _cli("cell", "check", str(path))
    assert rc == 2 and out == "" and err.count("\n") == 1 and "Traceback" not in err, (rc, err)
    return msg


def _check_agrees(path: Path) -> None:
    """A file that loads: ``cell check`` returns 0 and prints the cameras that were loaded, in order."""
    cell = read_cell(path)
    rc, out, err = _cli("cell", "check", "--json", str(path))
    if rc == 2:  # (the robot model refuses a link: read_cell does not load the robot)
        assert err.count("\n") == 1 and ("robot" in err or "parent" in err), err
        return
    assert rc == 0 and json.loads(out)["cameras"] == [c.name for c in cell.cameras], (rc, out, err)
    text = describe_cell(cell)
    lines = [x for x in text.splitlines() if x.startswith("camera '")]
    assert [x.split("'")[1] for x in lines] == [c.name for c in cell.cameras]


def _paths(d: Any, pre: tuple = ()) -> list[tuple]:
    out = []
    items = d.items() if isinstance(d, dict) else enumerate(d) if isinstance(d, list) else ()
    for k, v in items:
        out.append(pre + (k,))
        out += _paths(v, pre + (k,))
    return out


def _at(d: Any, path: tuple) -> Any:
    for k in path:
        d = d[k]
    return d


def _key_of(path: tuple) -> str:
    """The nearest table key on ``path`` (what the error message must name)."""
    return next(k for k in reversed(path) if isinstance(k, str))


PATHS = [(i, p) for i in range(len(EXAMPLES)) for p in _paths(_load(i))]
NUMBER_PATHS = [
    (i, p) for i, p in PATHS if isinstance(_at(_load(i), p), int | float) and not isinstance(_at(_load(i), p), bool)
]
ODD_NUMBERS = [float("nan"), float("inf"), -float("inf"), BIG, -BIG, True, False, "1", [], [1.0], {}]


# ------------------------------------------------------------------------------------- 1. byte mutations
@FUZZ
@given(
    which=st.integers(0, len(EXAMPLES) - 1),
    ops=st.lists(
        st.tuples(st.sampled_from(["truncate", "flip", "insert", "delete"]), st.floats(0, 1), st.integers(0, 255)),
        min_size=1,
        max_size=4,
    ),
)
@example(which=0, ops=[("insert", 0.0, ord("\xff"))])  # not UTF-8
def test_byte_mutations_load_or_name_the_file(which, ops):
    data = bytearray(EXAMPLES[which].read_bytes())
    for op, where, byte in ops:
        pos = min(int(where * len(data)), max(len(data) - 1, 0))
        if op == "truncate":
            data = data[:pos]
        elif op == "flip" and data:
            data[pos] ^= 1 << (byte % 8)
        elif op == "insert":
            data[pos:pos] = bytes([byte])
        elif data:
            del data[pos]
    path = _write("bytes.toml", bytes(data))
    try:
        read_cell(path)
    except InputError as exc:
        assert "bytes.toml" in str(exc) and "\n" not in str(exc)
        rc, out, err = _cli("cell", "check", str(path))
        assert rc == 2 and err.count("\n") == 1 and "bytes.toml" in err
        return
    _check_agrees(path)


# -------------------------------------------------------------------------------- 2. structured mutations
_REPLACEMENTS = st.one_of(
    st.sampled_from(ODD_NUMBERS + [-1, 0, 0.0, -0.5, 10**30, 1e308, "", "x", [[1, 0], [0, 1]]]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(-(2**70), 2**70),
    st.text(max_size=6),
    st.just("<delete>"),
    st.just("<rename>"),
)


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(where=st.sampled_from(PATHS), new=_REPLACEMENTS)
@example(where=(0, ("robot", "ee_radius")), new=BIG)  # an integer past the float range: was a TypeError
@example(where=(1, ("distance", "rho")), new=10**30)  # (the same: numpy's isfinite takes no such int)
@example(where=(2, ("controller", "distance_timeout")), new=float("nan"))
@example(where=(2, ("cameras", 0, "name")), new="<rename>")
def test_structured_mutations_load_or_name_the_key(where, new):
    i, path = where
    data = _load(i)
    parent, key = _at(data, path[:-1]), path[-1]
    old = parent[key]
    if new == "<delete>":
        del parent[key]
    elif new == "<rename>" and isinstance(key, str):
        parent[key + "_x"] = parent.pop(key)
    elif new != "<rename>":
        parent[key] = new
    p = _write("mut.toml", data)
    try:
        read_cell(p)
    except InputError as exc:
        msg = str(exc)
        assert "mut.toml" in msg and "\n" not in msg, msg
        if new == "<rename>" and isinstance(key, str):
            assert key + "_x" in msg, msg  # a typo is named, never ignored
        rc, _, err = _cli("cell", "check", str(p))
        assert rc == 2 and err.count("\n") == 1
        return
    # what loaded: never a typo, never a number that is not one
    assert not (new == "<rename>" and isinstance(key, str)), "a renamed key was ignored"
    number = isinstance(old, int | float) and not isinstance(old, bool)
    if number and new not in ("<delete>", "<rename>"):
        ok = isinstance(new, int | float) and not isinstance(new, bool) and math.isfinite(float(new))
        assert ok, f"{_key_of(path)} = {new!r} was taken for a number"
    _check_agrees(p)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(where=st.sampled_from(NUMBER_PATHS), new=st.sampled_from(ODD_NUMBERS))
@example(where=(1, ("distance", "fill_radius")), new=BIG)
@example(where=(2, ("cameras", 0, "eye", 0)), new=BIG)  # (numpy: OverflowError converting it)
@example(where=(0, ("robot", "attachments", 0, "size", 0)), new=BIG)  # (float(): the same, in the reader)
@example(where=(2, ("controller", "rate")), new=True)  # a bool is an int in Python, not a number here
def test_a_number_that_is_not_one_is_refused_naming_its_key(where, new):
    i, path = where
    data = _load(i)
    _at(data, path[:-1])[path[-1]] = new
    _refused(_write("num.toml", data), _key_of(path))


# keys where 0 or a negative value makes no sense or would make the robot less safe (docs/real-cell.md)
_POSITIVE = ["rho", "grid_dd", "period", "rate", "distance_timeout", "joint_timeout", "a_max", "j_max", "rho_ee"]
_POSITIVE += ["rho_body", "alpha", "v_rep_max", "min_depth", "max_depth", "velocity_scale", "fx", "fy"]


@settings(max_examples=40, deadline=None)
@given(
    where=st.sampled_from([(i, p) for i, p in NUMBER_PATHS if p[-1] in _POSITIVE]),
    new=st.sampled_from([0, 0.0, -0.0, -1e-9, -1, -1e300]),
)
def test_a_non_positive_safety_setting_is_refused(where, new):
    i, path = where
    data = _load(i)
    _at(data, path[:-1])[path[-1]] = new
    _refused(_write("neg.toml", data), path[-1])


@settings(max_examples=40, deadline=None)
@given(
    section=st.sampled_from(["cell", "robot", "cameras", "distance", "controller", "topics", "network", "top"]),
    typo=st.sampled_from(["min_Depth", "rh0", "ssm_rnage", "Rate", "tls_cert", "x"]),
)
def test_an_unknown_key_is_named(section, typo):
    data = _load(1)
    target = {"top": data, "cameras": data["cameras"][1]}.get(section) or data.setdefault(section, {})
    target[typo] = 1.0
    _refused(_write("typo.toml", data), typo)


def _rotation(q: list[float]) -> np.ndarray:
    w, x, y, z = np.asarray(q) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


@settings(max_examples=40, deadline=None)
@given(
    q=st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda v: np.linalg.norm(v) > 0.1),
    spoil=st.sampled_from(["none", "reflect", "scale", "shear", "swap"]),
    form=st.sampled_from(["R", "matrix"]),
    t=st.lists(st.floats(-3, 3), min_size=3, max_size=3),
)
def test_extrinsics_are_taken_iff_they_are_a_rotation(q, spoil, form, t):
    """A rotation (R R^T = I to 1e-6, det +1) is taken as written; a reflection, a scaled or sheared matrix,
    or swapped rows (det -1) is refused, naming the camera's key."""
    R = _rotation(q)
    if spoil == "reflect":
        R = R @ np.diag([1.0, 1.0, -1.0])
    elif spoil == "scale":
        R = R * 1.001
    elif spoil == "shear":
        R = R + np.array([[0.0, 1e-3, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    elif spoil == "swap":
        R = R[[1, 0, 2]]
    data = _load(2)
    cam = data["cameras"][0]
    del cam["eye"], cam["target"]
    if form == "R":
        cam["R"], cam["t"] = R.tolist(), list(t)
    else:
        cam["matrix"] = [[*R[k], t[k]] for k in range(3)] + [[0.0, 0.0, 0.0, 1.0]]
    p = _write("rot.toml", data)
    is_rotation = np.abs(R @ R.T - np.eye(3)).max() <= 1e-6 and np.linalg.det(R) > 0  # (independent of the reader)
    if not is_rotation:
        _refused(p, "cameras[0]")
        return
    got = read_cell(p).cameras[0]
    np.testing.assert_allclose(got.R, R, atol=1e-12)
    np.testing.assert_allclose(got.t, t, atol=1e-12)
    np.testing.assert_allclose(got.build().position, -R.T @ np.asarray(t), atol=1e-9)


@settings(max_examples=40, deadline=None)
@given(
    key=st.sampled_from(["t", "eye", "target", "up", "workspace", "xyz", "rpy", "size", "matrix"]),
    n=st.integers(0, 7),
)
def test_wrong_length_vectors_are_refused(key, n):
    data = _load(2)
    cam = data["cameras"][1]
    value = [0.5] * n
    want = {"t": 3, "eye": 3, "target": 3, "up": 3, "workspace": 6, "xyz": 3, "rpy": 3, "size": 2, "matrix": 4}
    if key == "t":
        del cam["eye"], cam["target"], cam["up"]
        cam["R"], cam["t"] = np.eye(3).tolist(), value
    elif key in ("eye", "target", "up"):
        cam[key] = value
    elif key == "workspace":
        data["distance"]["workspace"] = value
    elif key == "matrix":
        del cam["eye"], cam["target"], cam["up"]
        rows = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 2.0], [0.0, 0.0, 0.0, 1.0]]
        cam["matrix"] = (rows + [[0.0, 0.0, 0.0, 1.0]] * 4)[:n]
    else:
        att = {"name": "g", "link": "lwr_flange", "shape": "cylinder", "size": [0.04, 0.1]}
        data["robot"]["attachments"] = [{**att, key: value}]
    if n == want[key]:
        return  # (the right length: covered by the examples)
    _refused(_write("len.toml", data), f"{key} must be")


# ------------------------------------------------------------------------------ found faults, one by one
def _with(i: int, edit) -> Path:
    data = _load(i)
    edit(data)
    return _write("edit.toml", data)


@pytest.mark.parametrize("role", ["sim", "distance", "controller", "monitor", "run", "view", ""])
def test_a_camera_may_not_take_a_node_name(role):
    """Was taken: a camera named ``distance`` became a second node ``distance`` (its port and, with one
    certificate per node, the certificate allowed to publish distances)."""
    _refused(_with(2, lambda d: d["cameras"][1].update(name=role)), "cameras[1].name")


def test_duplicate_camera_names_are_refused():
    _refused(_with(1, lambda d: d["cameras"][2].update(name="camera0")), "unique")


@pytest.mark.parametrize(
    "edit, needle",
    [
        (lambda d: d.setdefault("topics", {}).update(monitor_distances="/depthguard/distances"), "the same topic"),
        (lambda d: d.setdefault("topics", {}).update(distances=""), "topics.distances"),
        (lambda d: d.setdefault("topics", {}).update(status="/a b"), "topics.status"),
        (lambda d: d["cameras"][1].update(topic=d["cameras"][0].get("topic", "/camera0/depth/image_raw")), "topic"),
        (lambda d: d["cameras"][0].update(info_topic=""), "cameras[0].info_topic"),
    ],
)
def test_topics_are_names_and_distinct(edit, needle):
    """Were taken: two cameras on one topic (each would read the other's images with its own pose), the
    monitor's distances on the repulsion's topic, an empty topic (a silent default for a camera)."""
    _refused(_with(1, edit), needle)


@pytest.mark.parametrize(
    "edit, needle",
    [
        (lambda d: d["robot"].update(ee_frame="lwr_flange"), "robot.ee_frame"),  # was ignored by the lwr4
        (lambda d: d["robot"].update(joint_names=["a", "a", "b", "c", "d", "e", "f"]), "robot.joint_names"),
        (lambda d: d["robot"].update(joint_names=[]), "robot.joint_names"),
        (lambda d: d["robot"]["attachments"][0].update(mesh="tool.stl"), "attachments[0].mesh"),  # ignored
        (lambda d: d["cameras"][0].update(up=[1.0, 0.0, 0.0]), "cameras[0].up"),  # ignored beside a matrix
        # a gripper in mm (45 m): `cell check` tried to allocate 93 GiB for its cover (a MemoryError traceback)
        (lambda d: d["robot"]["attachments"][0].update(size=[45.0, 120.0]), "attachments[0].size"),
        (lambda d: d["robot"]["attachments"][0].update(size=[1e30, 0.1]), "attachments[0].size"),
    ],
)
def test_a_value_that_would_be_ignored_is_refused(edit, needle):
    _refused(_with(0, edit), needle)


def test_shipped_model_ee_frame_is_the_models():
    from depthguard.io.cellfile import MODEL_EE_FRAMES
    from depthguard.robot.model import load_lwr4

    assert load_lwr4().ee_frame == MODEL_EE_FRAMES["lwr4"]


def test_cell_check_names_the_cell_file_for_robot_model_errors():
    """``cell check`` said ``frame 'lwr_ee' is not in the model`` for a URDF without that frame, naming neither
    file nor key; and it took a ``[[robot.spheres]]`` on a link that the robot does not have."""
    d = WORK / "urdf"
    d.mkdir(exist_ok=True)
    (d / "r.urdf").write_text('<robot name="x"><link name="a"/></robot>')
    text = EXAMPLES[2].read_text().replace('model = "lwr4"', 'urdf = "r.urdf"')
    rc, _, err = _cli("cell", "check", str(_write("cell.toml", text, d)))
    assert rc == 2 and err.count("\n") == 1 and "cell.toml" in err and "robot" in err, err
    sphere = '\n[[robot.spheres]]\nlink = "nolink"\nposition = [0.0, 0.0, 0.0]\nradius = 0.1\n'
    p = _write("sphere.toml", EXAMPLES[2].read_text() + sphere)
    read_cell(p)  # (the reader does not load the robot)
    rc, _, err = _cli("cell", "check", str(p))
    assert rc == 2 and err.count("\n") == 1 and "sphere.toml" in err and "robot.spheres" in err, err


# ------------------------------------------------------------------------- referenced files and their paths
_CAL = "[[cameras]]\nname = 'camera0'\nR = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]\nt = [0.0, 0.0, 2.0]\n"


@settings(max_examples=30, deadline=None)
@given(
    what=st.sampled_from(["urdf", "calibration", "background", "mesh", "tls"]),
    state=st.sampled_from(["missing", "folder", "relative"]),
)
def test_referenced_files_resolve_relative_to_the_cell_file(what, state):
    """Relative paths are the cell file's folder's; a missing file or a folder is refused, naming the key."""
    d = Path(tempfile.mkdtemp(dir=WORK))
    (d / "sub").mkdir()
    ref = {"missing": "sub/none.dat", "folder": "sub", "relative": "sub/f.dat"}[state]
    if state == "relative":
        body = {"calibration": _CAL, "urdf": "<robot/>", "mesh": "solid x\nendsolid x\n"}.get(what, "x")
        (d / "sub" / "f.dat").write_text(body)
    data = _load(2)
    needle = {"urdf": "robot.urdf", "calibration": "calibration", "background": "controller.background"}
    if what == "urdf":
        data["robot"] = {"urdf": ref}
    elif what == "calibration":
        data["calibration"] = ref
    elif what == "background":
        data["controller"]["background"] = ref
    elif what == "mesh":
        data["robot"]["attachments"] = [{"name": "g", "link": "lwr_flange", "shape": "mesh", "mesh": ref}]
        needle["mesh"] = "attachments[0].mesh"
    else:
        data["network"] = {"tls_root_ca": ref, "tls_certificate": ref, "tls_private_key": ref}
        needle["tls"] = "network.tls_root_ca"
    p = _write("cell.toml", data, d)
    if state != "relative":
        _refused(p, needle[what])
        return
    if what == "background":  # (not a background file: refused, naming the key and the file it resolved)
        assert str(d / "sub" / "f.dat") in _refused(p, needle[what])
        return
    with contextlib.chdir(WORK):  # (another working folder: the paths are the cell file's)
        cell = read_cell(p)
    want = str(d / "sub" / "f.dat")
    got = {
        "urdf": lambda: str(cell.robot.urdf),
        "mesh": lambda: str(cell.robot.attachments[0].mesh),
        "tls": lambda: cell.network["tls_root_ca"],
        "calibration": lambda: want,
    }[what]()
    assert got == want
    if what == "calibration":
        np.testing.assert_allclose(cell.cameras[0].t, [0.0, 0.0, 2.0])


@settings(max_examples=40, deadline=None)
@given(
    key=st.sampled_from(["rmse", "inlier_fraction", "date", "dup"]),
    value=st.sampled_from([float("nan"), -0.1, 1.5, [1], "abc", True, {}, 0.002]),
)
@example(key="rmse", value=[1])  # was a TypeError traceback in `cell check`
@example(key="rmse", value="abc")  # was exit 2 with "could not convert string to float" (no file, no key)
@example(key="dup", value=0.002)  # two entries for one camera: the second silently won
def test_calibration_file_metadata_is_checked(key, value):
    d = Path(tempfile.mkdtemp(dir=WORK))
    cal = _CAL + (_CAL.replace("2.0]", "3.0]") if key == "dup" else f"{key} = {_value(value)}\n")
    (d / "cal.toml").write_text(cal)
    data = _load(2)
    data["calibration"] = "cal.toml"
    p = _write("cell.toml", data, d)
    good = key != "dup" and (
        (key == "date" and isinstance(value, str))
        or (key == "rmse" and value in (0.002, 1.5))
        or (key == "inlier_fraction" and value == 0.002)
    )
    if good:
        _check_agrees(p)
        assert "calibration 'cal.toml'" in _cli("cell", "check", str(p))[1]
    else:
        _refused(p, "cal.toml", "cameras[")


# ------------------------------------------------------------------------------- 3. semantic properties
@pytest.mark.parametrize("i", range(len(EXAMPLES)))
def test_loading_is_deterministic_and_the_raw_table_reads_back_equal(i):
    """Two reads agree; the table that was read, written back (a TOML writer here: the project has none for
    cell files), reads back to the same cell; ``cell check`` prints the cameras that were loaded."""
    a, b = read_cell(EXAMPLES[i]), read_cell(EXAMPLES[i])
    again = read_cell(_write(EXAMPLES[i].name, copy.deepcopy(a.raw)))
    for c in (b, again):
        assert describe_cell(c).splitlines()[1:] == describe_cell(a).splitlines()[1:]
        assert (c.distance, c.controller, c.topics, c.network, c.robot) == (
            a.distance,
            a.controller,
            a.topics,
            a.network,
            a.robot,
        )
        for x, y in zip(a.cameras, c.cameras, strict=True):
            assert (x.name, x.params, x.parent, x.topic) == (y.name, y.params, y.parent, y.topic)
            np.testing.assert_array_equal(x.R, y.R)
    _check_agrees(EXAMPLES[i])
    want = len(tomllib.loads(EXAMPLES[i].read_text())["cameras"])  # (counted in the file, not by the reader)
    assert _cli("cell", "check", str(EXAMPLES[i]))[1].count("camera '") == want


def test_a_cell_file_error_is_an_input_error():
    """Was a plain ValueError (``CellError``): the readers promise :class:`InputError`."""
    with pytest.raises(InputError, match="robot.model"):
        read_cell(_with(0, lambda d: d["robot"].update(model="ur5")))


# ------------------------------------------------------------------------------- 4. the [network] table
def _network(net: dict[str, Any], i: int = 1) -> Path:
    data = _load(i)
    data["network"] = net
    return _write("net.toml", data)


_HOSTS = ["127.0.0.1", "localhost", "[::1]", "10.0.0.5", "robot-1.local", "::1", "", "a b", "[nope]", "h/x"]


@settings(max_examples=60, deadline=None)
@given(
    proto=st.sampled_from(["tcp", "tls", "udp", "quic", "ws", "TCP", "http", ""]),
    host=st.sampled_from(_HOSTS),
    port=st.sampled_from(["7447", "1", "65535", "0", "65536", "", "x", "-1"]),
    tail=st.sampled_from(["", "?prio=1", "#iface=lo"]),
)
@example(proto="", host="127.0.0.1", port="7447", tail="")  # "127.0.0.1:7447": was taken, failed in Zenoh
@example(proto="tcp", host="::1", port="7447", tail="")  # an IPv6 address needs its brackets
def test_connect_endpoints_are_checked(proto, host, port, tail):
    endpoint = f"{proto}/{host}:{port}{tail}" if proto else f"{host}:{port}"
    ok = (
        proto in ("tcp", "tls", "udp", "quic", "ws")
        and host in ("127.0.0.1", "localhost", "[::1]", "10.0.0.5", "robot-1.local")
        and port.isdecimal()
        and 1 <= int(port) <= 65535
    )
    p = _network({"connect": ["tcp/127.0.0.1:7447", endpoint]})
    if ok:
        assert read_cell(p).network["connect"][1] == endpoint
    else:
        _refused(p, "network.connect[1]")


@settings(max_examples=60, deadline=None)
@given(base=st.integers(0, 70000) | st.sampled_from([7440, 7441, 7447, 7448, 65528, 65529, 1023, 1024]))
@example(base=7440)  # node 7 (view) on the ROS 2 router's port: was taken
@example(base=65000)
def test_node_ports_stay_in_range_and_off_the_router(base):
    """With three cameras the cell has 9 nodes, on ``base_port .. base_port + 8``."""
    nodes = 9
    ok = 1024 <= base and base + nodes - 1 <= 65535 and not base <= 7447 <= base + nodes - 1
    p = _network({"base_port": base}, i=1)
    if ok:
        assert read_cell(p).network["base_port"] == base
    else:
        _refused(p, "network.base_port")


@settings(max_examples=30, deadline=None)
@given(given_=st.lists(st.sampled_from(["tls_root_ca", "tls_certificate", "tls_private_key"]), unique=True))
@example(given_=["tls_root_ca"])  # a root CA alone: was taken, and the nodes ran plain TCP
def test_tls_takes_all_three_files_or_none(given_):
    d = Path(tempfile.mkdtemp(dir=WORK))
    for k in given_:
        (d / f"{k}.pem").write_text("x")
    data = _load(1)
    data["network"] = {k: f"{k}.pem" for k in given_}
    p = _write("cell.toml", data, d)
    if len(given_) in (0, 3):
        net = read_cell(p).network
        assert all(net[k] == str(d / f"{k}.pem") for k in given_)
    else:
        _refused(p, "network.", "all, or none")


@settings(max_examples=30, deadline=None)
@given(host=st.sampled_from(_HOSTS[:2] + ["::1", "10.0.0.5", "0.0.0.0", "robot-1.local", "", "a b", "h/x", "[::1]"]))
def test_nodes_listen_on_loopback_unless_tls_is_given(host):
    """The default listens on 127.0.0.1 only; another host needs the TLS files; a host that is no address is
    refused, naming ``network.host``."""
    from depthguard.nodes.common import _endpoint

    assert read_cell(EXAMPLES[1]).network["host"] == "127.0.0.1"
    assert _endpoint(read_cell(EXAMPLES[1]), 7460) == "tcp/127.0.0.1:7460"
    p = _network({"host": host})
    if host in ("127.0.0.1", "localhost", "::1"):
        cell = read_cell(p)
        assert _endpoint(cell, 7460) == ("tcp/[::1]:7460" if host == "::1" else f"tcp/{host}:7460")
    else:
        _refused(p, "network.host")


def _host_reference(text: str) -> bool:
    """An IP address, or dot-separated labels of letters, digits, '_' and '-', none empty, none led by '-'."""
    import ipaddress
    import string

    try:
        ipaddress.ip_address(text)
        return True
    except ValueError:
        pass
    allowed = set(string.ascii_letters + string.digits + "_-")
    labels = text.split(".")
    return all(lab and set(lab) <= allowed and not lab.startswith("-") for lab in labels)


@settings(max_examples=150, deadline=None)
@given(host=st.text(alphabet="ab1-_.:%[] /é", max_size=8) | st.sampled_from(["a..b", "a.", ".a", "fe80::1%lo"]))
@example(host="a..b")  # a cell file's host took it, `certs --host` refused it
@example(host="a.")  # likewise
def test_a_host_is_the_same_host_for_the_cell_file_and_certs(host):
    """``network.host``, the hosts of ``network.connect`` endpoints and ``depthguard certs --host`` take the same
    hosts (one check, :func:`depthguard.validation.is_host`), the ones of an independent rule."""
    import argparse

    from depthguard.cli_common import host_name
    from depthguard.io.cell_network import check_endpoint
    from depthguard.validation import is_host

    want = _host_reference(host)
    assert is_host(host) == want
    try:
        host_name(host)
        cli = True
    except argparse.ArgumentTypeError:
        cli = False
    assert cli == want
    bracketed = f"[{host}]" if ":" in host else host
    try:
        check_endpoint(Path("c.toml"), "network.connect[0]", f"tcp/{bracketed}:7447")
        endpoint = True
    except InputError:
        endpoint = False
    assert endpoint == (want and not any(c in host for c in "?#"))


@pytest.mark.parametrize("bad", [{"publishers": ["distance", ""]}, {"publishers": "distance"}, {"connect": [7447]}])
def test_publishers_and_peers_must_be_lists_of_names(bad):
    _refused(_network(bad), f"network.{next(iter(bad))}")


@pytest.mark.parametrize("state", ["missing", "folder", "garbage"])
def test_certificate_common_name_names_the_file(state):
    from depthguard.io.zenoh_acl import certificate_common_name

    d = Path(tempfile.mkdtemp(dir=WORK))
    p = d / "c.pem"
    if state == "folder":
        p.mkdir()
    elif state == "garbage":
        p.write_text("-----BEGIN CERTIFICATE-----\nnot base64\n-----END CERTIFICATE-----\n")
    with pytest.raises(ValueError, match="c.pem"):
        certificate_common_name(p)
