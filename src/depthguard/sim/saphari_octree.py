"""Scenario ``saphari-octree`` (SAPHARI D4.1.1 §3.3): the mobile manipulator with platform-mounted sensors and
the occlusion-aware obstacle octree as the distance backend.

``depthguard scenario saphari-octree [--quick] [--octree-res 0.05] [--out DIR] --json``. The run uses SAPHARI's
semantics (unobserved space is free; the sensors do not cover all around the platform) and reports the
conservative mode (unobserved space inside C(t) is an obstacle) as the variant ``conservative``. Output: the
top-level keys of the other scenarios, ``stage_ms`` (median milliseconds per stage), node counts,
``reachability_reused`` (the fraction of frames whose C(t) was a reused grid, docs/octree.md), and with
``--out``: ``reachability_fig1.png`` (C(t) coloured by the minimum time, SAPHARI Fig. 1),
``octree_fig6.png`` (occupied red, occluded orange, Fig. 6), the usual plots, OctoMap files of the last frame
and ``recording.mcap`` with the channels ``/octree`` and ``/reachability`` besides the usual ones.
"""

from __future__ import annotations

import json
import time
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from depthguard.octree.grid import VoxelBox, check_res

__all__ = ["run", "scenario_path"]


def scenario_path() -> Path:
    return Path(str(resources.files("depthguard") / "data" / "octree" / "saphari_octree.toml"))


def _build(sc: dict, quick: bool):
    """The cell: the arm on the platform (the cell's table), people and boxes, the platform's sensors."""
    from depthguard.robot.platform import platform_sensors
    from depthguard.sim.cell import BoxSpec, CellSpec, build_cell
    from depthguard.sim.people import Keyframe, PersonScript
    from depthguard.sim.pipeline import Kinematics
    from depthguard.sim.scenario_setup import solve_ik

    w, h = sc["quick_resolution"] if quick else sc["resolution"]
    floor_z = float(sc["floor_z"])
    cams, scanners = platform_sensors(np.zeros(3), int(w), int(h), z0=floor_z)
    kin = Kinematics(sc.get("control_points", "ral-9"), ee_radius=float(sc.get("ee_radius", 0.1)))
    q0 = solve_ik(kin, np.asarray(sc["q0"], float), np.asarray(sc["ee_start"], float))
    people = [
        PersonScript(
            p["name"],
            [
                Keyframe(
                    t=float(k["t"]),
                    base=tuple(k["base"]),
                    yaw=float(k.get("yaw", 0.0)),
                    left_hand=tuple(k["left_hand"]) if "left_hand" in k else None,
                    right_hand=tuple(k["right_hand"]) if "right_hand" in k else None,
                )
                for k in p["keyframes"]
            ],
            floor_z=floor_z,
        )
        for p in sc.get("people", [])
    ]
    boxes = [BoxSpec(b["name"], tuple(b["center"]), tuple(b["half"])) for b in sc.get("boxes", [])]
    spec = CellSpec(
        cameras=cams, boxes=boxes, people=people, q0=tuple(q0), floor_z=floor_z, table_half=(0.4, 0.3),
        room=tuple(sc["room"]),
    )  # fmt: skip
    return build_cell(spec), kin, scanners


def _stage(sc: dict, cell, kin, scanners, mode: str, res: float):
    from depthguard.bench.octree_scene import omni_model
    from depthguard.sim.laser import LaserSim
    from depthguard.sim.octree_stage import OctreeStage

    floor_z = float(sc["floor_z"])
    omni = omni_model()
    offset = np.array([0.0, 0.0, floor_z])  # the omni model's origin is the floor under the platform centre

    def q_full(q_arm):
        return np.concatenate([np.zeros(3), q_arm])

    def capsules(q_arm):
        a, b, r = omni.link_capsules(q_full(q_arm))
        return a + offset, b + offset, r

    box = VoxelBox.around([-2.1, -2.1, floor_z + 0.1], [2.1, 2.1, floor_z + 2.1], res)
    av = sc.get("avoidance", {})
    return OctreeStage(
        cell, cell.cameras, box, reach_model=omni, reach_q=q_full, reach_offset=offset,
        lasers=[LaserSim(cell.model, s, seed=i) for i, s in enumerate(scanners)], scan_capsules=capsules,
        mode=mode, rho=float(av.get("rho", 0.4)), dist_mode=sc.get("mode", "hybrid"),
        alpha=float(av.get("alpha", 6.0)), horizon=float(sc.get("horizon", 0.5)),
        reach_res=float(sc.get("reach_res", 0.09)),
    )  # fmt: skip


def _run_one(
    sc: dict, quick: bool, avoidance: bool, progress: bool, mode: str, res: float, label: str, view: int | None = None
):
    from depthguard.sim.depthcam import KinectSim
    from depthguard.sim.live_run import run_loop_viewed
    from depthguard.sim.loop import LoopConfig
    from depthguard.sim.pipeline import Controller
    from depthguard.sim.scenario_setup import scenario_task

    cell, kin, scanners = _build(sc, quick)
    cams = [KinectSim(cell.model, c, i, seed=i) for i, c in enumerate(cell.cameras)]
    stage = _stage(sc, cell, kin, scanners, mode, res)
    av = sc.get("avoidance", {})
    alpha = float(av.get("alpha", 6.0))
    ctrl = Controller(
        kin, cell.q(), rho=float(av.get("rho", 0.4)), vmax=float(av.get("vmax", 1.0)), alpha=alpha,
        rho_body=float(av.get("rho_body", 0.3)), alpha_body=alpha,
    )  # fmt: skip
    ee0 = kin.evaluate(cell.q()).centres[0]
    task = scenario_task(sc, ee0)
    cfg = LoopConfig(
        duration=float(sc["quick_duration"] if quick else sc["duration"]), avoid=avoidance,
        rho=float(av.get("rho", 0.4)), vmax=float(av.get("vmax", 1.0)), alpha=float(av.get("alpha", 6.0)),
        progress=progress, label=label, distance_period=float(sc.get("distance_period", 0.003)),
        frame_period=float(sc["quick_frame_period"] if quick else sc["frame_period"]),
    )  # fmt: skip
    log = run_loop_viewed(view, cell, cams, kin, stage, ctrl, task, cfg)
    for c in cams:
        c.close()
    return cell, log, task, cfg, stage


def _stage_ms(log, stage) -> dict[str, float]:
    out = {"camera_capture": round(1e3 * float(np.median(log.wall_camera)), 3)}
    upd = np.asarray(stage.update_wall)
    n = min(len(upd), len(log.wall_frame))
    out["camera_selffilter"] = round(1e3 * float(np.median(np.asarray(log.wall_frame[:n]) - upd[:n])), 3)
    out.update(stage.stage_ms())
    return out


def _summary(log, task, cfg, stage) -> dict[str, Any]:
    from depthguard.sim.scenario_metrics import compute_metrics

    m = compute_metrics(log, task, cfg)
    m["stage_ms"] = _stage_ms(log, stage)
    if stage.reuse is not None:  # frames whose C(t) was a reused grid (depthguard.octree.reach_reuse)
        n = stage.reuse.reused + stage.reuse.computed
        m["reachability_reused"] = round(stage.reuse.reused / n, 3) if n else None
    counts = stage.counts
    m["octree_nodes_median"] = {k: int(np.median([c[k] for c in counts])) for k in counts[0]} if counts else {}
    return m


def run(
    name: str = "saphari-octree",
    quick: bool = False,
    avoidance: bool = True,
    out_dir: str | Path | None = None,
    progress: bool = False,
    options: dict | None = None,
) -> dict[str, Any]:
    """Run the scenario (``cli.EXTRA_SCENARIOS`` entry point); returns its metrics (module docstring)."""
    from depthguard.sim.scenarios import load_scenario

    options = options or {}
    sc = load_scenario(scenario_path())
    res = check_res(options.get("octree_res") or sc.get("octree_res", 0.05), "--octree-res")
    t0 = time.perf_counter()
    cell, log, task, cfg, stage = _run_one(
        sc, quick, avoidance, progress, "saphari", res, f"{name} (saphari)", view=options.get("view")
    )
    result: dict[str, Any] = {
        "scenario": name,
        "description": sc.get("description", ""),
        "quick": quick,
        "avoidance": avoidance,
        "backend": "octree",
        "octree_mode": "saphari",
        "octree_res": res,
        "sensors": {"cameras": len(cell.cameras), "scanners": len(stage.lasers)},
        "resolution": [cell.cameras[0].width, cell.cameras[0].height],
        "control_points": list(log.point_names),
    }
    result.update(_summary(log, task, cfg, stage))
    runs = {"main": (log, task)}
    if avoidance:
        _, vlog, vtask, vcfg, vstage = _run_one(
            sc, quick, avoidance, progress, "conservative", res, f"{name} (conservative)"
        )
        result["variants"] = {"conservative": _summary(vlog, vtask, vcfg, vstage)}
        runs["conservative"] = (vlog, vtask)
    result["wall_seconds_total"] = round(time.perf_counter() - t0, 2)
    if out_dir is not None:
        from depthguard.sim.saphari_octree_out import write_outputs

        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        result["out_dir"] = str(out)
        result["files"] = write_outputs(out, cell, log, stage, runs, name)
        (out / "metrics.json").write_text(json.dumps(result, indent=2, default=float))
    return result
