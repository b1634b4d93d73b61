import json

import numpy as np
import png
import pytest

from depthguard.camera import Camera, look_at
from depthguard.io import (
    ControlPoint,
    read_camera,
    read_depth,
    read_mask,
    read_points,
    write_camera,
    write_depth,
    write_mask,
    write_points,
)


def test_camera_round_trip(tmp_path):
    R, t = look_at([2.0, 0.0, 1.2], [0.0, 0.0, 0.6])
    cam = Camera.kinect_v1(R=R, t=t)
    write_camera(tmp_path / "c.json", cam)
    back = read_camera(tmp_path / "c.json")
    np.testing.assert_allclose(back.R, cam.R)
    np.testing.assert_allclose(back.t, cam.t)
    assert (back.fx, back.cx, back.width, back.min_depth) == (cam.fx, cam.cx, cam.width, cam.min_depth)


@pytest.mark.parametrize(
    "text,msg",
    [
        ("{not json", "not valid JSON"),
        ("[1, 2]", "must be an object"),
        ('{"width": 640}', "missing field"),
        (
            '{"width": 640, "height": 480, "fx": "a", "fy": 1, "cx": 1, "cy": 1, "R": [[1,0,0],[0,1,0],[0,0,1]], '
            '"t": [0,0,0]}',
            "'fx'",
        ),
    ],
)
def test_bad_camera_json(tmp_path, text, msg):
    p = tmp_path / "c.json"
    p.write_text(text)
    with pytest.raises(ValueError, match=msg):
        read_camera(p)


def test_points_round_trip_and_errors(tmp_path):
    pts = [ControlPoint("ee", np.array([0.1, 0.2, 0.3]), 0.05), ControlPoint("elbow", np.zeros(3), 0.1)]
    write_points(tmp_path / "p.json", pts)
    back = read_points(tmp_path / "p.json")
    assert [p.name for p in back] == ["ee", "elbow"]
    np.testing.assert_allclose(back[0].position, [0.1, 0.2, 0.3])
    for bad, msg in (
        ({"points": []}, "list"),
        ([{"name": "a", "radius": 0.1}], "position"),
        ([{"name": "a", "position": [0, 0], "radius": 0.1}], r"points\[0\]\.position"),
        ([{"name": "a", "position": [0, 0, 0], "radius": -1}], "radius"),
        ([{"name": 3, "position": [0, 0, 0], "radius": 1}], "name"),
    ):
        (tmp_path / "bad.json").write_text(json.dumps(bad))
        with pytest.raises(ValueError, match=msg):
            read_points(tmp_path / "bad.json")


def test_depth_png_is_millimetres_with_zero_as_missing(tmp_path):
    d = np.array([[1.0, np.nan, 2.5], [0.0, 4.4444, np.inf]], dtype=np.float32)
    write_depth(tmp_path / "d.png", d)
    raw = png.Reader(filename=str(tmp_path / "d.png")).asDirect()
    rows = np.vstack([np.asarray(r) for r in raw[2]])
    np.testing.assert_array_equal(rows, [[1000, 0, 2500], [0, 4444, 0]])
    back = read_depth(tmp_path / "d.png")
    np.testing.assert_allclose(back[0, [0, 2]], [1.0, 2.5])
    assert np.isnan(back[0, 1]) and np.isnan(back[1, 0]) and np.isnan(back[1, 2])


def test_depth_npy_round_trip_and_shape_check(tmp_path):
    d = np.full((480, 640), 2.0, dtype=np.float32)
    d[0, 0] = 0.0
    write_depth(tmp_path / "d.npy", d)
    back = read_depth(tmp_path / "d.npy", Camera.kinect_v1())
    assert np.isnan(back[0, 0]) and back[1, 1] == 2.0
    with pytest.raises(ValueError, match="shape"):
        read_depth(tmp_path / "d.npy", Camera.kinect_v1(width=320, height=240, cx=160, cy=120))


def test_bad_depth_files(tmp_path):
    with pytest.raises(ValueError, match="does not exist"):
        read_depth(tmp_path / "none.png")
    with pytest.raises(ValueError, match=r"\.png \(16-bit mm\) or \.npy"):
        (tmp_path / "d.jpg").write_bytes(b"x")
        read_depth(tmp_path / "d.jpg")
    with open(tmp_path / "d8.png", "wb") as fh:  # an 8-bit PNG is not a depth image
        png.Writer(width=2, height=2, greyscale=True, bitdepth=8).write(fh, [[1, 2], [3, 4]])
    with pytest.raises(ValueError, match="16-bit"):
        read_depth(tmp_path / "d8.png")
    (tmp_path / "broken.png").write_bytes(b"\x89PNG garbage")
    with pytest.raises(ValueError, match="cannot read PNG"):
        read_depth(tmp_path / "broken.png")
    np.save(tmp_path / "i.npy", np.zeros((4, 4), dtype=np.int32))
    with pytest.raises(ValueError, match="float"):
        read_depth(tmp_path / "i.npy")


def test_mask_round_trip(tmp_path):
    m = np.zeros((4, 5), dtype=bool)
    m[1:3, 2:4] = True
    write_mask(tmp_path / "m.png", m)
    np.testing.assert_array_equal(read_mask(tmp_path / "m.png"), m)
    with pytest.raises(ValueError, match="shape"):
        read_mask(tmp_path / "m.png", Camera.kinect_v1())
