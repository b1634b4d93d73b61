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
