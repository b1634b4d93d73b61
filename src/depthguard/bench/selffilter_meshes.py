"""``bench selffilter`` on real robots' meshes (Panda, UR5): the mesh self-filter against the capsule
filter (the coarse description of :attr:`RobotModel.capsules`, the only one before), same run, same frames,
and against bounding volumes fitted to the meshes (3 spheres per link as for ``auto``, ray cast exactly; counts
only).

Frames: the robot's collision meshes plus a floor and a wall, ray cast by MuJoCo through pinocchio/coal's
placements (:mod:`depthguard.bench.meshtruth`), 640x480 Kinect v1 intrinsics, random configurations
(seeded) and two viewpoints. Per robot: robot pixels visible and left in, background pixels removed (and
how many of them lie farther than the margin from the robot, by coal), ms per frame (median, p99; wall
clock and thread CPU time, which a shared machine distorts less), the triangle count of the filter's meshes.

``panda_x4``: the Panda with every collision triangle cut into four (:func:`dense_urdf`; the same surface,
9.6k triangles), the "about 10k triangles in view" case of the self-filter's time target; the truth and
the counts are those of the original meshes. Its meshes are convex, so the filter draws each as its hull's
rounded offset; the cut triangles' new vertices lie on the hull's facets to rounding and some count as
hull vertices, so it draws about 12k triangles (``triangles``), against 7.4k for the original Panda.
``panda_x4_decimated``: the same dense meshes loaded with
``max_triangles`` (:data:`DECIMATE_TO` per mesh), as the target allows ("decimate meshes at load time if
needed"); its counts too are against the original meshes.
"""

from __future__ import annotations

import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

__all__ = ["run_mesh_selffilter"]

ENV = (
    '<geom type="plane" size="5 5 0.1" pos="0 0 0" group="0"/>',
    '<geom type="box" size="0.05 3 2" pos="-1.3 0 1" group="0"/>',
)
VIEWS = {"front_1.5m": (1.4, 0.5, 1.0), "side_1.9m": (0.3, -1.3, 1.4)}
DECIMATE_TO = 250  # triangles per mesh for ``panda_x4_decimated`` (the self-filter's load-time option)


def _time(fn, repeat: int, warmup: int = 3) -> dict:
    """Wall-clock and thread-CPU ms per call (median, p99): CPU time is what a loaded machine distorts least."""
    for _ in range(warmup):
        fn()
    wall, cpu = np.empty(repeat), np.empty(repeat)
    for i in range(repeat):
        t0, c0 = time.perf_counter(), time.thread_time()
        fn()
        wall[i], cpu[i] = time.perf_counter() - t0, time.thread_time() - c0
    return {
        "ms_median": float(np.median(wall)) * 1e3,
        "ms_p99": float(np.percentile(wall, 99)) * 1e3,
        "cpu_ms_median": float(np.median(cpu)) * 1e3,
        "cpu_ms_p99": float(np.percentile(cpu, 99)) * 1e3,
    }


def _counts(mask, measured, robot_vis, urdf, q, cam, margin) -> dict:
    from depthguard.bench.meshtruth import distance_to_robot

    bg = mask & np.isfinite(measured) & ~robot_vis
    d = distance_to_robot(urdf, q, cam.unproject_image(measured)[bg]) if bg.any() else np.zeros(0)
    return {
        "pixels_left": int(np.sum(robot_vis & ~mask)),
        "background_removed": int(bg.sum()),
        "background_removed_beyond_margin": int(np.sum(d > margin + 1e-6)),
        "background_removed_max_distance_m": float(d.max(initial=0.0)),
    }


def dense_urdf(urdf: Path, out_dir: Path, subdivisions: int = 1) -> Path:
    """A copy of ``urdf`` in ``out_dir`` whose collision meshes have each triangle cut into four,
    ``subdivisions`` times (``trimesh``'s midpoint subdivision: the same surface, 4^k times the triangles);
    visual meshes are dropped. Returns the copy's path."""
    import trimesh

    from depthguard.robot.shapes import resolve_mesh_path

    tree = ET.parse(urdf)
    for link in tree.getroot().iter("link"):
        for vis in link.findall("visual"):
            link.remove(vis)
    for k, mesh in enumerate(tree.getroot().iter("mesh")):
        src = resolve_mesh_path(mesh.get("filename"), Path(urdf))
        m = trimesh.load(src, force="mesh", process=True)
        v, f = np.asarray(m.vertices), np.asarray(m.faces)
        for _ in range(subdivisions):
            v, f = trimesh.remesh.subdivide(v, f)
        dst = out_dir / f"mesh_{k}.stl"
        trimesh.Trimesh(v, f, process=False).export(dst)
        mesh.set("filename", str(dst))
    out = out_dir / Path(urdf).name
    tree.write(out)
    return out


def _robot(name: str, n_q: int, repeat: int, margin: float, subdivisions: int = 0, max_triangles=None) -> dict:
    from depthguard.bench.meshtruth import MeshRobotTruth
    from depthguard.camera import Camera, look_at
    from depthguard.robot.model import RobotModel
    from depthguard.robot.robots import ROBOTS, load_robot, robot_urdf
    from depthguard.robot.selffilter import self_filter, self_filter_capsules
    from depthguard.robot.spheres import cover_points

    urdf = str(robot_urdf(name))
    tmp = tempfile.TemporaryDirectory()  # the dense meshes live until the run ends
    if subdivisions:
        dense = dense_urdf(Path(urdf), Path(tmp.name), subdivisions)
        model = RobotModel.from_urdf(dense, ee_frame=ROBOTS[name][1], max_triangles=max_triangles)
    else:
        model = load_robot(name)
    # bounding volumes fitted to the meshes: 3 spheres per link (the base included), link frame
    fitted = {lk: cover_points(p, 3, radii=r) for lk, (p, r) in model.geometry.link_points().items()}
    rng = np.random.default_rng(2026)
    rows = []
    for _ in range(n_q):
        q = rng.uniform(np.maximum(model.q_min, -2.5), np.minimum(model.q_max, 2.5))
        truth = MeshRobotTruth(urdf, q, ENV)
        a, b, r = model.link_capsules(q)
        poses = {lk: model.frame_pose(q, lk) for lk in fitted}
        sa = np.vstack([c @ poses[lk][0].T + poses[lk][1] for lk, (c, _) in fitted.items()])
        sr = np.concatenate([rr for _, rr in fitted.values()])
        for view, eye in VIEWS.items():
            R, t = look_at(np.array(eye), np.array([0.0, 0.0, 0.4]))
            cam = Camera.kinect_v1(R, t, min_depth=0.3)
            measured, robot_only = truth.depth(cam), truth.robot_depth(cam)
            robot_vis = np.isfinite(robot_only) & (np.abs(measured - robot_only) < 1e-9)
            mesh = self_filter(cam, measured, q, model, margin=margin)
            caps = self_filter_capsules(cam, measured, a, b, r, margin=margin)
            sph = self_filter_capsules(cam, measured, sa, sa, sr, margin=margin)
            tm = _time(lambda c=cam, m=measured, q=q: self_filter(c, m, q, model, margin=margin), repeat)
            tc = _time(
                lambda c=cam, m=measured, a=a, b=b, r=r: self_filter_capsules(c, m, a, b, r, margin=margin), repeat
            )
            rows.append(
                {
                    "view": view,
                    "robot_pixels": int(robot_vis.sum()),
                    "mesh": {**_counts(mesh.mask, measured, robot_vis, urdf, q, cam, margin), **tm},
                    "capsules": {**_counts(caps.mask, measured, robot_vis, urdf, q, cam, margin), **tc},
                    "auto_spheres": _counts(sph.mask, measured, robot_vis, urdf, q, cam, margin),
                }
            )  # fmt: skip
    vis = sum(r["robot_pixels"] for r in rows)

    def agg(kind: str) -> dict:
        left = sum(r[kind]["pixels_left"] for r in rows)
        out = {
            "pixels_left": left,
            "pixels_left_fraction": left / max(vis, 1),
            "background_removed": sum(r[kind]["background_removed"] for r in rows),
            "background_removed_beyond_margin": sum(r[kind]["background_removed_beyond_margin"] for r in rows),
        }
        if kind == "auto_spheres":
            return out
        return {
            **out,
            "ms_median": float(np.median([r[kind]["ms_median"] for r in rows])),
            "ms_p99": float(np.max([r[kind]["ms_p99"] for r in rows])),
            "cpu_ms_median": float(np.median([r[kind]["cpu_ms_median"] for r in rows])),
            "cpu_ms_p99": float(np.max([r[kind]["cpu_ms_p99"] for r in rows])),
        }

    mesh, caps = agg("mesh"), agg("capsules")
    tmp.cleanup()
    return {
        "triangles": model.geometry.n_triangles,
        "analytic_capsules": len(model.geometry.cap_r),
        "frames": len(rows),
        "robot_pixels": vis,
        "mesh": mesh,
        "capsule_baseline": caps,
        "auto_spheres_baseline": agg("auto_spheres"),
        "time_ratio_mesh_over_capsules": mesh["ms_median"] / max(caps["ms_median"], 1e-9),
        "cpu_time_ratio_mesh_over_capsules": mesh["cpu_ms_median"] / max(caps["cpu_ms_median"], 1e-9),
        "frames_detail": rows,
    }


def run_mesh_selffilter(quick: bool = False, margin: float = 0.03, robots=("panda", "ur5", "lwr4")) -> dict:
    """Panda, UR5 and shipped-LWR entries of ``bench selffilter`` (module docstring; for the LWR the "capsule
    baseline" is its exact capsule model, the filter before this change), and ``panda_x4`` (the Panda's
    meshes at four times the triangles) unless ``quick``; ``quick``: 1 configuration, 20 calls."""
    n_q, repeat = (1, 20) if quick else (3, 200)
    out = {name: _robot(name, n_q, repeat, margin) for name in robots}
    if not quick and "panda" in robots:
        out["panda_x4"] = _robot("panda", n_q, repeat, margin, subdivisions=1)
        out["panda_x4_decimated"] = _robot("panda", n_q, repeat, margin, subdivisions=1, max_triangles=DECIMATE_TO)
    return out
