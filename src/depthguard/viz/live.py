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

__all__ = ["LiveView", "CAMERA_COLOURS"]  # (run_view_node: depthguard.viz.live_node)

from depthguard.viz.live_draw import (  # noqa: F401  (_distance_rgb: the tests read it here)
    CAMERA_COLOURS,
    OCTREE_COLOURS,
    ROBOT_PIXELS,
    UNKNOWN_DISTANCE,
    _cloud_points,
    _distance_rgb,
    _nearest_text,
)


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


def __getattr__(name: str) -> Any:  # (the view node lives in depthguard.viz.live_node; its old import path works)
    if name == "run_view_node":
        from depthguard.viz.live_node import run_view_node

        return run_view_node
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
