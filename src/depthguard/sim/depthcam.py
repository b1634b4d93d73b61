"""A simulated Kinect v1 depth camera: exact depth by ray casting (or OpenGL rendering), then sensor effects.

Output follows DepthGuard's convention (``docs/conventions.md``): an (H, W) float32 image in metres, NaN = no
reading, depth = ``z_C`` along the optical axis (not the ray length), pixel (u, v) sampled through its
centre ``(u + 0.5, v + 0.5)``. The camera pose is a depthguard :class:`~depthguard.camera.Camera`
(``P_C = R P_W + t``, OpenCV axes); the cell also holds a MuJoCo camera (-z forward, y up) at the same pose.

Two ways to get the exact depth:

* ``"raycast"``: ``mujoco.mj_multiRay`` from the optical centre through every pixel centre. The ray
  direction is scaled to ``z_C = 1``, so the returned ray parameter *is* the depth. Works everywhere.
* ``"render"``: ``mujoco.Renderer`` depth buffer (needs an OpenGL context, e.g. ``MUJOCO_GL=egl``). It
  needs the principal point at the image centre (``cx = W/2, cy = H/2``), as :func:`kinect_camera` makes.

Sensor model (Kinect v1, after Khoshelham & Elberink 2012): axial noise with standard deviation
``noise_coeff * z**2`` (1.4 mm at 1 m), quantisation to ``quantization`` (1 mm), readings only within
``[min_depth, max_depth]`` (0.5-4.5 m), and no reading on the far side of depth edges (the projector's
shadow band, ``edge_band`` pixels wide where the depth jumps by more than ``edge_jump`` m).
The noise generator is seeded (``seed``), so runs are repeatable.
"""

from __future__ import annotations

import math
import os

import numpy as np

from depthguard.camera import Camera, look_at

__all__ = ["kinect_camera", "KinectSim", "egl_available", "raycast_depth"]


def kinect_camera(
    eye: np.ndarray,
    target: np.ndarray,
    *,
    width: int = 640,
    height: int = 480,
    hfov_deg: float = 57.0,
    up: np.ndarray = (0.0, 0.0, 1.0),
) -> Camera:
    """A Kinect v1-like camera at ``eye`` looking at ``target``: ``hfov_deg`` horizontal FOV, 0.5-4.5 m.

    The principal point is the image centre (``cx = W/2``), square pixels, so the renderer path can
    reproduce it exactly. Reduced resolutions keep the same field of view.
    """
    fx = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
    R, t = look_at(np.asarray(eye, float), np.asarray(target, float), np.asarray(up, float))
    return Camera(
        width=width,
        height=height,
        fx=fx,
        fy=fx,
        cx=width / 2.0,
        cy=height / 2.0,
        R=R,
        t=t,
        min_depth=0.5,
        max_depth=4.5,
    )


def raycast_depth(
    model,
    data,
    camera: Camera,
    geomgroup: np.ndarray | None = None,
    bodyexclude: int = -1,
    rays: np.ndarray | None = None,
) -> np.ndarray:
    """Exact depth ``z_C`` (H, W) float64 by ``mj_multiRay``, NaN where nothing is hit.

    Args:
        geomgroup: (6,) uint8, 1 for the geom groups to hit (None: all groups).
        rays: optional precomputed world ray directions (H*W*3,) with ``z_C = 1`` (see :meth:`KinectSim`).
    """
    import mujoco

    n = camera.width * camera.height
    if rays is None:
        rays = np.ascontiguousarray((camera.pixel_ray_directions().reshape(-1, 3) @ camera.R).ravel())
    geomid = np.empty(n, np.int32)
    dist = np.empty(n, np.float64)
    gg = None if geomgroup is None else np.asarray(geomgroup, np.uint8)
    mujoco.mj_multiRay(
        model, data, np.asarray(camera.position, float), rays, gg, True, bodyexclude, geomid, dist, None, n, 1e3
    )
    dist[geomid < 0] = np.nan
    return dist.reshape(camera.height, camera.width)


_GL_OK: bool | None = None


def _gl_ok() -> bool:
    global _GL_OK
    if _GL_OK is None:
        _GL_OK = egl_available()
    return _GL_OK


def egl_available() -> bool:
    """True when a MuJoCo OpenGL context can be created (``MUJOCO_GL`` set to egl/osmesa/glfw)."""
    try:
        import mujoco

        m = mujoco.MjModel.from_xml_string("<mujoco><worldbody><geom size='.1'/></worldbody></mujoco>")
        r = mujoco.Renderer(m, 8, 8)
        r.close()
        return True
    except Exception:  # noqa: BLE001 - any failure means "no GL here"
        return False


class KinectSim:
    """A simulated Kinect v1 attached to a MuJoCo model.

    Args:
        camera: the depthguard camera (intrinsics, pose, range).
        index: the MuJoCo camera index ``depthcam<index>`` (renderer path).
        backend: "raycast", "render", or "auto" (render when ``MUJOCO_GL`` is set, an OpenGL context works
            and the image is at least 320x240; ray casting otherwise).
        noise_coeff: axial noise standard deviation per z^2, m^-1 (1.4e-3: 1.4 mm at 1 m).
        quantization: depth step in m (1e-3).
        edge_jump, edge_band: depth jump (m) that makes a depth edge, band width (pixels) without reading.
        seed: seed of the noise generator.
        geomgroup: the geom groups the camera sees (default: all).
    """

    def __init__(
        self,
        model,
        camera: Camera,
        index: int = 0,
        *,
        backend: str = "raycast",
        noise_coeff: float = 1.4e-3,
        quantization: float = 1e-3,
        edge_jump: float = 0.05,
        edge_band: int = 1,
        seed: int = 0,
        geomgroup: np.ndarray | None = None,
    ) -> None:
        if backend not in ("raycast", "render", "auto"):
            raise ValueError(f"backend must be 'raycast', 'render' or 'auto', got {backend!r}")
        if backend == "auto":
            # the renderer pays off at 320x240 and above (640x480: ~22 ms vs ~60 ms ray casting here);
            # it needs MUJOCO_GL (egl/osmesa) set before mujoco is imported
            big = camera.width * camera.height >= 320 * 240
            backend = "render" if (big and os.environ.get("MUJOCO_GL") and _gl_ok()) else "raycast"
        self.model = model
        self.camera = camera
        self.index = index
        self.backend = backend
        self.noise_coeff = noise_coeff
        self.quantization = quantization
        self.edge_jump = edge_jump
        self.edge_band = edge_band
        self.rng = np.random.default_rng(seed)
        self.geomgroup = geomgroup
        self._rays = np.ascontiguousarray((camera.pixel_ray_directions().reshape(-1, 3) @ camera.R).ravel())
        self._renderer = None
        if backend == "render":
            import mujoco

            if abs(camera.cx - camera.width / 2) > 1e-9 or abs(camera.cy - camera.height / 2) > 1e-9:
                raise ValueError("the render backend needs the principal point at the image centre (cx=W/2, cy=H/2)")
            self._renderer = mujoco.Renderer(model, camera.height, camera.width)
            self._renderer.enable_depth_rendering()
            self._ray_len = None

    def exact_depth(self, data) -> np.ndarray:
        """Noise-free depth ``z_C`` (H, W) float64 in metres, NaN where nothing is hit."""
        if self.backend == "raycast":
            return raycast_depth(self.model, data, self.camera, self.geomgroup, rays=self._rays)
        import mujoco

        scene_opt = mujoco.MjvOption()
        scene_opt.geomgroup[:] = 1 if self.geomgroup is None else self.geomgroup
        scene_opt.sitegroup[:] = 0
        self._renderer.update_scene(data, camera=f"depthcam{self.index}", scene_option=scene_opt)
        depth = np.array(self._renderer.render(), dtype=np.float64)
        far = self.model.vis.map.zfar * self.model.stat.extent
        depth[depth >= far * 0.999] = np.nan
        return depth

    def sensor_effects(self, depth: np.ndarray) -> np.ndarray:
        """Apply edge drop-outs, noise, quantisation and range to an exact depth image (float32 out)."""
        z = np.array(depth, dtype=np.float64)
        # far side of depth edges: a neighbour much nearer -> no reading (Kinect shadow band)
        zf = np.where(np.isfinite(z), z, np.inf)
        edge = np.zeros(z.shape, bool)
        for _ in range(self.edge_band):
            near = np.full(z.shape, np.inf)
            near[:, 1:] = np.minimum(near[:, 1:], zf[:, :-1])
            near[:, :-1] = np.minimum(near[:, :-1], zf[:, 1:])
            near[1:, :] = np.minimum(near[1:, :], zf[:-1, :])
            near[:-1, :] = np.minimum(near[:-1, :], zf[1:, :])
            edge |= zf - near > self.edge_jump
            zf = np.where(edge, np.inf, zf)
        noisy = z + self.rng.standard_normal(z.shape) * (self.noise_coeff * z * z)
        if self.quantization > 0:
            noisy = np.round(noisy / self.quantization) * self.quantization
        noisy[edge] = np.nan
        with np.errstate(invalid="ignore"):
            noisy[(noisy < self.camera.min_depth) | (noisy > self.camera.max_depth)] = np.nan
        return noisy.astype(np.float32)

    def capture(self, data) -> np.ndarray:
        """One depth frame (H, W) float32 metres, NaN = no reading, with the sensor model applied."""
        return self.sensor_effects(self.exact_depth(data))

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


def placement(name: str, width: int = 640, height: int = 480) -> list[Camera]:
    """Camera placements of the papers.

    * ``"icra"``: one Kinect at 2 m horizontal distance and 1.2 m height from the robot base (ICRA'12 §VI-A).
    * ``"ral"``: two Kinects about 4 m apart looking at the robot (RA-L'16 §VIII); the first is the principal.
      They aim at 0.45 m above the robot base, so that the principal camera sees the space within ρ of the
      arm's control points above the table (RA-L'16 §I, assumption 1; aimed at 0.35 m, the top of the
      image cut the space above the arm, which then counted as unseen obstacle 0.2-0.3 m over the arm).
    """
    target = (0.0, 0.0, 0.35)
    if name == "icra":
        return [kinect_camera((2.0, 0.0, 1.2), target, width=width, height=height)]
    if name == "ral":
        aim = (0.0, 0.0, 0.45)
        return [
            kinect_camera((1.75, -0.95, 1.5), aim, width=width, height=height),
            kinect_camera((-0.75, 1.85, 1.5), aim, width=width, height=height),
        ]
    raise ValueError(f"unknown camera placement {name!r}; known: 'icra', 'ral'")
