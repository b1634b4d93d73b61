"""Bad input named, not silently used: the items the stop-46 property attacks noticed and left alone.

Each case here was accepted before (a NaN that turned a safeguard off, a domain id ROS 2 does not have, a
negative padding that cut the box) and must now raise ``ValueError`` naming the field, or, for the risk of an
unknown distance, give the conservative value.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given
from hypothesis import strategies as st

from depthguard.io.rmw_zenoh import dds_type_name, parse_topic_keyexpr, topic_keyexpr
from depthguard.octree.grid import VoxelBox
from depthguard.pivot import pivot
from depthguard.repulsion import magnitude, repulsive_vectors, risk
from depthguard.robot.contact_force import estimate_contact_forces
from depthguard.sensors.graycode import SkewedLines
from depthguard.sensors.levels import LevelStepper

CHATTER_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"


# --- repulsion: an unknown distance is as risky as contact -------------------------------------------


def test_risk_of_an_unknown_distance_is_that_of_contact():
    """A NaN distance gave risk NaN, which every comparison downstream reads as "not risky"."""
    d = np.array([0.0, 0.1, np.nan, np.inf])
    f = risk(d, 0.4, 6.0)
    assert f[2] == 1.0 and f[3] == 0.0
    assert f[2] >= f[0]  # no finite distance is riskier than the unknown one
    assert magnitude(np.nan, 3.0, 0.4, 6.0) == 3.0


@given(st.floats(allow_nan=True, allow_infinity=True), st.floats(0.05, 2.0), st.floats(0.5, 20.0))
@example(float("nan"), 0.4, 6.0)
@example(-float("inf"), 0.4, 6.0)
def test_risk_is_a_number_in_unit_interval(d, rho, alpha):
    f = float(risk(d, rho, alpha))
    assert 0.0 <= f <= 1.0
    if not math.isnan(d) and d <= 0.0:
        assert f >= 1.0 / (1.0 + math.exp(-alpha)) - 1e-12  # at least the value at contact


def test_repulsive_vectors_unchanged_for_finite_distances():
    from depthguard.depthspace import PointDistances

    d = np.array([0.1, np.inf])
    dirs = np.array([[1.0, 0.0, 0.0], [np.nan, np.nan, np.nan]])
    pd = PointDistances(d, dirs, np.full((2, 3), np.nan), np.zeros(2, int))
    v = repulsive_vectors(pd, 2.0, 0.4, 6.0)
    assert v[1].tolist() == [0.0, 0.0, 0.0]
    assert v[0, 0] == pytest.approx(2.0 / (1.0 + math.exp((0.1 * 2 / 0.4 - 1) * 6)))


# --- pivot: bad vectors and parameters named -----------------------------------------------------------


@pytest.mark.parametrize(
    ("args", "field"),
    [
        (([np.nan, 0, 0], [1, 0, 0], 0.5, 5.0), "V"),
        (([1, 0, 0], [np.inf, 0, 0], 0.5, 5.0), "V_dot"),
        (([1, 0], [1, 0, 0], 0.5, 5.0), "V"),
        (([1, 0, 0], [1, 0, 0, 0], 0.5, 5.0), "V_dot"),
        (([1, 0, 0], [-1, 0.2, 0], 0.0, 5.0), "dv_max"),
        (([1, 0, 0], [-1, 0.2, 0], -0.5, 5.0), "dv_max"),
        (([1, 0, 0], [-1, 0.2, 0], 0.5, np.nan), "c"),
        (([1, 0, 0], [-1, 0.2, 0], 0.5, -5.0), "c"),
    ],
)
def test_pivot_names_bad_input(args, field):
    """Before: a NaN ``V`` came back NaN, a negative ``dv_max`` turned the sigmoid round (γ < β)."""
    with pytest.raises(ValueError, match=field):
        pivot(*args)


def test_pivot_bad_parallel_tol():
    for tol in (0.0, -1e-3, 0.5, float("nan")):
        with pytest.raises(ValueError, match="parallel_tol"):
            pivot([1, 0, 0], [-1, 0.2, 0], 0.5, 5.0, parallel_tol=tol)


# --- octree box and reachability grid ----------------------------------------------------------------


def test_voxel_box_negative_pad_refused():
    """A negative pad gave a box that no longer covered [lo, hi] (or a negative shape)."""
    assert VoxelBox.around([0, 0, 0], [0.2, 0.2, 0.2], 0.05, pad=1).shape == (7, 7, 7)
    for pad in (-1, -10, 1.5, True):
        with pytest.raises(ValueError, match="pad"):
            VoxelBox.around([0, 0, 0], [0.2, 0.2, 0.2], 0.05, pad=pad)


def test_reachability_grid_checks_a_given_box():
    from depthguard.octree.reach import ChainSweep, reachability_grid

    # one revolute joint about z at the origin turning a 0.3 m segment (the form test_octree_reach uses)
    chain = ChainSweep(
        np.array([0]), np.array([[0.0, 0.0, 1.0]]), np.zeros((1, 3)), np.array([-1.0]), np.array([1.0]),
        np.array([1.0]), np.array([[0.1, 0.0, 0.0]]), np.array([[0.4, 0.0, 0.0]]), np.zeros(1), np.array([1]),
    )  # fmt: skip
    good = VoxelBox.around([-0.6, -0.6, -0.3], [0.6, 0.6, 0.3], 0.09)
    assert np.isfinite(reachability_grid(chain, 0.2, box=good).time).any()
    for box, field in (
        (VoxelBox(good.origin, 0.5, good.shape), "box.res"),
        (VoxelBox(good.origin, 0.001, good.shape), "box.res"),
        (VoxelBox(good.origin, 0.09, (0, 5, 5)), "box.shape"),
        (VoxelBox(np.array([np.nan, 0, 0]), 0.09, good.shape), "box.origin"),
    ):
        with pytest.raises(ValueError, match=field):
            reachability_grid(chain, 0.2, box=box)


# --- rmw_zenoh names -----------------------------------------------------------------------------------


def test_parse_topic_keyexpr_reference_and_round_trip():
    key = f"0/chatter/std_msgs::msg::dds_::String_/{CHATTER_HASH}"
    k = parse_topic_keyexpr(key)
    assert (k.domain, k.topic, k.typename, k.type_hash) == (0, "/chatter", "std_msgs/msg/String", CHATTER_HASH)
    assert topic_keyexpr(k.domain, k.topic, k.typename, k.type_hash) == key


@pytest.mark.parametrize(
    "key",
    [
        f"233/chatter/std_msgs::msg::dds_::String_/{CHATTER_HASH}",  # no such ROS domain
        f"\u0663/chatter/std_msgs::msg::dds_::String_/{CHATTER_HASH}",  # an Arabic-Indic digit: isdigit() is True
        f"+1/chatter/std_msgs::msg::dds_::String_/{CHATTER_HASH}",
        "0/chatter/std_msgs::msg::dds_::String_/RIHS01_",  # no hash digits
        f"0/chatter/std_msgs::msg::dds_::String_/{CHATTER_HASH.upper()}",  # rmw_zenoh writes lower-case hex
        f"0//std_msgs::msg::dds_::String_/{CHATTER_HASH}",  # an empty topic level
    ],
)
def test_parse_topic_keyexpr_refuses_what_rmw_zenoh_never_writes(key):
    with pytest.raises(ValueError, match="rmw_zenoh topic key"):
        parse_topic_keyexpr(key)


@pytest.mark.parametrize("name", ["a:b/msg/T", "pkg/msg/T:x", "pkg/msg/T y", "pkg/msg/9T", "pkg/msg/T%"])
def test_dds_type_name_refuses_separators(name):
    """``a:b/msg/T`` became ``a:b::msg::dds_::T_``, which reads back as a different type."""
    with pytest.raises(ValueError, match="type name"):
        dds_type_name(name)


# --- contact force estimation parameters ---------------------------------------------------------------


@pytest.mark.parametrize(
    ("kw", "field"),
    [
        ({"eps": 0.0}, "eps"),
        ({"eps": np.nan}, "eps"),
        ({"eps": -0.005}, "eps"),
        ({"lambda_max": np.inf}, "lambda_max"),
        ({"lambda_max": -0.02}, "lambda_max"),
        ({"lambda_max": np.nan}, "lambda_max"),
        ({"tol": 1.0}, "tol"),
        ({"tol": -1e-3}, "tol"),
        ({"tol": np.nan}, "tol"),
    ],
)
def test_estimate_contact_forces_checks_its_parameters(kw, field):
    """Before: eps = 0 divided by zero inside the kernel (NaN forces); NaN parameters gave NaN forces."""
    J = np.array([[1.0, 0.0, 0.2], [0.0, 1.0, 0.1], [0.0, 0.0, 1.0]])
    est = estimate_contact_forces(J, np.array([1.0, 2.0, 3.0]))  # the defaults are fine
    assert np.all(np.isfinite(est.forces))
    with pytest.raises(ValueError, match=field):
        estimate_contact_forces(J, np.array([1.0, 2.0, 3.0]), **kw)


# --- Gray-code lines and the level stepper -------------------------------------------------------------


def test_skewed_lines_refuse_non_finite_delays_and_times():
    for delays in ((0.0, np.nan, 1e-3), (0.0, np.inf, 1e-3), (0.0, -1e-3, 1e-3)):
        with pytest.raises(ValueError, match="line_delays"):
            SkewedLines(delays)
    lines = SkewedLines()
    lines.write(0.0, 3)
    for t in (np.nan, np.inf, -1.0):
        with pytest.raises(ValueError, match="write time"):
            lines.write(t, 4)
    with pytest.raises(ValueError, match="read time"):
        lines.read(np.nan)
    assert lines.read(1.0) == 3  # unchanged by the refused writes


def test_level_stepper_refuses_nan_time_which_disabled_the_hold():
    """Before: a NaN time was written as ``t_last`` and every later update then wrote (the hold, which keeps
    the skewed lines from being read mid-change, was gone for good)."""
    s = LevelStepper(hold=0.01)
    assert s.update(0.0, 7) == (1, True)
    with pytest.raises(ValueError, match="time t"):
        s.update(float("nan"), 7)
    assert s.update(0.005, 7) == (1, False)  # the hold still holds
    assert s.update(0.011, 7) == (2, True)
    with pytest.raises(ValueError, match="time t"):
        s.update(0.0, 7)  # time went back
    for bad in (7.5, True, "3", -1, 8):
        with pytest.raises(ValueError, match="target"):
            s.update(0.1, bad)


# --- depth images: an integer image is not read as metres ------------------------------------------------


@pytest.mark.parametrize("dtype", [np.uint16, np.int32, np.int64, np.bool_])
def test_integer_depth_images_are_refused_not_read_as_metres(dtype):
    """A 16-bit millimetre image passed as it comes from a driver was read as metres: every obstacle 1000
    times too far, so a distance over-reported by orders of magnitude (found by the distance property tests,
    stop 47). Float images in metres are taken as before; uint16 converts with ``metres_or_nan``."""
    from depthguard.camera import Camera
    from depthguard.depthgrid import DepthGridFusion
    from depthguard.depthspace import prepare_frame, query_distances
    from depthguard.kernels.depthimage import metres_or_nan

    cam = Camera(width=32, height=24, fx=30.0, fy=30.0, cx=16.0, cy=12.0)
    mm = np.full(cam.shape, 1000, dtype=np.uint16)  # a wall 1 m in front of the camera
    with pytest.raises(ValueError, match="depth must be a float image in metres"):
        prepare_frame(cam, mm.astype(dtype))
    with pytest.raises(ValueError, match=r"depths\[0\] must be a float image in metres"):
        DepthGridFusion([cam, cam]).update([mm.astype(dtype), mm.astype(np.float32) / 1000])
    frame = prepare_frame(cam, metres_or_nan(mm, 1000.0), invalid="ignore")  # (out of view: free)
    d = query_distances(frame, np.array([[0.0, 0.0, 0.5]]), np.array([0.1]), rho=2.0).distance[0]
    assert 0.3 < d <= 0.4 + 1e-9  # (the truth is 0.4 m; the depth space gives a lower bound near it)


# --- the nodes' JSON lines are strict JSON ----------------------------------------------------------------


def test_node_json_lines_are_strict_json(tmp_path):
    """The monitor wrote ``"d_min": Infinity`` when nothing was within range, and the node logs NaN for an
    unknown value: Python reads them, strict parsers (jq, JavaScript's JSON.parse, serde_json) refuse the line.
    Non-finite numbers are now null, as in the distances' JSON."""
    import json

    from depthguard.nodes.common import JsonLog, json_line

    rec = {"d_min": float("inf"), "x": [1.0, float("nan"), np.float32(2.5)], "n": {"a": -float("inf")}, "s": "k"}
    line = json_line(rec)
    strict = json.loads(line, parse_constant=lambda c: pytest.fail(f"non-standard constant {c}"))
    assert strict == {"d_min": None, "x": [1.0, None, 2.5], "n": {"a": None}, "s": "k"}
    assert json_line({"t": 1.5, "q": np.float64(0.25)}) == '{"t": 1.5, "q": 0.25}'
    log = JsonLog(tmp_path / "log.jsonl")
    log.write(ev="status", qd_max=float("nan"))
    log.close()
    assert json.loads((tmp_path / "log.jsonl").read_text()) == {"ev": "status", "qd_max": None}


@pytest.mark.parametrize("scale", ["1 0 1", "0", "0.0 -0.0 1", "nan"])
def test_a_mesh_scale_that_flattens_or_is_not_a_number_is_refused(tmp_path, scale):
    """A zero factor in a URDF mesh ``scale`` gave a flat mesh (no volume to filter or to cover with spheres),
    loaded silently (noticed by the URDF property tests, stop 47)."""
    import trimesh

    from depthguard.robot.model import RobotModel

    trimesh.creation.box((0.1, 0.1, 0.1)).export(tmp_path / "box.stl")
    (tmp_path / "r.urdf").write_text(
        '<robot name="r"><link name="a"/><link name="b"><collision><geometry>'
        f'<mesh filename="box.stl" scale="{scale}"/></geometry></collision></link>'
        '<joint name="j" type="revolute"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/>'
        '<limit lower="-1" upper="1" velocity="1" effort="1"/></joint></robot>'
    )
    with pytest.raises(ValueError, match="mesh scale"):
        RobotModel.from_urdf(tmp_path / "r.urdf")
