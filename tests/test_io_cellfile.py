"""Cell files: the shipped examples parse to the cameras they describe; every mistake names its key."""

from pathlib import Path

import numpy as np
import pytest

from depthguard.cli import main
from depthguard.io.cell_describe import describe_cell
from depthguard.io.cellfile import read_cell

EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "cells"

BASE = """
[robot]
model = "lwr4"

[[cameras]]
name = "cam"
width = 640
height = 480
fx = 525.0
fy = 525.0
cx = 319.5
cy = 239.5
R = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
t = [0.0, 0.0, 2.0]
"""


def _write(tmp_path, text):
    p = tmp_path / "cell.toml"
    p.write_text(text)
    return p


def test_examples_parse_and_sim_hexagon_matches_the_scenario_cameras():
    for f in sorted(EXAMPLES.glob("*.toml")):
        assert "camera" in describe_cell(read_cell(f))
    cell = read_cell(EXAMPLES / "sim-hexagon.toml")
    # the scenario's cameras, by their definition: centres and the point they look at
    for cam, eye in zip(cell.cameras, ([2.0, -1.09, 1.5], [-0.75, 1.85, 1.5]), strict=True):
        c = cam.build()
        np.testing.assert_allclose(c.position, eye, atol=1e-12)
        px = c.project(np.array([[0.0, 0.0, 0.45]]))[0]
        np.testing.assert_allclose(px[:2], [c.cx, c.cy], atol=1e-9)
    # the principal camera upright (its image rows horizontal), the second one on its side (its columns
    # horizontal) with its image's top towards +x, away from the principal camera's side of the room
    principal, second = (c.build() for c in cell.cameras)
    assert abs(principal.R[0, 2]) < 1e-12 and abs(second.R[1, 2]) < 1e-12
    assert -second.R[1] @ np.array([1.0, 0.0, 0.0]) > 0.9


def test_minimal_file_defaults(tmp_path):
    cell = read_cell(_write(tmp_path, BASE))
    assert cell.distance["backend"] == "depthspace" and cell.distance["rho"] == 0.4
    assert cell.controller["joint_timeout"] == 0.005 and cell.controller["resume_time"] == 0.1
    cam = cell.cameras[0]
    assert cam.topic == "/cam/depth/image_raw" and cam.frame_id == "cam_optical"
    np.testing.assert_allclose(cam.build().position, [0, 0, -2.0])


def test_matrix_extrinsics_equal_R_t(tmp_path):
    text = BASE.replace(
        "R = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]\nt = [0.0, 0.0, 2.0]",
        "matrix = [[0.0, -1.0, 0.0, 0.1], [1.0, 0.0, 0.0, 0.2], [0.0, 0.0, 1.0, 0.3], [0, 0, 0, 1]]",
    )
    cam = read_cell(_write(tmp_path, text)).cameras[0].build()
    np.testing.assert_allclose(cam.R, [[0, -1, 0], [1, 0, 0], [0, 0, 1]])
    np.testing.assert_allclose(cam.t, [0.1, 0.2, 0.3])


@pytest.mark.parametrize(
    "edit, needle",
    [
        (lambda s: s + "\n[distance]\nrh0 = 0.3\n", "rh0"),  # typo in a key
        (lambda s: s.replace("fx = 525.0", "fx = -525.0"), "fx"),
        (lambda s: s.replace("fx = 525.0", 'fx = "525"'), "fx"),
        (lambda s: s.replace("width = 640", "width = 640\nmin_Depth = 0.4"), "min_Depth"),
        (lambda s: s.replace('model = "lwr4"', 'model = "ur5"'), "robot.model"),
        (lambda s: s.replace('model = "lwr4"', 'urdf = "nope.urdf"'), "robot.urdf"),
        (lambda s: s.replace("[0.0, 0.0, 1.0]]", "[0.0, 0.0, -1.0]]"), "det"),
        (lambda s: s.replace("t = [0.0, 0.0, 2.0]", "t = [0.0, 2.0]"), "t must be 3"),
        (lambda s: s + '\n[distance]\nmode = "nearest"\n', "distance.mode"),
        (lambda s: s + "\n[distance]\nworkspace = [1, 0, 0, 1, 0, 1]\n", "workspace"),
        (lambda s: s + "\n[distance]\ndirection_stride = 0\n", "direction_stride"),
        (lambda s: s + '\n[distance]\ndirection_stride = "two"\n', "direction_stride"),
        (lambda s: s + "\n[controller]\nvelocity_scale = 2.0\n", "velocity_scale"),
        (lambda s: s + "\n[controller]\njoint_timeout = 0\n", "joint_timeout"),
        (lambda s: s + '\n[[robot.attachments]]\nname = "g"\nlink = "l"\nshape = "box"\nsize = [1, 2]\n', "size"),
        (lambda s: s + '\n[[cameras]]\nname = "cam"\nintrinsics = "device"\nextrinsics = "tf"\n', "unique"),
        (lambda s: s.replace("[robot]", "[robots]"), "robots"),
        (lambda s: s.replace("cy = 239.5\n", ""), "cy"),
        (lambda s: s + "\n[cell\n", "TOML"),
    ],
)
def test_mistakes_name_their_key(tmp_path, edit, needle):
    with pytest.raises(ValueError, match=needle) as info:
        read_cell(_write(tmp_path, edit(BASE)))
    assert "cell.toml" in str(info.value)


FILE_INTRINSICS = "width = 640\nheight = 480\nfx = 525.0\nfy = 525.0\ncx = 319.5\ncy = 239.5\n"
DEVICE = BASE.replace(FILE_INTRINSICS, 'intrinsics = "device"\n')


def test_align_key_validated_and_described(tmp_path, capsys):
    """``align`` (live RealSense): default "none"; "color" needs device intrinsics; another value is refused
    naming the key and the allowed values; ``cell check`` says whose intrinsics and optical frame are used."""
    assert read_cell(_write(tmp_path, DEVICE)).cameras[0].align == "none"
    aligned = _write(tmp_path, DEVICE.replace('intrinsics = "device"', 'intrinsics = "device"\nalign = "color"'))
    assert read_cell(aligned).cameras[0].align == "color"
    assert main(["cell", "check", str(aligned)]) == 0
    out = capsys.readouterr().out
    assert "depth aligned to the colour stream" in out and "intrinsics from the device's colour stream" in out
    assert "these extrinsics place the colour camera's optical frame" in out
    assert main(["cell", "check", str(_write(tmp_path, DEVICE))]) == 0
    assert "colour" not in capsys.readouterr().out  # unaligned: the depth stream's, as before
    with pytest.raises(ValueError, match=r"cameras\[0\]\.align must be one of \['none', 'color'\], got 'colour'"):
        read_cell(_write(tmp_path, DEVICE.replace('intrinsics = "device"', 'intrinsics = "device"\nalign = "colour"')))
    with pytest.raises(ValueError, match=r'cameras\[0\]\.align = "color" needs intrinsics = "device"'):
        read_cell(_write(tmp_path, BASE + 'align = "color"\n'))


def test_align_refused_by_bag_and_sim_sources(tmp_path):
    from depthguard.runner import open_source
    from depthguard.runner.bag import BagSource

    cell = read_cell(_write(tmp_path, DEVICE + 'align = "color"\n'))
    with pytest.raises(ValueError, match=r'cameras\[0\]\.align = "color" .* not for a bag'):
        BagSource(tmp_path / "none.mcap", cell, ("a",))
    with pytest.raises(ValueError, match=r'cameras\[0\]\.align = "color" .* not for the simulated cell'):
        open_source("sim:ral-hexagon", cell, ("a",), quick=True)


def test_cli_cell_check(tmp_path, capsys):
    assert main(["cell", "check", str(EXAMPLES / "sim-hexagon.toml")]) == 0
    out = capsys.readouterr().out
    assert "camera 'camera0'" in out and "depth grid for 2 camera(s)" in out
    bad = _write(tmp_path, BASE + '\n[topics]\njoint_state = "/js"\n')
    assert main(["cell", "check", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "joint_state" in err and "cell.toml" in err and err.count("\n") == 1
    assert main(["cell", "check", str(tmp_path)]) == 2
    assert "directory" in capsys.readouterr().err
