"""The live 3-D view in the browser (``viser``): ``depthguard view --cell CELL.toml`` and ``run --view``.

What the page shows, in the world frame:

* the robot from its URDF (viser's ``ViserUrdf``) at the latest joint state;
* each camera's depth point cloud, one colour per camera (every ``stride``-th pixel), and the pixels the
  self-filter removed as the robot's (magenta); about 160 points per image row (``stride``);
* the control spheres coloured by distance (red at contact, yellow half way, green at rho and beyond, grey
  when the distance is unknown: NaN, or a distances array whose length is not the control points') and the
  repulsive vectors (orange segments, longer when nearer); a sphere whose centre or radius is not finite
  (or whose radius is not positive) is not drawn, and the spheres of a previous update beyond the current
  number of control points are removed;
* with the octree backend (``scenario --backend octree --view``, ``scenario saphari-octree --view``), the
  obstacle octree's nodes: occupied (red), occluded (orange) and unseen (grey; obstacles in the conservative
  mode) as squares of the node size;
* a panel with the controller status, the smallest distance (``inf``: nothing within range; ``unknown``
  when a distance is NaN or the distances do not match the control points, with the smallest known one
  beside it), the rates of frames, distance queries and commands, and how many updates were skipped.

The producers (the runner's hooks, or Zenoh callbacks in the ``view`` node) only store references under a
lock; one background thread turns the newest state into scene updates at most ``max_hz`` times a second, so
the control loop never waits on the browser.

Whatever the producers hand over, nothing raises into them and the drawing thread goes on: an input that
cannot be used (a joint state of the wrong length or not finite, a depth image that is not 2-D or not a
scaled image of its camera, a mask of another shape, a distances array that does not match, an octree frame
without its fields) is skipped and counted in :attr:`LiveView.skipped` (by kind), and what it would have
drawn is removed rather than left stale; the rest of the update is drawn. Each camera's cloud is decimated
before anything is converted, so the work per update is bounded by the points drawn (at most
``ceil(H/s) * ceil(W/s)`` per camera for stride ``s``), not by the image size.
"""

from __future__ import annotations

import contextlib
import sys
import threading
import time
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np

from depthguard.camera import Camera

__all__ = ["LiveView", "run_view_node", "CAMERA_COLOURS"]

#: Point-cloud colour of camera k (RGB 0-255).
CAMERA_COLOURS = [(40, 120, 255), (0, 190, 190), (250, 160, 0), (140, 90, 255)]
ROBOT_PIXELS = (255, 0, 220)
#: Colour of the octree's node kinds (depthguard.octree.fusion: 1 occupied, 2 occluded, 3 unseen).
OCTREE_COLOURS = {"occupied": (1, (230, 30, 30)), "occluded": (2, (255, 150, 40)), "unseen": (3, (120, 120, 130))}
#: Colour of a control sphere whose distance is unknown (NaN): never the green of "safe".
UNKNOWN_DISTANCE = (150, 150, 150)


def _distance_rgb(d: float, rho: float) -> tuple[int, int, int]:
    """Colour of a control sphere at distance ``d`` (m): red at contact (``d <= 0``, ``-inf`` included),
    yellow at ``rho / 2``, green at ``rho`` and beyond (``inf``: nothing within range); grey
    (:data:`UNKNOWN_DISTANCE`) when ``d`` is NaN (unknown)."""
    d = float(d)
    if np.isnan(d):
        return UNKNOWN_DISTANCE
    f = 1.0 if d == np.inf else 0.0 if d == -np.inf else float(np.clip(d / max(rho, 1e-9), 0.0, 1.0))
    return (int(255 * min(1.0, 2.0 * (1.0 - f))), int(255 * min(1.0, 2.0 * f)), 0)


def _nearest_text(d: np.ndarray | None) -> str:
    """The panel's nearest distance: ``-`` without control points, ``inf`` when nothing is within range,
    ``unknown`` when a distance is NaN (or ``d`` is None: the distances did not match), with the smallest
    known distance beside it."""
    if d is None:
        return "unknown (distances do not match the control points)"
    d = np.asarray(d, float).ravel()
    if d.size == 0:
        return "-"
    known = d[~np.isnan(d)]
    m = None if known.size == 0 else float(np.min(known))
    txt = "-" if m is None else "inf" if m == np.inf else "-inf" if m == -np.inf else f"{m:.3f} m"
    if known.size < d.size:
        return f"unknown ({d.size - known.size} of {d.size} NaN; smallest known {txt})"
    return txt


def _stride(width: int, stride: int | None) -> int:
    """The decimation of a depth image ``width`` pixels wide: ``stride``, or about 160 points per row."""
    return max(1, int(stride)) if stride else max(1, round(width / 160))


def _cloud_points(cam: Camera, depth: Any, mask: Any, stride: int | None) -> tuple[np.ndarray, np.ndarray]:
    """The world points of every ``s``-th pixel of a depth image (``s``: :func:`_stride`) with a finite
    positive depth: ``(environment, robot)`` float32 arrays, robot where ``mask`` is set. ``depth`` may be a
    scaled image of ``cam`` (same field of view). Raises ``ValueError`` when ``depth`` is not 2-D, is not a
    scaled image of ``cam``, or ``mask`` is not of its shape. The image is decimated before it is converted."""
    from depthguard.nodes.common import camera_at_size

    depth = np.asarray(depth)
    if depth.ndim != 2:
        raise ValueError(f"depth image of shape {depth.shape}, not 2-D")
    h, w = depth.shape
    if h == 0 or w == 0:
        e = np.zeros((0, 3), np.float32)
        return e, e
    s = _stride(w, stride)
    d = np.asarray(depth[::s, ::s], float)
    c = camera_at_size(cam, w, h)
    if mask is None:
        m = np.zeros(d.shape, bool)
    else:
        mask = np.asarray(mask)
        if mask.shape != depth.shape:
            raise ValueError(f"mask of shape {mask.shape} for a depth image of shape {depth.shape}")
        m = np.asarray(mask[::s, ::s], bool)
    v, u = np.mgrid[0:h:s, 0:w:s]
    ok = np.isfinite(d) & (d > 0)
    env, rob = ok & ~m, ok & m
    pts = c.unproject(u[ok] + 0.5, v[ok] + 0.5, d[ok])
    return pts[env[ok]].astype(np.float32), pts[rob[ok]].astype(np.float32)


def _rate(times: deque) -> float:
    if len(times) < 2:
        return 0.0
    span = times[-1] - times[0]
    return (len(times) - 1) / span if span > 0 else 0.0


class LiveView:
    """A viser page fed through the runner's sink hooks (``inputs``, ``masks``, ``query``, ``command``).

    Args:
        cell: the cell file; ``model``: the robot model (its URDF is drawn); ``points``: its control points;
        cameras: the cameras in use. ``host``/``port``: where the page is served (loopback by default).
    """

    def __init__(
        self,
        cell: Any,
        model: Any,
        points: Any,
        cameras: list[Camera],
        *,
        host: str = "127.0.0.1",
        port: int = 8080,
        stride: int | None = None,
        max_hz: float = 30.0,
    ) -> None:
        import viser
        from viser.extras import ViserUrdf

        self.cell, self.model, self.points, self.cameras = cell, model, points, list(cameras)
        # cameras carried by a link (given in its frame) are drawn where the link is at the latest joint state
        self._carried = [(i, c.parent) for i, c in enumerate(cell.cameras) if c.parent != "world"]
        self.rho = float(cell.distance["rho"])
        self.stride, self.period = stride, 1.0 / float(max_hz)
        with contextlib.redirect_stdout(sys.stderr):  # (viser's banner: stdout carries the commands' JSON)
            self.server = viser.ViserServer(host=host, port=port, verbose=False)
        self.port = port
        cam = self.server.initial_camera
        cam.position, cam.look_at, cam.up = (2.0, -2.0, 1.5), (0.0, 0.0, 0.45), (0.0, 0.0, 1.0)
        sc = self.server.scene
        sc.add_grid("/ground", width=3.0, height=3.0, cell_size=0.25, position=(0.0, 0.0, 0.0))
        self.urdf = ViserUrdf(
            self.server, Path(model.urdf_path), root_node_name="/robot", mesh_color_override=(0.45, 0.45, 0.5)
        )
        self._urdf_names = list(self.urdf.get_actuated_joint_names())
        self._idx = [list(model.joint_names).index(n) for n in self._urdf_names if n in model.joint_names]
        gui = self.server.gui
        self.md = gui.add_markdown("**DepthGuard**: waiting for data")
        self.lock = threading.Lock()
        self.state: dict[str, Any] = {
            "q": None,
            "frames": None,
            "masks": None,
            "res": None,
            "status": "-",
            "octree": None,
        }
        self.times = {k: deque(maxlen=60) for k in ("frames", "queries", "commands")}
        self.clouds: dict[str, Any] = {}
        self.draws = 0
        #: updates (or parts of one) skipped, by kind: "joints", "camera", "spheres", "octree", "input", "draw"
        self.skipped: dict[str, int] = {}
        self._skip_lock = threading.Lock()
        self._spheres: set[int] = set()
        self._dirty = threading.Event()
        self._draw_lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="depthguard-live-view", daemon=True)
        self._thread.start()

    @classmethod
    def for_scene(cls, name: str, model: Any, cameras: list[Camera], rho: float, **kw: Any) -> LiveView:
        """A view of a simulated scenario (``depthguard scenario NAME --view``): ``cameras`` fixed in the world
        (principal first), the robot ``model`` at the world origin, ``rho`` in metres; ``kw`` as the
        constructor's (``port``...)."""
        from types import SimpleNamespace

        # (the view reads of a cell file its name, rho and which cameras a link carries: none here)
        cell = SimpleNamespace(
            name=name, distance={"rho": float(rho)}, cameras=[SimpleNamespace(parent="world") for _ in cameras]
        )
        return cls(cell, model, None, cameras, **kw)

    # ------------------------------------------------------------------ producer side (cheap, any thread)
    # (each hook only stores references; one that cannot even do that is counted in skipped["input"], never
    # raised into the producer)
    def _skip(self, kind: str) -> None:
        with self._skip_lock:
            self.skipped[kind] = self.skipped.get(kind, 0) + 1

    def inputs(self, tick, frames) -> None:
        try:
            q = getattr(tick, "q", None)
            q = None if q is None else np.asarray(q, float)
        except (TypeError, ValueError):
            q = None
            self._skip("input")
        with self.lock:
            if q is not None:
                self.state["q"] = q
            if frames is not None:
                self.state["frames"] = frames
                self.times["frames"].append(time.perf_counter())
        if frames is not None:
            self._dirty.set()

    def masks(self, t: float, masks) -> None:
        with self.lock:
            self.state["masks"] = masks

    def query(self, t: float, res, cps) -> None:
        try:
            got = (np.asarray(cps.centres, float), np.asarray(cps.radii, float), res)
        except (AttributeError, TypeError, ValueError):
            got = (np.zeros((0, 3)), np.zeros(0), None)  # (drawn as: distances unknown)
            self._skip("input")
        with self.lock:
            self.state["res"] = got
            self.times["queries"].append(time.perf_counter())

    def command(self, t: float, out) -> None:
        status = getattr(getattr(out, "status", None), "name", None)
        with self.lock:
            self.state["status"] = str(status) if status is not None else "?"
            self.times["commands"].append(time.perf_counter())

    def set_joints(self, q: np.ndarray) -> None:
        try:
            q = np.asarray(q, float)
        except (TypeError, ValueError):
            self._skip("input")
            return
        with self.lock:
            self.state["q"] = q

    def set_frames(self, frames: list[np.ndarray], masks: list[np.ndarray] | None) -> None:
        with self.lock:
            self.state["frames"], self.state["masks"] = frames, masks
            self.times["frames"].append(time.perf_counter())
        self._dirty.set()

    def set_distances(self, centres, radii, distance, direction) -> None:
        class _R:
            pass

        r = _R()
        try:
            r.distance, r.direction = np.asarray(distance, float), np.asarray(direction, float)
            got = (np.asarray(centres, float), np.asarray(radii, float), r)
        except (TypeError, ValueError):
            got = (np.zeros((0, 3)), np.zeros(0), None)  # (drawn as: distances unknown)
            self._skip("input")
        with self.lock:
            self.state["res"] = got
            self.times["queries"].append(time.perf_counter())

    def set_status(self, status: str) -> None:
        with self.lock:
            self.state["status"] = status
            self.times["commands"].append(time.perf_counter())

    def set_octree(self, frame: Any) -> None:
        """The obstacle octree of the latest frame (:class:`depthguard.octree.fusion.OctreeFrame`, or None);
        its nodes are drawn at the next redraw."""
        with self.lock:
            self.state["octree"] = frame

    # ------------------------------------------------------------------ drawing side (its own thread)
    def _loop(self) -> None:
        last = 0.0
        while not self._stop.is_set():
            self._dirty.wait(0.2)
            wait = self.period - (time.perf_counter() - last)
            if wait > 0:
                time.sleep(wait)
            self._dirty.clear()
            last = time.perf_counter()
            try:
                with self._draw_lock:
                    self.draw()
            except Exception:  # noqa: BLE001 - a drawing problem must never reach the control loop
                self._skip("draw")

    def _drop(self, key: str) -> None:
        if key in self.clouds:
            with contextlib.suppress(Exception):
                self.clouds.pop(key).remove()

    def _cloud(self, cam: Camera | None, depth: np.ndarray, mask: np.ndarray | None, k: int) -> None:
        """Camera ``k``'s cloud; one that cannot be drawn (no pose, bad image) is removed and counted."""
        try:
            if cam is None:
                raise ValueError("camera not placed")
            env, rob = _cloud_points(cam, depth, mask, self.stride)
        except Exception:  # noqa: BLE001 - a bad image: this camera's cloud is skipped, not the update
            self._skip("camera")
            self._drop(f"cloud{k}")
            self._drop(f"robot{k}")
            return
        sc = self.server.scene
        col = CAMERA_COLOURS[k % len(CAMERA_COLOURS)]
        self.clouds[f"cloud{k}"] = sc.add_point_cloud(f"/cloud/{k}", env, col, point_size=0.02)
        if len(rob):
            self.clouds[f"robot{k}"] = sc.add_point_cloud(f"/robot_pixels/{k}", rob, ROBOT_PIXELS, point_size=0.02)
        else:
            self._drop(f"robot{k}")

    def _octree(self, frame: Any) -> None:
        """Draw the nodes of an octree frame by kind (squares of the node size at their centres)."""
        box = frame.box
        sc = self.server.scene
        for name, (code, col) in OCTREE_COLOURS.items():
            idx = np.argwhere(frame.kind == code)
            key = f"octree_{name}"
            if len(idx) == 0:
                if key in self.clouds:
                    self.clouds.pop(key).remove()
                continue
            pts = (np.asarray(box.origin, float) + (idx + 0.5) * float(box.res)).astype(np.float32)
            self.clouds[key] = sc.add_point_cloud(
                f"/octree/{name}", pts, col, point_size=0.9 * float(box.res), point_shape="square"
            )

    def _world_cameras(self, q) -> list[Camera] | None:
        """The cameras in the world frame at joint positions ``q``; None when a carried camera cannot be
        placed (no usable joint state yet)."""
        if not self._carried:
            return self.cameras
        from depthguard.runner.carried import place_carried

        try:
            q = np.asarray(q, float)
            if not np.all(np.isfinite(q)):
                return None
            cams = place_carried(self.cameras, self._carried, self.model, q)
        except Exception:  # noqa: BLE001 - no usable joint state: the carried cameras are not placed
            return None
        return cams if all(np.all(np.isfinite(c.R)) and np.all(np.isfinite(c.t)) for c in cams) else None

    def draw(self) -> None:
        """Push the newest state to the page (called by the view thread). Each part (robot, clouds, octree,
        spheres) that cannot be drawn is skipped and counted (:attr:`skipped`); the panel is always updated."""
        with self.lock:
            st = dict(self.state)
            rates = {k: _rate(v) for k, v in self.times.items()}
        joints = self._draw_robot(st["q"])
        if st["frames"] is not None:
            try:
                frames = list(st["frames"])
                masks = st["masks"]
                masks = [None] * len(frames) if masks is None else list(masks)
            except TypeError:
                frames, masks = [], []
                self._skip("camera")
            cams = self._world_cameras(st["q"]) if frames else None
            for k, dep in enumerate(frames[: len(self.cameras)]):
                cam = None if cams is None else cams[k]
                if cam is None and self._carried and all(i != k for i, _ in self._carried):
                    cam = self.cameras[k]  # (a world camera needs no joint state)
                self._cloud(cam, dep, masks[k] if k < len(masks) else None, k)
        if st["octree"] is not None:
            try:
                self._octree(st["octree"])
            except Exception:  # noqa: BLE001 - a malformed octree frame: skipped, not the update
                self._skip("octree")
                for name in OCTREE_COLOURS:
                    self._drop(f"octree_{name}")
        dm = "-" if st["res"] is None else self._draw_spheres(*st["res"])
        with self._skip_lock:
            skipped = ", ".join(f"{k} {v}" for k, v in sorted(self.skipped.items()))
        self.md.content = (
            f"**DepthGuard** cell `{self.cell.name}`  \nstatus: **{st['status']}**  \nnearest: {dm}  \n"
            f"frames {rates['frames']:.1f} Hz · distances {rates['queries']:.1f} Hz"
            f" · commands {rates['commands']:.0f} Hz"
            + (f"  \njoints: {joints}" if joints else "")
            + (f"  \nskipped: {skipped}" if skipped else "")
        )
        self.draws += 1

    def _draw_robot(self, q: Any) -> str:
        """The robot at joint positions ``q``; a state of the wrong length or not finite is skipped (the
        robot stays where it was drawn last) and counted. Returns what the panel says about it ('' when
        fine)."""
        if q is None or not self._idx:
            return ""
        try:
            q = np.asarray(q, float)
            if q.ndim != 1 or len(q) != len(self.model.joint_names):
                raise ValueError(f"{q.shape} joint positions for {len(self.model.joint_names)} joints")
            if not np.all(np.isfinite(q)):
                raise ValueError("not finite")
            self.urdf.update_cfg(q[self._idx])
        except Exception as exc:  # noqa: BLE001 - an unusable joint state: not drawn, the update goes on
            self._skip("joints")
            return f"unusable joint state ({exc}); robot as last drawn"
        return ""

    def _draw_spheres(self, centres: Any, radii: Any, res: Any) -> str:
        """The control spheres coloured by distance and the repulsive vectors; returns the panel's nearest
        distance. Distances that do not match the control points colour every sphere as unknown; centres
        and radii that do not match draw no sphere; both are counted."""
        sc = self.server.scene
        try:
            centres, radii = np.asarray(centres, float), np.asarray(radii, float)
            if centres.ndim != 2 or centres.shape[1] != 3 or radii.shape != (len(centres),):
                raise ValueError(f"centres {centres.shape}, radii {radii.shape}")
        except Exception:  # noqa: BLE001 - control points that cannot be drawn: none is
            self._skip("spheres")
            centres, radii = np.zeros((0, 3)), np.zeros(0)
            d = None
        else:
            n = len(centres)
            try:
                d = np.asarray(res.distance, float)
                if d.shape != (n,):
                    raise ValueError(f"{d.shape} distances for {n} control points")
            except Exception:  # noqa: BLE001 - every sphere unknown (grey), none safe
                self._skip("spheres")
                d = None
        n = len(centres)
        dd = np.full(n, np.nan) if d is None else d
        try:
            u = np.asarray(res.direction, float)
            if u.shape != (n, 3):
                u = np.full((n, 3), np.nan)
        except Exception:  # noqa: BLE001 - no direction: no repulsive vector
            u = np.full((n, 3), np.nan)
        segs, cols, drawn = [], [], set()
        for i in range(n):
            c, r, di = centres[i], float(radii[i]), float(dd[i])
            if not (np.all(np.isfinite(c)) and np.isfinite(r) and r > 0):
                continue
            sc.add_icosphere(
                f"/spheres/{i}", radius=r, color=_distance_rgb(di, self.rho), opacity=0.5,
                subdivisions=2, position=tuple(float(x) for x in c),
            )  # fmt: skip
            drawn.add(i)
            if np.isfinite(di) and di < self.rho and np.all(np.isfinite(u[i])):
                segs.append([c, c + u[i] * 0.3 * (1.0 - max(di, 0.0) / self.rho)])
                cols.append([(255, 120, 0), (255, 120, 0)])
        for i in self._spheres - drawn:  # (spheres of an earlier update that this one does not have)
            with contextlib.suppress(Exception):
                sc.remove_by_name(f"/spheres/{i}")
        self._spheres = drawn
        if segs:
            sc.add_line_segments("/repulsion", np.asarray(segs, np.float32), np.asarray(cols, np.uint8), thickness=0.01)
        else:
            sc.add_line_segments("/repulsion", np.zeros((1, 2, 3), np.float32), (255, 120, 0), thickness=0.0)
        return _nearest_text(d)

    def show_clouds(self, visible: bool) -> None:
        """Show or hide every point cloud (the robot's pixels included)."""
        with self._draw_lock:
            for h in self.clouds.values():
                try:
                    h.visible = visible
                except RuntimeError:  # replaced by a newer cloud meanwhile
                    pass

    def close(self) -> None:
        self._stop.set()
        self._dirty.set()
        self._thread.join(2.0)
        with contextlib.redirect_stdout(sys.stderr):
            self.server.stop()


def run_view_node(
    cell_path: str,
    *,
    port: int = 8080,
    duration: float | None = None,
    domain: int | None = None,
    connect: list[str] | None = None,
    stop: Any = None,
) -> dict[str, Any]:
    """The ``view`` node: the live view of a cell's nodes on Zenoh (prepared frames, masks, joint states,
    distances, status). Returns what it saw: ``draws``, ``frames``, ``distances``, ``status``, and ``skipped``
    (the updates or parts of one it could not draw, by kind: :attr:`LiveView.skipped`)."""
    from depthguard.io import ros2
    from depthguard.io.cellfile import read_cell
    from depthguard.nodes.common import StopFlag, Topics, open_node
    from depthguard.runner.chain import cell_control_points, load_cell_robot

    cell = read_cell(cell_path)
    model = load_cell_robot(cell)
    points = cell_control_points(cell, model)
    view = LiveView(cell, model, points, [c.build() for c in cell.cameras], port=port)
    top = Topics.of(cell)
    node = None
    names = [c.name for c in cell.cameras]
    frames: dict[str, np.ndarray] = {}
    masks: dict[str, np.ndarray] = {}
    lock = threading.Lock()

    def on_js(msg, att, recv_ns):
        view.set_joints(ros2.joints_in_order(msg, model.joint_names)[0])

    def on_depth(n):
        def cb(msg, att, recv_ns):
            with lock:
                frames[n] = ros2.image_to_depth(msg)
                if len(frames) == len(names):
                    view.set_frames([frames[k] for k in names], [masks.get(k) for k in names])

        return cb

    def on_mask(n):
        def cb(msg, att, recv_ns):
            with lock:
                masks[n] = ros2.image_to_mask(msg)

        return cb

    def on_dist(msg, att, recv_ns):
        P = msg.points
        view.set_distances(
            [[p.centre.x, p.centre.y, p.centre.z] for p in P], [p.radius for p in P],
            [p.distance for p in P], [[p.direction.x, p.direction.y, p.direction.z] for p in P],
        )  # fmt: skip

    stop = stop if stop is not None else StopFlag()
    try:  # (whatever fails here, the session and the web server close: neither keeps the process alive)
        node = open_node(cell, "view", domain=domain, connect=connect)
        node.subscribe(top.joint_states, "sensor_msgs/msg/JointState", on_js)
        for n in names:
            node.subscribe(top.depth[n], "sensor_msgs/msg/Image", on_depth(n))
            node.subscribe(top.mask[n], "sensor_msgs/msg/Image", on_mask(n))
        node.subscribe(top.distances, "depthguard_msgs/msg/ControlPointDistances", on_dist)
        node.subscribe(
            top.status, "depthguard_msgs/msg/ControllerStatus", lambda m, a, t: view.set_status(str(m.status))
        )
        print(f"depthguard view: http://127.0.0.1:{port}", flush=True)
        t0 = time.time()
        while not stop and (duration is None or time.time() - t0 < duration):
            stop.wait(0.2)
    finally:
        if node is not None:
            node.close()
        view.close()
    return {
        "draws": view.draws,
        "frames": len(view.times["frames"]),
        "distances": len(view.times["queries"]),
        "status": view.state["status"],
        "skipped": dict(view.skipped),
    }
