"""A small end-to-end example without the simulator: a person reaching towards an arm, one camera.

Builds the scene, renders a noisy Kinect-like depth image, computes distances and repulsive vectors for
9 control points, prints a table and saves a picture.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from depthguard.bench.scenes import arm_chain_points, bench_cameras, noisy_depth, person_scene
from depthguard.depthspace import prepare_frame, query_distances
from depthguard.repulsion import repulsive_vectors

__all__ = ["run_static_demo"]


def run_static_demo(out_dir: str | Path = "runs/demo-static", rho: float = 0.4) -> dict:
    """Run the static demo; returns the table rows and the picture path."""
    cam = bench_cameras()[0]
    scene = person_scene()
    depth = noisy_depth(cam, scene, seed=0)
    names, centres, radii = arm_chain_points()
    frame = prepare_frame(cam, depth)
    res = query_distances(frame, centres, radii, rho=rho, mode="all")
    rep = repulsive_vectors(res, vmax=2.0, rho=rho, alpha=6.0)
    truth = scene.distance(centres) - radii
    print(f"{'point':>6} {'distance [m]':>13} {'true [m]':>9} {'pixels':>7}  repulsive velocity [m/s]")
    rows = []
    for i, n in enumerate(names):
        d = res.distance[i]
        ds = f"{d:13.3f}" if np.isfinite(d) else f"{'none':>13}"
        print(f"{n:>6} {ds} {truth[i]:9.3f} {res.obstacle_pixels[i]:7d}  {np.array2string(rep[i], precision=2)}")
        rows.append({"name": n, "distance": float(d) if np.isfinite(d) else None, "true": float(truth[i])})
    from depthguard.viz.depth_figure import save_depth_figure

    png = save_depth_figure(
        Path(out_dir) / "depth_repulsion.png",
        cam,
        depth,
        centres,
        names,
        rep,
        res.distance,
        title=f"one camera, rho = {rho} m: distances and repulsive vectors",
    )
    print(f"\npicture: {png}")
    print("distances are lower bounds: the gray area behind the person counts as obstacle (true = visible geometry)")
    return {"rows": rows, "picture": str(png)}
