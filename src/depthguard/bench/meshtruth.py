"""Independent ground truth for mesh robots (tests and ``bench selffilter``): pinocchio/coal read the URDF
and its meshes, MuJoCo ray casts them.

Nothing here uses depthguard's URDF parsing, mesh loading or rasteriser: the collision geometry and its
placements come from ``pinocchio.buildGeomFromUrdf`` (coal), the meshes are read by MuJoCo from their files,
depth images come from ``mujoco.mj_multiRay`` through the pixel centres, and distances from coal.
"""

from __future__ import annotations

import numpy as np


def _quat(R: np.ndarray) -> np.ndarray:
    import mujoco

    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(R).ravel())
    return q


def _f(v) -> str:
    return " ".join(f"{float(x):.9g}" for x in np.atleast_1d(v))


class MeshRobotTruth:
    """The robot's collision geometry at ``q`` as static MuJoCo geoms (group 1), plus optional extra geoms
    (group 0) given as MJCF lines; ``depth(camera)`` ray casts the scene, ``robot_depth`` the robot only."""

    def __init__(self, urdf: str, q: np.ndarray, extra: tuple[str, ...] = (), attach: tuple = ()) -> None:
        import coal
        import mujoco
        import pinocchio as pin

        from depthguard.robot.robots import robot_data_dir

        share = str(robot_data_dir().parent)
        model = pin.buildModelFromUrdf(urdf)
        geom = pin.buildGeomFromUrdf(model, urdf, pin.COLLISION, package_dirs=[share])
        data, gdata = model.createData(), pin.GeometryData(geom)
        pin.forwardKinematics(model, data, np.asarray(q, float))
        pin.updateGeometryPlacements(model, data, geom, gdata)
        pin.updateFramePlacements(model, data)
        assets, geoms = [], []
        self.vertices: dict[str, list[np.ndarray]] = {}  # link -> world vertices of its original meshes
        for i, obj in enumerate(geom.geometryObjects):
            M = gdata.oMg[i]
            pos, quat = _f(M.translation), _f(_quat(M.rotation))
            g = obj.geometry
            link = model.frames[obj.parentFrame].name
            common = f'pos="{pos}" quat="{quat}" group="1"'
            if isinstance(g, coal.Box):
                geoms.append(f'<geom type="box" size="{_f(g.halfSide)}" {common}/>')
            elif isinstance(g, coal.Cylinder):
                geoms.append(f'<geom type="cylinder" size="{g.radius} {g.halfLength}" {common}/>')
            elif isinstance(g, coal.Capsule):
                geoms.append(f'<geom type="capsule" size="{g.radius} {g.halfLength}" {common}/>')
            elif isinstance(g, coal.Sphere):
                geoms.append(f'<geom type="sphere" size="{g.radius}" {common}/>')
            else:  # a mesh: MuJoCo reads the file itself
                name = f"m{i}"
                scale = _f(obj.meshScale)
                assets.append(f'<mesh name="{name}" file="{obj.meshPath}" scale="{scale}" inertia="shell"/>')
                geoms.append(f'<geom type="mesh" mesh="{name}" {common}/>')
                v = np.asarray(g.vertices(), float) * np.asarray(obj.meshScale)
                self.vertices.setdefault(link, []).append(v @ np.asarray(M.rotation).T + M.translation)
        for sh, R, p in attach:  # (MJCF geom fragment without pose, rotation, position) in the world
            geoms.append(f'<geom {sh} pos="{_f(p)}" quat="{_f(_quat(R))}" group="1"/>')
        xml = (
            '<mujoco><compiler angle="radian"/><asset>'
            + "".join(assets)
            + "</asset><worldbody>"
            + "".join(geoms)
            + "".join(extra)
            + "</worldbody></mujoco>"
        )
        self.mj = mujoco.MjModel.from_xml_string(xml)
        self.md = mujoco.MjData(self.mj)
        mujoco.mj_forward(self.mj, self.md)
        self.frames = {f.name: data.oMf[k] for k, f in enumerate(model.frames)}

    def depth(self, camera, groups=(1, 1, 1, 1, 1, 1)) -> np.ndarray:
        from depthguard.sim.depthcam import raycast_depth

        return raycast_depth(self.mj, self.md, camera, geomgroup=np.array(groups, np.uint8))

    def robot_depth(self, camera) -> np.ndarray:
        return self.depth(camera, (0, 1, 0, 0, 0, 0))

    def inside(self, points: np.ndarray) -> np.ndarray:
        """(P,) bool: world points (P, 3) inside the robot's closed collision geometry, by the parity of the
        surfaces of each geom that MuJoCo's rays (``mj_ray``, which meets triangles from either side) cross
        along five fixed directions (per geom: the links' meshes overlap at the joints); a point counts as
        inside when, along most directions, some geom is crossed an odd number of times (a ray through an
        edge or a vertex may count a crossing twice)."""
        import mujoco

        group = np.array([0, 1, 0, 0, 0, 0], np.uint8)
        gid = np.zeros(1, np.int32)
        dirs = np.array(
            [[0.31, 0.52, 0.79], [-0.67, 0.23, -0.41], [0.12, -0.93, 0.35], [0.58, 0.11, -0.81], [-0.44, -0.61, 0.66]]
        )
        dirs /= np.linalg.norm(dirs, axis=1)[:, None]
        out = np.zeros(len(points), bool)
        for k, p in enumerate(np.asarray(points, float)):
            odd = 0
            for u in dirs:
                o, hits = p.copy(), np.zeros(self.mj.ngeom, np.int64)
                for _ in range(1000):
                    d = mujoco.mj_ray(self.mj, self.md, o, u, group, 1, -1, gid)
                    if d < 0:
                        break
                    hits[gid[0]] += 1
                    o = o + (d + 1e-7) * u
                odd += bool(np.any(hits % 2 == 1))
            out[k] = odd >= 3
        return out


def distance_to_robot(urdf: str, q: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(P,) distance (m) of world points (P, 3) to the robot's collision geometry at ``q`` (coal)."""
    import coal
    import pinocchio as pin

    from depthguard.robot.robots import robot_data_dir

    model = pin.buildModelFromUrdf(urdf)
    geom = pin.buildGeomFromUrdf(model, urdf, pin.COLLISION, package_dirs=[str(robot_data_dir().parent)])
    data, gdata = model.createData(), pin.GeometryData(geom)
    pin.forwardKinematics(model, data, np.asarray(q, float))
    pin.updateGeometryPlacements(model, data, geom, gdata)
    dot = coal.Sphere(1e-9)
    req, res = coal.DistanceRequest(), coal.DistanceResult()
    tfs = [coal.Transform3s(np.asarray(M.rotation), np.asarray(M.translation)) for M in gdata.oMg]
    out = np.full(len(points), np.inf)
    for k, p in enumerate(np.asarray(points, float)):
        tp = coal.Transform3s(np.eye(3), p)
        for obj, tf in zip(geom.geometryObjects, tfs, strict=True):
            res.clear()
            out[k] = min(out[k], coal.distance(obj.geometry, tf, dot, tp, req, res))
    return np.maximum(out, 0.0)
