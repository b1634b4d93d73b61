"""The metrics of a scenario run (:mod:`depthguard.sim.scenarios`).

Metrics (ground truth from ``mj_geomDistance``, never seen by the pipeline):

* ``min_clearance`` (m), overall and per robot link (``min_clearance_per_link``);
* ``collision_steps``: 1 ms physics steps with a true clearance <= 0;
* ``time_below_margin_s``: time with a true clearance below 5 cm;
* ``path_error`` (m): RMS distance of the end effector from the nominal task path
  (the polyline through the waypoints; for a "hold" task the hold point); ``path_error_max``;
* ``task_completion``: fraction of the task's waypoints reached (hold task: 1 if the end effector is
  back within 3 cm at the end);
* ``distance_hz_median`` / ``distance_hz_p99``: wall-clock rate of the distance stage, ``1 / t`` for the
  median and the 99th-percentile call time ``t`` (control points + distances + repulsion);
* ``control_ms_p99``: 99th-percentile wall time of one control cycle; frame-stage timings likewise;
* ``max_over_report``, ``median_under_report``, ``time_at_zero_s``, ``declared_tolerance``: evaluated
  against true distances per control point and distance-stage call (:mod:`depthguard.sim.accuracy`);
* ``measured_bound``: on 24 sampled calls, the under-report split into what no camera measures and what
  the distance stage adds (:func:`depthguard.sim.accuracy.measured_bound_metrics`,
  :mod:`depthguard.sim.measured_bound`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from depthguard.sim.accuracy import accuracy_metrics

__all__ = ["MARGIN", "compute_metrics", "ssm_keys"]

MARGIN = 0.05  # m: the clearance below which time counts in ``time_below_margin_s``


def _path_distance(points: np.ndarray, path: np.ndarray) -> np.ndarray:
    """Distance from each of (T, 3) points to the polyline (P, 3)."""
    if len(path) == 1:
        return np.linalg.norm(points - path[0], axis=1)
    best = np.full(len(points), np.inf)
    for a, b in zip(path[:-1], path[1:], strict=True):
        ab = b - a
        s = np.clip((points - a) @ ab / max(ab @ ab, 1e-12), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(points - (a + s[:, None] * ab), axis=1))
    return best


def compute_metrics(log, task, cfg) -> dict[str, Any]:
    """Metrics of one run from its :class:`~depthguard.sim.loop.SimLog` (see the module docstring)."""
    steps = np.asarray(log.step_true_min)
    links = np.asarray(log.true_links)
    ee = np.asarray(log.ee)
    pe = _path_distance(ee, task.path())
    if task.kind == "hold":
        completion = 1.0 if pe[-1] < 0.03 else 0.0
    else:
        completion = min(task.reached, len(task.waypoints) if task.kind == "points" else task.reached) / (
            len(task.waypoints)
        )
        completion = float(min(completion, 1.0))

    def hz(ts: list[float], q: float) -> float:
        return float(1.0 / np.percentile(ts, q)) if ts else 0.0

    wd, wc, wf = log.wall_distance, log.wall_control, log.wall_frame
    t_dist = np.asarray(log.t_distance)
    out = {
        "collision_steps": int(np.sum(steps <= 0.0)),
        "min_clearance": float(np.min(steps)) if len(steps) else None,
        "min_clearance_per_link": {n: float(v) for n, v in zip(log.links, links.min(axis=0), strict=True)},
        "min_clearance_people_boxes": float(np.min(log.true_dynamic)) if log.true_dynamic else None,
        "time_below_margin_s": float(np.sum(steps < MARGIN) * cfg.control_dt),
        "path_error": float(np.sqrt(np.mean(pe**2))),
        "path_error_max": float(np.max(pe)),
        "task_completion": completion,
        "waypoints_reached": int(task.reached),
        "distance_hz_median": hz(wd, 50),
        "distance_hz_p99": hz(wd, 99),
        "distance_ms_median": float(np.median(wd) * 1e3) if wd else None,
        "distance_stage_sim_hz": float(1.0 / np.median(np.diff(t_dist))) if len(t_dist) > 1 else 0.0,
        "control_ms_median": float(np.median(wc) * 1e3),
        "control_ms_p99": float(np.percentile(wc, 99) * 1e3),
        "frame_ms_median": float(np.median(wf) * 1e3) if wf else None,
        "frame_ms_p99": float(np.percentile(wf, 99) * 1e3) if wf else None,
        "camera_ms_median": float(np.median(log.wall_camera) * 1e3) if log.wall_camera else None,
        "frames": len(log.wall_frame),
        "sim_seconds": cfg.duration,
        "wall_seconds": round(log.wall_total, 2),
        "collided_with": dict(log.nearest_obstacle),
    }
    out.update(accuracy_metrics(log, cfg.rho, cfg.distance_period))
    return out


def ssm_keys(log, cfg, on: bool) -> dict[str, Any]:
    """The SSM keys of a run (:func:`depthguard.sim.ssm_metrics.ssm_metrics`); ``{"ssm": False}`` when off."""
    if not on or getattr(log, "ssm", None) is None:
        return {"ssm": False}
    from depthguard.sim.ssm_metrics import ssm_metrics

    return ssm_metrics(log.ssm, cfg.control_dt, log.point_names)
