"""``depthguard bench distance``: single-camera depth-space distances vs. a KD-tree baseline (issue 2),
plus the multi-camera depth grid vs. a voxel baseline when available (issue 3), and the shadow scene.

Scene (:mod:`depthguard.bench.scenes`): 640x480, fx = fy = 525, a person reaching towards an arm about 2 m
from the camera, a wall at 3.5 m, 2 % missing pixels, Kinect-like noise, 9 control spheres.
Shadow scene (:func:`depthguard.bench.scenes.shadow_frames`): the ``ral-shadow`` situation, two cameras at
640x480, a person holding a panel between the principal camera and the robot, ``hybrid`` mode, ρ = 0.4
(entry ``depthgrid-2cam-shadow-hybrid``; ``scenario ral-shadow`` reports the same stage as
``distance_hz_median``); ``depthgrid-2cam-shadow-hybrid-first-query`` and its ``-shared`` form: the first query
of a frame set on one thread and shared with a side thread (``ratio_vs_one_thread``).

Every entry carries ``vs_reference``: its rate over that of the machine-speed reference kernel timed in
the same run (:func:`depthguard.bench.timing.reference_speed`), so that runs on different machines compare.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from depthguard.bench.scenes import arm_chain_points, bench_cameras, noisy_depth, person_scene
from depthguard.bench.timing import machine_info, reference_speed, time_calls, with_reference
from depthguard.depthspace import prepare_frame, query_distances

__all__ = ["run_distance_benchmark"]


def _kdtree_build(camera, depth):
    """Back-project the valid pixels and build a KD-tree (scipy's fastest build settings)."""
    valid = np.isfinite(depth)
    v, u = np.nonzero(valid)
    pts = camera.unproject(u + 0.5, v + 0.5, depth[valid])
    return cKDTree(pts, balanced_tree=False, compact_nodes=False)


def _kdtree_query(camera, depth, centres, radii):
    """Baseline: a new frame means a new tree; then the nearest point for each of the 9 spheres."""
    d, _ = _kdtree_build(camera, depth).query(centres, k=1)
    return d - radii


def run_distance_benchmark(quick: bool = False, include_grid: bool = True) -> dict:
    """Run the distance benchmark; returns the JSON-able result object.

    Args:
        quick: fewer repetitions (for CI smoke runs); the figures are noisier.
        include_grid: also run the multi-camera depth-grid benchmark if that module is installed.
    """
    repeat = 50 if quick else 500
    reference = reference_speed()
    cam = bench_cameras()[0]
    scene = person_scene()
    depth = noisy_depth(cam, scene, seed=1)
    names, centres, radii = arm_chain_points()
    frame = prepare_frame(cam, depth)
    results = []
    for rho in (0.4, 0.2):
        for mode in ("min", "all"):
            query_distances(frame, centres, radii, rho=rho, mode=mode)  # JIT warm-up
            t = time_calls(
                lambda rho=rho, mode=mode: query_distances(frame, centres, radii, rho=rho, mode=mode), repeat
            )
            results.append(
                {
                    "name": f"depthspace-1cam-{mode}",
                    "rho": rho,
                    "hz_median": t["hz_median"],
                    "us_median": t["us_median"],
                    "us_p99": t["us_p99"],
                }
            )
    t_kd = time_calls(lambda: _kdtree_query(cam, depth, centres, radii), max(10, repeat // 10))
    for rho in (0.4, 0.2):
        results.append(
            {
                "name": "kdtree-1cam",
                "rho": rho,
                "hz_median": t_kd["hz_median"],
                "us_median": t_kd["us_median"],
                "us_p99": t_kd["us_p99"],
            }
        )
    tree = _kdtree_build(cam, depth)
    t_kdq = time_calls(lambda: tree.query(centres, k=1), repeat)
    results.append(
        {
            "name": "kdtree-1cam-query-only",
            "rho": None,
            "hz_median": t_kdq["hz_median"],
            "us_median": t_kdq["us_median"],
            "us_p99": t_kdq["us_p99"],
        }
    )
    t_prep = time_calls(lambda: prepare_frame(cam, depth), max(10, repeat // 10))
    ratios = {
        r["name"] + f"@{r['rho']}": r["hz_median"] / t_kd["hz_median"]
        for r in results
        if r["name"].startswith("depthspace")
    }
    out = {
        "benchmark": "distance",
        "machine": machine_info(),
        "reference": reference,
        "parameters": {
            "width": cam.width,
            "height": cam.height,
            "fx": cam.fx,
            "points": len(centres),
            "missing_fraction": 0.02,
            "repeat": repeat,
            "quick": quick,
        },
        "results": results,
        "per_frame": {"prepare_frame_us_median": t_prep["us_median"], "prepare_frame_us_p99": t_prep["us_p99"]},
        "ratios_vs_kdtree": ratios,
        "notes": "depthspace times are per query (the frame is prepared once per camera frame, see per_frame); "
        "kdtree-1cam includes the tree build, since a new frame means a new tree; kdtree-1cam-query-only reuses "
        "one tree (information only: it ignores the gray area and missing pixels, so it over-reports distances).",
    }
    if include_grid:
        try:
            from depthguard.bench.grid import run_grid_benchmark
        except ImportError:
            pass
        else:
            grid = run_grid_benchmark(quick=quick)
            out["results"].extend(grid["results"] if isinstance(grid, dict) else grid)
            if isinstance(grid, dict):
                out["grid"] = {k: v for k, v in grid.items() if k != "results"}
            out["results"].extend(_shadow_results(quick))
    out["results"] = [with_reference(r, reference) for r in out["results"]]
    out["reference_end"] = reference_speed()  # the same kernel at the end: how much the machine's speed drifted
    return out


def _shadow_results(quick: bool) -> list[dict]:
    """The shadow scene (module docstring): fused query of the robot's 9 spheres, hybrid and min modes."""
    from depthguard.bench.scenes import shadow_frames
    from depthguard.depthgrid import DepthGridFusion

    sh = shadow_frames()
    fusion = DepthGridFusion(sh["cameras"], dd=0.01, workspace=sh["workspace"])
    fusion.update(sh["depths"], sh["masks"])
    out = []
    for mode in ("hybrid", "min"):
        fusion.query(sh["centres"], sh["radii"], rho=0.4, mode=mode)  # JIT warm-up
        t = time_calls(
            lambda mode=mode: fusion.query(sh["centres"], sh["radii"], rho=0.4, mode=mode), 30 if quick else 200
        )
        out.append(
            {
                "name": f"depthgrid-2cam-shadow-{mode}",
                "rho": 0.4,
                "hz_median": t["hz_median"],
                "us_median": t["us_median"],
                "us_p99": t["us_p99"],
                "column_searches": int(fusion.last_cells.sum()),
                "cell_votes": int(fusion.last_votes.sum()),
            }
        )
    out.extend(_first_query_results(fusion, sh, quick))
    out.append(_frame_stage_result(sh, quick))
    return out


def _first_query_results(fusion, sh: dict, quick: bool) -> list[dict]:
    """The first ``hybrid`` query of a frame set (the column cache empty, as after every update), on this
    thread alone and shared with a side thread (``DepthGridFusion.query(side=...)``, the distance stage's
    default on two CPUs or more), alternated in rounds; the entries give the median of the rounds' medians and
    the shared one its ratio to the one-thread one."""
    from depthguard.sidethread import SideThread

    side = SideThread("depthguard-bench")

    def first(ex) -> None:
        fusion._gen += 1  # (a new frame for the column cache, as update() makes, without the update's cost)
        fusion.query(sh["centres"], sh["radii"], rho=0.4, mode="hybrid", side=ex)

    def shared() -> None:
        with side.beside() as ex:
            first(ex)

    n = 10 if quick else 40
    rounds: dict[str, list] = {"": [], "-shared": []}
    try:
        for _ in range(3 if quick else 7):
            rounds[""].append(time_calls(lambda: first(None), n))
            rounds["-shared"].append(time_calls(shared, n))
    finally:
        side.shutdown()
    out = []
    for tag, ts in rounds.items():
        us = float(np.median([t["us_median"] for t in ts]))
        row = {
            "name": f"depthgrid-2cam-shadow-hybrid-first-query{tag}",
            "rho": 0.4,
            "hz_median": 1e6 / us,
            "us_median": us,
            "us_p99": float(np.median([t["us_p99"] for t in ts])),
        }
        out.append(row)
    out[1]["ratio_vs_one_thread"] = out[1]["us_median"] / out[0]["us_median"]
    return out


def _frame_stage_result(sh: dict, quick: bool) -> dict:
    """The fusion's frame stage on the shadow frames as the distance stage runs it once per frame set
    (:meth:`depthguard.sim.pipeline.DistanceStage.update`: the principal camera's robot pixels corrected,
    the secondary camera's robot windows, both images prepared, the vote pyramid)."""
    from depthguard.sim.pipeline import DistanceStage

    stage = DistanceStage(sh["cameras"], rho=0.4, mode="hybrid", workspace=sh["workspace"], dd=0.01)
    args = (sh["depths"], sh["masks"], sh["q"], sh["model"])
    stage.update(*args)  # JIT warm-up
    t = time_calls(lambda: stage.update(*args), 10 if quick else 60)
    return {
        "name": "depthgrid-2cam-shadow-frame-stage",
        "hz_median": t["hz_median"],
        "us_median": t["us_median"],
        "us_p99": t["us_p99"],
        "notes": "per frame set, not per query: DistanceStage.update with the robot's joint state and model",
    }
