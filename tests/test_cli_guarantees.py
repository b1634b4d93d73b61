"""The command line's promise attacked through its arguments (README "Bad input", docs/conventions.md "Errors").

Whatever the arguments, ``depthguard.cli.main`` (run in-process) returns 0, or 2 with ONE line on stderr that
names the option and the expected form; no exception escapes and no traceback is printed.
``tests/test_input_fuzz.py`` fuzzes the files of ``distance`` and ``scenario``; this file draws the option
VALUES of every subcommand (read from the argparse parser itself: every option of every subcommand is drawn)
from hostile pools: NaN, inf, negative, zero, huge, non-numbers, empty strings, folders, missing or
unwritable paths, malformed sources and Zenoh endpoints.

Commands that would do real work (``run``, ``node``, ``view``, ``calibrate``, ``commission``, ``certs``,
``ros2-msgs``, ``scenario``, ``bench``, ``demo``) run with their work function replaced by a stub that records
its arguments: the property is then exact. The command exits 0 (the stub was reached) if and only if every
drawn value has the documented form, and a refusal names one of the bad options. ``cell check`` and
``distance`` (small files) run for real. Derandomized like every property test here; ``make test-random``
draws fresh examples.
"""

from __future__ import annotations

import contextlib
import io
import math
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from depthguard.camera import Camera, look_at
from depthguard.cli import EXTRA_BENCHES, EXTRA_SCENARIOS, VIEW_SCENARIOS, build_parser, main
from depthguard.io import ControlPoint, write_camera, write_depth, write_points

ROOT = Path(__file__).resolve().parents[1]
CELL = str(ROOT / "examples" / "cells" / "sim-hexagon.toml")
WORK = Path(tempfile.mkdtemp(prefix="depthguard-cli-"))
PROP = settings(max_examples=300, deadline=None, suppress_health_check=list(HealthCheck))

# --------------------------------------------------------------------------------------------- the files
(WORK / "folder").mkdir()
(WORK / "file.txt").write_text("not a folder\n")
(WORK / "garbage.toml").write_text("[cell\nname = \n")
_R, _T = look_at([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], up=[0.0, -1.0, 0.0])
write_camera(WORK / "cam.json", Camera(width=32, height=24, fx=26.0, fy=26.0, cx=16.0, cy=12.0, R=_R, t=_T))
_DEPTH = np.full((24, 32), 2.0, np.float32)
_DEPTH[10:12, 10:12] = 0.0  # holes: --fill-radius matters
_DEPTH[:, 20] = 1.0
write_depth(WORK / "d.npy", _DEPTH)
write_points(WORK / "pts.json", [ControlPoint("ee", np.array([0.0, 0.0, 1.0]), 0.05)])
DISTANCE = ["distance", "--camera", str(WORK / "cam.json"), "--depth", str(WORK / "d.npy")]
DISTANCE += ["--points", str(WORK / "pts.json"), "--json"]

# ------------------------------------------------------------------------------------------ value pools
NUMBERS = (
    "nan", "NaN", "-nan", "inf", "-inf", "Infinity", "-1", "-0.5", "0", "-0", "0.0", "1e-300", "1e300", "1e309",
    "99999999999999999999", "-99999999999999999999", "9223372036854775807", "", " ", "abc", "0x10", "1,5",
    "0.01", "0.02", "0.05", "0.1", "0.5", "1", "1.0", "2", "30", "80", "99", "100", "232", "233", "1e3", "7447",
    "36500", "36501", "65535", "65536", "1000000", "1000001",
)  # fmt: skip


def _in_range(text: str, cast, lo: float, hi: float, lo_open: bool) -> bool:
    try:
        x = cast(text)
        if not math.isfinite(float(x)):
            return False
    except (ValueError, OverflowError):
        return False
    return (lo < x if lo_open else lo <= x) and x <= hi


def numbers(cast, lo: float, hi: float, lo_open: bool = False, pool=NUMBERS) -> list[tuple[str, bool]]:
    """The hostile numbers, each with whether it is in the documented range."""
    return [(t, _in_range(t, cast, lo, hi, lo_open)) for t in pool]


def texts(good, bad) -> list[tuple[str, bool]]:
    return [(t, True) for t in good] + [(t, False) for t in bad]


NEW_DIR = str(WORK / "new" / "out")
OUT_DIRS = texts([NEW_DIR, str(WORK / "folder")], ["", " ", str(WORK / "file.txt"), "/proc/nope/x", "/dev/null"])
OUT_FILES = texts(
    [str(WORK / "folder" / "x.out"), str(WORK / "file.txt")],
    ["", " ", str(WORK / "folder"), str(WORK / "missing" / "x.out"), "/proc/nope/x", "/"],
)
ANY_PATHS = texts([str(WORK / "folder"), NEW_DIR, "x"], ["", "   "])
SOURCES = {
    "run": texts(
        ["bag:/nonexistent.mcap", "sim:ral-hexagon", "sim:nonexistent", "realsense", f"bag:{WORK}"],
        ["", " ", "bag:", "bag: ", "sim:", "realsense:x", "realsense:", "foo", "bag", "sim", "ros:x", ":x", "BAG:x"],
    ),
}
SOURCES["commission"] = SOURCES["run"]
SOURCES["calibrate"] = texts(
    ["bag:/nonexistent.mcap", "sim:ral-hexagon"], ["", "bag:", "sim:", "realsense", "realsense:x", "foo"]
)
SOURCES["node"] = texts(["sim:ral-hexagon", "sim:x"], ["", "sim:", "bag:/x.mcap", "realsense", "foo"])
ENDPOINTS = texts(
    ["tcp/127.0.0.1:7447", "tcp/[::1]:7447", "udp/localhost:1", "tls/host.example:65535?x=1", "unixsock-stream/x"],
    ["", "garbage", "tcp/", "tcp/127.0.0.1", "tcp/127.0.0.1:0", "tcp/127.0.0.1:65536", "tcp/::1:7447", "ftp/a:1",
     "tcp/-a:1", "tcp/a b:1", "tcp/127.0.0.1:x"],
)  # fmt: skip
HOSTS = texts(["127.0.0.1", "::1", "localhost", "robot-1.cell.lan"], ["", " ", "a,b", "a b", "-a", ".a", "a..b", "a/b"])
DURATION = numbers(float, 0.0, 1e9, lo_open=True)
ZENOH = {"--zenoh-domain": numbers(int, 0, 232), "--zenoh-connect": ENDPOINTS}

#: per command: option -> its pool of (text, valid); the boolean options are drawn from the parser itself
SPEC: dict[str, dict[str, list[tuple[str, bool]]]] = {
    "run": {
        "--source": SOURCES["run"], "--out": OUT_DIRS,
        "--transport": texts(["none", "zenoh"], ["", "ros", "Zenoh"]), **ZENOH,
    },
    "calibrate": {"--source": SOURCES["calibrate"], "--write": OUT_FILES},
    "commission": {
        "--source": SOURCES["commission"], "--out": OUT_FILES, "--frames": numbers(int, 1, 1_000_000),
        "--noise-coeff": numbers(float, 0.0, 0.1), "--margin": numbers(float, 0.0, 1.0),
    },
    "node": {
        "--source": SOURCES["node"], "--duration": DURATION, "--log": OUT_FILES,
        "--watchdog": numbers(float, 0.0, 1.0, lo_open=True), "--rt-priority": numbers(int, 1, 99), **ZENOH,
    },
    "view": {"--port": numbers(int, 1, 65535), "--duration": DURATION, **ZENOH},
    "certs": {
        "--out": ANY_PATHS, "--days": numbers(int, 1, 36_500), "--host": HOSTS,
        "--node": texts(["x", "../x", ""], []),  # (the library names a node that cannot be a file name)
    },
    "ros2-msgs": {"--out": ANY_PATHS},
    "scenario": {
        "--cameras": texts(["1", "2", "3"], ["0", "4", "nan", ""]),
        "--placement": texts(["icra", "ral-rolled-far"], ["", "x"]),
        "--backend": texts(["depthspace", "octree"], ["", "x"]),
        "--octree-res": numbers(float, 0.02, 0.1), "--case": texts(["1", "4"], ["0", "5", "x"]),
        "--lambda": texts(["switch", "arctan", "linear"], ["", "x"]), "--contacts": texts(["1", "2"], ["0", "3"]),
        "--rate": numbers(float, 0.0, math.inf, lo_open=True), "--view-port": numbers(int, 1, 65535),
        "--out": OUT_DIRS,
    },
    "bench": {},
    "demo": {"--out": OUT_DIRS},
}  # fmt: skip
POSITIONALS = {
    "node": texts(["sim", "camera0", "distance", "controller", "monitor", "bogus", ""], []),
    "scenario": texts(["pivot", "ral-hexagon", "icra-exp1", *EXTRA_SCENARIOS], []),
    "bench": texts(["distance", "control", "selffilter", *EXTRA_BENCHES], ["", "x"]),
}
CELL_OPTION = {"run", "calibrate", "commission", "node", "view", "certs"}

# ---------------------------------------------------------------------------------------------- the stubs
CALLS: list[tuple[str, tuple, dict]] = []


def _stub(name: str, ret):
    def fn(*args, **kwargs):
        CALLS.append((name, args, kwargs))
        return ret() if callable(ret) else ret

    return fn


STUBS = {
    ("depthguard.runner", "run_cell"): {},
    ("depthguard.nodes", "run_node"): {},
    ("depthguard.viz.live_node", "run_view_node"): None,
    ("depthguard.runner.commission", "commission_cell"): {},
    ("depthguard.runner.calibrate", "calibrate_cell"): {},
    ("depthguard.nodes.certs", "make_cell_certificates"): {"folder": "x", "made": [], "kept": [], "network": []},
    ("depthguard.io.ros2_package", "write_msgs_package"): {"folder": "x", "files": []},
    ("depthguard.sim.scenarios", "run_scenario"): {},
    ("depthguard.pivot_scenario", "run_pivot_scenario"): {},
    ("depthguard.bench.distance", "run_distance_benchmark"): {},
    ("depthguard.bench.control", "run_control_benchmark"): {},
    ("depthguard.bench.control", "run_selffilter_benchmark"): {},
    ("depthguard.demo_static", "run_static_demo"): None,
    ("depthguard.sim.demo", "run_demo"): 0,
}


@contextlib.contextmanager
def stubbed():
    """Every work function of the command line replaced by a recording stub (``cli._load_entry`` too)."""
    import importlib

    CALLS.clear()
    with pytest.MonkeyPatch.context() as mp:
        for (mod, attr), ret in STUBS.items():
            mp.setattr(importlib.import_module(mod), attr, _stub(f"{mod}.{attr}", ret))
        mp.setattr("depthguard.cli._load_entry", lambda spec, what: _stub(spec, {}))
        mp.setattr("depthguard.cli._save_pivot_plot", lambda res, out_dir: None)
        yield


def run_cli(argv: list[str]) -> tuple[int, str, str]:
    """``main(argv)`` in-process; argparse's SystemExit (--help) counts as its code."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            rc = main(argv)
        except SystemExit as exc:  # (main catches argparse's own; anything else here is a fault)
            rc = exc.code
    return rc, out.getvalue(), err.getvalue()


def check_promise(argv: list[str], rc, out: str, err: str) -> None:
    assert rc in (0, 2), f"{argv}: exit code {rc!r}, stderr {err!r}"
    assert "Traceback" not in err and "Traceback" not in out, f"{argv}: {err}"
    if rc == 2:
        lines = err.splitlines()
        assert len(lines) == 1 and lines[0].strip(), f"{argv}: stderr is not one line: {err!r}"
        assert lines[0].startswith(f"depthguard {argv[0]}: error: "), f"{argv}: {err!r}"
        assert out == "", f"{argv}: output on a refusal: {out!r}"


# ------------------------------------------------------------------------------------------- the parser
def _subparsers() -> dict:
    import argparse

    parser = build_parser()
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


SUBPARSERS = _subparsers()


def test_every_option_is_attacked() -> None:
    """The parser's own options, one by one: each has a hostile pool here (a new option must get one)."""
    import argparse

    for cmd, sub in SUBPARSERS.items():
        if cmd in ("distance", "cell"):  # (run for real below)
            continue
        for a in sub._actions:
            if isinstance(a, argparse._HelpAction) or not a.option_strings:
                continue
            flags = isinstance(a, argparse._StoreTrueAction) or a.option_strings[0] == "--cell"
            assert flags or a.option_strings[0] in SPEC[cmd], f"{cmd} {a.option_strings[0]}: no pool"


def _flags(cmd: str) -> list[str]:
    import argparse

    return [a.option_strings[0] for a in SUBPARSERS[cmd]._actions if isinstance(a, argparse._StoreTrueAction)]


@st.composite
def argvs(draw, cmd: str | None = None) -> tuple[list[str], list[str]]:
    """``(argv, bad)``: an argv of a stubbed command and the options whose drawn value is out of form."""
    cmd = cmd or draw(st.sampled_from(sorted(SPEC)))
    argv, bad = [cmd], []
    if cmd in POSITIONALS:
        text, ok = draw(st.sampled_from(POSITIONALS[cmd]))
        argv.append(text)
        bad += [] if ok else [cmd]
    if cmd in CELL_OPTION:
        argv += ["--cell", CELL]
    spec = SPEC[cmd]
    required = {a.option_strings[0] for a in SUBPARSERS[cmd]._actions if a.required and a.option_strings}
    chosen = draw(st.sets(st.sampled_from(sorted(spec)))) if spec else set()
    for opt in sorted(chosen | (required & set(spec))):
        text, ok = draw(st.sampled_from(spec[opt]))
        argv += [f"{opt}={text}"] if draw(st.booleans()) or text.startswith("-") else [opt, text]
        bad += [] if ok else [opt]
    flags = [f for f in _flags(cmd) if f != "--fast"]  # (--realtime and --fast exclude each other)
    argv += draw(st.lists(st.sampled_from(flags), unique=True)) if flags else []
    if (
        cmd == "scenario"
        and "--view" in argv
        and (argv[1] == "pivot" or argv[1] in set(EXTRA_SCENARIOS) - set(VIEW_SCENARIOS))
    ):
        bad.append("--view")  # (a scenario without simulated cameras has nothing to show)
    return argv, bad


@PROP
@given(argvs())
@example((["node", "distance", "--cell", CELL, "--log", str(WORK / "folder")], ["--log"]))  # IsADirectoryError
@example((["node", "distance", "--cell", CELL, "--duration", "-1"], ["--duration"]))  # ran 0 s, exit 0
@example((["node", "distance", "--cell", CELL, "--duration=nan"], ["--duration"]))
@example((["node", "sim", "--cell", CELL, "--source", "sim:ral-hexagon", "--watchdog", "nan"], ["--watchdog"]))
@example((["node", "sim", "--cell", CELL, "--source", "sim:ral-hexagon", "--watchdog", "1e9"], ["--watchdog"]))
@example((["node", "distance", "--cell", CELL, "--zenoh-domain", "999"], ["--zenoh-domain"]))
@example((["node", "distance", "--cell", CELL, "--zenoh-connect", "garbage"], ["--zenoh-connect"]))
@example((["node", "distance", "--cell", CELL, "--source", "bag:x"], ["--source"]))
@example((["view", "--cell", CELL, "--port", "99999"], ["--port"]))  # hung in viser
@example((["view", "--cell", CELL, "--port", "0"], ["--port"]))  # "http://127.0.0.1:0"
@example((["run", "--cell", CELL, "--source", "bag:"], ["--source"]))
@example((["run", "--cell", CELL, "--source", "realsense:x"], ["--source"]))
@example((["run", "--cell", CELL, "--source", "sim:x", "--zenoh-domain", "-5"], ["--zenoh-domain"]))
@example((["run", "--cell", CELL, "--source", "sim:x", "--out="], ["--out"]))  # silently no recording
@example((["calibrate", "--cell", CELL, "--source", "sim:x", "--write", str(WORK / "folder")], ["--write"]))
@example((["commission", "--cell", CELL, "--source", "sim:x", "--margin", "1e300"], ["--margin"]))
@example((["commission", "--cell", CELL, "--source", "sim:x", "--frames", "99999999999999999999"], ["--frames"]))
@example((["certs", "--cell", CELL, "--out", str(WORK / "c"), "--days", "99999999999"], ["--days"]))  # openssl
@example((["certs", "--cell", CELL, "--out", str(WORK / "c"), "--host", ""], ["--host"]))
@example((["certs", "--cell", CELL, "--out", str(WORK / "c"), "--host", "a,b"], ["--host"]))
@example((["scenario", "ral-hexagon", "--octree-res", "1"], ["--octree-res"]))
@example((["scenario", "ral-hexagon", "--view-port", "0"], ["--view-port"]))
@example((["demo", "--out", ""], ["--out"]))
def test_stubbed_commands_refuse_exactly_the_bad_values(case) -> None:
    argv, bad = case
    with stubbed():
        rc, out, err = run_cli(argv)
    check_promise(argv, rc, out, err)
    if bad:
        assert rc == 2 and not CALLS, f"{argv}: {bad} accepted (exit {rc}, work called: {bool(CALLS)})"
        assert any(b in err for b in bad), f"{argv}: the refusal names none of {bad}: {err!r}"
    else:
        assert rc == 0 and len(CALLS) == 1, f"{argv}: refused: {err!r}"


def test_certs_without_openssl_is_one_line(monkeypatch) -> None:
    """No openssl command: a clean refusal (was a RuntimeError traceback)."""
    import shutil

    monkeypatch.setattr(shutil, "which", lambda name: None)
    argv = ["certs", "--cell", CELL, "--out", str(WORK / "c")]
    rc, out, err = run_cli(argv)
    check_promise(argv, rc, out, err)
    assert rc == 2 and "openssl" in err


def test_a_missing_extra_is_one_line(monkeypatch) -> None:
    """An extra that does not import once the command runs (Zenoh, viser): one line, no traceback."""

    def missing(*a, **k):
        raise ModuleNotFoundError("No module named 'zenoh'")

    monkeypatch.setattr("depthguard.nodes.run_node", missing)
    argv = ["node", "distance", "--cell", CELL]
    rc, out, err = run_cli(argv)
    check_promise(argv, rc, out, err)
    assert rc == 2 and "zenoh" in err


# ------------------------------------------------------------------------------------- real: cell check
CELL_PATHS = texts([CELL], ["", " ", str(WORK / "folder"), str(WORK / "missing.toml"), str(WORK / "garbage.toml"),
                            str(WORK / "cam.json"), "/dev/null", "/"])  # fmt: skip
BAD_CELL_PATHS = [p for p in CELL_PATHS if not p[1]]


def _ids(cases: list) -> list[str]:
    """Test ids without the temporary folder's random name (pytest-xdist's workers must collect the same ids)."""
    return [repr(path.replace(str(WORK), "WORK").replace(str(ROOT), "ROOT")) for path, _ in cases]


@pytest.mark.parametrize(("path", "ok"), CELL_PATHS, ids=_ids(CELL_PATHS))
@pytest.mark.parametrize("json_flag", [[], ["--json"]])
def test_cell_check_paths(path: str, ok: bool, json_flag: list[str]) -> None:
    argv = ["cell", "check", path, *json_flag]
    rc, out, err = run_cli(argv)
    check_promise(argv, rc, out, err)
    assert rc == (0 if ok else 2), err


@pytest.mark.parametrize("cmd", ["run", "calibrate", "commission", "node", "view", "certs"])
@pytest.mark.parametrize(("path", "ok"), BAD_CELL_PATHS, ids=_ids(BAD_CELL_PATHS))
def test_bad_cell_paths_refused_before_work(cmd: str, path: str, ok: bool) -> None:
    """Real commands (no stubs) with a bad --cell and otherwise valid arguments: refused at once."""
    argv = {
        "run": ["run", "--source", "sim:ral-hexagon"], "calibrate": ["calibrate", "--source", "sim:ral-hexagon"],
        "commission": ["commission", "--source", "sim:ral-hexagon", "--out", str(WORK / "folder" / "bg.npz")],
        "node": ["node", "distance", "--duration", "0.01"], "view": ["view", "--duration", "0.01"],
        "certs": ["certs", "--out", str(WORK / "certs")],
    }[cmd] + ["--cell", path]  # fmt: skip
    rc, out, err = run_cli(argv)
    check_promise(argv, rc, out, err)
    assert rc == 2


# ---------------------------------------------------------------------------------------- real: distance
DISTANCE_SPEC: dict[str, list[tuple[str, bool]]] = {
    "--rho": numbers(float, 0.0, math.inf, lo_open=True),
    "--mode": texts(["min", "all", "hybrid"], ["", "median"]),
    "--direction-stride": texts(["auto"], ["Auto", ""]) + numbers(int, 1, 10_000),
    "--invalid": texts(["conservative", "ignore"], ["", "x"]),
    "--repeat": texts(["1", "3"], ["0", "-1", "nan", "1e3", "", "99999999999999999999", "1000001"]),
    "--model": texts(["frustum", "icra", "ral16"], ["", "x"]),
    "--fill-radius": numbers(int, 0, 10_000),
    "--grid-dd": numbers(float, 0.0, math.inf, lo_open=True),
    "--workspace": texts(
        ["-1,1,-1,1,0,3", "-2.5,2.5,-2,2,0.5,4"],
        ["", "nan,1,0,1,0,1", "-inf,1,0,1,0,1", "0,inf,0,1,0,1", "1,0,0,1,0,1", "0,1,0,1,0", "a,b,c,d,e,f", "0,1"],
    ),
    "--grid-map": texts(["onthefly"], ["", "x"]),
    "--backend": texts(["depthspace"], ["", "x"]),
    "--octree-res": numbers(float, 0.02, 0.1),
}


@st.composite
def distance_argvs(draw) -> tuple[list[str], list[str]]:
    argv, bad = list(DISTANCE), []
    for opt in sorted(draw(st.sets(st.sampled_from(sorted(DISTANCE_SPEC))))):
        text, ok = draw(st.sampled_from(DISTANCE_SPEC[opt]))
        argv += [f"{opt}={text}"] if draw(st.booleans()) or text.startswith("-") else [opt, text]
        bad += [] if ok else [opt]
    return argv, bad


@settings(max_examples=120, deadline=None, suppress_health_check=list(HealthCheck))
@given(distance_argvs())
@example((DISTANCE + ["--fill-radius", "1000000000000000000000000"], ["--fill-radius"]))  # numba TypingError
@example((DISTANCE + ["--fill-radius", "9223372036854775807"], ["--fill-radius"]))  # overflowed: another distance
@example((DISTANCE + ["--workspace=nan,1,0,1,0,1"], ["--workspace"]))  # accepted
@example((DISTANCE + ["--repeat", "99999999999999999999"], ["--repeat"]))
@example((DISTANCE + ["--direction-stride", "99999999999999999999"], ["--direction-stride"]))
@example((DISTANCE + ["--octree-res", "1"], ["--octree-res"]))  # accepted without --backend octree
def test_distance_options(case) -> None:
    """``distance`` for real on a 32x24 image (one camera: the depth-space backend)."""
    argv, bad = case
    rc, out, err = run_cli(argv)
    check_promise(argv, rc, out, err)
    if bad:
        assert rc == 2 and any(b in err for b in bad), f"{argv}: {bad}: exit {rc}, {err!r}"
    else:
        assert rc == 0, f"{argv}: refused: {err!r}"


@pytest.mark.parametrize("rho", ["1000", "1e300", "1e308"])
def test_octree_box_too_large_is_refused(rho: str) -> None:
    """``--backend octree`` without --workspace: the box within rho of the points is checked before it is built
    (rho 1000: a 58 TiB MemoryError; 1e300: an overflowed box and a distance of 8e17 m)."""
    argv = [*DISTANCE, "--backend", "octree", "--rho", rho]
    rc, out, err = run_cli(argv)
    check_promise(argv, rc, out, err)
    assert rc == 2 and "--rho" in err
