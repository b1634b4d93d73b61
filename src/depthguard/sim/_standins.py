"""Small stand-ins for pipeline pieces that other modules provide, used only when those are absent.

* :func:`prepare_frame` / :func:`query_distances`: ICRA'12 eq. 4 depth-space distances with the gray
  area (``d_o < d_p`` -> obstacle along the pixel ray at the control point's depth), pure numpy.
* :class:`VoxelFusion`: multi-camera fusion on a voxel grid with the RA-L'16 rule (the principal camera
  cannot see past a cell and every other involved camera confirms it; robot pixels never confirm in
  a secondary camera).
* :class:`MjKinematics`: control points and Jacobians from a robot-only MuJoCo model of the same URDF.
* :func:`capsule_self_filter`: robot mask by ray casting the model's capsules.

They are deliberately simple and slower than the project's modules; :func:`depthguard.sim.pipeline.backends`
reports which are in use.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from depthguard.camera import Camera

PRESETS: dict[str, dict[str, int]] = {
    "ee": {},
    "icra-exp3": {"lwr_link_2": 1, "lwr_link_3": 2, "lwr_link_4": 1, "lwr_link_5": 1},
    "ral-9": {"lwr_link_2": 1, "lwr_link_3": 2, "lwr_link_4": 2, "lwr_link_5": 2, "lwr_link_6": 1},
}


class PointDistances(NamedTuple):
    distance: np.ndarray
    direction: np.ndarray
    nearest: np.ndarray
    obstacle_pixels: np.ndarray


class _Frame(NamedTuple):
    camera: Camera
    obstacle_depth: np.ndarray
    rays: np.ndarray


def _fill(depth: np.ndarray, robot: np.ndarray, camera: Camera, fill_radius: int = 4) -> np.ndarray:
    d = np.asarray(depth, np.float32)
    missing = ~np.isfinite(d) | (d <= 0)
    valid = np.where(missing | robot, np.inf, d)
    near = ndimage.minimum_filter(valid, size=2 * fill_radius + 1, mode="constant", cval=np.inf)
    obs = np.where(missing, np.where(np.isfinite(near), near, camera.min_depth), d)
    obs[robot] = np.inf
    return obs.astype(np.float32)


def prepare_frame(
    camera: Camera,
    depth: np.ndarray,
    mask: np.ndarray | None = None,
    invalid: str = "conservative",
    fill_radius: int = 4,
) -> _Frame:
    robot = np.zeros(camera.shape, bool) if mask is None else np.asarray(mask, bool)
    return _Frame(camera, _fill(depth, robot, camera, fill_radius), camera.pixel_ray_directions())


def query_distances(
    frame: _Frame, centres: np.ndarray, radii: np.ndarray, rho: float = 0.4, mode: str = "all", alpha: float = 6.0
) -> PointDistances:
    cam = frame.camera
    c = np.atleast_2d(np.asarray(centres, float))
    r = np.broadcast_to(np.asarray(radii, float), (len(c),))
    n = len(c)
    dist = np.full(n, np.inf)
    direc = np.full((n, 3), np.nan)
    nearest = np.full((n, 3), np.nan)
    count = np.zeros(n, int)
    pc = cam.world_to_camera(c)
    for i in range(n):
        rr = rho + r[i]
        P = pc[i]
        if P[2] - rr > 0:
            corners = P + rr * np.array([[sx, sy, -1.0] for sx in (-1, 1) for sy in (-1, 1)])
            px = cam.fx * corners[:, 0] / corners[:, 2] + cam.cx
            py = cam.fy * corners[:, 1] / corners[:, 2] + cam.cy
            u0, u1 = max(int(np.floor(px.min())) - 1, 0), min(int(np.ceil(px.max())) + 1, cam.width)
            v0, v1 = max(int(np.floor(py.min())) - 1, 0), min(int(np.ceil(py.max())) + 1, cam.height)
        else:
            u0, u1, v0, v1 = 0, cam.width, 0, cam.height
        if u0 >= u1 or v0 >= v1:
            continue
        d_o = frame.obstacle_depth[v0:v1, u0:u1]
        ok = d_o <= P[2] + rr
        if not ok.any():
            continue
        ray = frame.rays[v0:v1, u0:u1][ok]
        s = np.maximum(d_o[ok], (ray @ P) / np.einsum("ij,ij->i", ray, ray))
        O = ray * s[:, None]
        diff = P - O
        dd = np.linalg.norm(diff, axis=1)
        foot = 0.71 * s / min(cam.fx, cam.fy)
        D = np.maximum(dd - r[i] - foot, 0.0)
        within = D < rho
        if not within.any():
            continue
        D, diff, dd, O = D[within], diff[within], dd[within], O[within]
        units = diff / np.maximum(dd, 1e-9)[:, None]
        k = int(np.argmin(D))
        dist[i] = D[k]
        nearest[i] = cam.camera_to_world(O[k])
        count[i] = len(D)
        if mode == "min":
            v = units[k]
        elif mode == "hybrid":
            v = units.mean(axis=0)
        else:
            w = 1.0 / (1.0 + np.exp((D * 2.0 / rho - 1.0) * alpha))
            v = (units * w[:, None]).sum(axis=0)
        nv = np.linalg.norm(v)
        direc[i] = cam.vector_to_world(v / nv if nv > 1e-9 else units[k])
    return PointDistances(dist, direc, nearest, count)


class VoxelFusion:
    """Multi-camera fusion on a voxel grid (RA-L'16 §VI rule), a stand-in for ``DepthGridFusion``.

    A cell is an obstacle when every involved camera (the cell in its field of view) cannot see past
    it; in a secondary camera a robot pixel never confirms (the robot is not an obstacle to itself),
    in the principal camera the space behind the robot stays possibly occupied.
    """

    def __init__(
        self, cameras: list[Camera], dd: float = 0.01, workspace: tuple[float, ...] = (-1.2, 1.2, -1.2, 1.2, -0.3, 1.5)
    ) -> None:
        self.cameras = list(cameras)
        self.dd = max(float(dd), 0.03)  # the stand-in keeps the grid coarse
        x0, x1, y0, y1, z0, z1 = workspace
        g = np.mgrid[x0 : x1 : self.dd, y0 : y1 : self.dd, z0 : z1 : self.dd].reshape(3, -1).T + self.dd / 2
        self.cells = g
        self.half = 0.87 * self.dd
        self.proj = []
        for cam in self.cameras:
            p = cam.project(g)
            with np.errstate(invalid="ignore"):
                u = np.floor(p[:, 0])
                v = np.floor(p[:, 1])
                inside = (p[:, 2] > cam.min_depth) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
            idx = np.where(inside, v * cam.width + u, 0).astype(np.int64)
            win = int(np.ceil(self.dd * cam.fx / 1.0)) | 1
            self.proj.append((inside, idx, p[:, 2], win))
        self.tree = None
        self.occupied = np.zeros((0, 3))
        self.ready = False

    def update(self, depths: list[np.ndarray], masks: list[np.ndarray] | None) -> None:
        n = len(self.cells)
        involved = np.zeros(n, int)
        confirms = np.zeros(n, int)
        for k, cam in enumerate(self.cameras):
            inside, idx, z, win = self.proj[k]
            robot = np.zeros(cam.shape, bool) if masks is None else np.asarray(masks[k], bool)
            obs = _fill(depths[k], robot, cam)
            if k == 0:
                d = np.asarray(depths[k], np.float32)
                obs = np.where(robot, np.where(np.isfinite(d), d, cam.min_depth), obs)
            m = ndimage.minimum_filter(obs, size=win, mode="nearest").ravel()
            involved += inside
            confirms += inside & (m[idx] <= z + self.half)
        occ = (involved > 0) & (confirms == involved)
        self.occupied = self.cells[occ]
        self.tree = cKDTree(self.occupied) if len(self.occupied) else None
        self.ready = True

    def query(
        self, centres: np.ndarray, radii: np.ndarray, rho: float = 0.4, mode: str = "hybrid", alpha: float = 6.0
    ) -> PointDistances:
        c = np.atleast_2d(np.asarray(centres, float))
        r = np.broadcast_to(np.asarray(radii, float), (len(c),))
        n = len(c)
        dist = np.full(n, np.inf)
        direc = np.full((n, 3), np.nan)
        nearest = np.full((n, 3), np.nan)
        count = np.zeros(n, int)
        if self.tree is None:
            return PointDistances(dist, direc, nearest, count)
        for i in range(n):
            ids = self.tree.query_ball_point(c[i], rho + r[i] + self.half)
            if not ids:
                continue
            O = self.occupied[ids]
            diff = c[i] - O
            dd = np.linalg.norm(diff, axis=1)
            D = np.maximum(dd - self.half - r[i], 0.0)
            ok = D < rho
            if not ok.any():
                continue
            D, diff, dd, O = D[ok], diff[ok], dd[ok], O[ok]
            units = diff / np.maximum(dd, 1e-9)[:, None]
            k = int(np.argmin(D))
            dist[i], nearest[i], count[i] = D[k], O[k], len(D)
            v = units[k] if mode == "min" else units.mean(axis=0)
            nv = np.linalg.norm(v)
            direc[i] = v / nv if nv > 1e-9 else units[k]
        return PointDistances(dist, direc, nearest, count)


def bounding_spheres(a: np.ndarray, b: np.ndarray, radius: float, k: int) -> tuple[np.ndarray, np.ndarray]:
    a, b = np.asarray(a, float), np.asarray(b, float)
    L = float(np.linalg.norm(b - a))
    if k == 1:
        return (0.5 * (a + b))[None], np.array([0.5 * L + radius])
    t = np.linspace(0.0, 1.0, k)
    return a + t[:, None] * (b - a), np.full(k, np.hypot(radius, 0.5 * L / (k - 1)))


class MjKinematics:
    """Control points from a robot-only MuJoCo model built from the same URDF (stand-in for pinocchio)."""

    def __init__(self, preset: str = "ral-9", ee_radius: float = 0.06) -> None:
        import mujoco

        from depthguard.sim.cell import _robot_xml
        from depthguard.sim.robotdesc import load_robot_desc

        self.desc = load_robot_desc()
        body, actuated = _robot_xml(self.desc, 0.0)
        xml = f"<mujoco><compiler angle='radian'/><worldbody>{body}</worldbody></mujoco>"
        self.m = mujoco.MjModel.from_xml_string(xml)
        self.d = mujoco.MjData(self.m)
        m = self.m
        self.qadr = np.array([m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, j)] for j in actuated])
        self.q_min = np.array([j.lower for j in self.desc.actuated])
        self.q_max = np.array([j.upper for j in self.desc.actuated])
        self.v_max = np.array([j.velocity for j in self.desc.actuated])
        self.ee_body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, self.desc.ee_link)
        counts = PRESETS[preset] if isinstance(preset, str) else preset
        names, bodies, offsets, radii = ["ee"], [self.ee_body], [np.zeros(3)], [ee_radius]
        for link, k in counts.items():
            bid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, link)
            for cap in [c for c in self.desc.capsules if c.link == link]:
                cs, rs = bounding_spheres(cap.a, cap.b, cap.radius, k)
                for i, (cc, rr) in enumerate(zip(cs, rs, strict=True)):
                    names.append(f"{link}/{i}")
                    bodies.append(bid)
                    offsets.append(cc)
                    radii.append(rr)
        self.names = tuple(names)
        self.bodies = np.array(bodies)
        self.offsets = np.array(offsets)
        self.radii = np.array(radii, float)
        self.cap_bodies = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, c.link) for c in self.desc.capsules]
        self.cap_a = np.array([c.a for c in self.desc.capsules], float)
        self.cap_b = np.array([c.b for c in self.desc.capsules], float)
        self.cap_r = np.array([c.radius for c in self.desc.capsules], float)

    def _fk(self, q: np.ndarray) -> None:
        import mujoco

        self.d.qpos[self.qadr] = q
        mujoco.mj_kinematics(self.m, self.d)
        mujoco.mj_comPos(self.m, self.d)

    def evaluate(self, q: np.ndarray):
        import mujoco

        from depthguard.sim.pipeline import CPState

        self._fk(q)
        R = self.d.xmat[self.bodies].reshape(-1, 3, 3)
        centres = np.einsum("kij,kj->ki", R, self.offsets) + self.d.xpos[self.bodies]
        jac = np.zeros((len(centres), 3, self.m.nv))
        for i, (b, c) in enumerate(zip(self.bodies, centres, strict=True)):
            mujoco.mj_jac(self.m, self.d, jac[i], None, c, int(b))
        return CPState(centres, self.radii.copy(), jac[:, :, self.qadr], self.names)

    def capsules(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        self._fk(q)
        R = self.d.xmat[self.cap_bodies].reshape(-1, 3, 3)
        p = self.d.xpos[self.cap_bodies]
        return (
            np.einsum("kij,kj->ki", R, self.cap_a) + p,
            np.einsum("kij,kj->ki", R, self.cap_b) + p,
            self.cap_r.copy(),
        )


def capsule_depth(camera: Camera, a: np.ndarray, b: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Depth z_C (H, W) of the union of capsules through each pixel centre, NaN where none is hit."""
    from depthguard.scene import Capsule

    rays_c = camera.pixel_ray_directions().reshape(-1, 3)
    o = camera.position
    d = rays_c @ camera.R  # world directions with z_C = 1, so the ray parameter is the depth
    best = np.full(len(d), np.inf)
    # only rays inside the capsules' projected bounding box
    proj = camera.project(np.concatenate([a, b]))
    for ai, bi, ri in zip(a, b, r, strict=True):
        best = np.minimum(best, Capsule(ai, bi, float(ri)).ray_hit(o, d))
    del proj
    out = best.reshape(camera.shape)
    out[~np.isfinite(out)] = np.nan
    return out


def capsule_self_filter(
    camera: Camera, depth: np.ndarray, a: np.ndarray, b: np.ndarray, r: np.ndarray, tol: float = 0.02
) -> tuple[np.ndarray, np.ndarray]:
    robot_depth = capsule_depth(camera, a, b, r)
    d = np.asarray(depth, float)
    on_robot = np.isfinite(robot_depth)
    with np.errstate(invalid="ignore"):
        mask = on_robot & (~np.isfinite(d) | (d >= robot_depth - tol))
    return mask, robot_depth.astype(np.float32)
