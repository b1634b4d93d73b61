"""``depthguard distance --backend octree``: JSON contract and accuracy on analytic scenes (issue 11 §3)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from depthguard.camera import Camera, look_at
from depthguard.cli import main
from depthguard.io import ControlPoint, write_camera, write_depth, write_points
from depthguard.scene import HalfSpace, Scene, Sphere, render_depth

RHO = 0.4
SPHERE = Sphere(np.array([0.0, 0.0, 2.0]), 0.25)
SCENE = Scene((SPHERE, HalfSpace(np.array([0, 0, 3.5]), np.array([0, 0, -1.0]))))


def wide_camera(eye, target, up=(0, -1, 0)) -> Camera:
    R, t = look_at(np.array(eye, float), np.array(target, float), up=np.array(up, float))
    return Camera(width=160, height=120, fx=70.0, fy=70.0, cx=80, cy=60, R=R, t=t, min_depth=0.3, max_depth=6.0)


CAM1 = wide_camera([0, 0, 0], [0, 0, 1])
CAM2 = wide_camera([1.5, 0, 0.5], [0, 0, 2.0])


def sample_points(n, seed=0):
    rng = np.random.default_rng(seed)
    pts = rng.uniform([-0.35, -0.3, 1.0], [0.35, 0.3, 1.72], size=(n, 3))
    d = np.linalg.norm(pts - SPHERE.center, axis=1) - SPHERE.radius
    return pts[d > 0.06]


def run(tmp_path, capsys, cams, pts, radius=0.05, res=0.05, extra=()):
    args = ["distance"]
    for i, cam in enumerate(cams):
        write_camera(tmp_path / f"c{i}.json", cam)
        write_depth(tmp_path / f"d{i}.npy", render_depth(cam, SCENE))
        args += ["--camera", str(tmp_path / f"c{i}.json"), "--depth", str(tmp_path / f"d{i}.npy")]
    write_points(tmp_path / "pts.json", [ControlPoint(f"p{i}", p, radius) for i, p in enumerate(pts)])
    args += ["--points", str(tmp_path / "pts.json"), "--rho", str(RHO), "--backend", "octree"]
    args += ["--octree-res", str(res), *extra, "--json"]
    assert main(args) == 0
    return json.loads(capsys.readouterr().out)["points"]


def seen(cams, P, reach):
    """Whether the whole cube of half-size ``reach`` around P lies in some camera's field of view."""
    corners = P + reach * np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], float)
    for cam in cams:
        pr = cam.project(corners)
        if np.all((pr[:, 2] > cam.min_depth) & (pr[:, 0] >= 0) & (pr[:, 0] < cam.width) & (pr[:, 1] >= 0)
                  & (pr[:, 1] < cam.height)):  # fmt: skip
            return True
    return False


@pytest.mark.parametrize("cams", [[CAM1], [CAM1, CAM2]], ids=["one-camera", "two-cameras"])
@pytest.mark.parametrize("res", [0.05, 0.1])
def test_octree_distances_within_the_declared_tolerances(tmp_path, capsys, cams, res):
    pts = sample_points(40, seed=int(res * 100) + len(cams))
    out = run(tmp_path, capsys, cams, pts, res=res)
    assert [p["name"] for p in out] == [f"p{i}" for i in range(len(pts))]
    n_seen = 0
    for p, P in zip(out, pts, strict=True):
        true = float(SPHERE.distance(P[None])[0]) - 0.05
        assert set(p) == {"name", "distance", "direction", "nearest", "obstacle_pixels"}
        if true < RHO - 0.05:
            assert p["distance"] is not None, f"{P}: null with a true distance of {true:.3f}"
        if p["distance"] is None:
            assert p["obstacle_pixels"] == 0
            continue
        assert p["distance"] <= true + 0.01, f"{P}: over-reports {p['distance']:.3f} > {true:.3f}"
        if seen(cams, P, RHO + 0.05 + res):
            n_seen += 1
            assert p["distance"] >= true - (math.sqrt(3) * res + 0.03), f"{P}: {p['distance']:.3f} vs {true:.3f}"
            assert p["obstacle_pixels"] > 0
            assert np.linalg.norm(p["direction"]) == pytest.approx(1.0)
    assert n_seen >= 5


def test_default_backend_is_unchanged_and_workspace_is_used(tmp_path, capsys):
    pts = np.array([[0.0, 0.0, 1.55]])
    ds = run(tmp_path, capsys, [CAM1], pts, extra=("--backend", "depthspace"))[0]
    oc = run(tmp_path, capsys, [CAM1], pts, extra=("--workspace", "-1,1,-1,1,0.5,2.6"))[0]
    true = 2.0 - 0.25 - 1.55 - 0.05
    assert ds["distance"] == pytest.approx(true, abs=0.02)
    assert true - math.sqrt(3) * 0.05 - 0.03 <= oc["distance"] <= true + 0.01


def test_octree_res_is_checked(tmp_path, capsys):
    write_camera(tmp_path / "c.json", CAM1)
    write_depth(tmp_path / "d.npy", render_depth(CAM1, SCENE))
    write_points(tmp_path / "p.json", [ControlPoint("a", np.array([0, 0, 1.5]), 0.05)])
    files = [
        "--camera",
        str(tmp_path / "c.json"),
        "--depth",
        str(tmp_path / "d.npy"),
        "--points",
        str(tmp_path / "p.json"),
    ]
    rc = main(["distance", *files, "--backend", "octree", "--octree-res", "0.5", "--json"])
    assert rc == 2
    assert "--octree-res" in capsys.readouterr().err
