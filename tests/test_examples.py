"""The numbered examples run as documented, and what they print is right.

Each example's output is parsed line by line; the numbers are checked against the geometry of the scene
the example builds (recomputed here from the analytic scene, independently of the depth images), against
the repulsion profile (ICRA'12 eq. 7) and against the robot's forward kinematics.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

EXAMPLES = Path(__file__).parent.parent / "examples"
NUM = r"-?\d+\.\d+"
VEC = rf"\[\s*({NUM})\s+({NUM})\s+({NUM})\s*\]"


def _run(name: str) -> list[str]:
    proc = subprocess.run([sys.executable, str(EXAMPLES / name)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    return proc.stdout.strip().splitlines()


def test_every_example_is_checked_here():
    names = sorted(p.name for p in EXAMPLES.glob("[0-9][0-9]_*.py"))
    assert names == [
        "01_single_camera_distance.py",
        "02_avoidance_loop.py",
        "12_proximity_nsb.py",
    ], "add a test for the new example"


@pytest.mark.slow
def test_01_single_camera_distance_output():
    from depthguard.bench.scenes import arm_chain_points, person_scene
    from depthguard.repulsion import magnitude

    lines = _run("01_single_camera_distance.py")
    pattern = re.compile(rf"step (\d): closest point (\w+) at ({NUM}) m, repulsion {VEC} m/s")
    parsed = [pattern.fullmatch(ln) for ln in lines]
    assert len(lines) == 3 and all(parsed), lines
    names, centres, radii = arm_chain_points()
    scene = person_scene()
    for step, m in enumerate(parsed):
        assert int(m[1]) == step
        d, v = float(m[3]), np.array([float(m[i]) for i in (4, 5, 6)])
        moved = centres + np.array([0.0, -0.02 * step, 0.0])
        truth = scene.distance(moved) - radii  # true clearance of every sphere
        # a lower bound of the true clearance (within noise + one pixel footprint at 2 m: 1 cm), never a
        # wild under-estimate here: the closest sphere is in plain view of the camera
        assert truth.min() - 0.05 <= d <= truth.min() + 0.01, (d, truth.min())
        i = names.index(m[2])
        assert truth[i] <= truth.min() + 0.03  # the reported closest sphere is (one of) the truly closest
        # eq. 7: |V| = Vmax / (1 + exp((d 2/ρ - 1) α)) with the example's Vmax = 2, ρ = 0.4, α = 6
        expected = float(magnitude(np.array([d]), vmax=2.0, rho=0.4, alpha=6.0)[0])
        assert np.linalg.norm(v) == pytest.approx(expected, abs=0.02)
        # the repulsion points away from the person: along the true distance gradient of that sphere
        eps = 1e-4
        grad = np.array(
            [(scene.distance(moved[i] + e) - scene.distance(moved[i] - e))[0] / (2 * eps) for e in np.eye(3) * eps]
        )
        assert v @ grad / np.linalg.norm(v) / np.linalg.norm(grad) > 0.8
    assert [float(m[3]) for m in parsed] == sorted(float(m[3]) for m in parsed)  # moving away: growing


@pytest.mark.slow
def test_02_avoidance_loop_output():
    from depthguard.control import AvoidanceController  # noqa: F401  (the extra is installed)
    from depthguard.robot.control_points import ControlPointSet
    from depthguard.robot.model import load_lwr4
    from depthguard.scene import Box, HalfSpace, Scene

    lines = _run("02_avoidance_loop.py")
    pattern = re.compile(rf"t=\s*({NUM}) s  ee={VEC}  d_min=({NUM}) m \((\S+)\) (\w+)")
    rows = [pattern.fullmatch(ln) for ln in lines[:-1]]
    assert all(rows) and len(rows) == 10, lines
    final = re.fullmatch(
        rf"end effector ({NUM}) m from the goal; true minimum clearance to the box ({NUM}) m", lines[-1]
    )
    assert final, lines[-1]
    assert [float(m[1]) for m in rows] == pytest.approx([0.5 * k for k in range(10)])
    assert {m[7] for m in rows} <= {"OK", "SCALED"}  # never a stop in this plain task

    model = load_lwr4()
    points = ControlPointSet.build(model, "ral-9")
    q0 = np.array([0.6 - np.pi, 0.7, 0.0, -1.2, 0.0, 0.8, 0.0])
    ee0 = model.frame_pose(q0)[1]
    np.testing.assert_allclose([float(rows[0][i]) for i in (2, 3, 4)], ee0, atol=1e-3)  # forward kinematics
    box = Box(np.array([0.6, 0.0, 0.4]), np.array([0.05, 0.05, 0.05]))
    scene = Scene((box, HalfSpace(np.zeros(3), np.array([0, 0, 1.0]))))
    cps = points.evaluate(q0)
    truth0 = scene.distance(cps.centres) - cps.radii
    d0 = float(rows[0][5])
    assert d0 <= truth0.min() + 0.01, (d0, truth0.min())  # a lower bound at t = 0 (known configuration)
    assert rows[0][6] in cps.names
    # the end effector crosses to the mirrored goal above the box, and never touches the box
    goal = ee0 * np.array([1.0, -1.0, 1.0]) + [0.0, 0.0, 0.2]
    last_ee = np.array([float(rows[-1][i]) for i in (2, 3, 4)])
    assert np.linalg.norm(last_ee - goal) < np.linalg.norm(ee0 - goal) / 2
    assert float(final[1]) < 0.05
    assert 0.0 < float(final[2]) <= truth0.min() + 1e-3
    assert all(float(m[5]) > 0.0 for m in rows)


@pytest.mark.slow
def test_12_proximity_nsb_output():
    """The base backs off the kerb (the front sensor's range grows, the spring energy falls) while the end
    effector stays within 3 cm; the skin levels step up one at a time on lines whose code is the reflected
    binary Gray code of the level (computed here as level ^ (level >> 1)), one bit per step."""
    lines = _run("12_proximity_nsb.py")
    nsb = re.compile(
        rf"t = ({NUM}) s  d2 = ({NUM}) m  sigma = ({NUM}) m\^2  lambda = ({NUM})  "
        rf"base x = ({NUM}) m  ee error = ({NUM}) mm"
    )
    rows = [[float(x) for x in m.groups()] for m in map(nsb.fullmatch, lines) if m]
    assert len(rows) >= 5
    d2, sigma, base_x, ee = (np.array([r[i] for r in rows]) for i in (1, 2, 4, 5))
    assert np.all(np.diff(d2) >= -1e-9) and d2[-1] > d2[0]
    assert np.all(np.diff(sigma) <= 1e-12) and sigma[-1] < sigma[0]
    assert base_x[-1] < -0.01 and np.all(ee < 30.0)
    lvl = re.compile(r"\s*(\d+)\s+(\d+\.\d)\s+(\d)\s+([01]{3})")
    steps = [m.groups() for m in map(lvl.fullmatch, lines) if m]
    levels = [int(s[2]) for s in steps]
    assert levels == list(range(levels[0], levels[0] + len(levels))) and levels[-1] == 7
    for _, _dist, level, code in steps:
        assert code == format(int(level) ^ (int(level) >> 1), "03b")
    codes = [int(s[3], 2) for s in steps]
    assert all(bin(a ^ b).count("1") == 1 for a, b in zip(codes, codes[1:], strict=False))
    dists = [float(s[1]) for s in steps]
    assert dists == sorted(dists, reverse=True)
