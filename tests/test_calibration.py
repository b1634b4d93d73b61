"""Calibration against the arm (SAPHARI §3.3) in the simulated cell: Kinect-like noise, 640x480, six poses."""

import numpy as np
import pytest

pytest.importorskip("small_gicp")
pytest.importorskip("mujoco")
pytest.importorskip("pinocchio")

from scipy.spatial.transform import Rotation  # noqa: E402

from depthguard.robot.calibration import calibrate_extrinsics, capsule_surface_points, moving_pixels  # noqa: E402

POSES = [
    [0.3, 0.5, 0.0, -1.2, 0.0, 0.8, 0.0],
    [-0.8, -0.4, 0.5, 1.4, 0.3, -0.6, 0.0],
    [1.2, 0.9, -0.4, 0.6, -0.5, 0.9, 0.5],
    [0.0, -0.9, 0.0, -1.5, 1.0, 0.5, 0.0],
    [-0.4, 0.3, 1.2, 1.8, -1.0, -0.3, 0.2],
    [0.9, -0.2, -1.0, -0.8, 0.6, 1.2, -0.4],
]


def _captures(poses, width: int, height: int, seed: int):
    """``(camera, [(depth, q)], model)``: one simulated Kinect (noise 1.4e-3 z^2, 1 mm quantisation, edge
    drop-outs) watching the LWR at each of ``poses``."""
    from depthguard.robot.model import load_lwr4
    from depthguard.sim.cell import CellSpec, build_cell
    from depthguard.sim.depthcam import KinectSim, kinect_camera

    model = load_lwr4()
    cam = kinect_camera((1.75, -0.95, 1.5), (0.0, 0.0, 0.45), width=width, height=height)
    cell = build_cell(CellSpec(cameras=[cam], boxes=[], people=[], q0=tuple(np.zeros(7))))
    sim = KinectSim(cell.model, cam, 0, seed=seed)
    frames = []
    for q in poses:
        cell.set_q(np.array(q))
        frames.append((sim.capture(cell.data), np.array(q)))
    return cam, frames, model


@pytest.fixture(scope="module")
def scene():
    return _captures(POSES, 640, 480, seed=1)


def _perturbed(cam, deg, metres, seed):
    rng = np.random.default_rng(seed)
    ax = rng.normal(size=3)
    ax /= np.linalg.norm(ax)
    dp = rng.normal(size=3)
    dp *= metres / np.linalg.norm(dp)
    R0 = cam.R @ Rotation.from_rotvec(ax * np.deg2rad(deg)).as_matrix().T
    return cam.with_pose(R0, -R0 @ (cam.position + dp))


def _errors(res, cam):
    centre, _ = res.camera_pose
    return np.linalg.norm(centre - cam.position), np.rad2deg(Rotation.from_matrix(res.R @ cam.R.T).magnitude())


def test_surface_samples_lie_on_the_capsules():
    a, b, r = np.array([[0.0, 0, 0]]), np.array([[0.0, 0, 0.5]]), np.array([0.07])
    p, n = capsule_surface_points(a, b, r, 0.01)
    s = np.clip(p[:, 2] / 0.5, 0, 1)
    d = np.linalg.norm(p - s[:, None] * np.array([0, 0, 0.5]), axis=1)
    np.testing.assert_allclose(d, 0.07, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0)
    assert np.all(np.einsum("ij,ij->i", n, p - s[:, None] * np.array([0, 0, 0.5])) > 0)


def test_motion_reveals_the_robot_without_a_guess(scene):
    """Pixels that the arm's motion reveals are robot pixels: their points lie on the true robot surface."""
    from scipy.spatial import cKDTree

    from depthguard.robot.calibration import _moving_points, _visible_model

    cam, frames, model = scene
    masks = moving_pixels([d for d, _ in frames])
    for (depth, q), m in zip(frames, masks, strict=True):
        pts = cam.camera_to_world(_moving_points(cam, depth, m))
        d = cKDTree(_visible_model(cam, model, q, 0.004)).query(pts)[0]
        assert len(pts) > 2000 and np.mean(d < 0.01) > 0.9


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1])
def test_converges_from_10_degrees_and_10_cm(scene, seed):
    cam, frames, model = scene
    res = calibrate_extrinsics(_perturbed(cam, 10.0, 0.10, seed), frames, model)
    pos, ang = _errors(res, cam)
    assert res.accepted, res.message
    assert pos <= 0.005 and ang <= 0.5, (pos, ang)
    assert res.rmse < 0.006 and res.inlier_fraction > 0.8


@pytest.mark.slow
def test_far_start_still_converges_or_refuses(scene):
    """The motion-revealed robot points carry no background, so even 100 degrees and 0.6 m off converges;
    whatever happens, an accepted result is right."""
    cam, frames, model = scene
    res = calibrate_extrinsics(_perturbed(cam, 100.0, 0.6, 3), frames, model)
    pos, ang = _errors(res, cam)
    assert not res.accepted or (pos <= 0.005 and ang <= 0.5)


@pytest.mark.slow
def test_refuses_when_the_joint_states_do_not_match(scene):
    """Depth frames paired with the wrong joint states (unsynchronised streams): no transform explains them,
    so the calibration refuses instead of returning one."""
    cam, frames, model = scene
    shifted = [(d, frames[(i + 1) % len(frames)][1]) for i, (d, _) in enumerate(frames)]
    res = calibrate_extrinsics(_perturbed(cam, 5.0, 0.05, 4), shifted, model)
    assert not res.accepted and res.message.startswith("refused")


def test_refuses_without_arm_motion(scene):
    cam, frames, model = scene
    same = [frames[0]] * 5
    res = calibrate_extrinsics(cam, same, model)
    assert not res.accepted and "too few poses" in res.message
    with pytest.raises(ValueError, match="at least 5"):
        calibrate_extrinsics(cam, frames[:4], model)


@pytest.mark.slow
def test_self_filter_margin_covers_the_residual(scene):
    """Robot pixels left by the self-filter: many with the initial guess, as few as with the true pose after
    calibration (the 3 cm margin covers the residual error)."""
    from depthguard.robot.selffilter import self_filter

    cam, frames, model = scene
    guess = _perturbed(cam, 5.0, 0.05, 7)
    res = calibrate_extrinsics(guess, frames, model)
    calibrated = cam.with_pose(res.R, res.t)
    masks = moving_pixels([d for d, _ in frames])
    left = {}
    for name, c in (("guess", guess), ("calibrated", calibrated), ("true", cam)):
        left[name] = sum(
            int(np.sum(m & ~np.asarray(self_filter(c, d, q, model)[0])))
            for (d, q), m in zip(frames, masks, strict=True)
        )
    assert left["guess"] > 10 * max(left["true"], 50)
    assert left["calibrated"] <= left["true"] + 0.002 * sum(int(m.sum()) for m in masks)


@pytest.mark.slow
def test_cli_calibrate_writes_a_file_the_cell_file_uses(tmp_path, capsys):
    """`depthguard calibrate` on the simulated hexagon cell (quick resolution) from a guess 3 deg / 3 cm off:
    the written calibration, referenced from the cell file, moves the cameras back to the truth."""
    import json
    from pathlib import Path

    from depthguard.cli import main
    from depthguard.io.cellfile import read_cell
    from depthguard.sim.depthcam import placement

    src = (Path(__file__).resolve().parents[1] / "examples" / "cells" / "sim-hexagon.toml").read_text()
    off = src.replace("eye = [1.75, -0.95, 1.5]", "eye = [1.77, -0.97, 1.52]").replace(
        "target = [0.0, 0.0, 0.45]", "target = [0.05, 0.0, 0.50]", 1
    )
    cell = tmp_path / "cell.toml"
    cell.write_text(off)
    assert main(["calibrate", "--cell", str(cell), "--source", "sim:ral-hexagon", "--quick", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert all(c["accepted"] for c in out["cameras"])
    cell.write_text('calibration = "cell.calibration.toml"\n' + off)
    truth = placement("ral", 160, 120)
    for cc, cam in zip(read_cell(cell).cameras, truth, strict=True):
        assert np.linalg.norm(cc.build().position - cam.position) < 0.01
        assert np.rad2deg(Rotation.from_matrix(cc.R @ cam.R.T).magnitude()) < 0.5


# -- a camera carried by a link (SAPHARI §3.3: sensors on a parked platform), calibrated in the link's frame

LINK = "lwr_link_1"
STILL_POSES = [[0.4, *q[1:]] for q in POSES]  # joint 1 held: link 1 stays still, the rest of the arm moves


def _in_link(cam, model, q):
    """The camera ``cam`` (world) as carried by ``LINK`` at ``q``: ``P_C = (R R_l) P_L + (t + R p_l)``."""
    R_l, p_l = model.frame_pose(np.asarray(q, float), LINK)
    return cam.with_pose(cam.R @ R_l, cam.t + cam.R @ p_l)


def test_a_moving_link_is_refused_with_its_motion_named():
    from depthguard.robot.calibration import still_link_pose
    from depthguard.robot.model import load_lwr4

    model = load_lwr4()
    R, p = still_link_pose(model, LINK, STILL_POSES)
    R0, p0 = model.frame_pose(np.asarray(STILL_POSES[0], float), LINK)
    assert np.allclose(R, R0) and np.allclose(p, p0)
    with pytest.raises(ValueError, match=r"'lwr_link_1' moves between the calibration poses \(pose 1: .* deg"):
        still_link_pose(model, LINK, POSES)


@pytest.mark.slow
def test_carried_camera_converges_in_its_link_frame():
    """The Kinect of the other tests, carried by link 1 (joint 1 held at 0.4 rad over six poses): from a
    guess 10 degrees and 10 cm off in the link's frame, the link-frame extrinsics end within 5 mm and 0.5
    degrees of the truth; the same frames with the world guess give the same camera (to 1e-9)."""
    cam, frames, model = _captures(STILL_POSES, 640, 480, seed=2)
    local = _in_link(cam, model, STILL_POSES[0])
    guess = _perturbed(local, 10.0, 0.10, 5)
    res = calibrate_extrinsics(guess, frames, model, link=LINK)
    assert res.accepted, res.message
    pos, ang = _errors(res, local)
    assert pos <= 0.005 and ang <= 0.5, (pos, ang)
    # the same calibration from the world guess that the link-frame guess stands for
    world = calibrate_extrinsics(_in_link_inverse(guess, model, STILL_POSES[0]), frames, model)
    back = _in_link(guess.with_pose(world.R, world.t), model, STILL_POSES[0])
    np.testing.assert_allclose(back.R, res.R, atol=1e-9)
    np.testing.assert_allclose(back.t, res.t, atol=1e-9)


def _in_link_inverse(local, model, q):
    """The world camera of the link-frame camera ``local`` at ``q``."""
    R_l, p_l = model.frame_pose(np.asarray(q, float), LINK)
    R_w = local.R @ R_l.T
    return local.with_pose(R_w, local.t - R_w @ p_l)


@pytest.mark.slow
def test_calibrate_cell_writes_a_link_frame_calibration_that_only_that_mounting_takes(tmp_path, monkeypatch):
    """`calibrate_cell` with a camera on ``lwr_link_1`` (its frames as a bag source would hand them: the
    simulated captures at the still-link poses): the written file holds the link-frame extrinsics and the
    parent, the cell file that references it moves the camera to the truth, and a cell file whose camera
    hangs elsewhere refuses the file."""
    import depthguard.runner.calibrate as cal_mod
    from depthguard.io.cellfile import CellError, read_cell

    cam, frames, model = _captures(STILL_POSES, 320, 240, seed=3)
    local = _in_link(cam, model, STILL_POSES[0])
    guess = _perturbed(local, 4.0, 0.04, 9)
    monkeypatch.setattr(cal_mod, "_bag_frames", lambda path, cell, names, change: ([guess], [frames]))

    def cell_text(parent: str, R, t, calibration: str = "") -> str:
        return f"""{calibration}
[cell]
name = "carried"
[robot]
model = "lwr4"
[[cameras]]
name = "mast"
topic = "/mast/depth"
parent = "{parent}"
width = {cam.width}
height = {cam.height}
fx = {cam.fx}
fy = {cam.fy}
cx = {cam.cx}
cy = {cam.cy}
R = {np.asarray(R).tolist()}
t = {np.asarray(t).tolist()}
"""

    path = tmp_path / "cell.toml"
    path.write_text(cell_text(LINK, guess.R, guess.t))
    out = cal_mod.calibrate_cell(path, "bag:unused")
    entry = out["cameras"][0]
    assert entry["accepted"], entry
    left_guess, left_cal = entry["robot_pixels_left_guess_vs_calibrated"]
    assert left_cal < left_guess
    written = (tmp_path / "cell.calibration.toml").read_text()
    assert f'parent = "{LINK}"' in written
    path.write_text(cell_text(LINK, guess.R, guess.t, 'calibration = "cell.calibration.toml"'))
    got = read_cell(path).cameras[0]
    assert np.linalg.norm(got.build().position - local.position) < 0.005
    assert np.rad2deg(Rotation.from_matrix(got.R @ local.R.T).magnitude()) < 0.5
    path.write_text(cell_text("world", guess.R, guess.t, 'calibration = "cell.calibration.toml"'))
    with pytest.raises(CellError, match=r"parent = 'lwr_link_1', but camera 'mast'.*another mounting"):
        read_cell(path)
