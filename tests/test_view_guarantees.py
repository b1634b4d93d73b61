"""The live view's safety guarantees (:mod:`depthguard.viz.live`), attacked at the level of its update
functions, with a real viser server in-process (no browser).

A monitoring view must never slow, stop or crash the run it watches, and must show unknown values honestly:

* the producer hooks (``set_*``, ``inputs``, ``query``, ``command``) never raise and return at once, even
  while a redraw is busy; only the newest state is kept (latest wins), redraws at most ``max_hz``;
* a redraw with bad or odd data (NaN/inf depths, empty or all-robot images, a camera at another resolution,
  a mask of another shape, a NaN joint state, distances of the wrong length, a malformed octree frame)
  draws what it can, removes what it cannot draw instead of leaving it stale, counts the skip
  (``LiveView.skipped``) and always updates the panel;
* sphere colours follow the docstring's map (red at contact, yellow at rho/2, green at rho and beyond;
  inf = nothing within range = green; NaN = unknown, never on the red-yellow-green scale), and the panel's
  nearest distance says ``unknown`` when a distance is NaN, never ``inf``;
* the points drawn per camera are every ``s``-th pixel (``s = stride or round(W / 160)``) with a finite,
  positive depth, unprojected through the (scaled) camera: at most ``ceil(H/s) * ceil(W/s)``, and at most
  240 per image row (the docstring says "about 160"; round() gives up to 1.5x that for W just under 240);
* a browser client that connects and disconnects does not disturb the drawing thread.

Most tests stop the view's own drawing thread and redraw synchronously, exactly as that thread does
(``_redraw``: an exception is swallowed there, so the tests check its consequences: a stale panel, stale
spheres or clouds).
"""

from __future__ import annotations

import gc
import math
import socket
import threading
import time
import tracemalloc
import uuid
import weakref
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

pytest.importorskip("viser")

from depthguard.camera import Camera  # noqa: E402
from depthguard.robot.model import load_lwr4  # noqa: E402
from depthguard.viz import live  # noqa: E402
from depthguard.viz.live import LiveView  # noqa: E402

RHO = 0.4
W0, H0 = 64, 48
SETTINGS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _camera(w: int = W0, h: int = H0) -> Camera:
    return Camera(
        width=w, height=h, fx=50.0 * w / W0, fy=50.0 * h / H0, cx=w / 2, cy=h / 2, R=np.eye(3), t=np.array([0, 0, 2.0])
    )


@pytest.fixture(scope="module")
def model():
    return load_lwr4()


class Recorder:
    """What the view handed to the scene: the last call per node name (point clouds, spheres, segments)."""

    def __init__(self, view: LiveView) -> None:
        self.calls: dict[str, tuple[str, tuple, dict]] = {}
        sc = view.server.scene
        for fn in ("add_point_cloud", "add_icosphere", "add_line_segments"):
            real = getattr(sc, fn)

            def wrap(name, *a, _real=real, _fn=fn, **k):
                self.calls[name] = (_fn, a, k)
                return _real(name, *a, **k)

            setattr(sc, fn, wrap)
        self.scene = sc

    def present(self, prefix: str) -> set[str]:
        """Names of the scene's nodes under ``prefix`` now (viser's own registry)."""
        return {n for n in self.scene._handle_from_node_name if n.startswith(prefix)}

    def points(self, name: str) -> np.ndarray:
        _, a, k = self.calls[name]
        return np.asarray(k.get("points", a[0] if a else None), float)


@pytest.fixture(scope="module")
def view(model):
    """One view for the module, its drawing thread stopped: the tests redraw synchronously."""
    v = LiveView.for_scene("guarantees", model, [_camera()], RHO, port=_free_port())
    v._stop.set()
    v._dirty.set()
    v._thread.join(5.0)
    v.rec = Recorder(v)
    yield v
    v.close()


def _redraw(view: LiveView) -> None:
    """One redraw as the view's thread does it (which swallows an exception: the tests check what it left)."""
    try:
        with view._draw_lock:
            view.draw()
    except Exception:  # noqa: BLE001 - as LiveView._loop
        pass


def _mark(view: LiveView) -> str:
    """A fresh status that the panel must show after the next redraw (else the redraw was aborted)."""
    token = f"S{uuid.uuid4().hex[:8]}"
    view.set_status(token)
    return token


def _skipped(view: LiveView) -> int:
    return sum(getattr(view, "skipped", {}).values())


# ----------------------------------------------------------------------------- colours: the docstring's map
def _ref_rgb(d: float, rho: float):
    """Red (255, 0, 0) at d <= 0, yellow (255, 255, 0) at rho/2, green (0, 255, 0) at d >= rho, linear in
    between; +inf green, -inf red; NaN None (unknown: must be off that scale)."""
    if math.isnan(d):
        return None
    f = 1.0 if d == math.inf else 0.0 if d == -math.inf else min(max(d / rho, 0.0), 1.0)
    return (255 * min(1.0, 2 * (1 - f)), 255 * min(1.0, 2 * f), 0.0)


def _on_scale(c) -> bool:
    r, g, b = c
    return b == 0 and max(r, g) >= 254


def _check_colour(got, d: float, rho: float) -> None:
    want = _ref_rgb(d, rho)
    if want is None:
        assert not _on_scale(got), f"unknown distance {d} drawn on the red-yellow-green scale as {got}"
        assert got[1] < 200 or got[0] > 100, f"unknown distance {d} drawn green {got}"
    else:
        assert np.allclose(got, want, atol=1.01), (d, rho, got, want)


finite_or_odd = st.floats(allow_nan=True, allow_infinity=True, width=64) | st.sampled_from(
    [0.0, -0.0, RHO, RHO / 2, -1.0, math.inf, -math.inf, math.nan]
)


@given(d=finite_or_odd, rho=st.floats(0.01, 5.0))
@example(d=math.nan, rho=RHO)  # was green: an unknown distance drawn as "safe"
@example(d=-math.inf, rho=RHO)  # was green: -inf taken as "nothing within range"
@example(d=math.inf, rho=RHO)
@SETTINGS
def test_distance_colour_follows_the_documented_map(d, rho):
    _check_colour(live._distance_rgb(d, rho), d, rho)


# ----------------------------------------------------------------------------- spheres and the panel
dist_lists = st.integers(0, 10).flatmap(lambda n: st.lists(finite_or_odd, min_size=n, max_size=n))


@given(d=dist_lists)
@example(d=[math.nan, 0.2])  # the panel said "nearest: inf" and the sphere was green
@example(d=[math.nan])
@example(d=[])  # zero control points: the spheres of the previous update stayed
@example(d=[math.inf, math.inf])
@SETTINGS
def test_spheres_coloured_by_distance_and_nearest_honest(view, d):
    n_before = 10  # an earlier update with more control points
    view.set_distances(
        np.zeros((n_before, 3)), np.full(n_before, 0.05), np.full(n_before, 0.3), np.zeros((n_before, 3))
    )
    _redraw(view)
    n = len(d)
    centres = np.column_stack([np.arange(n) * 0.1, np.zeros(n), np.full(n, 0.5)])
    dirs = np.tile([1.0, 0.0, 0.0], (n, 1))
    view.set_distances(centres, np.full(n, 0.06), d, dirs)
    token = _mark(view)
    _redraw(view)
    assert token in view.md.content, "the redraw was aborted"
    assert view.rec.present("/spheres/") == {f"/spheres/{i}" for i in range(n)}, "stale or missing spheres"
    for i, di in enumerate(d):
        _check_colour(view.rec.calls[f"/spheres/{i}"][2]["color"], di, RHO)
    line = next(x for x in view.md.content.splitlines() if x.startswith("nearest:"))
    arr = np.asarray(d, float)
    if n == 0:
        assert line.strip() == "nearest: -"
    elif np.isnan(arr).any():
        assert "unknown" in line, f"a NaN distance shown as {line!r}"
    else:
        m = float(arr.min())
        want = "inf" if m == math.inf else "-inf" if m == -math.inf else f"{m:.3f} m"
        assert line.strip().removesuffix("  ").endswith(want), (line, want)


@pytest.mark.parametrize(
    "n_centres, n_radii, n_dist, n_dir",
    [(4, 4, 2, 4), (4, 4, 6, 4), (4, 4, 0, 4), (4, 3, 4, 4), (4, 4, 4, 1), (0, 0, 3, 0)],
)
def test_distances_of_the_wrong_length(view, n_centres, n_radii, n_dist, n_dir):
    """Distances that do not match the control points: nothing drawn as safe, the panel says unknown, the
    redraw goes on and the skip is counted. (Old code: IndexError/ValueError aborted the redraw: stale panel;
    with more distances than points the panel showed a minimum over values of no control point.)"""
    view.set_distances(np.zeros((8, 3)), np.full(8, 0.05), np.full(8, 1.0), np.zeros((8, 3)))  # 8 green
    _redraw(view)
    before = _skipped(view)
    view.set_distances(
        np.zeros((n_centres, 3)), np.full(n_radii, 0.05), np.full(n_dist, 1.0), np.zeros((n_dir, 3))
    )  # (every listed distance "safe": 1 m > rho)
    token = _mark(view)
    _redraw(view)
    assert token in view.md.content
    mismatched = n_dist != n_centres or n_radii != n_centres
    if mismatched:
        assert _skipped(view) > before, "a mismatched update was not counted"
        assert "unknown" in view.md.content
    for name in view.rec.present("/spheres/"):
        col = view.rec.calls[name][2]["color"]
        if mismatched:
            assert not _on_scale(col), f"{name} drawn as {col} from distances that are not its own"
    left = [n for n in view.rec.present("/spheres/") if int(n.split("/")[-1]) >= n_centres]
    assert not left, f"spheres of the earlier 8 points left: {left}"


@pytest.mark.parametrize(
    "call",
    [
        lambda v: v.set_distances([[0, 0], [0, 0, 0]], [0.1, 0.1], [0.1, 0.2], [[1, 0, 0]]),  # ragged
        lambda v: v.set_distances([[0, 0, 0]], [0.1], ["far"], [[1, 0, 0]]),
        lambda v: v.set_joints([0.0, [1.0, 2.0]]),
        lambda v: v.set_joints("seven"),
        lambda v: v.query(0.0, SimpleNamespace(distance=[0.1]), object()),  # cps without centres
        lambda v: v.query(0.0, object(), SimpleNamespace(centres=[[0, 0]], radii=[[0.1, 0.1], [1]])),
        lambda v: v.command(0.0, object()),  # out without a status
        lambda v: v.inputs(SimpleNamespace(q=[[1.0], [1.0, 2.0]]), None),
        lambda v: v.inputs(object(), None),  # tick without q
        lambda v: v.set_frames(None, None),
        lambda v: v.set_octree(object()),
    ],
)
def test_producer_hooks_never_raise(view, call):
    call(view)  # must not raise into the producer
    token = _mark(view)
    _redraw(view)
    assert token in view.md.content, "a bad input stopped the panel from updating"


def test_unreadable_distances_shown_unknown_not_absent(view):
    """Distances that cannot even be read (ragged) replace the last ones: the panel says unknown, not the
    last value nor "-" (no control points), and no sphere of the last update stays."""
    view.set_distances(np.zeros((2, 3)), np.full(2, 0.05), [0.3, 0.3], np.zeros((2, 3)))
    _redraw(view)
    view.set_distances([[0, 0], [0, 0, 0]], [0.1, 0.1], [0.1, 0.2], [[1, 0, 0]])
    _redraw(view)
    assert "unknown" in next(x for x in view.md.content.splitlines() if x.startswith("nearest:"))
    assert not view.rec.present("/spheres/")


# ----------------------------------------------------------------------------- clouds
def _ref_cloud(cam: Camera, depth: np.ndarray, mask, s: int):
    """Every s-th pixel with finite positive depth, unprojected through the camera scaled to the image."""
    h, w = depth.shape
    c = Camera(
        width=w, height=h, fx=cam.fx * w / cam.width, fy=cam.fy * h / cam.height, cx=cam.cx * w / cam.width,
        cy=cam.cy * h / cam.height, R=cam.R, t=cam.t,
    )  # fmt: skip
    v, u = np.mgrid[0:h:s, 0:w:s]
    d = depth[::s, ::s].astype(float)
    ok = np.isfinite(d) & (d > 0)
    m = np.zeros_like(ok) if mask is None else mask[::s, ::s].astype(bool)
    pts = c.unproject(u + 0.5, v + 0.5, np.where(ok, d, 1.0))
    return pts[ok & ~m], pts[ok & m]


depth_values = st.sampled_from([0.5, 1.0, 2.5, 0.0, -1.0, math.nan, math.inf, -math.inf])


@st.composite
def images(draw):
    scale = draw(st.sampled_from([0.5, 1, 2, 3, 5]))
    h, w = int(H0 * scale), int(W0 * scale)
    fill = draw(st.sampled_from(["random", "nan", "inf", "zero", "ok"]))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    if fill == "random":
        vals = np.array([0.5, 1.0, 2.5, 0.0, -1.0, np.nan, np.inf, -np.inf])
        depth = vals[rng.integers(0, len(vals), (h, w))] * rng.uniform(0.9, 1.1, (h, w))
    else:
        depth = np.full((h, w), {"nan": np.nan, "inf": np.inf, "zero": 0.0, "ok": 1.5}[fill])
    dtype = draw(st.sampled_from([np.float32, np.float64]))
    mask_kind = draw(st.sampled_from(["none", "random", "all", "empty"]))
    mask = {
        "none": None,
        "random": rng.random((h, w)) < 0.3,
        "all": np.ones((h, w), bool),
        "empty": np.zeros((h, w), bool),
    }[mask_kind]
    return depth.astype(dtype), mask


@given(img=images())
@SETTINGS
def test_cloud_points_are_the_decimated_valid_pixels(view, img):
    depth, mask = img
    view.set_frames([depth], None if mask is None else [mask])
    token = _mark(view)
    _redraw(view)
    assert token in view.md.content
    s = max(1, round(depth.shape[1] / 160))
    env, rob = _ref_cloud(view.cameras[0], depth, mask, s)
    got = view.rec.points("/cloud/0")
    assert got.shape == env.shape
    np.testing.assert_allclose(got, env, rtol=1e-5, atol=1e-5)
    if len(rob):
        assert "/robot_pixels/0" in view.rec.present("/robot_pixels/")
        np.testing.assert_allclose(view.rec.points("/robot_pixels/0"), rob, rtol=1e-5, atol=1e-5)
    else:
        assert not view.rec.present("/robot_pixels/"), "stale robot pixels"


@pytest.mark.parametrize(
    "depth, mask, why",
    [
        (np.full((48, 80), 1.0), None, "another aspect ratio than the announced 64x48"),
        (np.full((48, 64), 1.0), np.zeros((24, 32), bool), "a mask of another shape"),
        (np.full((48, 64, 1), 1.0), None, "a 3-D depth image"),
        (np.full(64, 1.0), None, "a 1-D depth image"),
        (np.full((48, 64), "x"), None, "not numbers"),
    ],
)
def test_bad_image_skipped_counted_not_stale(view, depth, mask, why):
    """A camera image that cannot be drawn: that camera's cloud is removed (not left showing an old scene),
    the skip counted, the rest of the update drawn. (Old code: the redraw was aborted, panel stale.)"""
    view.set_frames([np.full((H0, W0), 1.0)], None)
    _redraw(view)
    assert "/cloud/0" in view.rec.present("/cloud/")
    before = _skipped(view)
    view.set_frames([depth], None if mask is None else [mask])
    token = _mark(view)
    _redraw(view)
    assert token in view.md.content, why
    assert _skipped(view) > before, why
    assert "/cloud/0" not in view.rec.present("/cloud/"), f"stale cloud after {why}"


def test_masks_as_one_stacked_array(view):
    """``masks`` as an (n, H, W) array instead of a list (``x or [...]`` on an array raised)."""
    depth = np.full((H0, W0), 1.0)
    view.set_frames([depth], np.ones((1, H0, W0), bool))
    token = _mark(view)
    _redraw(view)
    assert token in view.md.content
    assert view.rec.points("/robot_pixels/0").shape[0] == H0 * W0


@given(k=st.integers(1, 400))
@example(k=59)  # W = 236: s = 1, 236 points per row
@example(k=60)  # W = 240: s = 2
@SETTINGS
def test_points_per_update_bounded(view, k):
    """A frame at any scale of the announced 64x48 camera (W = 4k, H = 3k): the points sent are exactly the
    ceil(H/s) * ceil(W/s) decimated pixels, at most 240 per image row (the docstring's "about 160")."""
    w, h = 4 * k, 3 * k
    view.set_frames([np.full((h, w), 1.0, np.float32)], None)
    _redraw(view)
    s = max(1, round(w / 160))
    n = view.rec.points("/cloud/0").shape[0]
    assert n == math.ceil(h / s) * math.ceil(w / s)
    assert math.ceil(w / s) <= 240


def test_large_image_sends_the_budget_and_allocates_little(view):
    """A frame 40x the announced size in each direction: the points sent stay at about 160 per row, and the
    memory used by the redraw is bounded by those points, not by the image (old code: a float64 copy of the
    whole image, about 78 MB here)."""
    depth = np.full((H0 * 40, W0 * 40), 1.5, np.float32)  # 2560 x 1920
    view.set_frames([depth], None)
    _redraw(view)
    tracemalloc.start()
    try:
        _redraw(view)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    n = view.rec.points("/cloud/0").shape[0]
    s = round(depth.shape[1] / 160)
    assert n == math.ceil(depth.shape[0] / s) * math.ceil(depth.shape[1] / s) <= 160 * 120
    assert peak < 16e6, f"a redraw allocated {peak / 1e6:.1f} MB for {n} points"


# ----------------------------------------------------------------------------- joints, octree
@pytest.mark.parametrize(
    "q",
    [np.full(7, np.nan), np.r_[np.zeros(6), np.inf], np.zeros(3), np.zeros(9), np.zeros((7, 1))],
    ids=["nan", "inf", "short", "long", "2-D"],
)
def test_unusable_joint_state(view, q):
    """The robot is not posed from a NaN/inf or wrong-length joint state (it stays as last drawn, the panel
    says so); the rest of the update is drawn and the skip counted."""
    seen = []
    real = view.urdf.update_cfg
    view.urdf.update_cfg = lambda cfg: (seen.append(np.array(cfg, float)), real(cfg))
    try:
        view.set_joints(np.zeros(7))
        _redraw(view)
        before = _skipped(view)
        view.set_joints(q)
        token = _mark(view)
        _redraw(view)
    finally:
        del view.urdf.update_cfg
    assert token in view.md.content
    assert all(np.all(np.isfinite(c)) and c.shape == (7,) for c in seen), "robot posed from an unusable state"
    assert _skipped(view) > before
    view.set_joints(np.zeros(7))


def test_octree_frame_drawn_or_skipped(view):
    kind = np.zeros((4, 4, 4), np.uint8)
    kind[0, 0, 0], kind[1, 2, 3], kind[3, 3, 3] = 1, 2, 3
    view.set_octree(SimpleNamespace(kind=kind, box=SimpleNamespace(origin=(0.0, 0.0, 0.0), res=0.1)))
    _redraw(view)
    np.testing.assert_allclose(view.rec.points("/octree/occluded"), [[0.15, 0.25, 0.35]], atol=1e-6)
    before = _skipped(view)
    view.set_octree(SimpleNamespace(kind=kind))  # no box
    token = _mark(view)
    _redraw(view)
    assert token in view.md.content and _skipped(view) > before
    assert not view.rec.present("/octree/"), "stale octree nodes"
    view.set_octree(None)


# ----------------------------------------------------------------------------- never blocks the caller
def test_producers_return_at_once_while_a_redraw_is_busy(model):
    """With every scene update taking 0.3 s (a busy server), the producers' calls still return in well under
    that (bound 0.2 s each, typically well under 1 ms: they only store references), only the newest frame set
    is kept (an older one is freed), and the view redraws no more than max_hz."""
    v = LiveView.for_scene("busy", model, [_camera()], RHO, port=_free_port(), max_hz=20.0)
    try:
        sc = v.server.scene
        real = sc.add_point_cloud
        busy = threading.Event()

        def slow(*a, **k):
            busy.set()
            time.sleep(0.3)
            return real(*a, **k)

        sc.add_point_cloud = slow
        first = np.full((H0, W0), 1.0)
        ref = weakref.ref(first)
        v.set_frames([first], None)
        del first
        assert busy.wait(5.0), "the view never drew"
        worst, t_start = 0.0, time.perf_counter()
        for i in range(300):
            t0 = time.perf_counter()
            v.set_frames([np.full((H0, W0), 1.0 + i * 1e-3)], None)
            v.set_joints(np.full(7, 0.01 * i))
            v.set_distances(np.zeros((3, 3)), np.full(3, 0.05), [0.1, np.nan, np.inf], np.zeros((3, 3)))
            v.set_status("RUN")
            v.inputs(SimpleNamespace(q=np.zeros(7)), None)
            worst = max(worst, time.perf_counter() - t0)
        elapsed = time.perf_counter() - t_start
        # (a call that waited for the redraw would take >= 0.3 s; 0.2 s leaves room for a loaded 2-core CI)
        assert worst < 0.2, f"a producer call took {worst * 1e3:.0f} ms while a redraw was busy"
        d0 = v.draws  # (the redraw in flight may hold the first frame set until it ends)
        t0 = time.time()
        while (v.draws < d0 + 2 or ref() is not None) and time.time() - t0 < 15.0:
            time.sleep(0.05)
            gc.collect()
        assert ref() is None, "an older frame set is still held (not latest-wins)"
        assert v.draws <= (elapsed + 1.0) * 20.0 + 2
        assert v._thread.is_alive()
    finally:
        v.close()


def test_client_connects_and_disconnects(model):
    """A websocket client (what the browser opens) that connects, reads a little and drops, several times,
    while updates arrive: the drawing thread keeps drawing and nothing is counted as a failed redraw."""
    ws = pytest.importorskip("websockets.sync.client")
    import viser

    v = LiveView.for_scene("clients", model, [_camera()], RHO, port=_free_port(), max_hz=30.0)
    try:
        for i in range(3):
            with ws.connect(f"ws://127.0.0.1:{v.port}", subprotocols=[f"viser-v{viser.__version__}"]) as c:
                v.set_frames([np.full((H0, W0), 1.0 + i)], None)
                v.set_distances(np.zeros((2, 3)), np.full(2, 0.05), [0.1, 0.2], np.zeros((2, 3)))
                got, t0 = 0, time.time()
                while time.time() - t0 < 0.5:  # (the view keeps sending: read for a while, then drop)
                    try:
                        c.recv(timeout=0.1)
                        got += 1
                    except TimeoutError:
                        pass
                assert got > 0, "the client received nothing"
            time.sleep(0.1)
        draws = v.draws
        v.set_frames([np.full((H0, W0), 2.0)], None)
        t0 = time.time()
        while v.draws == draws and time.time() - t0 < 5.0:
            time.sleep(0.05)
        assert v.draws > draws and v._thread.is_alive()
        assert getattr(v, "skipped", {}).get("draw", 0) == 0
    finally:
        v.close()
