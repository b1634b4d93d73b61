"""Commissioning (``depthguard commission``) and the commissioned background of speed and separation monitoring
(``[controller] background``): the pixel rule against hand-built arrays, the simulated cell end to end (with
the background the SSM arm moves, without it it never does), a box above the table still seen within the
declared tolerance, and bad inputs named in one line (exit 2)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from depthguard.cli import main
from depthguard.io.background import BackgroundFile, read_background, write_background
from depthguard.robot.background import apply_background, background_threshold

ROOT = Path(__file__).resolve().parents[1]
SSM_CELL = ROOT / "examples" / "cells" / "sim-hexagon-ssm.toml"
SCENARIO = ROOT / "src" / "depthguard" / "data" / "scenarios" / "ral-hexagon.toml"
NAMES = ("camera0", "camera1", "camera2")


# ------------------------------------------------------------------------------------------ the pixel rule
def test_pixel_rule_on_hand_built_arrays():
    """Background 2 m (a table), Kinect noise c = 1.4e-3, quantization 1 mm, margin 1 cm: the tolerance is
    3 * 1.4e-3 * 4 + 0.001 + 0.01 = 0.0278 m, so readings at or beyond 1.9722 m are background."""
    b = np.array([[2.0, 2.0, 2.0, 2.0], [2.0, 2.0, np.nan, np.inf]], np.float32)
    thr = background_threshold(b, 1.4e-3, 1e-3, 0.01)
    np.testing.assert_allclose(thr[0], [1.9722] * 4, atol=1e-6)
    assert thr[1, 2] == np.inf and thr[1, 3] == np.inf  # never background where the empty cell had nothing
    depth = np.array(
        [
            [2.0, 2.05, 1.975, 1.95],  # on the table, behind it, within the tolerance, a hand 5 cm above
            [np.nan, 2.0, 2.0, 3.0],  # no reading, a robot pixel, no background there (twice)
        ],
        np.float32,
    )
    mask = np.array([[False, False, False, False], [False, True, False, False]])
    out = apply_background(depth, mask, thr, 4.5)
    expected = np.array([[4.5, 4.5, 4.5, 1.95], [np.nan, 2.0, 2.0, 3.0]], np.float32)
    np.testing.assert_array_equal(out, expected)
    assert out.dtype == np.float32 and not np.shares_memory(out, depth)
    # the edge of the tolerance: 1 mm in front of the threshold stays, at the threshold it is background
    edge = apply_background(np.array([[1.9712, 1.9722]], np.float32), np.zeros((1, 2), bool), thr[:1, :2], 4.5)
    np.testing.assert_allclose(edge, [[1.9712, 4.5]], atol=1e-6)


def test_background_file_round_trip(tmp_path):
    d = np.array([[1.0, np.nan, 3.0]], np.float32)
    bg = BackgroundFile(("a",), (d,), (1e-3,), (2e-3,), (0.01,), "2026-01-01T00:00:00+00:00", 7, "bag:x", (2 / 3,))
    p = write_background(tmp_path / "bg.npz", bg)
    back = read_background(p)
    assert back.names == ("a",) and back.size(0) == (3, 1) and back.frames == 7 and back.source == "bag:x"
    np.testing.assert_array_equal(back.depths[0], d)
    assert (back.noise_coeff, back.quantization, back.margin) == ((1e-3,), (2e-3,), (0.01,))


# ------------------------------------------------------------------------------------------------ helpers
def _cell(tmp_path: Path, background: str | None = None, *, ssm: bool = True, name: str = "cell.toml") -> Path:
    text = SSM_CELL.read_text()
    if not ssm:
        text = text.replace("\nssm = true\n", "\nssm = false\n")
    if background is not None:
        text = re.sub(r"^# background = .*$", f'background = "{background}"', text, flags=re.M)
    p = tmp_path / name
    p.write_text(text)
    return p


def _scenario(tmp_path: Path, seconds: float, *, people: bool = True, boxes: str = "") -> Path:
    """ral-hexagon as a file: ``seconds`` of quick run, without its variants (and people), plus ``boxes``."""
    text = SCENARIO.read_text()
    text = re.sub(r"^quick_duration = .*$", f"quick_duration = {seconds}", text, flags=re.M)
    text = text[: text.index("[[variants]]")]
    if not people:
        text = text[: text.index("[[people]]")]
    p = tmp_path / "hexagon.toml"
    p.write_text(text + boxes)
    return p


def _fake_background(path: Path, names=NAMES, size=(160, 120)) -> Path:
    w, h = size
    depths = tuple(np.full((h, w), 3.0, np.float32) for _ in names)
    n = len(names)
    bg = BackgroundFile(tuple(names), depths, (1.4e-3,) * n, (1e-3,) * n, (0.01,) * n, "", 1, "test", (1.0,) * n)
    return write_background(path, bg)


@pytest.fixture(scope="module")
def commissioned(tmp_path_factory):
    """``depthguard commission`` of the people-free ral-hexagon cell (quick: 160x120), with its summary."""
    tmp = tmp_path_factory.mktemp("commission")
    cell = _cell(tmp)
    out = tmp / "cell.background.npz"
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = main(
            ["commission", "--cell", str(cell), "--source", "sim:ral-hexagon", "--quick", "--out", str(out), "--json"]
        )
    assert rc == 0
    return tmp, out, json.loads(buf.getvalue())


# -------------------------------------------------------------------------------------------- end to end
def test_commissioned_background_is_the_empty_cell(commissioned):
    """Every camera's background is the ray-cast depth of the static cell (room, floor, table) where both
    exist, to the noise (the nearest of 30 noisy readings lies about 2 sigma in front); the robot's path and
    the parcel (a box, on the floor far away) are the only other things in it."""
    from depthguard.runner.sources import SimSource
    from depthguard.sim.depthcam import raycast_depth

    _, out, summary = commissioned
    assert summary["frames"] == 30 and [c["name"] for c in summary["cameras"]] == list(NAMES)
    bg = read_background(out)
    assert bg.names == NAMES and bg.frames == 30 and bg.source == "sim:ral-hexagon" and bg.date
    src = SimSource("ral-hexagon", quick=True, cameras=3, people=False, ssm=True)
    try:
        groups = np.zeros(6, np.uint8)
        groups[0] = 1
        src.cell.forward()
        for k, (cam, sim) in enumerate(zip(src.cameras, src.cams, strict=True)):
            assert bg.size(k) == (160, 120) and bg.valid_fraction[k] > 0.9
            ref = raycast_depth(src.cell.model, src.cell.data, cam, groups)
            both = np.isfinite(ref) & np.isfinite(bg.depths[k])
            sigma = sim.noise_coeff * ref[both] ** 2
            diff = bg.depths[k][both] - ref[both]
            assert np.mean(np.abs(diff) <= 4 * sigma + 2e-3) > 0.95, k
            assert summary["cameras"][k]["noise_coeff_measured"] == pytest.approx(sim.noise_coeff, rel=0.1)
    finally:
        src.close()


def _run(cell: Path, scenario: Path, capsys) -> dict:
    rc = main(["run", "--cell", str(cell), "--source", f"sim:{scenario}", "--quick", "--json"])
    out = capsys.readouterr().out
    assert rc == 0
    return json.loads(out.strip().splitlines()[-1])


@pytest.mark.slow
def test_ssm_run_moves_with_the_background_and_never_without(commissioned, tmp_path, capsys):
    """The SSM cell of ral-hexagon, 2.5 s (the person walks in from 1.5 s): with the commissioned background
    the arm moves in most cycles; without it the table keeps the lower points within S_p: stopped all along
    (as with two cameras, and as before the background existed)."""
    from depthguard.runner import run_cell
    from depthguard.runner.run import RunLog

    tmp, out, _ = commissioned
    scenario = _scenario(tmp_path, 2.5)
    with_bg = _cell(tmp_path, str(out), name="with.toml")
    log = RunLog()
    res = run_cell(with_bg, f"sim:{scenario}", quick=True, log=log)
    st = res["statuses"]
    moving = st.get("OK", 0) + st.get("SCALED", 0)
    assert res["background"] == str(out.resolve())
    assert moving > 0.5 * res["commands"], st
    q = np.asarray(log.q_cmd)
    assert np.abs(q[-1] - q[0]).max() > 0.05  # commanded motion (rad)
    res0 = _run(_cell(tmp_path, name="without.toml"), scenario, capsys)
    assert res0["background"] is None
    st0 = res0["statuses"]  # (a few SCALED cycles at the very start, before the first stop latches)
    assert st0.get("STOP_PROTECTIVE", 0) >= 0.99 * res0["commands"] and st0.get("OK", 0) == 0, st0


def test_a_box_above_the_table_is_still_seen(commissioned, tmp_path):
    """One frame set of the people-free cell with a box 5 cm above the table (not in the background): with
    the background applied (the monitor's distances), every control point's distance is at most its true
    clearance to the box (the geometry of a sphere and a box) + the stage's declared tolerance, and the box is
    seen (the nearest point's distance within 5 cm of the truth); a box 1 cm flat on the table is the
    documented limit: hidden from the monitor. The repulsion's distances (the images as measured: two
    distance sets) still see that plate, and the table."""
    from depthguard.io.cellfile import read_cell
    from depthguard.runner.chain import Chain, load_cell_robot
    from depthguard.runner.sources import SimSource

    tmp, out, _ = commissioned
    cell = read_cell(_cell(tmp_path, str(out)))
    model = load_cell_robot(cell)

    def frame(center, half):
        box = f'\n[[boxes]]\nname = "probe"\ncenter = {list(center)}\nhalf = {list(half)}\n'
        src = SimSource(str(_scenario(tmp_path, 0.1, people=False, boxes=box)), quick=True, cameras=3, ssm=True)
        try:
            q = src.cell.q()
            src.cell.forward()
            depths = [c.capture(src.cell.data) for c in src.cams]
            chain = Chain(cell, src.cameras, model)
            chain.on_frames(depths, q, 0.0)
            res = chain.query(0.0, q)
            mon = chain.latest_monitor
            cps = chain.points.evaluate(q)
            tol = chain.stage.monitor.tolerance(cps.centres, 1.4e-3)
            # the control input carries both sets: the repulsion's and the monitor's own
            inp_d = chain.control(0.0, q, np.zeros_like(q), 0.0, np.zeros(3))
            assert inp_d.ssm is not None
        finally:
            src.close()
        lo, hi = np.asarray(center) - half, np.asarray(center) + half
        true = np.linalg.norm(cps.centres - np.clip(cps.centres, lo, hi), axis=1) - cps.radii
        return np.asarray(mon.distance, float), np.maximum(true, 0.0), tol, np.asarray(res.distance, float)

    # on the table's front corner (the table: 0.6 x 0.6 m, top at z = 0), 5 cm above it, 10 cm high
    d, true, tol, _ = frame((0.22, -0.22, 0.10), (0.05, 0.05, 0.05))
    near = true < 0.6  # within the monitor's range (ssm_range)
    assert near.any()
    assert np.all(np.minimum(d, 0.6)[near] <= true[near] + tol[near]), (d, true, tol)
    k = int(np.argmin(true))
    assert d[k] <= true[k] + 0.05
    # a plate 1 cm thick flat on the table: within the background's tolerance, hidden (the limit)
    d2, true2, _, rep2 = frame((0.22, -0.22, 0.005), (0.05, 0.05, 0.005))
    k2 = int(np.argmin(true2))
    assert d2[k2] > true2[k2] + 0.05
    assert rep2[k2] <= true2[k2] + 0.05  # the repulsion sees it (and the table under it)


# ------------------------------------------------------------------------------------------- bad inputs
def _one_line_error(capsys, *needles: str) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    for n in needles:
        assert n in err, err
    return err


def test_missing_background_file(tmp_path, capsys):
    cell = _cell(tmp_path, "nope.npz")
    assert main(["cell", "check", str(cell)]) == 2
    _one_line_error(capsys, "controller.background", "nope.npz", "is not a file")


def test_not_a_background_file(tmp_path, capsys):
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    assert main(["cell", "check", str(_cell(tmp_path, "junk.npz"))]) == 2
    _one_line_error(capsys, "controller.background", "not a background file")


def test_background_of_other_cameras(tmp_path, capsys):
    _fake_background(tmp_path / "bg.npz", names=("camera0", "camera1", "cam_x"))
    assert main(["cell", "check", str(_cell(tmp_path, "bg.npz"))]) == 2
    _one_line_error(capsys, "controller.background", "cam_x", "commission this cell again")


def test_background_of_another_image_size(tmp_path, capsys):
    _fake_background(tmp_path / "bg.npz", size=(80, 60))
    cell = _cell(tmp_path, "bg.npz")
    assert main(["cell", "check", str(cell)]) == 0  # (the size is the source's: checked when a run starts)
    assert "background: 'bg.npz'" in capsys.readouterr().out
    assert main(["run", "--cell", str(cell), "--source", "sim:ral-hexagon", "--quick", "--json"]) == 2
    _one_line_error(capsys, "controller.background", "camera0", "80x60", "160x120")


def test_commission_out_in_a_missing_folder_fails_before_any_work(tmp_path, capsys):
    import time

    t0 = time.perf_counter()
    out = tmp_path / "no" / "such" / "bg.npz"
    rc = main(["commission", "--cell", str(_cell(tmp_path)), "--source", "sim:ral-hexagon", "--out", str(out)])
    assert rc == 2 and time.perf_counter() - t0 < 5.0
    _one_line_error(capsys, "--out", "does not exist")
    assert main(["commission", "--cell", str(_cell(tmp_path)), "--source", "sim:ral-hexagon", "--frames", "0"]) == 2
    _one_line_error(capsys, "--frames")


def test_cell_check_says_whether_the_background_is_used(tmp_path, capsys):
    _fake_background(tmp_path / "bg.npz")
    assert main(["cell", "check", str(_cell(tmp_path, "bg.npz"))]) == 0
    assert "applied to the depth images before the distances (SSM on)" in capsys.readouterr().out
    assert main(["cell", "check", str(_cell(tmp_path, "bg.npz", ssm=False, name="off.toml"))]) == 0
    assert "not applied (SSM off" in capsys.readouterr().out
    assert main(["cell", "check", str(_cell(tmp_path, name="none.toml"))]) == 0
    assert "background: none" in capsys.readouterr().out


def test_without_ssm_the_background_is_not_applied(tmp_path):
    from depthguard.io.cellfile import read_cell
    from depthguard.robot.background import BackgroundStage
    from depthguard.runner.chain import cell_distance_stage
    from depthguard.sim.depthcam import placement

    _fake_background(tmp_path / "bg.npz")
    cams = placement("ral3", 160, 120)
    on = cell_distance_stage(read_cell(_cell(tmp_path, "bg.npz")), cams)
    off = cell_distance_stage(read_cell(_cell(tmp_path, "bg.npz", ssm=False, name="off.toml")), cams)
    assert isinstance(on, BackgroundStage) and not isinstance(off, BackgroundStage)
