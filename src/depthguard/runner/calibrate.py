"""``depthguard calibrate``: camera extrinsics of a cell from the arm itself (SAPHARI §3.3), on a source.

Frames: from a ROS 2 bag, the depth frames at arm poses at least ``min_pose_change`` rad apart from every
pose taken before (at least 5); from the simulated cell (``sim:SCENARIO``), the scenario's cell without its
people with the arm put at six poses spread over the workspace (what a calibration routine on a real arm
commands). The cell file's extrinsics are the initial guess. The result goes into a calibration file (TOML:
per camera ``R``, ``t``, its ``parent`` frame, the date, the residual) that the cell file references with
``calibration = "FILE"``; a refused calibration writes nothing and exits with an error naming the fitness.
A camera carried by a link (``parent`` = a link) is calibrated in that link's frame from a bag in which the
link stays still (a parked platform; :func:`depthguard.robot.calibration.still_link_pose`).

The summary shows the effect per camera, with the initial guess and with the result: the robot pixels that the
self-filter leaves (``robot_pixels_left_guess_vs_calibrated``), how much the control points' distances change
(``distance_change_m``) and the self-filter margin the residual must stay inside (``self_filter_margin_m``);
from the simulated cell, whose true extrinsics are known, also ``truth``: the position and angle errors, how
far the robot surface is misplaced (``robot_surface_shift_m_guess_vs_calibrated``, to compare with the margin)
and the largest distance error of the control points (``distance_error_m_guess_vs_calibrated``).
"""

from __future__ import annotations

import datetime as _dt
import inspect
import json
from pathlib import Path
from typing import Any

import numpy as np

from depthguard.io.cellfile import CellFile, read_cell
from depthguard.robot.selffilter import self_filter

__all__ = ["calibrate_cell", "CALIBRATION_POSES", "SELF_FILTER_MARGIN"]

#: The self-filter's margin in the chain (``Chain.on_frames`` uses :func:`self_filter`'s default), m: the
#: residual calibration error must stay well inside it.
SELF_FILTER_MARGIN = float(inspect.signature(self_filter).parameters["margin"].default)

#: Arm poses of the simulated calibration routine (rad, 7 joints): spread out, none symmetric to another.
CALIBRATION_POSES = (
    (0.3, 0.5, 0.0, -1.2, 0.0, 0.8, 0.0),
    (-0.8, -0.4, 0.5, 1.4, 0.3, -0.6, 0.0),
    (1.2, 0.9, -0.4, 0.6, -0.5, 0.9, 0.5),
    (0.0, -0.9, 0.0, -1.5, 1.0, 0.5, 0.0),
    (-0.4, 0.3, 1.2, 1.8, -1.0, -0.3, 0.2),
    (0.9, -0.2, -1.0, -0.8, 0.6, 1.2, -0.4),
)


def _sim_frames(scenario: str, quick: bool) -> tuple[list, list[list[tuple[np.ndarray, np.ndarray]]]]:
    from depthguard.sim.depthcam import KinectSim
    from depthguard.sim.scenario_setup import build_scenario_cell
    from depthguard.sim.scenarios import load_scenario

    sc = load_scenario(scenario)
    sc["people"] = []
    cell, _, _ = build_scenario_cell(sc, quick=quick, cameras=None)
    sims = [KinectSim(cell.model, c, i, seed=11 + i) for i, c in enumerate(cell.cameras)]
    per_cam: list[list[tuple[np.ndarray, np.ndarray]]] = [[] for _ in sims]
    for q in CALIBRATION_POSES:
        cell.set_q(np.array(q))
        for k, s in enumerate(sims):
            per_cam[k].append((s.capture(cell.data), np.array(q)))
    for s in sims:
        s.close()
    return list(cell.cameras), per_cam


def _bag_frames(path: str, cell: CellFile, joint_names, min_change: float):
    from depthguard.runner.bag import BagSource

    src = BagSource(Path(path), cell, joint_names)
    per_cam: list[list[tuple[np.ndarray, np.ndarray]]] = [[] for _ in src.cameras]
    taken: list[np.ndarray] = []
    for tick in src.ticks():
        if tick.frames is None or tick.q is None:
            continue
        if all(np.linalg.norm(tick.q - p) >= min_change for p in taken):
            taken.append(tick.q.copy())
            for k, d in enumerate(tick.frames):
                per_cam[k].append((d, tick.q.copy()))
    return src.cameras, per_cam


def calibrate_cell(
    cell_path: str | Path,
    source: str,
    *,
    write: str | Path | None = None,
    quick: bool = False,
    min_pose_change: float = 0.3,
) -> dict[str, Any]:
    """Calibrate every camera of the cell; write the calibration file (default: ``<cell>.calibration.toml``)
    when every camera is accepted. Returns a JSON-ready summary; raises ``ValueError`` when refused."""
    from depthguard.robot.calibration import calibrate_extrinsics
    from depthguard.runner.carried import refuse_carried_cameras
    from depthguard.runner.chain import load_cell_robot

    cell = read_cell(cell_path)
    model = load_cell_robot(cell)
    kind, _, arg = source.partition(":")
    if kind == "sim":
        refuse_carried_cameras(
            cell, "`depthguard calibrate --source sim:...`", "calibrate a carried camera from a bag: --source bag:PATH"
        )
        cameras, per_cam = _sim_frames(arg, quick)
        # the cell file's extrinsics are the guess; the simulated cameras are the truth (reported)
        guesses = [
            cc.build(**_intrinsics(cam)) if cc.R is not None else cam
            for cc, cam in zip(cell.cameras, cameras, strict=True)
        ]
    elif kind == "bag":
        cameras, per_cam = _bag_frames(arg, cell, model.joint_names, min_pose_change)
        guesses = cameras
    else:
        raise ValueError(f"--source must be bag:PATH or sim:SCENARIO for a calibration, got {source!r}")
    out: dict[str, Any] = {"cell": cell.name, "source": source, "cameras": []}
    results = []
    truths = cameras if kind == "sim" else [None] * len(guesses)
    for cc, guess, frames, truth in zip(cell.cameras, guesses, per_cam, truths, strict=True):
        if len(frames) < 5:
            raise ValueError(
                f"{source}: camera '{cc.name}' has {len(frames)} frames at distinct arm poses; a calibration needs"
                f" at least 5 (poses at least {min_pose_change} rad apart)"
            )
        link = None if cc.parent == "world" else cc.parent
        res = calibrate_extrinsics(guess, frames, model, link=link)
        out["cameras"].append(_camera_entry(cell, model, cc.name, link, guess, res, frames, truth))
        results.append((cc.name, cc.parent, res))
    refused = [e for e in out["cameras"] if not e["accepted"]]
    if refused:
        raise ValueError("; ".join(f"camera '{e['name']}': {e['message']}" for e in refused))
    path = Path(write) if write else Path(cell.path).with_suffix(".calibration.toml")
    _write_calibration(path, results)
    out["written"] = str(path)
    return out


def _angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> float:
    return float(np.rad2deg(np.arccos(np.clip((np.trace(Ra @ Rb.T) - 1) / 2, -1, 1))))


def _camera_entry(cell: CellFile, model, name: str, link, guess, res, frames, truth) -> dict[str, Any]:
    """The summary of one camera's calibration ``res`` from ``guess``: fitness, the correction, and its effect
    on the chain: robot pixels the self-filter leaves (robot pixels: those the arm's motion reveals,
    independent of any pose) and the distances of the cell's control points (cell's distance settings,
    this camera alone), with the guess and with the result. With the simulated cameras' ``truth`` (sim
    sources) also the errors from the truth: camera position and angle, how far the robot surface seen by
    the true camera is misplaced (``robot_surface_shift_m``: what the self-filter margin must cover) and
    the distance error."""
    from depthguard.robot.calibration import moving_pixels

    calibrated = guess.with_pose(res.R, res.t)
    robot = moving_pixels([d for d, _ in frames])
    effect = {k: _chain_effect(cell, model, c, frames, robot, link) for k, c in (("guess", guess), ("cal", calibrated))}
    entry: dict[str, Any] = {
        "name": name,
        "accepted": res.accepted,
        "message": res.message,
        "rmse_m": res.rmse,
        "inlier_fraction": res.inlier_fraction,
        "poses": len(frames),
        "correction_m": float(np.linalg.norm(calibrated.position - guess.position)),
        "correction_deg": _angle_deg(res.R, guess.R),
        "robot_pixels_left_guess_vs_calibrated": [effect["guess"][0], effect["cal"][0]],
        "distance_change_m": float(np.max(np.abs(effect["guess"][1] - effect["cal"][1]), initial=0.0)),
        "self_filter_margin_m": SELF_FILTER_MARGIN,
    }
    if truth is not None:  # the simulated cell: the true extrinsics are known
        d_true = _chain_effect(cell, model, truth, frames, robot, link)[1]
        est = (guess, calibrated)
        entry["truth"] = {
            "position_error_m_guess_vs_calibrated": [float(np.linalg.norm(c.position - truth.position)) for c in est],
            "angle_error_deg_guess_vs_calibrated": [_angle_deg(c.R, truth.R) for c in est],
            "robot_surface_shift_m_guess_vs_calibrated": [_surface_shift(model, truth, c, frames) for c in est],
            "distance_error_m_guess_vs_calibrated": [
                float(np.max(np.abs(effect[k][1] - d_true), initial=0.0)) for k in ("guess", "cal")
            ],
        }
    return entry


def _chain_effect(cell: CellFile, model, cam, frames, robot, link) -> tuple[int, np.ndarray]:
    """With the camera ``cam`` (its pose in ``link``'s frame when ``link``): the robot pixels of ``robot``
    (per frame (H, W) bool) that the self-filter leaves, summed over the frames, and the control points'
    distances per frame (F, N), m, capped at rho (nothing within rho: rho)."""
    from depthguard.runner.carried import carried_camera
    from depthguard.runner.chain import cell_control_points, cell_distance_stage

    points = cell_control_points(cell, model)
    rho = float(cell.distance["rho"])
    left, dist = 0, []
    for (d, q), m in zip(frames, robot, strict=True):
        c = cam if link is None else carried_camera(cam, model, q, link)
        mask = np.asarray(self_filter(c, d, q, model, margin=SELF_FILTER_MARGIN, with_depth=False)[0])
        left += int(np.sum(m & ~mask))
        stage = cell_distance_stage(cell, [c])
        stage.update([d], [mask], q, model)
        cps = points.evaluate(q)
        dist.append(np.minimum(np.asarray(stage.query(cps.centres, cps.radii).distance, float), rho))
    return left, np.asarray(dist)


def _surface_shift(model, truth, cam, frames, spacing: float = 0.01) -> float:
    """How far the robot surface is misplaced with ``cam`` instead of the ``truth`` (world cameras): the largest
    distance, over the robot's surface at every pose, between a point and where ``cam`` puts the point that
    ``truth`` measures there, m."""
    from depthguard.robot.calibration import capsule_surface_points

    worst = 0.0
    for _, q in frames:
        p, _ = capsule_surface_points(*model.link_capsules(np.asarray(q, float)), spacing)
        moved = cam.camera_to_world(truth.world_to_camera(p))
        worst = max(worst, float(np.linalg.norm(moved - p, axis=1).max()))
    return worst


def _intrinsics(cam) -> dict[str, float]:
    return dict(width=cam.width, height=cam.height, fx=cam.fx, fy=cam.fy, cx=cam.cx, cy=cam.cy)


def _toml_string(s: str) -> str:
    """``s`` as a TOML basic string that reads back as ``s`` for every name a cell file can hold: JSON's escapes
    are TOML's, except ``\\uXXXX`` surrogate pairs (non-BMP characters such as an emoji), which TOML refuses:
    those stay literal UTF-8, and DEL, which TOML wants escaped, is escaped."""
    return json.dumps(s, ensure_ascii=False).replace("\x7f", "\\u007f")


def _write_calibration(path: Path, results) -> None:
    """The calibration file (UTF-8 TOML); the names (camera, parent) are written so that they read back."""
    date = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
    lines = [
        "# Camera extrinsics from `depthguard calibrate` (SAPHARI §3.3): P_camera = R P_world + t.",
        '# Reference it from the cell file with: calibration = "' + path.name + '"',
    ]
    for name, parent, res in results:
        lines += [
            "",
            "[[cameras]]",
            f"name = {_toml_string(name)}",
            f"parent = {_toml_string(parent)}  # the frame of R, t: P_camera = R P_parent + t",
            f"R = {json.dumps(np.round(res.R, 12).tolist())}",
            f"t = {json.dumps(np.round(res.t, 12).tolist())}",
            f"date = {json.dumps(date)}",
            f"rmse = {res.rmse:.6g}",
            f"inlier_fraction = {res.inlier_fraction:.4g}",
        ]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
