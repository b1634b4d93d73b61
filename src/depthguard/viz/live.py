"""The live 3-D view in the browser (``viser``): ``depthguard view --cell CELL.toml`` and ``run --view``.

What the page shows, in the world frame:

* the robot from its URDF (viser's ``ViserUrdf``) at the latest joint state;
* each camera's depth point cloud, one colour per camera (every ``stride``-th pixel), and the pixels the
  self-filter removed as the robot's (magenta); about 160 points per image row (``stride``);
* the control spheres coloured by distance (red at contact, yellow half way, green at rho and beyond) and the
  repulsive vectors (orange segments, longer when nearer);
* with the octree backend (``scenario --backend octree --view``, ``scenario saphari-octree --view``), the
  obstacle octree's nodes: occupied (red), occluded (orange) and unseen (grey; obstacles in the conservative
  mode) as squares of the node size;
* a panel with the controller status, the smallest distance and the rates of frames, distance queries and
  commands.

The producers (the runner's hooks, or Zenoh callbacks in the ``view`` node) only store references under a
lock; one background thread turns the newest state into scene updates at most ``max_hz`` times a second, so
the control loop never waits on the browser.
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


def _distance_rgb(d: float, rho: float) -> tuple[int, int, int]:
    f = 1.0 if not np.isfinite(d) else float(np.clip(d / max(rho, 1e-9), 0.0, 1.0))
    return (int(255 * min(1.0, 2.0 * (1.0 - f))), int(255 * min(1.0, 2.0 * f)), 0)


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
    def inputs(self, tick, frames) -> None:
        with self.lock:
            if tick.q is not None:
                self.state["q"] = np.asarray(tick.q, float)
            if frames is not None:
                self.state["frames"] = frames
                self.times["frames"].append(time.perf_counter())
        if frames is not None:
            self._dirty.set()

    def masks(self, t: float, masks) -> None:
        with self.lock:
            self.state["masks"] = masks

    def query(self, t: float, res, cps) -> None:
        with self.lock:
            self.state["res"] = (np.asarray(cps.centres), np.asarray(cps.radii), res)
            self.times["queries"].append(time.perf_counter())

    def command(self, t: float, out) -> None:
        with self.lock:
            self.state["status"] = out.status.name
            self.times["commands"].append(time.perf_counter())

    def set_joints(self, q: np.ndarray) -> None:
        with self.lock:
            self.state["q"] = np.asarray(q, float)

    def set_frames(self, frames: list[np.ndarray], masks: list[np.ndarray] | None) -> None:
        with self.lock:
            self.state["frames"], self.state["masks"] = frames, masks
            self.times["frames"].append(time.perf_counter())
        self._dirty.set()

    def set_distances(self, centres, radii, distance, direction) -> None:
        class _R:
            pass

        r = _R()
        r.distance, r.direction = np.asarray(distance, float), np.asarray(direction, float)
        with self.lock:
            self.state["res"] = (np.asarray(centres, float), np.asarray(radii, float), r)
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
                pass

    def _cloud(self, cam: Camera, depth: np.ndarray, mask: np.ndarray | None, k: int) -> None:
        from depthguard.nodes.common import camera_at_size

        s = self.stride or max(1, round(depth.shape[1] / 160))
        d = np.asarray(depth, float)[::s, ::s]
        c = camera_at_size(cam, depth.shape[1], depth.shape[0])
        v, u = np.mgrid[0 : depth.shape[0] : s, 0 : depth.shape[1] : s]
        ok = np.isfinite(d) & (d > 0)
        m = np.zeros_like(ok) if mask is None else np.asarray(mask, bool)[::s, ::s]
        pts = c.unproject(u + 0.5, v + 0.5, np.where(ok, d, 0.0))
        env, rob = ok & ~m, ok & m
        sc = self.server.scene
        col = CAMERA_COLOURS[k % len(CAMERA_COLOURS)]
        self.clouds[f"cloud{k}"] = sc.add_point_cloud(f"/cloud/{k}", pts[env].astype(np.float32), col, point_size=0.02)
        if rob.any():
            h = sc.add_point_cloud(f"/robot_pixels/{k}", pts[rob].astype(np.float32), ROBOT_PIXELS, point_size=0.02)
            self.clouds[f"robot{k}"] = h
        elif f"robot{k}" in self.clouds:
            self.clouds.pop(f"robot{k}").remove()

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
            return place_carried(self.cameras, self._carried, self.model, np.asarray(q, float))
        except (ValueError, TypeError):
            return None

    def draw(self) -> None:
        """Push the newest state to the page (called by the view thread)."""
        with self.lock:
            st = dict(self.state)
            rates = {k: _rate(v) for k, v in self.times.items()}
        if st["q"] is not None and self._idx:
            self.urdf.update_cfg(np.asarray(st["q"])[self._idx])
        cams = self._world_cameras(st["q"])
        if st["frames"] is not None and cams is not None:
            masks = st["masks"] or [None] * len(st["frames"])
            for k, (cam, dep) in enumerate(zip(cams, st["frames"], strict=False)):
                self._cloud(cam, dep, masks[k] if k < len(masks) else None, k)
        if st["octree"] is not None:
            self._octree(st["octree"])
        dmin = None
        if st["res"] is not None:
            centres, radii, res = st["res"]
            d, u = np.asarray(res.distance, float), np.asarray(res.direction, float)
            dmin = float(np.min(d)) if d.size else None
            sc = self.server.scene
            segs, cols = [], []
            for i, (c, r) in enumerate(zip(centres, radii, strict=True)):
                sc.add_icosphere(
                    f"/spheres/{i}", radius=float(r), color=_distance_rgb(d[i], self.rho), opacity=0.5,
                    subdivisions=2, position=tuple(float(x) for x in c),
                )  # fmt: skip
                if np.isfinite(d[i]) and d[i] < self.rho and np.all(np.isfinite(u[i])):
                    segs.append([c, c + u[i] * 0.3 * (1.0 - max(d[i], 0.0) / self.rho)])
                    cols.append([(255, 120, 0), (255, 120, 0)])
            if segs:
                sc.add_line_segments(
                    "/repulsion", np.asarray(segs, np.float32), np.asarray(cols, np.uint8), thickness=0.01
                )
            else:
                sc.add_line_segments("/repulsion", np.zeros((1, 2, 3), np.float32), (255, 120, 0), thickness=0.0)
        dm = "-" if dmin is None else ("inf" if not np.isfinite(dmin) else f"{dmin:.3f} m")
        self.md.content = (
            f"**DepthGuard** cell `{self.cell.name}`  \nstatus: **{st['status']}**  \nnearest: {dm}  \n"
            f"frames {rates['frames']:.1f} Hz · distances {rates['queries']:.1f} Hz"
            f" · commands {rates['commands']:.0f} Hz"
        )
        self.draws += 1

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
    distances, status). Returns what it saw: ``draws``, ``frames``, ``distances``, ``status``."""
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
    }
