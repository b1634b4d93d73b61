"""The command-line contract of issue 2 (kept exactly; checks outside the suite rely on it)."""

import json
import subprocess
import sys

import numpy as np
import pytest

from depthguard.camera import Camera, look_at
from depthguard.cli import main
from depthguard.io import ControlPoint, write_camera, write_depth, write_points
from depthguard.scene import HalfSpace, Scene, Sphere, render_depth


@pytest.fixture
def files(tmp_path):
    R, t = look_at([0, 0, 0], [0, 0, 1], up=[0, -1, 0])
    cam = Camera(width=160, height=120, fx=131.25, fy=131.25, cx=80, cy=60, R=R, t=t)
    scene = Scene((Sphere(np.array([0.0, 0.0, 2.0]), 0.2), HalfSpace(np.array([0, 0, 3.5]), np.array([0, 0, -1.0]))))
    write_camera(tmp_path / "cam.json", cam)
    write_depth(tmp_path / "d.png", render_depth(cam, scene))
    write_points(
        tmp_path / "pts.json",
        [ControlPoint("near", np.array([0.0, 0.0, 1.6]), 0.05), ControlPoint("far", np.array([0.0, 0.0, 1.15]), 0.05)],
    )
    return tmp_path


def test_distance_json_contract(files, capsys):
    rc = main(
        [
            "distance",
            "--camera",
            str(files / "cam.json"),
            "--depth",
            str(files / "d.png"),
            "--points",
            str(files / "pts.json"),
            "--json",
        ]
    )
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert list(out) == ["points"]
    near, far = out["points"]
    assert set(near) == {"name", "distance", "direction", "nearest", "obstacle_pixels"}
    assert near["name"] == "near" and near["distance"] == pytest.approx(0.2 - 0.05, abs=0.01)
    assert near["direction"][2] < -0.99 and len(near["nearest"]) == 3 and near["obstacle_pixels"] > 0
    assert far == {"name": "far", "distance": None, "direction": None, "nearest": None, "obstacle_pixels": 0}


def test_distance_options_and_timing(files, capsys):
    rc = main(
        [
            "distance",
            "--camera",
            str(files / "cam.json"),
            "--depth",
            str(files / "d.png"),
            "--points",
            str(files / "pts.json"),
            "--rho",
            "0.2",
            "--mode",
            "all",
            "--invalid",
            "ignore",
            "--repeat",
            "20",
            "--json",
        ]
    )
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert out["points"][0]["distance"] == pytest.approx(0.15, abs=0.01)
    assert set(out["timing"]) == {"us_median", "us_p99"} and out["timing"]["us_median"] > 0


def test_distance_direction_stride_option(files, capsys):
    """``--direction-stride`` (an extension of the contract): the distance is the same for every stride;
    a stride below 1 exits 2 naming the option."""
    base = ["distance", "--camera", str(files / "cam.json"), "--depth", str(files / "d.png")]
    base += ["--points", str(files / "pts.json"), "--mode", "hybrid", "--json"]
    got = []
    for stride in ("auto", "1", "3"):
        assert main([*base, "--direction-stride", stride]) == 0
        got.append(json.loads(capsys.readouterr().out)["points"][0]["distance"])
    assert got[0] == got[1] == got[2]
    proc = subprocess.run(
        [sys.executable, "-m", "depthguard.cli", *base, "--direction-stride", "0"], capture_output=True, text=True
    )
    assert proc.returncode == 2 and "--direction-stride" in proc.stderr


def test_distance_errors_exit_2_with_the_field(files):
    bad = files / "bad.json"
    bad.write_text(
        json.dumps(
            {"width": 160, "height": 120, "fx": -1, "fy": 1, "cx": 0, "cy": 0, "R": np.eye(3).tolist(), "t": [0, 0, 0]}
        )
    )
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "depthguard.cli",
            "distance",
            "--camera",
            str(bad),
            "--depth",
            str(files / "d.png"),
            "--points",
            str(files / "pts.json"),
            "--json",
        ],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 2 and "fx" in proc.stderr and proc.stdout == ""
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "depthguard.cli",
            "distance",
            "--camera",
            str(files / "cam.json"),
            "--depth",
            str(files / "d.png"),
            "--points",
            str(files / "pts.json"),
            "--mode",
            "median",
        ],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 2 and "--mode" in proc.stderr


def test_wrong_image_size_is_an_error(files, capsys):
    write_depth(files / "small.npy", np.ones((10, 10)))
    rc = main(
        [
            "distance",
            "--camera",
            str(files / "cam.json"),
            "--depth",
            str(files / "small.npy"),
            "--points",
            str(files / "pts.json"),
            "--json",
        ]
    )
    assert rc == 2 and "shape" in capsys.readouterr().err


def test_scenario_pivot_json(capsys):
    assert main(["scenario", "pivot", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out) == {"direct", "pivot"}
    assert out["direct"]["collided"] is True and out["pivot"]["collided"] is False
    assert isinstance(out["pivot"]["min_distance"], float)


def test_distance_two_cameras_fuses_the_shadow_away(tmp_path, capsys):
    """RA-L'16 Fig. 8/12 through the CLI: a blocker hides a point from camera 1; camera 2 sees it is free."""
    from depthguard.scene import Box

    cams = []
    for eye, target in (([0.0, 0.0, 0.0], [0.0, 0.0, 2.0]), ([2.0, 0.0, 2.0], [0.0, 0.0, 2.0])):
        R, t = look_at(eye, target, up=[0, -1, 0])
        cams.append(Camera(width=160, height=120, fx=131.25, fy=131.25, cx=80, cy=60, R=R, t=t, max_depth=6.0))
    blocker = Box(np.array([0.0, 0.0, 1.2]), np.array([0.15, 0.15, 0.05]))
    walls = (
        HalfSpace(np.array([0, 0, 4.0]), np.array([0, 0, -1.0])),
        HalfSpace(np.array([-2.0, 0, 0]), np.array([1.0, 0, 0])),
    )
    scene = Scene((blocker, *walls))
    args = ["distance", "--points", str(tmp_path / "p.json"), "--json", "--rho", "0.4"]
    for k, cam in enumerate(cams):
        write_camera(tmp_path / f"c{k}.json", cam)
        write_depth(tmp_path / f"d{k}.npy", render_depth(cam, scene))
        args += ["--camera", str(tmp_path / f"c{k}.json"), "--depth", str(tmp_path / f"d{k}.npy")]
    P = np.array([0.0, 0.0, 1.5])  # 0.25 m behind the blocker, in its shadow
    write_points(tmp_path / "p.json", [ControlPoint("p", P, 0.0)])
    truth = float(scene.distance(P[None])[0])
    assert main(args[:6] + args[6:10]) == 0  # camera 1 only
    one = json.loads(capsys.readouterr().out)["points"][0]["distance"]
    assert one is not None and one < 0.02
    assert main(args + ["--grid-dd", "0.01", "--workspace", "-1,1,-1,1,0.5,3.5"]) == 0
    two = json.loads(capsys.readouterr().out)["points"][0]["distance"]
    assert two is not None and truth - 0.03 <= two <= truth + 1e-6
