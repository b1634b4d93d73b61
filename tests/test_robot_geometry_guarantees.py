"""The robot-geometry guarantees, attacked with property tests against independent computations.

Ground truth never comes from depthguard's geometry code: pinocchio reads the URDF (kinematics and the
collision objects, as coal shapes), coal measures distances, numpy ray casts the collision objects
(spheres, capsules, cylinders, boxes: analytic; meshes: Möller-Trumbore over every triangle), and finite
differences check Jacobians. The scenes are drawn at random: joint positions at and beyond the limits,
cameras far, near (within the margin of a link), inside the robot's bounding box and looking away, margins
down to 0, depth images with noise and every kind of missing reading (NaN, 0, inf, -inf, negative).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st

pin = pytest.importorskip("pinocchio")
coal = pytest.importorskip("coal")
pytest.importorskip("trimesh")

from depthguard.camera import Camera, look_at  # noqa: E402
from depthguard.robot.background import apply_background, background_threshold  # noqa: E402
from depthguard.robot.calibration import capsule_surface_points  # noqa: E402
from depthguard.robot.control_points import ControlPointSet, bounding_spheres  # noqa: E402
from depthguard.robot.hand_locate import foreground_mask, image_box  # noqa: E402
from depthguard.robot.inflation import is_closed, rounded_convex_mesh  # noqa: E402
from depthguard.robot.model import load_lwr4  # noqa: E402
from depthguard.robot.robots import load_robot, robot_data_dir, robot_urdf  # noqa: E402
from depthguard.robot.selffilter import ZNEAR, self_filter  # noqa: E402
from depthguard.robot.sensor_kinematics import SensorArray  # noqa: E402
from depthguard.robot.shapes import Shape  # noqa: E402
from depthguard.robot.spheres import cover_points, shape_cover  # noqa: E402
from depthguard.sensors.mount import SensorMount  # noqa: E402

_MODELS: dict[str, object] = {}
_TRUTHS: dict[str, GeometryTruth] = {}


def _model(name: str):
    if name not in _MODELS:
        _MODELS[name] = load_robot(name)
    return _MODELS[name]


# --------------------------------------------------------------------------------------- ground truth


def _seg_roots(a, b, c):
    """Roots of a t^2 + 2 b t + c = 0 per ray (NaN where none)."""
    disc = b * b - a * c
    with np.errstate(invalid="ignore", divide="ignore"):
        sq = np.sqrt(disc)
        return (-b - sq) / a, (-b + sq) / a


def _crossings(kind, geom, o, d):
    """(P, K) depths ``t`` at which the rays ``o + t d`` (object frame, o (P, 3) or (3,), d (P, 3)) cross the
    surface of one collision object (NaN padding)."""
    P = len(d)
    o = np.broadcast_to(np.asarray(o, float), (P, 3))

    def dot(a, b):
        return np.einsum("ij,ij->i", a, b)

    if kind == "sphere" or kind == "capsule":
        r = geom.radius
        h = geom.halfLength if kind == "capsule" else 0.0
        out = []
        for zc in (-h, h):  # end spheres
            oc = o - [0.0, 0.0, zc]
            t0, t1 = _seg_roots(dot(d, d), dot(d, oc), dot(oc, oc) - r * r)
            out += [t0, t1]
        if h > 0:
            a = d[:, 0] ** 2 + d[:, 1] ** 2
            t0, t1 = _seg_roots(a, d[:, 0] * o[:, 0] + d[:, 1] * o[:, 1], o[:, 0] ** 2 + o[:, 1] ** 2 - r * r)
            for t in (t0, t1):
                z = o[:, 2] + t * d[:, 2]
                out.append(np.where(np.abs(z) <= h, t, np.nan))
        T = np.stack(out, axis=1)
        # keep the crossings that lie on the capsule's surface (not inside its other parts)
        pts = o[:, None, :] + T[..., None] * d[:, None, :]
        zz = np.clip(pts[..., 2], -h, h)
        dist = np.sqrt(pts[..., 0] ** 2 + pts[..., 1] ** 2 + (pts[..., 2] - zz) ** 2)
        return np.where(np.abs(dist - r) < 1e-9 * max(1.0, r) + 1e-12, T, np.nan)
    if kind == "cylinder":
        r, h = geom.radius, geom.halfLength
        a = d[:, 0] ** 2 + d[:, 1] ** 2
        t0, t1 = _seg_roots(a, d[:, 0] * o[:, 0] + d[:, 1] * o[:, 1], o[:, 0] ** 2 + o[:, 1] ** 2 - r * r)
        out = [np.where(np.abs(o[:, 2] + t * d[:, 2]) <= h, t, np.nan) for t in (t0, t1)]
        with np.errstate(divide="ignore", invalid="ignore"):
            for zc in (-h, h):
                t = (zc - o[:, 2]) / d[:, 2]
                x, y = o[:, 0] + t * d[:, 0], o[:, 1] + t * d[:, 1]
                out.append(np.where(x * x + y * y <= r * r, t, np.nan))
        return np.stack(out, axis=1)
    if kind == "box":
        hs = np.asarray(geom.halfSide)
        out = []
        with np.errstate(divide="ignore", invalid="ignore"):
            for k in range(3):
                for s in (-1.0, 1.0):
                    t = (s * hs[k] - o[:, k]) / d[:, k]
                    p = o + t[:, None] * d
                    ok = np.all(np.abs(np.delete(p, k, axis=1)) <= np.delete(hs, k) + 1e-12, axis=1)
                    out.append(np.where(ok, t, np.nan))
        return np.stack(out, axis=1)
    V, F = geom  # a mesh: (V, 3), (F, 3); Möller-Trumbore against every triangle
    tri = V[F]
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    out = np.full((P, len(F)), np.nan)
    for s in range(0, P, 128):
        dd, oo = d[s : s + 128], o[s : s + 128]
        pv = np.cross(dd[:, None, :], e2[None])  # (p, F, 3)
        det = np.einsum("pfk,fk->pf", pv, e1)
        tv = oo[:, None, :] - tri[None, :, 0]  # (p, F, 3)
        qv = np.cross(tv, e1[None])
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / det
            u = np.einsum("pfk,pfk->pf", pv, tv) * inv
            v = np.einsum("pk,pfk->pf", dd, qv) * inv
            t = np.einsum("pfk,fk->pf", qv, e2) * inv
        ok = (np.abs(det) > 1e-15) & (u >= -1e-12) & (v >= -1e-12) & (u + v <= 1 + 1e-12)
        out[s : s + 128] = np.where(ok, t, np.nan)
    return out


class GeometryTruth:
    """The collision objects of a URDF as pinocchio and coal read them (independent of depthguard)."""

    def __init__(self, urdf: str) -> None:
        self.model = pin.buildModelFromUrdf(urdf)
        self.geom = pin.buildGeomFromUrdf(self.model, urdf, pin.COLLISION, package_dirs=[str(robot_data_dir().parent)])
        self.data = self.model.createData()
        self.gdata = pin.GeometryData(self.geom)
        self.kinds, self.shapes = [], []
        for obj in self.geom.geometryObjects:
            g = obj.geometry
            if isinstance(g, coal.BVHModelBase):
                V = np.asarray(g.vertices(), float) * np.asarray(obj.meshScale)
                F = np.array([[t[0], t[1], t[2]] for t in (g.tri_indices(k) for k in range(g.num_tris))])
                bvh = coal.BVHModelOBBRSS()
                bvh.beginModel(len(F), len(V))
                bvh.addVertices(V)
                bvh.addTriangles(F)
                bvh.endModel()
                self.kinds.append("mesh")
                self.shapes.append(((V, F), bvh))
            else:
                kind = {coal.Sphere: "sphere", coal.Capsule: "capsule", coal.Cylinder: "cylinder", coal.Box: "box"}
                self.kinds.append(kind[type(g)])
                self.shapes.append((g, g))

    def at(self, q: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        pin.forwardKinematics(self.model, self.data, q)
        pin.updateGeometryPlacements(self.model, self.data, self.geom, self.gdata)
        return [(np.array(M.rotation), np.array(M.translation)) for M in self.gdata.oMg]

    def depth(self, cam: Camera, q: np.ndarray, inside: bool = False):
        """(H, W) z_C of the first surface crossing in front of the camera (NaN: the ray misses), and with
        ``inside`` also the number of crossings of each object (to test whether a point lies inside)."""
        dirs = cam.pixel_ray_directions().reshape(-1, 3) @ cam.R  # world, scaled so that z_C = t
        best = np.full(len(dirs), np.inf)
        for (R, p), kind, (g, _) in zip(self.at(q), self.kinds, self.shapes, strict=True):
            T = _crossings(kind, g, R.T @ (cam.position - p), dirs @ R)
            T = np.where(T > 0, T, np.inf)
            best = np.minimum(best, np.min(T, axis=1, initial=np.inf))
        return np.where(np.isfinite(best), best, np.nan).reshape(cam.shape)

    def inside(self, q: np.ndarray, pts: np.ndarray) -> np.ndarray:
        """(P,) bool: the point lies inside a collision object (parity of crossings along a fixed ray)."""
        d = np.array([0.5377, -0.3259, 0.7773])
        out = np.zeros(len(pts), bool)
        for (R, p), kind, (g, _) in zip(self.at(q), self.kinds, self.shapes, strict=True):
            T = _crossings(kind, g, (pts - p) @ R, np.tile(R.T @ d, (len(pts), 1)))
            T = np.sort(np.where(np.isfinite(T) & (T > 0), T, np.inf), axis=1)
            # (a crossing on an edge of two triangles counts once)
            with np.errstate(invalid="ignore"):
                n = np.sum(np.isfinite(T) & (np.diff(T, axis=1, prepend=-1.0) > 1e-12), axis=1)
            out |= n % 2 == 1
        return out

    def distance(self, q: np.ndarray, pts: np.ndarray) -> np.ndarray:
        """(P,) distance (m) from each point to the robot's solid collision geometry (0 inside)."""
        poses = self.at(q)
        dot, req, res = coal.Sphere(0.0), coal.DistanceRequest(), coal.DistanceResult()
        out = np.full(len(pts), np.inf)
        for (R, p), (_, cg) in zip(poses, self.shapes, strict=True):
            M = coal.Transform3s(R, p)
            for k, x in enumerate(pts):
                res.clear()
                out[k] = min(out[k], coal.distance(cg, M, dot, coal.Transform3s(np.eye(3), x), req, res))
        out = np.maximum(out, 0.0)
        pos = out > 0
        if pos.any():
            out[np.flatnonzero(pos)[self.inside(q, pts[pos])]] = 0.0
        return out


def _truth(name: str) -> GeometryTruth:
    if name not in _TRUTHS:
        _TRUTHS[name] = GeometryTruth(str(robot_urdf(name)))
    return _TRUTHS[name]


# ------------------------------------------------------------------------------------------- scenes


def _random_q(model, rng, beyond: float) -> np.ndarray:
    """Joint positions: inside the limits, exactly at them, or up to ``beyond`` past them."""
    lo, hi = np.maximum(model.q_min, -np.pi), np.minimum(model.q_max, np.pi)
    q = rng.uniform(lo, hi)
    at = rng.uniform(size=len(q))
    q = np.where(at < 0.15, model.q_min, np.where(at < 0.3, model.q_max, q))
    return q + rng.uniform(-beyond, beyond, len(q)) * (rng.uniform(size=len(q)) < 0.3)


def _random_camera(truth: GeometryTruth, q: np.ndarray, rng, mode: str, margin: float = 0.03) -> Camera:
    """A 48x36 camera: ``far`` (1-2.5 m around the robot), ``near`` (0.3-15 cm off a collision object's
    surface, half the time within ``margin`` of it, looking at it or anywhere), ``shell`` (within ``margin``
    of it, looking at it), ``graze`` (``margin`` -1 to +2 mm off it, about the inflated shell and the near
    plane, looking at it), ``box`` (inside the robot's
    bounding box), ``away`` (turned away)."""
    poses = truth.at(q)
    centres = np.array([p for _, p in poses])
    lo, hi = centres.min(axis=0) - 0.1, centres.max(axis=0) + 0.1
    target = centres[rng.integers(len(centres))]
    if mode == "far":
        u = rng.normal(size=3)
        eye = target + rng.uniform(1.0, 2.5) * u / np.linalg.norm(u)
        look = target + rng.normal(scale=0.1, size=3)
    elif mode in ("near", "shell", "graze"):
        k = int(rng.integers(len(poses)))
        u = rng.normal(size=3)
        u /= np.linalg.norm(u)
        # from the object's centre outward until the point is the wanted distance off the geometry
        start = poses[k][1]
        gap = rng.uniform(0.003, 0.15) if mode == "near" and rng.uniform() < 0.5 else rng.uniform(0.1, 0.9) * margin
        if mode == "graze":  # about the inflated shell: up to 1 mm inside it, up to 2 mm outside
            gap = max(margin + rng.uniform(-1e-3, 2e-3), 2e-4)
        ts = np.linspace(0.0, 0.6, 301)
        dist = truth.distance(q, start + ts[:, None] * u)
        first = ts[np.argmax(dist >= gap)] if np.any(dist >= gap) else 0.6
        if mode == "graze" and 0.0 < first < 0.6:  # to 1 µm: the steps above are 2 mm
            a, b = first - ts[1], first
            while b - a > 1e-6:
                mid = 0.5 * (a + b)
                a, b = (mid, b) if truth.distance(q, (start + mid * u)[None])[0] < gap else (a, mid)
            first = b
        eye = start + first * u
        look = (
            eye + rng.normal(size=3)
            if mode == "near" and rng.uniform() < 0.3
            else start + rng.normal(scale=0.05, size=3)
        )
    elif mode == "box":
        eye = rng.uniform(lo, hi)
        look = eye + rng.normal(size=3)
    else:  # away
        u = rng.normal(size=3)
        eye = target + rng.uniform(0.2, 1.5) * u / np.linalg.norm(u)
        look = eye + u + 0.3 * rng.normal(size=3)
    up = np.array([0.0, 0.0, 1.0]) if rng.uniform() < 0.8 else rng.normal(size=3)
    d = look - eye
    assume(np.linalg.norm(d) > 1e-6 and np.linalg.norm(np.cross(d, up)) > 1e-3 * np.linalg.norm(d) * np.linalg.norm(up))
    R, t = look_at(eye, look, up)
    return Camera(width=48, height=36, fx=36.0, fy=36.0, cx=24.0, cy=18.0, R=R, t=t, min_depth=0.01, max_depth=10.0)


def _pixel_points(cam: Camera, depth: np.ndarray) -> np.ndarray:
    return cam.unproject_image(np.where(np.isfinite(depth), depth, 0.0))


JUNK = (np.nan, 0.0, np.inf, -np.inf, -0.5)


def _check_self_filter(
    name: str, seed: int, mode: str, margin: float, noise: float, tol, exact_from: float = 1e-9
) -> None:
    """The self-filter's documented guarantees in one random scene (module docstring of selffilter);
    ``exact_from``: the least margin at which exactly read robot pixels must all go (below it, the drawn
    surface is the robot's own, and the last bit decides)."""
    model = _model(name)
    truth = _truth(name)
    rng = np.random.default_rng(seed)
    q = _random_q(model, rng, beyond=1.0)
    cam = _random_camera(truth, q, rng, mode, margin)
    assume(truth.distance(q, cam.position[None])[0] > 1e-3)  # (a camera inside the robot sees nothing real)
    exact = truth.depth(cam, q)
    robot = np.isfinite(exact)
    # the scene: a wall far behind everything, the robot's exact depth, noise, holes of every kind
    measured = np.where(robot, exact, rng.uniform(3.0, 6.0, cam.shape))
    noisy = rng.uniform(size=cam.shape) < 0.3
    measured = np.where(noisy, measured + rng.normal(scale=noise, size=cam.shape), measured)
    junk = rng.uniform(size=cam.shape) < 0.15
    measured[junk] = rng.choice(JUNK, size=int(junk.sum()))
    res = self_filter(cam, measured, q, model, margin=margin)
    valid = np.isfinite(measured) & (measured > 0)
    pts = _pixel_points(cam, measured)
    tol_out = tol(margin)
    # 1. every robot pixel read exactly (no noise) is removed (with a margin: at margin 0 the surface depth
    #    itself decides, to the last bit of two ways of computing it)
    exact_robot = robot & valid & ~noisy & (margin >= exact_from)
    assert np.all(res.mask[exact_robot]), ("robot pixels left", int(np.sum(exact_robot & ~res.mask)), cam.position)
    # 2. every removed reading lies within the margin of the robot (+ the documented tolerance)
    removed = res.mask & valid
    d_removed = truth.distance(q, pts[removed])
    assert np.all(d_removed <= margin + tol_out), ("removed beyond the margin", d_removed.max(), margin)
    # 3. noisy robot readings within half the margin of the robot are removed
    near = robot & valid & noisy
    if near.any() and margin >= exact_from:
        d_near = truth.distance(q, pts[near])
        assert np.all(res.mask[near][d_near <= 0.5 * margin - 1e-6]), ("noisy robot pixel left", margin)
    # 4. a pixel without a reading whose ray meets the robot is robot
    assert np.all(res.mask[robot & ~valid])
    # 5. robot_depth: finite exactly at the inflated silhouette, never behind the robot, and its point lies
    #    within the margin of the robot; a pixel without a reading is robot there and only there
    rd = res.robot_depth
    sil = np.isfinite(rd)
    assert np.all(sil[robot]) and np.all(rd[robot] <= exact[robot] + 1e-9)
    assert np.array_equal(res.mask & ~valid, sil & ~valid)
    assert not np.any(res.mask & ~sil)
    d_rd = truth.distance(q, _pixel_points(cam, np.where(sil, rd, np.nan))[sil])
    assert np.all(d_rd <= margin + tol_out + 1e-3 * np.sqrt(2)), ("robot depth beyond the margin", d_rd.max())


# (r + margin) (1 / cos(pi / 24) - 1): the LWR's base cylinder is drawn as the 24-gon prism around it
def _lwr_tol(margin: float) -> float:
    return (0.075 + margin) * (1.0 / np.cos(np.pi / 24) - 1.0) + 1e-9


def _panda_tol(margin: float) -> float:
    # a convex mesh is drawn as its hull, whose excess over the mesh (<= 0.41 mm on the Panda) is taken off
    # the margin; with a margin below it the hull itself is drawn
    return max(float(_model("panda").geometry.excess.max()) - margin, 0.0) + 1e-7


@settings(deadline=None, max_examples=10)
@given(
    seed=st.integers(0, 2**31 - 1),
    mode=st.sampled_from(["far", "near", "near", "box", "away"]),
    margin=st.one_of(st.just(0.0), st.floats(0.0, 0.08)),
    noise=st.floats(0.0, 0.05),
)
def test_lwr_self_filter_guarantees(seed, mode, margin, noise) -> None:
    _check_self_filter("lwr4", seed, mode, margin, noise, _lwr_tol)


@settings(deadline=None, max_examples=6)
@given(
    seed=st.integers(0, 2**31 - 1),
    mode=st.sampled_from(["far", "near", "near", "box", "away"]),
    margin=st.one_of(st.just(0.0), st.floats(0.0, 0.08)),
    noise=st.floats(0.0, 0.05),
)
@example(seed=0, mode="far", margin=2.02e-06, noise=0.0)  # (a margin below the hull's excess: fresh seeds)
def test_panda_self_filter_guarantees(seed, mode, margin, noise) -> None:
    _check_self_filter("panda", seed, mode, margin, noise, _panda_tol, _panda_exact_from())


def _panda_exact_from() -> float:
    # below the hull's excess over the mesh the hull itself is drawn, and a robot pixel on a face the mesh
    # shares with its hull lies on the drawn surface (seed 0, far, margin 2e-6: 21 such pixels kept)
    return float(_model("panda").geometry.excess.max()) + 1e-5


def _shape_beside_the_camera(kind: str, gap: float, askew: list) -> tuple:
    """The LWR with a box or a cylinder (drawn as a mesh) attached to its base at (1.5, 0, 0.6) m, and 48x36
    cameras ``gap`` m off the shape's +x face, looking at the shape and along each ``askew`` offset from the
    eye: ``(model, [(camera, exact depth of the shape's first crossing, inf where the ray misses)])``."""
    model = load_lwr4()
    centre = np.array([1.5, 0.0, 0.6])
    if kind == "box":
        size = (0.2, 0.12, 0.16)
        obj, face = coal.Box(*size), 0.1
    else:
        size = (0.08, 0.3)
        obj, face = coal.Cylinder(*size), 0.08
    model.attach(Shape(link="lwr_link_0", kind=kind, size=size, xyz=tuple(centre)))  # the base: world frame
    eye = centre + np.array([face + gap, 0.0, 0.0])
    views = []
    for target in [centre + [0.0, 0.01, 0.0]] + [eye + np.asarray(a) for a in askew]:
        R, t = look_at(eye, target)
        cam = Camera(width=48, height=36, fx=30.0, fy=30.0, cx=24.0, cy=18.0, R=R, t=t, min_depth=0.01)
        dirs = cam.pixel_ray_directions().reshape(-1, 3) @ cam.R
        T = _crossings(kind, obj, eye - centre, dirs)
        views.append((cam, np.min(np.where(T > 0, T, np.inf), axis=1).reshape(cam.shape)))
    return model, views


@pytest.mark.parametrize("kind", ["box", "cylinder"])
@pytest.mark.parametrize("gap", [0.005, 0.02])
def test_camera_within_the_margin_of_a_mesh_still_removes_it(kind, gap) -> None:
    """A camera 0.5-2 cm off a box or a cylinder (drawn as meshes) sits inside their inflated shell: every
    ray starts inside it and crosses only the surface where it leaves. The robot's surface in front of
    that exit must still go, and ``robot_depth`` must not lie behind it (found by the property tests
    above: the mesh rasteriser took the exit for the near side and kept every robot pixel, while a
    capsule in the same place was removed)."""
    model, views = _shape_beside_the_camera(kind, gap, [[-0.3, 0.4, 0.2]])  # at the shape, and askew
    for cam, first in views:
        robot = np.isfinite(first)
        assert robot.sum() > 100
        for margin in (0.03, 2.0 * gap + 2e-3):  # (a prism's side edges move out by margin / sqrt(2))
            res = self_filter(cam, np.where(robot, first, 5.0), np.zeros(7), model, margin=margin)
            assert np.all(res.mask[robot]), int(np.sum(robot & ~res.mask))
            assert np.all(res.robot_depth[robot] <= first[robot])
        far = self_filter(cam, np.where(robot, first, 5.0), np.zeros(7), model, margin=0.5 * gap)
        assert np.all(far.mask[robot]) and np.all(far.robot_depth[robot] > 0)  # the camera outside: as before


@pytest.mark.parametrize("kind", ["box", "cylinder"])
@pytest.mark.parametrize("outside_by", [0.1 * ZNEAR, 0.5 * ZNEAR, 0.95 * ZNEAR])
def test_camera_just_outside_the_inflated_shape_still_removes_it(kind, outside_by) -> None:
    """A camera outside the inflated shell but nearer to it than the near plane (``ZNEAR``, 1 mm): rays that
    enter the shell before the plane lost their entry with the clipped triangles, and the robot's surface
    between the plane and their exit was kept (the documented limit of stop 46; the Panda case had the
    camera 0.19 mm out). The near plane's cross-section of the shape now counts as its near side."""
    gap = 0.005
    margin = gap - outside_by  # (the side facets move out by exactly the margin)
    model, views = _shape_beside_the_camera(kind, gap, [[-0.3, 0.25, 0.1], [-0.3, -0.1, -0.35]])
    for cam, first in views:
        robot = np.isfinite(first)
        assert robot.sum() > 100
        measured = np.where(robot, first, 5.0)
        res = self_filter(cam, measured, np.zeros(7), model, margin=margin)
        assert np.all(res.mask[robot]), int(np.sum(robot & ~res.mask))
        assert np.all(res.robot_depth[robot] <= first[robot])
        assert not np.any(res.mask[~robot])  # the wall behind stays


# ------------------------------------------------------------------------------------------- kinematics


@settings(deadline=None, max_examples=8)
@given(seed=st.integers(0, 2**31 - 1), name=st.sampled_from(["lwr4", "panda"]))
def test_kinematics_match_pinocchio_and_finite_differences_at_and_beyond_the_limits(seed, name) -> None:
    """Joint poses, frame poses, point Jacobians, control points and sensors at any q (the limits are not
    the kinematics' business): against pinocchio and central differences."""
    model = _model(name)
    rng = np.random.default_rng(seed)
    q = _random_q(model, rng, beyond=2.0 * np.pi)
    data = model.model.createData()
    pin.computeJointJacobians(model.model, data, q)
    pin.updateFramePlacements(model.model, data)
    H, Jw = model.joint_kinematics(q)
    np.testing.assert_allclose(H, np.array([M.homogeneous for M in data.oMi]), atol=1e-12)
    np.testing.assert_allclose(Jw, np.array(data.J), atol=1e-12)
    frame = model.model.frames[int(rng.integers(1, model.model.nframes))].name
    point = rng.normal(scale=0.2, size=3)
    R, p = model.frame_pose(q, frame)
    M = data.oMf[model.frame_id(frame)]
    np.testing.assert_allclose(R, M.rotation, atol=1e-12)
    np.testing.assert_allclose(p, M.translation, atol=1e-12)
    x, J = model.point_jacobian(q, frame, point)
    np.testing.assert_allclose(x, M.rotation @ point + M.translation, atol=1e-12)
    cps = ControlPointSet.build(model, "auto") if name == "panda" else ControlPointSet.build(model, "ral-9")
    mount = SensorMount("s", frame, tuple(point), (0.0, 0.0, 1.0), 1.0)
    sensors = SensorArray(model, [mount])
    state, sens = cps.evaluate(q), sensors.evaluate(q)
    np.testing.assert_allclose(sens.positions[0], x, atol=1e-12)
    np.testing.assert_allclose(sens.axes[0], M.rotation[:, 2], atol=1e-12)
    h = 1e-6
    for i in range(model.n_dof):
        dq = np.zeros(model.n_dof)
        dq[i] = h
        fd = (model.point_jacobian(q + dq, frame, point)[0] - model.point_jacobian(q - dq, frame, point)[0]) / (2 * h)
        np.testing.assert_allclose(J[:, i], fd, atol=1e-7)
        np.testing.assert_allclose(sens.jacobians[0][:, i], fd, atol=1e-7)
        fd_c = (cps.evaluate(q + dq).centres - cps.evaluate(q - dq).centres) / (2 * h)
        np.testing.assert_allclose(state.jacobians[:, :, i], fd_c, atol=1e-7)


@pytest.mark.parametrize(
    "bad", [np.zeros(6), np.zeros(8), np.zeros((7, 1)), np.zeros((1, 7)), np.full(7, np.nan), [0] * 6 + [np.inf],
            "0000000", None, [[0.0]] * 7],
)  # fmt: skip
def test_bad_joint_positions_raise_value_errors_naming_q(bad) -> None:
    model = _model("lwr4")
    cam = Camera(width=8, height=6, fx=8.0, fy=8.0, cx=4.0, cy=3.0, R=np.eye(3), t=np.array([0.0, 0.0, 2.0]))
    cps = ControlPointSet.build(model, "ral-9")
    sensors = SensorArray(model, [SensorMount("s", "lwr_link_3", (0.0, 0.0, 0.1), (1.0, 0.0, 0.0), 1.0)])
    from depthguard.robot.interior import interior_capsules

    calls = [
        lambda: self_filter(cam, np.zeros(cam.shape), bad, model),
        lambda: cps.evaluate(bad),
        lambda: sensors.evaluate(bad),
        lambda: interior_capsules(model, bad),
        lambda: model.frame_pose(bad),
        lambda: model.link_capsules(bad),
    ]
    for call in calls:
        with pytest.raises(ValueError, match=r"\bq\b"):
            call()


# ------------------------------------------------------------------------------------------- spheres


def _capsule_surface(a, b, r, n, rng):
    """Random points on the surface of the capsule a-b (radius r) and on its axis' ends' rims."""
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    t = rng.uniform(0.0, 1.0, n)
    t[: n // 4] = np.round(t[: n // 4])  # the end caps
    base = a + t[:, None] * (b - a)
    ax = b - a
    L = np.linalg.norm(ax)
    if L > 0:  # on the cylinder: directions perpendicular to the axis, except at the caps
        ax = ax / L
        perp = u - (u @ ax)[:, None] * ax
        side = np.linalg.norm(perp, axis=1) > 1e-9
        mid = (t > 0) & (t < 1) & side
        u[mid] = perp[mid] / np.linalg.norm(perp[mid], axis=1, keepdims=True)
        caps = ~mid
        u[caps] *= np.where(((u[caps] @ ax) * (2 * t[caps] - 1)) < 0, -1.0, 1.0)[:, None]
    return base + r * u


def _outside(pts, centres, radii):
    """(P,) how far each point lies outside the union of the spheres (<= 0: covered)."""
    return np.min(np.linalg.norm(pts[:, None] - centres[None], axis=2) - radii[None], axis=1)


@settings(deadline=None, max_examples=10)
@given(seed=st.integers(0, 2**31 - 1), preset=st.sampled_from(["ral-9", "icra-exp3", "auto"]))
def test_control_spheres_cover_the_links_and_bound_their_distances(seed, preset) -> None:
    """Each covered link's real collision geometry (pinocchio/coal: the LWR's cylinders and spheres) lies in
    the union of its spheres, so the distance from the spheres never exceeds the distance from the link."""
    model = _model("lwr4")
    truth = _truth("lwr4")
    rng = np.random.default_rng(seed)
    q = _random_q(model, rng, beyond=2.0)
    state = ControlPointSet.build(model, preset).evaluate(q)
    poses = truth.at(q)
    for link in {n.split("/")[0] for n in state.names[1:]}:
        idx = [i for i, n in enumerate(state.names) if n.startswith(link + "/")]
        c, r = state.centres[idx], state.radii[idx]
        objs = [k for k, o in enumerate(truth.geom.geometryObjects) if truth.model.frames[o.parentFrame].name == link]
        assert objs
        pts = []
        for k in objs:
            (R, p), g = poses[k], truth.shapes[k][0]
            h = g.halfLength if truth.kinds[k] == "cylinder" else 0.0
            local = _capsule_surface(np.array([0, 0, -h]), np.array([0, 0, h]), g.radius, 400, rng)
            if h > 0:  # the cylinder itself: its rims and flat ends too
                ang = rng.uniform(0, 2 * np.pi, 200)
                rim = np.c_[g.radius * np.cos(ang), g.radius * np.sin(ang), rng.choice([-h, h], 200)]
                disc = np.sqrt(rng.uniform(0, 1, 200))[:, None] * [1.0, 1.0, 0.0] + [0.0, 0.0, 1.0]
                local = np.vstack([local, rim, rim * disc])
            pts.append(local @ R.T + p)
        pts = np.vstack(pts)
        assert np.all(_outside(pts, c, r) <= 1e-9), (link, _outside(pts, c, r).max())
        x = pts.mean(axis=0) + rng.normal(scale=0.4, size=(40, 3))  # obstacle points
        dot, req, res = coal.Sphere(0.0), coal.DistanceRequest(), coal.DistanceResult()
        for xi in x:
            d_link = min(
                coal.distance(truth.shapes[k][1], coal.Transform3s(*poses[k]), dot, coal.Transform3s(np.eye(3), xi),
                              req, res)
                for k in objs
            )  # fmt: skip
            assert np.min(np.linalg.norm(c - xi, axis=1) - r) <= max(d_link, 0.0) + 1e-9


_SHAPES = st.fixed_dictionaries(
    {
        "kind": st.sampled_from(["box", "cylinder", "capsule", "sphere"]),
        "dims": st.lists(st.floats(0.005, 0.5), min_size=3, max_size=3),
        "xyz": st.lists(st.floats(-0.3, 0.3), min_size=3, max_size=3),
        "rpy": st.lists(st.floats(-3.2, 3.2), min_size=3, max_size=3),
    }
)


def _shape(d, link: str) -> Shape:
    n = {"box": 3, "cylinder": 2, "capsule": 2, "sphere": 1}[d["kind"]]
    return Shape(link=link, kind=d["kind"], size=tuple(d["dims"][:n]), xyz=tuple(d["xyz"]), rpy=tuple(d["rpy"]))


def _shape_surface(s: Shape, rng, n: int = 600) -> np.ndarray:
    """Random points on the surface of a primitive shape (and every box corner), link frame."""
    if s.kind == "box":
        h = 0.5 * np.asarray(s.size)
        p = rng.uniform(-1, 1, (n, 3))
        k = rng.integers(0, 3, n)
        p[np.arange(n), k] = np.sign(p[np.arange(n), k])
        corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
        local = np.vstack([p, corners]) * h
    elif s.kind == "cylinder":
        r, h = s.size[0], 0.5 * s.size[1]
        ang = rng.uniform(0, 2 * np.pi, n)
        rad = np.where(rng.uniform(size=n) < 0.5, r, r * np.sqrt(rng.uniform(size=n)))
        z = np.where(rad < r, rng.choice([-h, h], n), rng.uniform(-h, h, n))
        z[: n // 10] = rng.choice([-h, h], n // 10)  # the rims
        local = np.c_[rad * np.cos(ang), rad * np.sin(ang), z]
    else:
        h = 0.5 * s.size[1] if s.kind == "capsule" else 0.0
        local = _capsule_surface(np.array([0, 0, -h]), np.array([0, 0, h]), s.size[0], n, rng)
    return local @ s.rotation.T + np.asarray(s.xyz)


@settings(deadline=None, max_examples=40)
@given(shape=_SHAPES, k=st.integers(1, 6), seed=st.integers(0, 2**31 - 1))
def test_shape_cover_contains_the_whole_solid(shape, k, seed) -> None:
    s = _shape(shape, "lwr_link_7")
    c, r = shape_cover(s, max_spheres=k)
    assert 1 <= len(r) <= k and np.all(np.isfinite(c)) and np.all(r > 0)
    pts = _shape_surface(s, np.random.default_rng(seed))
    assert np.all(_outside(pts, c, r) <= 1e-9 * max(1.0, r.max())), _outside(pts, c, r).max()


@settings(deadline=None, max_examples=6)
@given(shapes=st.lists(_SHAPES, min_size=1, max_size=3), k=st.integers(1, 4), length=st.floats(0.02, 0.5),
       seed=st.integers(0, 2**31 - 1))  # fmt: skip
def test_auto_spheres_cover_attached_tools(shapes, k, length, seed) -> None:
    """``auto`` control points built after attaching random boxes, cylinders, capsules and spheres to the
    flange contain every point of their surfaces (analytic samples), at any q."""
    model = load_lwr4()
    attached = [_shape(d, "lwr_link_7") for d in shapes]
    model.attach(*attached)
    cps = ControlPointSet.build(model, "auto", auto_spheres=k, auto_length=length)
    rng = np.random.default_rng(seed)
    q = _random_q(model, rng, beyond=1.0)
    st_ = cps.evaluate(q)
    idx = [i for i, n in enumerate(st_.names) if n.startswith("lwr_link_7/")]
    assert 1 <= len(idx) <= k
    R, p = model.frame_pose(q, "lwr_link_7")
    pts = np.vstack([_shape_surface(s, rng) for s in attached]) @ R.T + p
    out = _outside(pts, st_.centres[idx], st_.radii[idx])
    assert np.all(out <= 1e-9), out.max()


@settings(deadline=None, max_examples=40)
@given(
    n=st.integers(1, 60), k=st.integers(1, 8), seed=st.integers(0, 2**31 - 1),
    flat=st.sampled_from(["none", "same", "line", "plane"]), balls=st.booleans(),
)  # fmt: skip
def test_cover_points_contains_every_point_and_ball(n, k, seed, flat, balls) -> None:
    """Degenerate sets too: one point repeated, points on a line or in a plane, with and without balls."""
    rng = np.random.default_rng(seed)
    p = rng.normal(scale=0.2, size=(n, 3))
    if flat == "same":
        p[:] = p[0]
    elif flat == "line":
        p = p[:, :1] * np.array([[0.3, -0.5, 0.8]])
    elif flat == "plane":
        p[:, 2] = 0.1
    w = rng.uniform(0.0, 0.05, n) if balls else None
    c, r = cover_points(p, k, radii=w)
    assert 1 <= len(r) <= k
    reach = np.linalg.norm(p[:, None] - c[None], axis=2) + (0.0 if w is None else w[:, None]) - r[None]
    assert np.all(reach.min(axis=1) <= 1e-12)


@settings(deadline=None, max_examples=30)
@given(L=st.floats(0.0, 1.0), r=st.floats(0.0, 0.2), k=st.integers(1, 8), seed=st.integers(0, 2**31 - 1))
def test_bounding_spheres_hold_the_capsule_s_hardest_points(L, r, k, seed) -> None:
    """The points of a capsule farthest from every sphere: on its surface midway between two centres, and
    the tips of the end caps (radius 0 and length 0 included)."""
    rng = np.random.default_rng(seed)
    a = rng.normal(size=3)
    ax = rng.normal(size=3)
    ax /= np.linalg.norm(ax)
    b = a + L * ax
    c, rad = bounding_spheres(a, b, r, k)
    perp = np.cross(ax, rng.normal(size=3))
    perp /= np.linalg.norm(perp)
    t = np.r_[np.linspace(0, 1, 4 * k + 1), (np.arange(k - 1) + 0.5) / max(k - 1, 1)]
    pts = np.vstack([a + t[:, None] * (b - a) + r * perp, a - r * ax, b + r * ax])
    assert np.all(_outside(pts, c, rad) <= 1e-12)


# ------------------------------------------------------------------------------------ inflation


@settings(deadline=None, max_examples=12)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(4, 30), margin=st.floats(0.001, 0.1))
def test_rounded_convex_mesh_lies_within_the_margin_and_holds_93_percent_of_it(seed, n, margin) -> None:
    """The inflated hull is a closed, outward, convex mesh; nothing of it lies farther than ``margin`` from
    the hull (its vertices: 0.934-1 ``margin``, distances by coal), and it contains every point within 0.93
    ``margin`` of the hull in every direction."""
    from scipy.spatial import ConvexHull

    rng = np.random.default_rng(seed)
    pts = rng.uniform(-0.1, 0.1, (n, 3)) * rng.uniform(0.2, 1.5, 3)
    hull = ConvexHull(pts)
    V, O, F = rounded_convex_mesh(pts)
    X = V + margin * O
    assert is_closed(F)
    tri = X[F]
    vol = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0
    big = ConvexHull(X)
    assert vol == pytest.approx(big.volume, rel=1e-9)  # outward wound, and it is its own hull: convex

    def dist_to_hull(x):  # points outside the hull: their distance to its surface (coal, its triangles)
        bvh = coal.BVHModelOBBRSS()
        bvh.beginModel(len(hull.simplices), len(pts))
        bvh.addVertices(np.ascontiguousarray(pts))
        bvh.addTriangles(np.ascontiguousarray(hull.simplices, dtype=np.int64))
        bvh.endModel()
        dot, req, res = coal.Sphere(0.0), coal.DistanceRequest(), coal.DistanceResult()
        eye = coal.Transform3s()
        return np.array([coal.distance(bvh, eye, dot, coal.Transform3s(np.eye(3), y), req, res) for y in x])

    d_v = np.max(hull.equations[:, :3] @ X.T + hull.equations[:, 3:], axis=0)  # a lower bound of the distance
    assert np.all(d_v <= margin * (1 + 1e-9))  # never farther than the margin along any facet normal
    sample = X[rng.choice(len(X), min(len(X), 40), replace=False)]
    # every vertex lies on the sum's surface: between 0.934 margin (the ball's inradius) and the margin off the
    # hull (not exactly the margin: a ring direction need not be normal to the hull at its corner)
    d_s = dist_to_hull(sample)
    assert np.all(d_s <= margin * (1 + 1e-9) + 1e-12) and np.all(d_s >= 0.934 * margin - 1e-9), d_s
    # points 0.93 margin off the hull, in every direction (faces, edges, corners) are inside
    u = rng.normal(size=(300, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    support = pts[np.argmax(u @ pts.T, axis=1)]  # the hull's farthest vertex along u: x = it + 0.93 m u
    x = support + 0.93 * margin * u  # (its distance to the hull is at most 0.93 m)
    assert np.all(big.equations[:, :3] @ x.T + big.equations[:, 3:] <= 1e-12)


# ---------------------------------------------------------------------- hands, background, calibration


@settings(deadline=None, max_examples=40)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 4), behind=st.booleans())
def test_image_box_holds_every_pixel_of_the_grown_spheres(seed, n, behind) -> None:
    """Every point of every sphere grown by ``reach`` that lies in front of the camera lands in a pixel of
    the box (u0 <= u < u1, v0 <= v < v1); None only when none does; the whole image when one reaches
    behind the camera."""
    rng = np.random.default_rng(seed)
    cam = Camera(width=64, height=48, fx=50.0, fy=45.0, cx=31.3, cy=24.6, R=np.eye(3), t=np.zeros(3))
    centres = np.c_[rng.uniform(-2, 2, (n, 2)), rng.uniform(0.05 if behind else 0.3, 3.0, n)]
    reach = rng.uniform(0.01, 0.3, n)
    box = image_box(cam, centres, reach)
    u = rng.normal(size=(n, 4000, 3))
    u /= np.linalg.norm(u, axis=2, keepdims=True)
    pts = (centres[:, None] + reach[:, None, None] * u * rng.uniform(0, 1, (n, 4000, 1)) ** 0.3).reshape(-1, 3)
    pts = pts[pts[:, 2] > 1e-6]
    px = cam.project(pts)
    uu, vv = np.floor(px[:, 0]), np.floor(px[:, 1])
    seen = (uu >= 0) & (uu < cam.width) & (vv >= 0) & (vv < cam.height)
    if np.any(centres[:, 2] - reach <= 1e-3):
        assert box == (0, cam.width, 0, cam.height)
        return
    if box is None:
        assert not seen.any()
        return
    u0, u1, v0, v1 = box
    assert np.all((uu[seen] >= u0) & (uu[seen] < u1) & (vv[seen] >= v0) & (vv[seen] < v1))


@settings(deadline=None, max_examples=25)
@given(
    seed=st.integers(0, 2**31 - 1), erode=st.booleans(), dtype=st.sampled_from([np.float32, np.float64]),
    margin_kind=st.sampled_from(["float", "int", "np32", "np64", "image"]), boxed=st.booleans(),
)  # fmt: skip
def test_foreground_mask_is_its_documented_rule(seed, erode, dtype, margin_kind, boxed) -> None:
    """``d < b - margin`` where both read (a background without reading admits any reading), robot and
    missing pixels excluded, then a 4-neighbour erosion: written out here in plain numpy."""
    rng = np.random.default_rng(seed)
    H, W = 20, 24
    bg = rng.uniform(1.0, 3.0, (H, W)).astype(dtype)
    bg[rng.uniform(size=(H, W)) < 0.1] = rng.choice([np.nan, 0.0, np.inf])
    d = (bg - rng.uniform(-0.2, 0.6, (H, W))).astype(dtype)
    d[rng.uniform(size=(H, W)) < 0.5] = rng.uniform(0.5, 2.0)  # blobs of foreground
    d[rng.uniform(size=(H, W)) < 0.1] = rng.choice([np.nan, 0.0, np.inf, -1.0])
    robot = rng.uniform(size=(H, W)) < 0.1
    m = rng.uniform(0.0, 0.1)
    margin = {"float": m, "int": 0, "np32": np.float32(m), "np64": np.float64(m),
              "image": rng.uniform(0.0, 0.1, (H, W)).astype(dtype)}[margin_kind]  # fmt: skip
    box = (3, 19, 2, 17) if boxed else None
    got = foreground_mask(d, bg, robot, margin, erode=erode, box=box)
    d64, b64 = d.astype(np.float64), bg.astype(np.float64)
    b_ok = np.isfinite(b64) & (b64 > 0)
    with np.errstate(invalid="ignore"):
        thr = np.where(b_ok, (b64 - np.asarray(margin, np.float64)), np.inf)
        fg = np.isfinite(d64) & (d64 > 0) & (d64 < thr) & ~robot
    # (the comparison in float32 may round differently within an ulp of the threshold: skip those pixels)
    with np.errstate(invalid="ignore"):
        edge = np.abs(d64 - thr) <= 4 * np.finfo(np.float32).eps * np.maximum(np.abs(thr), 1.0)
    u0, u1, v0, v1 = box if box else (0, W, 0, H)
    crop = fg[v0:v1, u0:u1]  # a box: the window alone is computed (and eroded), the rest is False
    if erode:
        e = crop.copy()
        e[1:] &= crop[:-1]
        e[:-1] &= crop[1:]
        e[:, 1:] &= crop[:, :-1]
        e[:, :-1] &= crop[:, 1:]
        crop = e
    fg = np.zeros((H, W), bool)
    fg[v0:v1, u0:u1] = crop
    grown = edge.copy()
    for sh in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        grown |= np.roll(edge, sh, axis=(0, 1))
    assert got.shape == (H, W) and got.dtype == bool
    assert np.array_equal(got & ~grown, fg & ~grown)


@settings(deadline=None, max_examples=30)
@given(seed=st.integers(0, 2**31 - 1), dtype=st.sampled_from([np.float32, np.float64]))
def test_apply_background_keeps_nan_robot_and_nearer_pixels(seed, dtype) -> None:
    rng = np.random.default_rng(seed)
    b = rng.uniform(0.5, 4.0, (12, 16))
    b[rng.uniform(size=b.shape) < 0.2] = rng.choice([np.nan, np.inf])
    thr = background_threshold(b, 1.4e-3, 0.002)
    d = (np.nan_to_num(b, nan=2.0, posinf=2.0) + rng.normal(scale=0.05, size=b.shape)).astype(dtype)
    d[rng.uniform(size=b.shape) < 0.2] = np.nan
    mask = rng.uniform(size=b.shape) < 0.2
    out = apply_background(d, mask, thr, 9.0)
    assert out.dtype == d.dtype
    assert np.all(np.isnan(out[np.isnan(d)]))
    assert np.array_equal(out[mask], d[mask], equal_nan=True)
    assert np.all(thr[~np.isfinite(b)] == np.inf)
    tol = 3 * 1.4e-3 * b * b + 0.002 + 0.01
    with np.errstate(invalid="ignore"):
        is_bg = ~mask & np.isfinite(b) & (d.astype(float) >= b - tol + 1e-5)
        near = ~mask & ~(d.astype(float) >= b - tol - 1e-5)
    assert np.all(out[is_bg] == 9.0)
    assert np.array_equal(out[near], d[near], equal_nan=True)


@settings(deadline=None, max_examples=15)
@given(L=st.floats(0.0, 0.6), r=st.floats(0.005, 0.2), spacing=st.floats(0.005, 0.05), seed=st.integers(0, 2**31 - 1))
def test_capsule_surface_points_lie_on_the_surface_with_outward_normals(L, r, spacing, seed) -> None:
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(1, 3))
    ax = rng.normal(size=3)
    b = a + L * ax / np.linalg.norm(ax)
    p, nrm = capsule_surface_points(a, b, np.array([r]), spacing)
    ab = (b - a)[0]
    s = np.clip((p - a[0]) @ ab / max(ab @ ab, 1e-300), 0.0, 1.0) if L > 0 else np.zeros(len(p))
    closest = a[0] + s[:, None] * ab
    np.testing.assert_allclose(np.linalg.norm(p - closest, axis=1), r, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(nrm, (p - closest) / r, atol=1e-9)
    # dense enough: every surface point is within about a spacing of a sample
    probe = _capsule_surface(a[0], b[0], r, 200, rng)
    gap = np.min(np.linalg.norm(probe[:, None] - p[None], axis=2), axis=1)
    assert np.all(gap <= 1.5 * spacing)


@settings(deadline=None, max_examples=4)
@given(seed=st.integers(0, 2**31 - 1), margin=st.floats(0.01, 0.08), noise=st.floats(0.0, 0.03))
def test_panda_self_filter_guarantees_from_inside_the_margin(seed, margin, noise) -> None:
    """A camera within the margin of a link (a wrist camera, or the arm passing close to a fixed one),
    looking at it: it sits inside the inflated shape."""
    _check_self_filter("panda", seed, "shell", margin, noise, _panda_tol, _panda_exact_from())


@settings(deadline=None, max_examples=4)
@given(seed=st.integers(0, 2**31 - 1), margin=st.floats(0.005, 0.08), noise=st.floats(0.0, 0.03))
@example(seed=268151132, margin=0.03, noise=0.0)
def test_panda_self_filter_guarantees_at_the_shell(seed, margin, noise) -> None:
    """A camera about the inflated shell of a link, from 1 mm inside to 2 mm outside it: within the near
    plane's 1 mm outside it the clipped triangles took the entry of the rays that enter the shell there
    (seed 268151132 of the shell test had the camera 0.19 mm out, 98 robot pixels kept)."""
    _check_self_filter("panda", seed, "graze", margin, noise, _panda_tol, _panda_exact_from())
