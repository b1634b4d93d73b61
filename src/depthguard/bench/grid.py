"""Multi-camera benchmark (issue 3): the depth grid of RA-L'16 vs. a Cartesian voxel grid.

Scene (:mod:`depthguard.bench.scenes`): two Kinect-like cameras (640x480, fx = fy = 525) about 4 m apart,
a person reaching towards the arm about 2 m from the principal camera, walls, 2 % missing pixels,
Kinect-like noise; 9 control spheres; workspace [-1.5, 1.5] x [-1.5, 1.5] x [-0.5, 1.5] m; Δd = 1 cm.

Figures (each the median and p99 over repeated runs, all measured in the same run):

* ``depthgrid-2cam-all`` / ``depthgrid-2cam-min``: one fused query of the 9 spheres (RA-L'16 §VI);
* ``voxel-2cam``: the voxel baseline's query of the 9 spheres (mode "all");
* per frame: the depth grid's ``update`` (hole filling, per-camera images) and the voxel grid's fill;
* the frame-plus-query ratio ``(voxel fill + voxel query) / (grid update + grid query)``, which is what
  a new camera frame costs each method before its first answer;
* the map: on-the-fly (tables only) and stored (every cell's footprint) memory and build time, and the
  query time with each (their answers are identical, see ``tests/test_depthgrid_properties.py``).

The depth grid runs on one thread (``DepthGridFusion(parallel=False)``: on the shared 2-core machine,
waking a second numba thread cost milliseconds). The voxel query runs on one thread as well; the voxel
fill uses numba's threads (``prange``) and is also timed on one thread for a like-for-like ratio.
"""

from __future__ import annotations

import time

import numpy as np

from depthguard.bench.scenes import arm_chain_points, bench_cameras, noisy_depth, person_scene
from depthguard.bench.timing import machine_info, time_calls
from depthguard.bench.voxel import VoxelFusion
from depthguard.depthgrid import DepthGridFusion

__all__ = ["run_grid_benchmark", "WORKSPACE"]

WORKSPACE = (-1.5, 1.5, -1.5, 1.5, -0.5, 1.5)


def _entry(name: str, rho, t: dict, **extra) -> dict:
    return {
        "name": name,
        "rho": rho,
        "hz_median": t["hz_median"],
        "us_median": t["us_median"],
        "us_p99": t["us_p99"],
        **extra,
    }


def run_grid_benchmark(quick: bool = False, stored_map: bool | None = None) -> dict:
    """Run the multi-camera benchmark; returns ``{"results": [...], "grid_map": {...}, ...}``.

    Args:
        quick: fewer repetitions (CI smoke runs) and no stored map (it takes 843 MB and ~10-30 s).
        stored_map: also build the stored map and time queries with it (default: ``not quick``).
    """
    stored_map = (not quick) if stored_map is None else stored_map
    repeat = 50 if quick else 500
    frames = 3 if quick else 10
    cams = bench_cameras()
    scene = person_scene()
    depths = [noisy_depth(c, scene, seed=1 + i) for i, c in enumerate(cams)]
    names, centres, radii = arm_chain_points()

    t0 = time.perf_counter()
    fusion = DepthGridFusion(cams, dd=0.01, workspace=WORKSPACE, map_mode="onthefly")
    fly_build = time.perf_counter() - t0
    fusion.update(depths)
    results = []
    answers = {}
    query_t = {}
    for rho in (0.4, 0.2):
        for mode in ("all", "min"):
            fusion.query(centres, radii, rho=rho, mode=mode)  # JIT warm-up
            t = time_calls(lambda rho=rho, mode=mode: fusion.query(centres, radii, rho=rho, mode=mode), repeat)
            query_t[(mode, rho)] = t
            answers[(mode, rho)] = fusion.query(centres, radii, rho=rho, mode=mode)
            results.append(
                _entry(
                    f"depthgrid-2cam-{mode}",
                    rho,
                    t,
                    column_searches=int(fusion.last_cells.sum()),
                    cell_votes=int(fusion.last_votes.sum()),
                )
            )
    t_update = time_calls(lambda: fusion.update(depths), frames)

    voxel = VoxelFusion(cams, WORKSPACE, res=0.01)
    voxel.update(depths)  # JIT warm-up
    t_fill = time_calls(lambda: voxel.update(depths), frames, warmup=1)
    # the same fill on one thread, for a like-for-like figure (the depth grid's update is single-threaded)
    import numba

    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        t_fill_1 = time_calls(lambda: voxel.update(depths), frames, warmup=1)
    finally:
        numba.set_num_threads(threads)
    vox_t = {}
    for rho in (0.4, 0.2):
        voxel.query(centres, radii, rho=rho, mode="all")
        t = time_calls(lambda rho=rho: voxel.query(centres, radii, rho=rho, mode="all"), max(10, repeat // 10))
        vox_t[rho] = t
        results.append(_entry("voxel-2cam", rho, t, per_frame_fill_us_median=t_fill["us_median"]))

    ratios = {}
    for rho in (0.4, 0.2):
        for mode in ("all", "min"):
            g = query_t[(mode, rho)]["us_median"]
            ratios[f"depthgrid-2cam-{mode}@{rho}"] = {
                "query_only": vox_t[rho]["us_median"] / g,
                "frame_plus_query": (t_fill["us_median"] + vox_t[rho]["us_median"]) / (t_update["us_median"] + g),
                "frame_plus_query_1thread": (t_fill_1["us_median"] + vox_t[rho]["us_median"])
                / (t_update["us_median"] + g),
            }

    truth = np.maximum(scene.distance(centres) - radii, 0.0)
    vox_ans = voxel.query(centres, radii, rho=0.4, mode="all")
    accuracy = {
        "truth": [round(float(x), 4) for x in truth],
        "depthgrid": [None if not np.isfinite(x) else round(float(x), 4) for x in answers[("all", 0.4)].distance],
        "voxel": [None if not np.isfinite(x) else round(float(x), 4) for x in vox_ans.distance],
        "tolerance": [round(float(x), 4) for x in fusion.tolerance(centres, 0.4)],
    }

    grid_map = {
        "cells": int(fusion.grid.size),
        "grid_shape": list(fusion.grid.shape),
        "d_min": fusion.grid.d_min,
        "onthefly_bytes": fusion.map_nbytes,
        "onthefly_build_s": fly_build,
        "voxel_bytes": voxel.nbytes,
    }
    if stored_map:
        t0 = time.perf_counter()
        stored = DepthGridFusion(cams, dd=0.01, workspace=WORKSPACE, map_mode="stored", cache_dir=False)
        grid_map["stored_build_s"] = time.perf_counter() - t0
        grid_map["stored_bytes"] = stored.map_nbytes
        stored.update(depths)
        same = True
        for mode in ("all", "min"):
            stored.query(centres, radii, rho=0.4, mode=mode)
            t = time_calls(lambda mode=mode: stored.query(centres, radii, rho=0.4, mode=mode), repeat)
            grid_map[f"stored_query_{mode}_us_median"] = t["us_median"]
            grid_map[f"stored_query_{mode}_us_p99"] = t["us_p99"]
            grid_map[f"onthefly_query_{mode}_us_median"] = query_t[(mode, 0.4)]["us_median"]
            a = stored.query(centres, radii, rho=0.4, mode=mode)
            b = fusion.query(centres, radii, rho=0.4, mode=mode)
            same &= all(np.array_equal(x, y, equal_nan=True) for x, y in zip(a, b, strict=True))
        grid_map["stored_equals_onthefly"] = bool(same)
        del stored

    return {
        "benchmark": "grid",
        "machine": machine_info(),
        "parameters": {
            "cameras": len(cams),
            "width": cams[0].width,
            "height": cams[0].height,
            "fx": cams[0].fx,
            "dd": 0.01,
            "workspace": list(WORKSPACE),
            "points": len(centres),
            "voxel_res": 0.01,
            "repeat": repeat,
            "frames": frames,
            "quick": quick,
        },
        "results": results,
        "per_frame": {
            "depthgrid_update_us_median": t_update["us_median"],
            "depthgrid_update_us_p99": t_update["us_p99"],
            "voxel_fill_us_median": t_fill["us_median"],
            "voxel_fill_us_p99": t_fill["us_p99"],
            "voxel_fill_threads": threads,
            "voxel_fill_1thread_us_median": t_fill_1["us_median"],
        },
        "ratios_vs_voxel": ratios,
        "grid_map": grid_map,
        "accuracy_rho_0.4": accuracy,
        "notes": "depthgrid times are per query of the 9 spheres on one thread (the frame is prepared once "
        "per camera frame, see per_frame); voxel-2cam is the voxel grid's query (mode all), its fill is per "
        "frame; frame_plus_query = (voxel fill + voxel query) / (depthgrid update + depthgrid query), with the "
        "voxel fill on numba's threads (frame_plus_query_1thread: on one thread, like the depth grid).",
    }


if __name__ == "__main__":  # pragma: no cover
    import json
    import sys

    print(json.dumps(run_grid_benchmark(quick="--quick" in sys.argv), indent=2))
