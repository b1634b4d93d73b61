"""Sensor health where it runs: the camera node's gate, the one-process chain's stamps, and the "moved" check.

Each check is against an independent reference: scipy's erosion of the whole image, a reference model of the
documented latch rules (``depthguard.robot.health``'s docstring, written here from the text), and a camera
that looks through the robot model's arm (the "moved" camera) against one that sees it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from scipy.ndimage import binary_erosion

pytest.importorskip("pinocchio")

from depthguard.io.cellfile import read_cell  # noqa: E402
from depthguard.nodes.camera import FrameGate, HealthWorker  # noqa: E402
from depthguard.nodes.common import camera_at_size  # noqa: E402
from depthguard.robot.health import CameraHealth, _eroded, predicted_robot_depth  # noqa: E402
from depthguard.runner.chain import Chain, load_cell_robot  # noqa: E402

CELL = Path(__file__).resolve().parents[1] / "examples/cells/sim-hexagon.toml"


@pytest.fixture(scope="module")
def hexagon():
    cell = read_cell(CELL)
    model = load_cell_robot(cell)
    cam = camera_at_size(cell.cameras[0].build(), 160, 120)
    return cell, model, cam


@st.composite
def masks(draw):
    h, w = draw(st.integers(1, 24)), draw(st.integers(1, 24))
    kind = draw(st.sampled_from(["random", "blob", "border", "empty", "full"]))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    if kind == "random":
        m = rng.random((h, w)) < draw(st.floats(0.1, 0.95))
    elif kind == "blob":
        m = np.zeros((h, w), bool)
        v0, u0 = rng.integers(0, h), rng.integers(0, w)
        m[v0 : v0 + rng.integers(1, h + 1), u0 : u0 + rng.integers(1, w + 1)] = True
    elif kind == "border":
        m = np.zeros((h, w), bool)
        m[0, :] = m[:, -1] = True
    else:
        m = np.full((h, w), kind == "full")
    return m


@given(masks(), st.integers(1, 6))
@settings(max_examples=300, deadline=None)
def test_erosion_of_the_robot_box_is_the_erosion_of_the_whole_image(mask, iterations):
    """The "moved" check erodes only the box around the predicted robot pixels: the same pixels as scipy's
    erosion of the whole image (the image border counts as empty in both)."""
    np.testing.assert_array_equal(
        _eroded(mask, iterations, binary_erosion), binary_erosion(mask, iterations=iterations)
    )


def test_erode_zero_is_no_erosion_not_erosion_until_nothing_is_left():
    """scipy's ``iterations < 1`` erodes until nothing changes; ``erode = 0`` (documented: >= 0) meant that,
    which left no robot pixel to judge and so silently disabled the "moved" check."""
    m = np.zeros((20, 30), bool)
    m[3:15, 4:25] = True
    np.testing.assert_array_equal(_eroded(m, 0, binary_erosion), m)


def _through(cam, seed: int) -> np.ndarray:
    """A frame that sees 5 m everywhere, through where the model puts the arm; a fresh noise each call."""
    rng = np.random.default_rng(seed)
    return (5.0 + 0.002 * rng.standard_normal(cam.shape)).astype(np.float32)


def _seen(cam, model, q, seed: int) -> np.ndarray:
    """A frame that sees the arm where the model puts it (a wall at 5 m behind)."""
    pred = predicted_robot_depth(cam, model, q)
    d = np.where(np.isfinite(pred), pred, 5.0)
    rng = np.random.default_rng(seed)
    return (d + 0.002 * rng.standard_normal(cam.shape)).astype(np.float32)


@pytest.mark.parametrize("erode", [0, 1, 3])
def test_a_camera_that_sees_through_the_arm_is_moved_whatever_the_erosion(hexagon, erode):
    _, model, cam = hexagon
    q = np.zeros(7)
    assert np.isfinite(predicted_robot_depth(cam, model, q)).sum() > 500  # (the arm is in view)
    h = CameraHealth(cam, "camera0", model, erode=erode)
    faults = [h.check(_through(cam, k), q, float(k)) for k in range(4)]
    assert faults == [None, None, "moved", "moved"]
    h = CameraHealth(cam, "camera0", model, erode=erode)
    assert [h.check(_seen(cam, model, q, k), q, float(k)) for k in range(4)] == [None] * 4


def _reference(events, frozen_frames: int, clear_frames: int, covered_fraction: float) -> tuple[list, dict]:
    """The documented rules, for a camera without a robot model: which frames are published, and the withheld
    counts. ``events``: (frame id, covered?, stamp) in order; equal ids are bit-identical frames."""
    fault, healthy, same, last, last_stamp = None, 0, 0, None, None
    published, withheld = [], {}
    for fid, covered, stamp in events:
        published.append(fault is None)
        if fault is not None:
            withheld[fault] = withheld.get(fault, 0) + 1
        if last_stamp is not None and stamp <= last_stamp:  # not a new frame: only "covered" counts
            if covered:
                fault, healthy = "covered", 0
            else:
                healthy = 0
            continue
        last_stamp = stamp
        same = same + 1 if fid == last else 0
        last = fid
        now = "frozen" if same >= frozen_frames - 1 else ("covered" if covered else None)
        if now is not None:
            fault, healthy = now, 0
        elif fault is not None:
            healthy += 1
            if healthy >= clear_frames:
                fault, healthy = None, 0
    return published, withheld


@given(
    st.lists(
        st.tuples(st.integers(0, 3), st.booleans(), st.sampled_from(["next", "same", "back"])), min_size=1, max_size=40
    )
)
@settings(max_examples=150, deadline=None)
@example([(0, False, "next")] * 3 + [(1, False, "next")] * 3 + [(2, False, "next")])  # frozen, then clears
@example([(0, False, "next")] * 2 + [(0, False, "same")] * 5)  # one frame repeated with its stamp: not frozen
@example([(1, True, "next"), (2, False, "back"), (3, False, "next"), (0, False, "next"), (1, False, "next")])
def test_the_camera_nodes_gate_publishes_only_what_the_documented_rules_allow(seq):
    """Frames (each a fresh one or a repeat of an earlier one, covered or not, stamped after, at or before
    the last) through the camera node's gate: published exactly while the rules say the camera is healthy,
    and every withheld frame counted under its fault."""
    from depthguard.camera import Camera

    cam = Camera(fx=20.0, fy=20.0, cx=8.0, cy=6.0, width=16, height=12)
    rng = np.random.default_rng(0)
    frames = {i: (1.0 + rng.random(cam.shape)).astype(np.float32) for i in range(4)}
    covered = {i: np.where(rng.random(cam.shape) < 0.9, np.nan, f).astype(np.float32) for i, f in frames.items()}
    gate, t, events, published = FrameGate("c", None), 10.0, [], []
    for fid, cov, when in seq:
        t = {"next": t + 0.1, "same": t, "back": t - 0.05}[when]
        d = (covered if cov else frames)[fid]
        events.append(((fid, cov), cov, t))
        published.append(gate.open)
        if not gate.open:
            gate.withhold()
        gate.after(cam, d, np.zeros(0), t)
    h = CameraHealth(cam, "c")
    want, withheld = _reference(events, h.frozen_frames, h.clear_frames, h.covered_fraction)
    assert published == want
    assert gate.withheld == withheld


def test_the_gate_names_each_change_once(hexagon):
    _, model, cam = hexagon
    q, gate, changes = np.zeros(7), FrameGate("camera0", model), []
    for k in range(8):
        d = _through(cam, k) if k < 4 else _seen(cam, model, q, k)
        changes.append(gate.after(cam, d, q, float(k)))
    assert changes == [None, None, "moved", None, None, None, "healthy", None]


def test_the_chain_counts_a_frame_set_only_when_its_stamp_advances(hexagon):
    """``depthguard run``'s chain passes the frame set's stamp: one frame set delivered again with its stamp
    is not a frozen camera (the distances' timeout covers it), the same image with fresh stamps is."""
    cell, model, _ = hexagon
    cams = [c.build() for c in cell.cameras]
    q = np.zeros(7)
    frames = [_seen(c, model, q, i) for i, c in enumerate(cams)]
    chain = Chain(cell, cams, model)
    for _ in range(4):
        chain.on_frames(frames, q, 1.0)
    assert chain.faults == {}
    for k in range(4):
        chain.on_frames(frames, q, 2.0 + k)
    assert set(chain.faults.values()) == {"frozen"}


def _wait(cond, timeout: float = 10.0) -> None:
    import time

    end = time.time() + timeout
    while not cond() and time.time() < end:
        time.sleep(0.002)
    assert cond()


def test_the_camera_nodes_health_worker_runs_at_a_low_priority_and_closes_the_gate():
    """The node's checks run on a thread at nice 10 (off the distance node's CPUs when they are busy), with
    the same verdicts as the gate itself; a check that raises shuts the gate for good, naming why."""
    import sys

    from depthguard.camera import Camera

    cam = Camera(fx=20.0, fy=20.0, cx=8.0, cy=6.0, width=16, height=12)
    frame = np.full(cam.shape, 2.0, np.float32)
    gate, changes = FrameGate("c", None), []
    w = HealthWorker(gate, lambda c, t: changes.append((c, t)))
    try:
        for k in range(3):
            w.submit(cam, frame, np.zeros(0), float(k))
            _wait(lambda k=k: w.checked == k + 1)
        assert changes == [("frozen", 2.0)] and not gate.open
        if sys.platform.startswith("linux"):
            stat = Path(f"/proc/self/task/{w.native_id}/stat").read_text()
            assert int(stat.rsplit(")", 1)[1].split()[16]) == HealthWorker.NICE  # (field 19 of stat: nice)
    finally:
        w.close()
    gate, changes = FrameGate("c", None), []

    def broken(*args):
        raise RuntimeError("boom")

    gate.after = broken
    w = HealthWorker(gate, lambda c, t: changes.append((c, t)))
    try:
        assert gate.open
        w.submit(cam, frame, np.zeros(0), 1.0)
        _wait(lambda: w.checked == 1)
        assert not gate.open and changes == [("health check failed (RuntimeError: boom)", 1.0)]
        gate.withhold()
        assert gate.withheld == {"health check failed (RuntimeError: boom)": 1}
    finally:
        w.close()


def test_a_health_check_that_falls_behind_holds_the_frames():
    """A starved check thread must not let frames through unchecked: more than ``MAX_BEHIND`` frames handed
    over and not checked is ``behind`` (the node withholds them); catching up clears it."""
    import threading

    from depthguard.camera import Camera

    cam = Camera(fx=20.0, fy=20.0, cx=8.0, cy=6.0, width=16, height=12)
    gate, release = FrameGate("c", None), threading.Event()
    after = gate.after

    def slow(*args):
        release.wait(10)
        return after(*args)

    gate.after = slow
    w = HealthWorker(gate, lambda c, t: None)
    try:
        rng = np.random.default_rng(1)
        for k in range(HealthWorker.MAX_BEHIND + 1):
            assert not w.behind
            w.submit(cam, (1 + rng.random(cam.shape)).astype(np.float32), np.zeros(0), float(k))
        assert w.behind
        release.set()
        _wait(lambda: not w.behind)
        assert gate.open
    finally:
        release.set()
        w.close()
