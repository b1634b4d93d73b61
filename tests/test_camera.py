import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from depthguard.camera import Camera, look_at


def _cam():
    R, t = look_at([2.0, 0.5, 1.2], [0.0, 0.0, 0.5])
    return Camera.kinect_v1(R=R, t=t)


def test_look_at_points_optical_axis_at_target():
    cam = _cam()
    p = cam.project(np.array([0.0, 0.0, 0.5]))
    assert p[0] == pytest.approx(cam.cx) and p[1] == pytest.approx(cam.cy)
    assert p[2] == pytest.approx(np.linalg.norm([2.0, 0.5, 0.7]))
    # image "up" is world +z: a point above the target projects to a smaller row
    assert cam.project(np.array([0.0, 0.0, 0.8]))[1] < cam.cy


@settings(max_examples=200, deadline=None)
@given(
    st.floats(0, 639.99),
    st.floats(0, 479.99),
    st.floats(0.5, 4.5),
)
def test_project_unproject_round_trip(px, py, d):
    cam = _cam()
    pw = cam.unproject(px, py, d)
    back = cam.project(pw)
    np.testing.assert_allclose(back, [px, py, d], rtol=1e-9, atol=1e-9)


def test_pixel_centre_convention():
    cam = Camera(width=4, height=2, fx=2.0, fy=2.0, cx=2.0, cy=1.0)
    # a point on the optical axis lands on the corner between pixels (2, 1) after floor()
    p = cam.project(np.array([0.0, 0.0, 1.0]))
    assert (int(np.floor(p[0])), int(np.floor(p[1]))) == (2, 1)
    dirs = cam.pixel_ray_directions()
    assert dirs[1, 2, 0] == pytest.approx(0.25)  # (2 + 0.5 - 2) / 2


@pytest.mark.parametrize(
    "field,value,msg",
    [
        ("fx", -1.0, "fx"),
        ("fy", float("nan"), "fy"),
        ("width", 0, "width"),
        ("height", 2.5, "height"),
        ("R", [[1, 0, 0], [0, 1, 0], [0, 0, 2]], "orthonormal"),
        ("R", [[1, 0, 0], [0, 1, 0], [0, 0, -1]], "det"),
        ("t", [1, 2], "shape"),
        ("max_depth", 0.1, "max_depth"),
    ],
)
def test_bad_intrinsics_name_the_field(field, value, msg):
    d = Camera.kinect_v1().to_dict()
    d[field] = value
    with pytest.raises(ValueError, match=msg):
        Camera.from_dict(d)


def test_missing_field_is_named():
    d = Camera.kinect_v1().to_dict()
    del d["cy"]
    with pytest.raises(ValueError, match="cy"):
        Camera.from_dict(d)


def test_image_shape_check():
    cam = Camera.kinect_v1()
    with pytest.raises(ValueError, match=r"\(480, 640\)"):
        cam.check_image(np.zeros((640, 480)))
