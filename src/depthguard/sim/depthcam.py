"""A simulated Kinect v1 depth camera: exact depth by ray casting (or OpenGL rendering), then sensor effects.

Output follows DepthGuard's convention (``docs/conventions.md``): an (H, W) float32 image in metres, NaN = no
reading, depth = ``z_C`` along the optical axis (not the ray length), pixel (u, v) sampled through its
centre ``(u + 0.5, v + 0.5)``. The camera pose is a depthguard :class:`~depthguard.camera.Camera`
(``P_C = R P_W + t``, OpenCV axes); the cell also holds a MuJoCo camera (-z forward, y up) at the same pose.

Two ways to get the exact depth:

* ``"raycast"``: ``mujoco.mj_multiRay`` from the optical centre through every pixel centre. The ray
  direction is scaled to ``z_C = 1``, so the returned ray parameter *is* the depth. Works everywhere.
  The room (the world body's geoms) is cast once; each frame casts only the rays that can meet a moving
  geom (:mod:`depthguard.sim.raysplit`; the same image, 3-8x faster).
* ``"render"``: ``mujoco.Renderer`` depth buffer (needs an OpenGL context, e.g. ``MUJOCO_GL=egl``). It
  needs the principal point at the image centre (``cx = W/2, cy = H/2``), as :func:`kinect_camera` makes.

Sensor model (Kinect v1, after Khoshelham & Elberink 2012): axial noise with standard deviation
``noise_coeff * z**2`` (1.4 mm at 1 m), quantisation to ``quantization`` (1 mm), readings only within
``[min_depth, max_depth]`` (0.5-4.5 m), and no reading where the pattern projector cannot light the surface
(``shadow="projector"``, the default): the projector sits ``baseline`` (7.5 cm) to the camera's right (+x),
so a nearer object casts, on the surface behind it, a band without reading on its *left* side, as wide as
the disparity difference ``f b (1/z_near - 1/z_far)`` pixels, and horizontal edges cast none (the
structured-light geometry: the pattern's epipolar lines are the image rows). The projector is rigid on the
camera body: a camera rolled about its optical axis (:func:`kinect_camera`'s ``roll_deg``; 180 = mounted
upside down, -90 = projector above the lens) keeps the band on the left *in its image*, which puts it on
another side of the objects in the world. ``shadow="band"`` is the
older, cruder model: ``edge_band`` pixels on the far side of every edge, in all four directions, where
the depth jumps by more than ``edge_jump`` m.
The noise generator is seeded (``seed``), so runs are repeatable.
"""

from __future__ import annotations

import math
import os

import numba as nb
import numpy as np

from depthguard.camera import Camera, look_at
from depthguard.validation import check_finite_array

__all__ = ["kinect_camera", "KinectSim", "cast_rays", "egl_available", "raycast_depth", "projector_shadow"]

KINECT_BASELINE = 0.075  # m, IR projector to IR camera (Kinect v1)


@nb.njit(cache=True, nogil=True)
def projector_shadow(z, fx, baseline):
    """(H, W) bool: the pixels whose surface the projector cannot light (structured-light shadow).

    The projector sits at ``(baseline, 0, 0)`` in the camera frame; the point seen at pixel column u
    with depth z lies in projector column ``u_p = u - fx baseline / z``. Along a row (an epipolar line)
    the projector lights a point only if no point to its right (nearer the projector) has a projector
    column at or left of its own: scanning from the right, a pixel whose ``u_p`` is not below the
    running minimum lies in the shadow of a nearer surface. ``z``: (H, W) exact depth, NaN or inf
    where nothing is hit (casts no shadow). Example: a 1 m object in front of a 3 m wall at
    fx = 575 px casts a band of 575 * 0.075 * (1 - 1/3) = 28.75 px on the wall to its left.
    """
    H, W = z.shape
    out = np.zeros((H, W), dtype=np.bool_)
    fb = fx * baseline
    for v in range(H):
        run = np.inf
        for u in range(W - 1, -1, -1):
            d = z[v, u]
            if not (d > 0.0 and d < np.inf):
                continue
            up = u - fb / d
            if up >= run - 1e-9:
                out[v, u] = True
            else:
                run = up
    return out


def kinect_camera(
    eye: np.ndarray,
    target: np.ndarray,
    *,
    width: int = 640,
    height: int = 480,
    hfov_deg: float = 57.0,
    up: np.ndarray = (0.0, 0.0, 1.0),
    roll_deg: float = 0.0,
) -> Camera:
    """A Kinect v1-like camera at ``eye`` looking at ``target``: ``hfov_deg`` horizontal FOV, 0.5-4.5 m.

    The principal point is the image centre (``cx = W/2``), square pixels, so the renderer path can
    reproduce it exactly. Reduced resolutions keep the same field of view.

    ``roll_deg``: the camera body rolled about its optical axis by this angle (degrees; positive turns
    the image's x axis towards its y axis, i.e. clockwise as seen from behind the camera), after
    aiming with ``up``. 180 is a Kinect mounted upside down: its image is turned by 180 degrees and its
    projector, rigidly ``baseline`` m along the camera's +x axis, sits on the other side of the lens in the
    world, so the projector shadow bands fall on the other side of the nearer objects in the world (still
    on their left in the image, :func:`projector_shadow`). 0 (default) leaves the pose bit-identical.
    """
    fx = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
    R, t = look_at(np.asarray(eye, float), np.asarray(target, float), np.asarray(up, float))
    if roll_deg:
        R, t = _rolled(R, t, float(roll_deg))
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


def _rolled(R: np.ndarray, t: np.ndarray, roll_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """``(R, t)`` of the camera rolled by ``roll_deg`` about its optical axis (the centre stays put): the new
    x axis is ``cos a x + sin a y``, the new y axis ``-sin a x + cos a y`` (multiples of 90 degrees exact)."""
    a = math.radians(roll_deg)
    c, s = math.cos(a), math.sin(a)
    q = roll_deg / 90.0
    if abs(q - round(q)) < 1e-12:  # exact signs for quarter turns (180: x -> -x, y -> -y)
        c, s = [(1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0)][int(round(q)) % 4]
    Rz = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    return Rz @ R, Rz @ t


def cast_rays(
    model, data, origin: np.ndarray, rays: np.ndarray, geomgroup: np.ndarray | None = None, bodyexclude: int = -1
) -> tuple[np.ndarray, np.ndarray]:
    """``mj_multiRay`` from ``origin`` (3,) along ``rays`` ((N, 3) or (3N,), world): ``(ray parameter (N,),
    NaN where nothing is hit; geom id (N,) int32, -1 there)``. Static geoms included; ``geomgroup``: (6,)
    1 for the groups to hit (None: all). The parameter is in units of each ray's length (a ray scaled to
    ``z_C = 1`` gives the depth ``z_C``). A non-finite origin or ray, a zero ray, or a wrong shape:
    ``ValueError`` naming the argument (MuJoCo would report "no hit" for them)."""
    import mujoco

    r = np.ascontiguousarray(rays, dtype=np.float64).ravel()
    if r.shape[0] % 3:
        raise ValueError(f"cast_rays: rays must be (N, 3) or (3N,), got {r.shape[0]} numbers")
    if not (math.isfinite(r.sum()) or np.isfinite(r).all()):  # (a sum of finite numbers may overflow)
        raise ValueError("cast_rays: rays must be finite (no NaN or inf)")
    n = r.shape[0] // 3
    v = r.reshape(n, 3)
    if n and not ((v[:, 0] != 0.0) | (v[:, 1] != 0.0) | (v[:, 2] != 0.0)).all():
        raise ValueError("cast_rays: rays must be non-zero directions")
    o = check_finite_array(origin, (3,), "cast_rays: origin")
    gg = _geomgroup(geomgroup, "cast_rays: geomgroup")
    geomid = np.empty(n, np.int32)
    dist = np.empty(n, np.float64)
    if n:
        mujoco.mj_multiRay(model, data, o, r, gg, True, bodyexclude, geomid, dist, None, n, 1e3)
    dist[geomid < 0] = np.nan
    return dist, geomid


def _geomgroup(geomgroup: np.ndarray | None, name: str) -> np.ndarray | None:
    """``geomgroup`` as a (6,) uint8 array of 0/1 (None stays None), or ``ValueError`` naming ``name``."""
    if geomgroup is None:
        return None
    g = np.asarray(geomgroup)
    if g.shape != (6,) or g.dtype.kind not in "biuf" or not np.all((g == 0) | (g == 1)):
        raise ValueError(f"{name} must be None or six 0/1 flags (one per geom group 0-5), got {geomgroup!r}")
    return g.astype(np.uint8)


def raycast_depth(
    model,
    data,
    camera: Camera,
    geomgroup: np.ndarray | None = None,
    bodyexclude: int = -1,
    rays: np.ndarray | None = None,
    return_geoms: bool = False,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Exact depth ``z_C`` (H, W) float64 by ``mj_multiRay``, NaN where nothing is hit.

    Args:
        geomgroup: (6,) uint8, 1 for the geom groups to hit (None: all groups).
        rays: optional precomputed world ray directions (H*W*3,) with ``z_C = 1`` (see :meth:`KinectSim`).
        return_geoms: also return the geom id (H, W) int32 hit by each pixel's ray (-1: none).
    """
    if rays is None:
        rays = np.ascontiguousarray((camera.pixel_ray_directions().reshape(-1, 3) @ camera.R).ravel())
    dist, geomid = cast_rays(model, data, camera.position, rays, geomgroup, bodyexclude)
    shape = (camera.height, camera.width)
    return (dist.reshape(shape), geomid.reshape(shape)) if return_geoms else dist.reshape(shape)


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
        shadow: "projector" (default: the projector's shadow, ``baseline`` m to the camera's right, see
            :func:`projector_shadow`), "band" (``edge_band`` pixels without reading on the far side of
            every depth jump larger than ``edge_jump`` m) or "none".
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
        shadow: str = "projector",
        baseline: float = KINECT_BASELINE,
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
        if shadow not in ("projector", "band", "none"):
            raise ValueError(f"shadow must be 'projector', 'band' or 'none', got {shadow!r}")
        if not (math.isfinite(baseline) and baseline >= 0):
            raise ValueError(f"baseline must be a non-negative number of metres, got {baseline!r}")
        for name, value in (("noise_coeff", noise_coeff), ("quantization", quantization), ("edge_jump", edge_jump)):
            ok = not isinstance(value, bool) and isinstance(value, int | float | np.number)
            if not (ok and math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
        if isinstance(edge_band, bool) or not isinstance(edge_band, int | np.integer) or edge_band < 0:
            raise ValueError(f"edge_band must be an integer number of pixels >= 0, got {edge_band!r}")
        geomgroup = _geomgroup(geomgroup, "geomgroup")
        self.shadow = shadow
        self.baseline = float(baseline)
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
        self._split = None
        if backend == "raycast":
            from depthguard.sim.raysplit import SplitRaycaster

            split = SplitRaycaster(model, camera, self._rays, geomgroup)
            self._split = split if split.usable() else None  # the still room cast once (same image)
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
            if self._split is not None:
                return self._split.depth(data)
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
        """Apply the projector shadow (or edge band), noise, quantisation and range to an exact depth image
        (float32 out). ``depth``: a 2-D image (the camera's, or a window of it), metres, NaN where nothing is
        hit (else ``ValueError``)."""
        z = np.array(depth, dtype=np.float64)
        if z.ndim != 2:
            raise ValueError(f"depth must be a 2-D image (H, W) in metres, got shape {z.shape}")
        zf = np.where(np.isfinite(z), z, np.inf)
        edge = np.zeros(z.shape, bool)
        if self.shadow == "projector":
            edge = projector_shadow(zf, float(self.camera.fx), self.baseline)
        for _ in range(self.edge_band if self.shadow == "band" else 0):
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


PLACEMENTS = ("icra", "icra-ssm", "ral", "ral3", "ral-rolled", "ral-rolled-far")
RAL_TWO = ("ral", "ral-rolled", "ral-rolled-far")  # two-camera placements that take ral3's third camera for 3


def placement(name: str, width: int = 640, height: int = 480) -> list[Camera]:
    """Camera placements of the papers.

    * ``"icra"``: one Kinect at 2 m horizontal distance and 1.2 m height from the robot base (ICRA'12 §VI-A).
    * ``"icra-ssm"``: the same camera placed for speed and separation monitoring, which counts unseen space
      as a person: moved back and up to (2.2, 0, 1.8) (the room's wall is at x = 2.3) and aimed at
      (0, 0, 0.15), so that its image edges stay 0.40-0.50 m from the control points along the ICRA tasks
      (the ``"icra"`` camera's lower edge passes 0.16 m from the end effector near the table and its upper
      edge 0.3 m above the elbow, both within the protective distance ``S_p`` of 0.2-0.4 m; docs/ssm.md).
    * ``"ral"``: two Kinects about 4 m apart looking at the robot (RA-L'16 §VIII); the first is the principal.
      They aim at 0.45 m above the robot base, so that the principal camera sees the space within ρ of the
      arm's control points above the table (RA-L'16 §I, assumption 1; aimed at 0.35 m, the top of the
      image cut the space above the arm, which then counted as unseen obstacle 0.2-0.3 m over the arm).
    * ``"ral3"``: the two ``"ral"`` cameras and a third one 2 m high behind the arm, at (-0.9, -0.9, 2.0): it
      sees the rays that the two leave unmeasured (the projector shadows of the second camera that pass
      behind the arm in the principal view, ``docs/phantom-zero.md``). ``--cameras 3`` of a ``"ral"``
      scenario uses it.
    * ``"ral-rolled"``: the ``"ral"`` cameras with the second one on its side (rolled by -90 degrees, its
      projector above the lens), so that its projector shadows no longer cross the space that the arm and
      the panel hide from the principal camera (docs/phantom-zero.md, fourth round); ``ral-shadow`` and
      ``ral-hidden`` use it.
    * ``"ral-rolled-far"``: ``"ral-rolled"`` with the principal camera 0.29 m farther back along its own
      horizontal direction, at (2.0, -1.09, 1.5), so that the end effector pushed towards it stays in its
      view (it changes the one-camera premise of ``ral-hidden``: the arm no longer hits the hidden box);
      ``ral-hexagon`` uses it.
    A scenario file names its placement (``cameras``); ``depthguard scenario NAME --placement NAME`` overrides
    it. The two-camera ``"ral"`` placements take ``"ral3"``'s third camera for ``--cameras 3``.
    """
    target = (0.0, 0.0, 0.35)
    if name == "icra":
        return [kinect_camera((2.0, 0.0, 1.2), target, width=width, height=height)]
    if name == "icra-ssm":
        return [kinect_camera((2.2, 0.0, 1.8), (0.0, 0.0, 0.15), width=width, height=height)]
    if name in ("ral", "ral3"):
        aim = (0.0, 0.0, 0.45)
        cams = [
            kinect_camera((1.75, -0.95, 1.5), aim, width=width, height=height),
            kinect_camera((-0.75, 1.85, 1.5), aim, width=width, height=height),
        ]
        if name == "ral3":  # a third camera high behind the arm (docs/phantom-zero.md)
            cams.append(kinect_camera((-0.9, -0.9, 2.0), aim, width=width, height=height))
        return cams
    if name in ("ral-rolled", "ral-rolled-far"):
        aim = (0.0, 0.0, 0.45)
        principal = (2.0, -1.09, 1.5) if name == "ral-rolled-far" else (1.75, -0.95, 1.5)
        return [
            kinect_camera(principal, aim, width=width, height=height),
            kinect_camera((-0.75, 1.85, 1.5), aim, width=width, height=height, roll_deg=-90.0),
        ]
    raise ValueError(f"unknown camera placement {name!r}; known: {', '.join(repr(k) for k in PLACEMENTS)}")
