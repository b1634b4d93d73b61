"""The metrics of a scenario run (:mod:`depthguard.sim.scenarios`).

Metrics (ground truth from ``mj_geomDistance``, never seen by the pipeline):

* ``min_clearance`` (m), overall and per robot link (``min_clearance_per_link``);
* ``collision_steps``: 1 ms physics steps with a true clearance <= 0;
* ``time_below_margin_s``: time with a true clearance below 5 cm (a NaN truth counts in both, and makes
  ``min_clearance`` NaN: an unknown clearance is never read as a clear one);
* ``path_error`` (m): RMS distance of the end effector from the nominal task path
  (the polyline through the waypoints; for a "hold" task the hold point); ``path_error_max``;
* ``task_completion``: fraction of the task's waypoints reached (hold task: 1 if the end effector is
  back within 3 cm at the end);
* ``distance_hz_median`` / ``distance_hz_p99``: wall-clock rate of the distance stage, ``1 / t`` for the
  median and the 99th-percentile call time ``t`` (control points + distances + repulsion); 0 without calls,
  null where ``t`` is not a positive number (a zero time is no rate: JSON has no inf);
  ``distance_stage_sim_hz`` likewise from the median step between the calls' simulated times (in time order);
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
    """Distance (T,) m from each of (T, 3) points to the polyline through (P, 3) points, P >= 1 (m; a segment
    of zero length is its point)."""
    if len(path) == 1:
        return np.linalg.norm(points - path[0], axis=1)
    best = np.full(len(points), np.inf)
    for a, b in zip(path[:-1], path[1:], strict=True):
        ab = b - a
        ab2 = float(ab @ ab)  # (not floored: a floor of 1e-12 put the foot up to |ab| from the nearest point)
        s = np.clip((points - a) @ ab / ab2, 0.0, 1.0) if ab2 > 0 else np.zeros(len(points))
        best = np.minimum(best, np.linalg.norm(points - (a + s[:, None] * ab), axis=1))
    return best


def _rate(t: float) -> float | None:
    """``1 / t`` (Hz) for a time ``t`` (s); None unless ``t`` is a positive finite number."""
    return float(1.0 / t) if np.isfinite(t) and t > 0 else None


def _completion(task, pe: np.ndarray) -> float:
    """``task_completion``: fraction of the waypoints reached (capped at 1); for a hold task 1 when the last
    end-effector distance ``pe[-1]`` (m) from the hold point is below 3 cm, else 0 (also without rows)."""
    if task.kind == "hold":
        return 1.0 if len(pe) and pe[-1] < 0.03 else 0.0
    return float(min(task.reached / len(task.waypoints), 1.0))


def _timings(log) -> dict[str, Any]:
    """The wall-clock and rate keys of a run (module docstring); None where there is nothing to time."""
    wd, wc, wf = log.wall_distance, log.wall_control, log.wall_frame

    def hz(q: float) -> float | None:
        return _rate(float(np.percentile(wd, q))) if len(wd) else 0.0

    def ms(ts, q: float) -> float | None:
        return float(np.percentile(ts, q) * 1e3) if len(ts) else None

    t_dist = np.sort(np.asarray(log.t_distance, float))
    return {
        "distance_hz_median": hz(50),
        "distance_hz_p99": hz(99),
        "distance_ms_median": ms(wd, 50),
        "distance_stage_sim_hz": _rate(float(np.median(np.diff(t_dist)))) if len(t_dist) > 1 else 0.0,
        "control_ms_median": ms(wc, 50),
        "control_ms_p99": ms(wc, 99),
        "frame_ms_median": ms(wf, 50),
        "frame_ms_p99": ms(wf, 99),
        "camera_ms_median": ms(log.wall_camera, 50),
    }


def compute_metrics(log, task, cfg) -> dict[str, Any]:
    """Metrics of one run from its :class:`~depthguard.sim.loop.SimLog` (see the module docstring).

    ``task``: the run's :class:`~depthguard.sim.loop.Task`; ``cfg``: its :class:`~depthguard.sim.loop.LoopConfig`
    (``control_dt`` s, ``duration`` s, ``rho`` m, ``distance_period`` s). A log without rows gives None for the
    minima and the path error.
    """
    steps = np.asarray(log.step_true_min, float).reshape(-1)
    links = np.asarray(log.true_links, float)
    ee = np.asarray(log.ee, float).reshape(-1, 3)
    pe = _path_distance(ee, task.path()) if len(ee) else np.zeros(0)
    dyn = np.asarray(log.true_dynamic, float)
    out = {
        "collision_steps": int(np.sum(~(steps > 0.0))),  # (NaN counts)
        "min_clearance": float(np.min(steps)) if len(steps) else None,
        "min_clearance_per_link": {n: float(v) for n, v in zip(log.links, links.min(axis=0), strict=True)}
        if links.ndim == 2 and len(links)
        else {},
        "min_clearance_people_boxes": float(np.min(dyn)) if dyn.size else None,
        "time_below_margin_s": float(np.sum(~(steps >= MARGIN)) * cfg.control_dt),  # (NaN counts)
        "path_error": float(np.sqrt(np.mean(pe**2))) if len(pe) else None,
        "path_error_max": float(np.max(pe)) if len(pe) else None,
        "task_completion": _completion(task, pe),
        "waypoints_reached": int(task.reached),
        **_timings(log),
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
