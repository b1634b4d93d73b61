"""The principal point at every boundary with other tools (docs/conventions.md, "Pixels").

DepthGuard puts the centre of pixel u at ``p_x = u + 0.5``; ROS ``CameraInfo`` (OpenCV, ``image_geometry``)
and librealsense put it at ``p_x = u``. A camera read from either must cast, through the centre of pixel
(u, v), the ray that the other tool casts through (u, v), and a ``CameraInfo`` that DepthGuard writes must
say what ROS tools expect. The references are the other tools' own formulas: librealsense's
``rs2_deproject_pixel_to_point`` (pyrealsense2, the library itself) and ``image_geometry``'s
``projectPixelTo3dRay`` (``((u - cx) / fx, (v - cy) / fy, 1)`` with ``K``'s ``cx, cy``), and OpenCV's
distortion model for the undistortion map. Before, both readers took the principal point as it was: every
ray half a pixel off (about 1 cm at 3 m at 160x120).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from depthguard.camera import Camera, principal_point_from_opencv, principal_point_to_opencv
from depthguard.io import ros2
from depthguard.io.cellfile import read_cell
from depthguard.io.mcap_ros2 import Ros2McapWriter
from depthguard.runner.bag import BagSource, undistort_map

SOME = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
JOINTS = ("j0", "j1", "j2")

intrinsics = st.tuples(
    st.integers(4, 64),  # width
    st.integers(3, 48),  # height
    st.floats(20.0, 2000.0),  # fx
    st.floats(20.0, 2000.0),  # fy
    st.floats(-0.5, 1.5),  # cx as a fraction of the width (off-centre, even outside)
    st.floats(-0.5, 1.5),  # cy
)


def _ros_ray(u: np.ndarray, v: np.ndarray, K: np.ndarray) -> np.ndarray:
    """image_geometry.PinholeCameraModel.projectPixelTo3dRay, scaled to z = 1."""
    return np.stack([(u - K[2]) / K[0], (v - K[5]) / K[4], np.ones_like(u)], axis=-1)


def _bag_camera(tmp: Path, info) -> Camera:
    w, h = int(info.width), int(info.height)
    (tmp / "cell.toml").write_text(
        '[robot]\nmodel = "lwr4"\n[[cameras]]\nname = "cam0"\ntopic = "/cam0/depth"\ninfo_topic = "/cam0/info"\n'
        'frame_id = "cam0"\nintrinsics = "camera_info"\nextrinsics = "tf"\n'
    )
    with Ros2McapWriter(tmp / "b.mcap") as wr:
        wr.write(
            "/tf_static", "tf2_msgs/msg/TFMessage", ros2.tf_msg(0.0, [("world", "cam0", np.eye(3), np.zeros(3))]), 0.0
        )
        wr.write("/cam0/info", "sensor_msgs/msg/CameraInfo", info, 0.0)
        img = ros2.image_msg(1.0, "cam0", np.full((h, w), 1.0, np.float32), "32FC1")
        wr.write("/cam0/depth", "sensor_msgs/msg/Image", img, 1.0)
        js = ros2.joint_state_msg(1.0, list(JOINTS), np.zeros(3), np.zeros(3))
        wr.write("/joint_states", "sensor_msgs/msg/JointState", js, 1.0)
    return BagSource(tmp / "b.mcap", read_cell(tmp / "cell.toml"), JOINTS).cameras[0]


def _info(w: int, h: int, fx: float, fy: float, cx: float, cy: float, d=None, model: str = "plumb_bob"):
    info = ros2.camera_info_msg(0.0, "cam0", Camera(width=w, height=h, fx=fx, fy=fy, cx=1.0, cy=1.0))
    info.k = np.array([fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0])
    info.p = np.array([fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0])
    if d is not None:
        info.d, info.distortion_model = np.asarray(d, float), model
    return info


@SOME
@given(intr=intrinsics)
def test_a_bag_camera_casts_image_geometry_s_rays(intr, tmp_path_factory) -> None:
    w, h, fx, fy, fcx, fcy = intr
    info = _info(w, h, fx, fy, fcx * w, fcy * h)
    cam = _bag_camera(tmp_path_factory.mktemp("bag"), info)
    v, u = np.mgrid[0:h, 0:w].astype(float)
    np.testing.assert_allclose(cam.pixel_ray_directions(), _ros_ray(u, v, np.asarray(info.k)), rtol=0, atol=1e-12)


@SOME
@given(intr=intrinsics)
def test_a_written_camera_info_reads_back_as_the_same_camera_and_says_ros_s_principal_point(intr, tmp_path_factory):
    w, h, fx, fy, fcx, fcy = intr
    cam = Camera(width=w, height=h, fx=fx, fy=fy, cx=fcx * w, cy=fcy * h)
    info = ros2.camera_info_msg(0.0, "cam0", cam)
    v, u = np.mgrid[0:h, 0:w].astype(float)
    # what a ROS tool casts from the message is what DepthGuard casts from the camera
    np.testing.assert_allclose(_ros_ray(u, v, np.asarray(info.k)), cam.pixel_ray_directions(), rtol=0, atol=1e-12)
    P = np.asarray(info.p).reshape(3, 4)
    assert (P[0, 2], P[1, 2]) == (info.k[2], info.k[5])
    back = _bag_camera(tmp_path_factory.mktemp("bag"), info)
    assert back.cx == pytest.approx(cam.cx, abs=1e-12) and back.cy == pytest.approx(cam.cy, abs=1e-12)


def test_the_conversions_are_half_a_pixel_and_inverse() -> None:
    assert principal_point_from_opencv(319.5, 239.5) == (320.0, 240.0)  # a 640x480 image's centre
    assert principal_point_to_opencv(*principal_point_from_opencv(12.25, -3.0)) == (12.25, -3.0)


def _opencv_distort(x, y, D):
    """OpenCV's plumb_bob (k1, k2, p1, p2, k3) on normalised coordinates, written from its documentation."""
    k1, k2, p1, p2, k3 = D
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
    return x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x), y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y


@SOME
@given(
    intr=intrinsics,
    D=st.tuples(
        st.floats(-0.3, 0.3), st.floats(-0.1, 0.1), st.floats(-0.01, 0.01), st.floats(-0.01, 0.01),
        st.floats(-0.05, 0.05),
    ),
)  # fmt: skip
def test_the_undistortion_map_takes_the_pixel_that_opencv_s_model_names(intr, D, tmp_path_factory) -> None:
    w, h, fx, fy, fcx, fcy = intr
    K = np.array([fx, 0.0, fcx * w, 0.0, fy, fcy * h, 0.0, 0.0, 1.0])
    cam = _bag_camera(tmp_path_factory.mktemp("bag"), _info(w, h, fx, fy, K[2], K[5], d=D))
    rows, cols = undistort_map(cam, "plumb_bob", np.asarray(D))
    v, u = np.mgrid[0:h, 0:w].astype(float)
    xd, yd = _opencv_distort((u - K[2]) / fx, (v - K[5]) / fy, D)
    su, sv = xd * fx + K[2], yd * fy + K[5]  # OpenCV pixel coordinates: pixel i spans [i - 0.5, i + 0.5)
    ref_c, ref_r = np.floor(su + 0.5), np.floor(sv + 0.5)
    inside = (ref_c >= 0) & (ref_c < w) & (ref_r >= 0) & (ref_r < h)
    clear = (np.abs(su + 0.5 - np.round(su + 0.5)) > 1e-6) & (np.abs(sv + 0.5 - np.round(sv + 0.5)) > 1e-6)
    ok = inside & clear
    np.testing.assert_array_equal(cols[ok], ref_c[ok])
    np.testing.assert_array_equal(rows[ok], ref_r[ok])
    assert np.all(rows[~inside & clear] == -1)


# --------------------------------------------------------------------------------------------------- librealsense
def test_a_realsense_camera_casts_librealsense_s_rays(tmp_path) -> None:
    try:
        import pyrealsense2 as rs
    except ImportError as exc:  # the wheel needs the system's libusb (.ci/run installs it)
        pytest.skip(f"pyrealsense2 does not import here ({exc})")
    from depthguard.runner.realsense import RealSenseSource

    W, H = 64, 48
    intr = rs.intrinsics()
    intr.width, intr.height, intr.ppx, intr.ppy, intr.fx, intr.fy = W, H, 30.25, 25.75, 50.0, 51.0
    intr.model, intr.coeffs = rs.distortion.none, [0.0] * 5
    sd = rs.software_device()
    sensor = sd.add_sensor("Depth")
    sensor.add_read_only_option(rs.option.depth_units, 0.001)
    vs = rs.video_stream()
    vs.type, vs.index, vs.uid, vs.width, vs.height, vs.fps, vs.bpp, vs.fmt = (
        rs.stream.depth, 0, 0, W, H, 30, 2, rs.format.z16,
    )  # fmt: skip
    vs.intrinsics = intr
    profile = sensor.add_video_stream(vs).as_video_stream_profile()
    syncer = rs.syncer()
    sensor.open(profile)
    sensor.start(syncer)
    (tmp_path / "cell.toml").write_text(
        '[robot]\nmodel = "lwr4"\n[[cameras]]\nname = "d435"\nintrinsics = "device"\n'
        "eye = [1.5, 0.0, 1.0]\ntarget = [0.0, 0.0, 0.5]\n"
    )
    src = RealSenseSource(read_cell(tmp_path / "cell.toml"), JOINTS, device=(sensor, syncer, profile), duration=0.05)
    try:
        cam = src.cameras[0]
        rays = cam.pixel_ray_directions()
        for u, v in [(0, 0), (W - 1, H - 1), (30, 25), (31, 26), (7, 40)]:
            z = 2.0
            ref = np.asarray(rs.rs2_deproject_pixel_to_point(intr, [float(u), float(v)], z))
            np.testing.assert_allclose(rays[v, u] * z, ref, rtol=0, atol=1e-5, err_msg=f"pixel {(u, v)}")
    finally:
        src.close()


@SOME
@given(intr=intrinsics, step=st.integers(1, 5))
def test_a_strided_camera_casts_the_rays_of_the_pixels_it_keeps(intr, step) -> None:
    """The recordings keep every ``step``-th pixel (``image[::step, ::step]``); the CameraInfo they carry is
    ``Camera.strided``'s. Before, ``cx / step`` described a binned image: half an original pixel off."""
    w, h, fx, fy, fcx, fcy = intr
    cam = Camera(width=w, height=h, fx=fx, fy=fy, cx=fcx * w, cy=fcy * h)
    small = cam.strided(step)
    assert small.shape == cam.pixel_ray_directions()[::step, ::step].shape[:2]
    np.testing.assert_allclose(
        small.pixel_ray_directions(), cam.pixel_ray_directions()[::step, ::step], rtol=0, atol=1e-12
    )
