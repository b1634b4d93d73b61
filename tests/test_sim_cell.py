"""The simulated cell: arm from the URDF, servos, people, depth camera conventions, truth clearances."""

from __future__ import annotations

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

from depthguard.camera import Camera, look_at  # noqa: E402
from depthguard.sim.cell import BoxSpec, CellSpec, build_cell  # noqa: E402
from depthguard.sim.depthcam import KinectSim, kinect_camera, placement, raycast_depth  # noqa: E402
from depthguard.sim.people import Keyframe, PersonScript, person_segments  # noqa: E402
from depthguard.sim.robotdesc import load_robot_desc  # noqa: E402
from depthguard.sim.truth import TrueClearance  # noqa: E402

Q0 = np.array([0.0, -0.3, 0.0, 1.6, 0.0, -0.8, 0.0])


def test_robot_description_has_seven_joints_and_capsules():
    desc = load_robot_desc()
    assert len(desc.actuated) == 7
    assert {c.link for c in desc.capsules} >= {f"lwr_link_{i}" for i in range(1, 8)}


def test_arm_matches_the_controllers_model():
    """The simulated arm and the controller's kinematics (pinocchio) agree on the tool point."""
    from depthguard.sim.pipeline import Kinematics

    cell = build_cell(CellSpec(q0=tuple(Q0)))
    kin = Kinematics("ee")
    rng = np.random.default_rng(1)
    for _ in range(5):
        q = Q0 + rng.uniform(-0.5, 0.5, 7)
        cell.set_q(q)
        np.testing.assert_allclose(cell.ee_position(), kin.evaluate(q).centres[0], atol=1e-6)


def test_servo_holds_and_tracks():
    cell = build_cell(CellSpec(q0=tuple(Q0)))
    for _ in range(200):
        cell.step(Q0)
    np.testing.assert_allclose(cell.q(), Q0, atol=1e-6)  # no drift without a command
    qd = np.full(7, 0.2)
    q = Q0.copy()
    for _ in range(500):
        q = q + qd * 1e-3
        cell.step(q, qd)
    np.testing.assert_allclose(cell.q(), q, atol=5e-3)  # follows a 0.2 rad/s ramp within 5 mrad


def test_depth_is_z_along_the_optical_axis_and_opencv_axes():
    """A box face perpendicular to the optical axis reads the same depth across the image (z, not ray length);
    a box on the right of the scene appears on the right of the image."""
    R, t = look_at([0.0, 0.0, 3.0], [0.0, 0.0, 0.0], up=[0.0, 1.0, 0.0])
    cam = Camera(width=64, height=48, fx=50.0, fy=50.0, cx=32.0, cy=24.0, R=R, t=t, min_depth=0.1, max_depth=10)
    spec = CellSpec(
        cameras=[cam], boxes=[BoxSpec("wall", (0.0, 0.0, 1.0), (3.0, 3.0, 0.01))], q0=tuple(Q0), backdrops=False
    )
    cell = build_cell(spec)
    d = raycast_depth(cell.model, cell.data, cam, geomgroup=np.array([0, 0, 0, 1, 0, 0], np.uint8))
    np.testing.assert_allclose(d, 3.0 - 1.01, atol=1e-9)
    spec2 = CellSpec(cameras=[cam], boxes=[BoxSpec("b", (0.8, 0.0, 0.5), (0.1, 0.1, 0.1))], q0=tuple(Q0))
    cell2 = build_cell(spec2)
    d2 = raycast_depth(cell2.model, cell2.data, cam, geomgroup=np.array([0, 0, 0, 1, 0, 0], np.uint8))
    hit = np.argwhere(np.isfinite(d2))
    u_hit = hit[:, 1].mean()
    expected = cam.project(np.array([0.8, 0.0, 0.6]))[0]  # top face centre
    assert abs(u_hit - expected) < 3


def test_sensor_model_noise_quantisation_range_and_seed():
    cam = kinect_camera((2.0, 0.0, 1.2), (0.0, 0.0, 0.35), width=80, height=60)
    cell = build_cell(CellSpec(cameras=[cam], q0=tuple(Q0)))
    k1 = KinectSim(cell.model, cam, 0, seed=3)
    k2 = KinectSim(cell.model, cam, 0, seed=3)
    exact = k1.exact_depth(cell.data)
    a, b = k1.sensor_effects(exact), k2.sensor_effects(exact)
    np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
    np.testing.assert_array_equal(a[np.isfinite(a)], b[np.isfinite(b)])  # fixed seed: same frame
    ok = np.isfinite(a)
    assert np.all(a[ok] >= 0.5) and np.all(a[ok] <= 4.5)
    mm = a[ok].astype(np.float64) * 1000
    np.testing.assert_allclose(mm, np.round(mm), atol=1e-3)  # 1 mm steps
    err = (a[ok] - exact[ok]) / exact[ok] ** 2
    assert 0.8e-3 < np.std(err) < 2.0e-3  # sigma ~ 1.4 mm * z^2
    assert np.any(~ok & np.isfinite(exact))  # some edge drop-outs


def test_people_segments_and_reach():
    segs = person_segments(np.array([1.0, 0.0]), np.pi, None, np.array([0.5, 0.2, 0.6]), floor_z=-0.8)
    assert set(segs) >= {"torso", "head", "l_uarm", "r_farm", "r_hand", "l_hand"}
    np.testing.assert_allclose(segs["r_hand"][0], [0.5, 0.2, 0.6], atol=1e-6)
    p = PersonScript("p", [Keyframe(0.0, (1.5, 0.0), 180), Keyframe(1.0, (1.0, 0.0), 180, right_hand=(0.5, 0.2, 0.6))])
    assert 0.3 < p.max_hand_speed() < 3.0
    with pytest.raises(ValueError, match="increase"):
        PersonScript("bad", [Keyframe(1.0, (0, 0)), Keyframe(0.5, (0, 0))])


def test_true_clearance_matches_geometry():
    """mj_geomDistance clearance of the tool to a box equals an independent capsule-to-box computation."""
    cell = build_cell(CellSpec(q0=tuple(Q0)))
    ee = cell.ee_position()
    centre, half = np.array([ee[0] + 0.30, ee[1], ee[2]]), np.array([0.05, 0.05, 0.05])
    cell = build_cell(CellSpec(q0=tuple(Q0), boxes=[BoxSpec("b", tuple(centre), tuple(half))]))
    per_link, dmin, name, _ = TrueClearance(cell).evaluate()
    assert name == "b"
    m, d = cell.model, cell.data
    g = [i for i in range(m.ngeom) if cell.geom_names[i].startswith("lwr_link_7")][0]
    axis, hl, r = d.geom_xmat[g].reshape(3, 3)[:, 2], m.geom_size[g, 1], m.geom_size[g, 0]
    s = np.linspace(-hl, hl, 2001)
    pts = d.geom_xpos[g] + s[:, None] * axis
    expected = np.min(np.linalg.norm(np.maximum(np.abs(pts - centre) - half, 0.0), axis=1)) - r
    assert dmin == pytest.approx(expected, abs=1e-3)
    assert np.all(per_link >= dmin - 1e-12)


def test_placements_match_the_papers():
    (icra,) = placement("icra")
    assert np.hypot(*icra.position[:2]) == pytest.approx(2.0)
    assert icra.position[2] == pytest.approx(1.2)
    hfov = 2 * np.degrees(np.arctan(icra.width / 2 / icra.fx))
    assert hfov == pytest.approx(57.0)
    c1, c2 = placement("ral")
    assert 3.5 < np.linalg.norm(c1.position - c2.position) < 4.5
