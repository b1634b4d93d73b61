"""Simulated Kinect: the ray-cast and OpenGL paths agree; the self-filter against the exact robot silhouette."""

from __future__ import annotations

import os

import numpy as np
import pytest

pytest.importorskip("mujoco")

from depthguard.sim.cell import GROUP_ROBOT, CellSpec, build_cell  # noqa: E402
from depthguard.sim.depthcam import KinectSim, placement, raycast_depth  # noqa: E402
from depthguard.sim.people import Keyframe, PersonScript  # noqa: E402

Q0 = (0.0, -0.3, 0.0, 1.6, 0.0, -0.8, 0.0)


def _cell(width=160, height=120):
    cams = placement("ral", width, height)
    person = PersonScript("p", [Keyframe(0.0, (0.9, 0.6), yaw=-150, right_hand=(0.55, 0.25, 0.55))])
    return build_cell(CellSpec(cameras=cams, people=[person], q0=Q0, room=(-1.1, 2.0, -1.1, 2.0)))


_RENDER_CHECK = r"""
import json, sys
import numpy as np
from depthguard.sim.depthcam import KinectSim, egl_available
sys.path.insert(0, sys.argv[1])
from test_sim_depthcam import _cell
if not egl_available():
    print(json.dumps({"skip": True}))
    sys.exit(0)
cell = _cell()
out = []
for i, cam in enumerate(cell.cameras):
    ray = KinectSim(cell.model, cam, i, backend="raycast").exact_depth(cell.data)
    ren = KinectSim(cell.model, cam, i, backend="render")
    gl = ren.exact_depth(cell.data)
    ren.close()
    both = np.isfinite(ray) & np.isfinite(gl)
    diff = np.abs(ray[both] - gl[both])
    a = KinectSim(cell.model, cam, i, seed=5).sensor_effects(ray)
    b = KinectSim(cell.model, cam, i, seed=5).sensor_effects(gl)
    ok = np.isfinite(a) & np.isfinite(b)
    out.append({"both": float(both.mean()), "median": float(np.median(diff)), "frac1cm": float(np.mean(diff > 0.01)),
                "noisy_p95": float(np.percentile(np.abs(a[ok] - b[ok]), 95))})
print(json.dumps({"skip": False, "cams": out}))
"""


def test_render_and_raycast_agree():
    """The OpenGL depth buffer (MUJOCO_GL=egl, run in a subprocess) and mj_multiRay give the same image
    within the sensor noise. Skipped where no OpenGL context can be created."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    env = dict(os.environ)
    env.setdefault("MUJOCO_GL", "egl")
    proc = subprocess.run(
        [sys.executable, "-c", _RENDER_CHECK, str(Path(__file__).parent)],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    if proc.returncode != 0 or not lines:
        pytest.skip(
            f"renderer unavailable: {proc.stderr.strip().splitlines()[-1:] if proc.stderr else proc.returncode}"
        )
    res = json.loads(lines[-1])
    if res["skip"]:
        pytest.skip("no OpenGL context (EGL/OSMesa) available")
    for cam in res["cams"]:
        assert cam["both"] > 0.99
        # tessellated capsules/spheres and the depth buffer's resolution: millimetres, below the sensor noise
        assert cam["median"] < 1e-3
        assert cam["frac1cm"] < 0.005
        assert cam["noisy_p95"] < 0.01


def test_raycast_frame_budget():
    """Cost of one ray-cast frame at the demo resolution (reported, loosely bounded)."""
    import time

    cell = _cell()
    k = KinectSim(cell.model, cell.cameras[0], 0)
    k.capture(cell.data)
    t0 = time.perf_counter()
    for _ in range(5):
        k.capture(cell.data)
    assert (time.perf_counter() - t0) / 5 < 0.5


def test_self_filter_against_the_exact_robot_silhouette():
    """The pipeline's self-filter (controller's model, measured q) removes every pixel where the simulator
    sees the robot, and removes little else."""
    from depthguard.robot.selffilter import self_filter as robot_self_filter
    from depthguard.sim.pipeline import Kinematics, self_filter

    cell = _cell()
    kin = Kinematics("ral-9")
    q = cell.q()
    for i, cam in enumerate(cell.cameras):
        sim = KinectSim(cell.model, cam, i, seed=i)
        depth = sim.capture(cell.data)
        # exact silhouette: which geom every pixel ray hits first
        import mujoco

        n = cam.width * cam.height
        geomid = np.empty(n, np.int32)
        dist = np.empty(n)
        mujoco.mj_multiRay(cell.model, cell.data, cam.position, sim._rays, None, True, -1, geomid, dist, None, n, 1e3)
        robot = np.isin(geomid, cell.robot_geoms).reshape(cam.shape)
        assert robot.sum() > 50
        mask = self_filter(cam, depth, q, kin)
        robot_depth = robot_self_filter(cam, depth, q, kin.model).robot_depth
        assert np.array_equal(mask, robot_self_filter(cam, depth, q, kin.model).mask)
        leaked = robot & ~mask & np.isfinite(depth)
        assert leaked.sum() == 0, f"camera {i}: {leaked.sum()} robot pixels left as obstacles"
        extra = mask & ~robot
        # the margin widens the silhouette by a few pixels only
        assert extra.sum() < 1.5 * robot.sum()
        # the robot depth is conservative: at most the measured depth (+noise) on robot pixels
        on = robot & np.isfinite(depth) & np.isfinite(robot_depth)
        assert np.all(robot_depth[on] <= depth[on] + 0.02)
        only_robot = raycast_depth(cell.model, cell.data, cam, geomgroup=np.eye(6, dtype=np.uint8)[GROUP_ROBOT])
        assert np.isfinite(only_robot).sum() >= robot.sum()


@pytest.mark.parametrize("roll", [0.0, 180.0, -90.0])
def test_projector_shadow_matches_rays_cast_from_the_projector(roll):
    """The simulated Kinect's missing band is the projector's shadow: checked against MuJoCo rays cast from
    the projector (7.5 cm to the camera's right) to every pixel's surface point. Away from the band's
    boundary pixels (sampling), a pixel is dropped exactly when that ray is blocked; and the band lies to the
    left of the nearer object (none along horizontal edges). Also for a camera rolled about its optical axis
    (``kinect_camera(roll_deg=)``: 180 = mounted upside down, -90 = projector above the lens), whose
    projector, rigid on the body, moves with it."""
    import mujoco

    from depthguard.sim.depthcam import KINECT_BASELINE, kinect_camera, projector_shadow

    cell = _cell(160, 120)
    cam = cell.cameras[0]
    if roll:
        cam = kinect_camera(cam.position, (0.0, 0.0, 0.45), width=160, height=120, roll_deg=roll)
    z = raycast_depth(cell.model, cell.data, cam)
    shadow = projector_shadow(np.where(np.isfinite(z), z, np.inf), float(cam.fx), KINECT_BASELINE)
    proj = cam.position + cam.R.T @ np.array([KINECT_BASELINE, 0.0, 0.0])
    rays = cam.pixel_ray_directions()  # (H, W, 3), camera frame, z = 1
    blocked = np.zeros_like(shadow)
    gid = np.zeros(1, np.int32)
    for v in range(cam.height):
        for u in range(cam.width):
            if not np.isfinite(z[v, u]):
                continue
            p = cam.position + cam.R.T @ (rays[v, u] * z[v, u])
            d = p - proj
            n = float(np.linalg.norm(d))
            hit = mujoco.mj_ray(cell.model, cell.data, proj, d / n, None, 1, -1, gid)
            blocked[v, u] = 0 <= hit < n - 2e-3
    # compare away from the shadow's boundary (one pixel either side of a change along the row)
    edge = np.zeros_like(shadow)
    edge[:, 1:] |= shadow[:, 1:] != shadow[:, :-1]
    edge[:, :-1] |= shadow[:, 1:] != shadow[:, :-1]
    edge[:, 1:] |= blocked[:, 1:] != blocked[:, :-1]
    edge[:, :-1] |= blocked[:, 1:] != blocked[:, :-1]
    inner = ~edge & np.isfinite(z)
    assert blocked.sum() > 50 and shadow.sum() > 50  # the person and the arm cast shadows
    assert np.mean(shadow[inner] == blocked[inner]) > 0.995
    # one-sided: a shadow pixel's nearest valid right neighbour is nearer, its left one is not
    vv, uu = np.nonzero(shadow)
    for v, u in zip(vv, uu, strict=True):
        right = z[v, u + 1 :][~shadow[v, u + 1 :] & np.isfinite(z[v, u + 1 :])]
        assert right.size and right[0] < z[v, u]


def test_kinect_camera_roll():
    """``roll_deg`` turns the camera about its optical axis: 0 is bit-identical to no roll, 180 equals aiming
    with ``up`` reversed (the image turned by 180 degrees), and a quarter turn keeps the centre and the axis."""
    from depthguard.sim.depthcam import kinect_camera

    eye, aim = (1.75, -0.95, 1.5), (0.0, 0.0, 0.45)
    a = kinect_camera(eye, aim, width=160, height=120)
    b = kinect_camera(eye, aim, width=160, height=120, roll_deg=0.0)
    assert np.array_equal(a.R, b.R) and np.array_equal(a.t, b.t)
    c = kinect_camera(eye, aim, width=160, height=120, roll_deg=180.0)
    d = kinect_camera(eye, aim, width=160, height=120, up=(0.0, 0.0, -1.0))
    assert np.array_equal(c.R, d.R) and np.array_equal(c.R[:2], -a.R[:2]) and np.array_equal(c.R[2], a.R[2])
    q = kinect_camera(eye, aim, width=160, height=120, roll_deg=-90.0)
    assert np.allclose(q.position, eye) and np.array_equal(q.R[2], a.R[2])
    assert np.array_equal(q.R[0], -a.R[1]) and np.array_equal(q.R[1], a.R[0])  # +x (projector) = old "up"
    assert q.R[0][2] > 0  # the projector side points up in the world
    assert np.allclose(q.R @ q.R.T, np.eye(3)) and np.isclose(np.linalg.det(q.R), 1.0)


def test_rolled_placements():
    """``ral-rolled``: the "ral" principal camera and the second one on its side, projector up;
    ``ral-rolled-far``: the principal 0.29 m farther back along its horizontal direction, same height and
    aim. The command line offers exactly the known placements."""
    import argparse

    from depthguard.cli import _add_scenario
    from depthguard.sim.depthcam import PLACEMENTS, placement

    ral, rolled, far = (placement(n, 160, 120) for n in ("ral", "ral-rolled", "ral-rolled-far"))
    assert np.array_equal(rolled[0].R, ral[0].R) and np.array_equal(rolled[0].t, ral[0].t)
    assert np.allclose(rolled[1].position, ral[1].position) and np.array_equal(rolled[1].R[2], ral[1].R[2])
    assert rolled[1].R[0][2] > 0.8  # the projector (+x) points up in the world (the camera looks down)
    assert np.array_equal(far[1].R, rolled[1].R) and np.allclose(far[0].R[2], ral[0].R[2], atol=0.06)  # a bit flatter
    back = far[0].position[:2] - ral[0].position[:2]
    assert np.isclose(np.linalg.norm(back), 0.29, atol=0.01) and back @ ral[0].position[:2] > 0
    assert np.isclose(far[0].position[2], ral[0].position[2])
    sub = argparse.ArgumentParser().add_subparsers()
    _add_scenario(sub)
    action = next(a for a in sub.choices["scenario"]._actions if "--placement" in a.option_strings)
    assert tuple(action.choices) == PLACEMENTS
    with pytest.raises(ValueError, match="unknown camera placement"):
        placement("ral-sideways")


def test_projector_shadow_band_width():
    """A 1 m plane in front of a 3 m wall at fx = 575 px: f b (1/1 - 1/3) = 28.75 px to its left, none to its
    right, above or below."""
    from depthguard.sim.depthcam import projector_shadow

    z = np.full((40, 640), 3.0)
    z[10:30, 300:400] = 1.0
    s = projector_shadow(z, 575.0, 0.075)
    assert not s[:10].any() and not s[30:].any() and not s[:, 300:].any()
    cols = np.nonzero(s[20])[0]
    assert cols.max() == 299 and 28 <= cols.size <= 29


_SPLIT_XML = """
<mujoco>
  <worldbody>
    <geom type="plane" size="5 5 0.1" pos="0 0 -0.5" group="0"/>
    <geom type="box" size="0.3 0.2 0.4" pos="0.8 0.3 0" group="0"/>
    <geom type="cylinder" size="0.1 0.5" pos="-0.6 0.5 0" group="0"/>
    <body name="a" mocap="true"><geom type="capsule" size="0.05 0.2" group="1"/></body>
    <body name="b" mocap="true"><geom type="box" size="0.1 0.05 0.15" group="2"/></body>
    <body name="c" mocap="true"><geom type="sphere" size="0.08" group="3"/>
      <geom type="ellipsoid" size="0.1 0.04 0.06" pos="0.1 0 0" group="3"/></body>
  </worldbody>
</mujoco>
"""


def test_split_raycast_equals_one_full_cast():
    """The room cast once plus the moving geoms' rays (sim.raysplit) give the full cast's image to the
    bit: geoms anywhere (in view, at the image edge, touching or behind the camera), every camera geom
    group selection, and after a still geom was moved in the model."""
    import mujoco

    from depthguard.camera import Camera, look_at

    model = mujoco.MjModel.from_xml_string(_SPLIT_XML)
    data = mujoco.MjData(model)
    R, t = look_at(np.array([2.0, -1.5, 1.0]), np.array([0.0, 0.0, 0.0]))
    cam = Camera(width=96, height=72, fx=80.0, fy=80.0, cx=48.0, cy=36.0, R=R, t=t)
    rng = np.random.default_rng(3)
    groups = [None, np.array([1, 1, 0, 1, 0, 0], np.uint8), np.array([0, 1, 1, 1, 0, 0], np.uint8)]
    split_used = 0
    for gg in groups:
        k = KinectSim(model, cam, 0, geomgroup=gg)
        split_used += k._split is not None
        for trial in range(60):
            # near the view centre, around the camera itself, or far off to a side
            centre = rng.choice([np.zeros(3), cam.position, np.array([0.0, -3.0, 0.0])])
            data.mocap_pos[:] = centre + rng.normal(scale=0.6, size=(3, 3))
            if trial % 4 == 0:  # a bounding sphere across the camera plane, in front of the lens
                data.mocap_pos[2] = cam.position + cam.R[2] * rng.uniform(-0.05, 0.08) + rng.normal(scale=0.02, size=3)
            q = rng.normal(size=(3, 4))
            data.mocap_quat[:] = q / np.linalg.norm(q, axis=1, keepdims=True)
            if trial == 30:
                model.geom_pos[1] += np.array([0.0, 0.2, 0.1])  # a still geom moved: cast again
            mujoco.mj_forward(model, data)
            full = raycast_depth(model, data, cam, gg, rays=k._rays)
            np.testing.assert_array_equal(k.exact_depth(data), full)
        model.geom_pos[1] -= np.array([0.0, 0.2, 0.1])
    assert split_used == 2  # (the third selection hides group 0: no still group, a plain cast)


def test_split_raycast_casts_fewer_rays_in_the_cell():
    """In the simulated cell the moving geoms' boxes cover a minority of the image."""
    cell = _cell()
    for i, c in enumerate(cell.cameras):
        k = KinectSim(cell.model, c, i)
        assert k._split is not None
        assert 0.0 < k._split.moving_pixels(cell.data).mean() < 0.6
    cell.data.geom_xpos[k._split._moving_geoms[0]] = np.nan  # a broken pose: every ray is cast
    assert k._split.moving_pixels(cell.data).all()
