"""Scenario ``saphari-nsb``: distributed proximity sensing and NSB control on a youBot-like mobile
manipulator (SAPHARI D4.1.1 §5.3, Figs. 14-20).

The place task: the robot opens its gripper, moves to a handover point where a person gives it an object,
closes the gripper and carries the object into a box 1.6 m ahead. The end-effector path is planned off
line (minimum-jerk segments through the waypoints, position only). The NSB controller
(:mod:`depthguard.control.nsb`) runs at the sensors' 300 Hz on the ten Sharp sensors' readings
(:mod:`depthguard.sim.nsb_cell`). Case studies, numbered as in the seed:

1. the task in an empty workspace, then with the box (the "stretched arm" correction, Fig. 14);
2. an unexpected obstacle between the box and the robot, planner off (= ``--case 3 --no-avoidance``);
3. the same with the planner on (the default);
4. a cluttered scene: two obstacles and an overhead beam.

Metrics: ``collision_steps`` (300 Hz steps with a true robot-obstacle clearance <= 0), ``min_clearance``
(m), ``task_completion`` (share of the planned path length followed within 3 cm), ``path_error`` (RMS
end-effector error, m), ``place_error`` (m), ``peak_energy`` (max sigma, m^2), ``chattering`` (total
variation of the commanded joint accelerations, sum over joints of |delta qddot| per second of run,
units/s^3), ``max_normalised_output`` (per sensor, 1 = peak output), ``distance_hz_median`` = null (the
sensors run at a fixed 300 Hz, ``sensor_rate_hz``).
With ``--out`` and case 3 the other two weighting functions are run too: ``chattering_by_lambda`` and
``chattering.png``.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from depthguard.control.nsb import NSBConfig, NSBController
from depthguard.robot.youbot import YOUBOT_Q0, YOUBOT_SENSORS, load_youbot
from depthguard.sim.nsb_cell import BOX_CENTRE, NSBCell, case_obstacles

__all__ = ["TaskPlan", "nsb_config", "run_case", "nsb_metrics", "run"]

BASE = np.array([0, 1, 2, 3, 7, 8])


@dataclass(frozen=True)
class TaskPlan:
    """The place task: waypoints (m) and segment durations (s); ``hold`` segments keep the point."""

    waypoints: tuple[tuple[float, float, float], ...]
    durations: tuple[float, ...]
    labels: tuple[str, ...]

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Desired position (3,) and velocity (3,) at time ``t`` (minimum-jerk segments)."""
        w = np.asarray(self.waypoints, float)
        t0 = 0.0
        for k, T in enumerate(self.durations):
            if t < t0 + T:
                s = (t - t0) / T
                p = 10 * s**3 - 15 * s**4 + 6 * s**5
                dp = (30 * s**2 - 60 * s**3 + 30 * s**4) / T
                return w[k] + p * (w[k + 1] - w[k]), dp * (w[k + 1] - w[k])
            t0 += T
        return w[-1].copy(), np.zeros(3)

    @property
    def duration(self) -> float:
        return float(sum(self.durations))


def place_task(ee0: np.ndarray, slow: float = 1.0) -> TaskPlan:
    """Open gripper (hold), go to the handover point, receive (hold), carry above the box, lower, release."""
    bx = BOX_CENTRE[0]
    hand = (0.60, 0.20, 0.40)
    above = (bx, 0.0, 0.36)
    inside = (bx, 0.0, 0.27)
    e = tuple(float(x) for x in ee0)
    wps = (e, e, hand, hand, above, inside, inside)
    durs = tuple(slow * x for x in (0.8, 2.0, 1.2, 8.0, 1.5, 1.0))
    labels = ("open gripper", "to the person", "receive, close gripper", "carry to the box", "lower", "release")
    return TaskPlan(wps, durs, labels)


def nsb_config(lambda_kind: str = "arctan") -> NSBConfig:
    """The experiment's controller: 300 Hz, arm favoured 5:1, springs of 0.20 m (base) and 0.12 m (arm)."""
    rest = tuple(0.20 if m.kind == "GP2Y0A21YK" else 0.12 for m in YOUBOT_SENSORS)
    return NSBConfig(
        dt=1 / 300, gamma_g=15.0, gamma_o=10.0, rest=rest, lambda_kind=lambda_kind, f=0.15, K=40.0, delta=0.10
    )


def run_case(obstacles, avoidance: bool, lambda_kind: str, slow: float = 1.0, seed: int = 0, progress: bool = False):
    """Simulate the place task among ``obstacles``; returns a log dict of arrays."""
    robot = load_youbot()
    cfg = nsb_config(lambda_kind)
    ctrl = NSBController(robot, YOUBOT_SENSORS, cfg)
    cell = NSBCell(obstacles, seed=seed)
    q = YOUBOT_Q0.copy()
    plan = place_task(ctrl.sensors.evaluate(q).ee_position, slow)
    n = int(round((plan.duration + 1.0) / cfg.dt))
    L = {k: np.zeros(n) for k in ("t", "sigma", "lam", "d_min", "clear", "err", "scale")}
    for k, shape in (("q", 8), ("qdot", 8), ("xd", 3), ("ee", 3), ("vnorm", 10), ("dist", 10), ("true", 10)):
        L[k] = np.zeros((n, shape))
    L["nearest"] = []
    L["self_hits"] = 0
    for i in range(n):
        t = i * cfg.dt
        cell.set_q(q)
        _, vn, dist = cell.read(t)
        x_d, xd_d = plan.at(t)
        out = ctrl.step(q, x_d, xd_d, dist if avoidance else np.full(10, np.inf))
        if not avoidance:  # still report the energy the sensors see (Fig. 16)
            out = out._replace(sigma=float(np.sum(np.where(dist <= ctrl.rest, 0.5 * (dist - ctrl.rest) ** 2, 0.0))))
        clr, name = cell.clearance()
        true = cell.last_true
        for k, v in (("t", t), ("sigma", out.sigma), ("lam", out.lam), ("d_min", float(np.min(dist))), ("clear", clr),
                     ("err", np.linalg.norm(x_d - out.ee)), ("scale", out.scale)):  # fmt: skip
            L[k][i] = v
        L["q"][i], L["qdot"][i], L["xd"][i], L["ee"][i] = q, out.qdot, x_d, out.ee
        L["vnorm"][i], L["dist"][i], L["true"][i] = vn, dist, true
        L["nearest"].append(name)
        q = np.clip(out.q_next, robot.q_min, robot.q_max)
        if progress and i % 600 == 0:
            print(f"  t = {t:5.1f} s  sigma {out.sigma:.4f}  lambda {out.lam:.2f}  clearance {clr:.3f} m", flush=True)
    L["plan"] = plan
    L["self_hits"] = cell.self_hits
    return L


def chattering(qdot: np.ndarray, dt: float) -> float:
    """Total variation of the commanded joint accelerations per second: sum |qddot[k+1] - qddot[k]| / T."""
    qdd = np.diff(qdot, axis=0) / dt
    return float(np.abs(np.diff(qdd, axis=0)).sum() / (len(qdot) * dt))


def nsb_metrics(L: dict, dt: float = 1 / 300, tol: float = 0.03) -> dict:
    """The scenario's JSON metrics (module docstring) from a :func:`run_case` log."""
    step = np.linalg.norm(np.diff(L["xd"], axis=0), axis=1)
    ok = L["err"][1:] <= tol
    return {
        "collision_steps": int(np.count_nonzero(L["clear"] <= 0.0)),
        "min_clearance": float(L["clear"].min()) if np.isfinite(L["clear"].min()) else None,
        "task_completion": float(step[ok].sum() / max(step.sum(), 1e-12)),
        "path_error": float(np.sqrt(np.mean(L["err"] ** 2))),
        "place_error": float(L["err"][-1]),
        "distance_hz_median": None,
        "sensor_rate_hz": 1 / dt,
        "peak_energy": float(L["sigma"].max()),
        "chattering": chattering(L["qdot"], dt),
        "max_lambda": float(L["lam"].max()),
        "max_normalised_output": [round(float(x), 3) for x in L["vnorm"].max(axis=0)],
        "self_detections": int(L["self_hits"]),
        "duration_s": float(L["t"][-1] + dt),
    }


def run(name: str, quick: bool, avoidance: bool, out_dir: str | None, progress: bool, options: dict) -> dict:
    """CLI entry (``depthguard scenario saphari-nsb [--case N] [--lambda K] [--no-avoidance]``)."""
    case = int(options.get("case") or 3)
    lam = options.get("lambda_") or "arctan"
    slow = 1.0 if quick else 2.0
    t0 = time.perf_counter()
    runs = {}
    if case == 1:
        runs["no box"] = run_case(case_obstacles(1, with_box=False), avoidance, lam, slow, progress=progress)
    if case == 2:
        avoidance = False
    runs["main"] = run_case(case_obstacles(case), avoidance, lam, slow, progress=progress)
    if progress and out_dir and case == 3 and avoidance:
        print("  (with --out, case 3 also runs the other two weighting functions for chattering.png)", flush=True)
    out = {"scenario": name, "case": case, "lambda": lam, "quick": quick, "avoidance": avoidance}
    out.update(nsb_metrics(runs["main"]))
    if "no box" in runs:
        out["no_box"] = nsb_metrics(runs["no box"])
    out["wall_s"] = time.perf_counter() - t0
    if out_dir:
        from depthguard.viz.saphari_plots import plot_nsb

        d = Path(out_dir)
        d.mkdir(parents=True, exist_ok=True)
        from depthguard.sim.nsb_cell import robot_outlines

        outlines = {}
        for key, L in runs.items():
            idx = np.linspace(0, len(L["t"]) - 1, 5).astype(int)
            obst = case_obstacles(1, with_box=False) if key == "no box" else case_obstacles(case)
            outlines[key] = (L["t"][idx], robot_outlines(obst, L["q"][idx]))
        out["files"] = plot_nsb(d, runs, case_obstacles(case), f"saphari-nsb case {case} ({lam})", outlines)
        if case == 3 and avoidance:  # the chattering comparison of the three weighting functions
            from depthguard.viz.saphari_plots import plot_chattering

            by = {lam: runs["main"]}
            for other in ("switch", "arctan", "linear"):
                if other not in by:
                    by[other] = run_case(case_obstacles(3), True, other, slow)
            out["chattering_by_lambda"] = {k: chattering(v["qdot"], 1 / 300) for k, v in by.items()}
            out["files"]["chattering"] = plot_chattering(d, by, out["chattering_by_lambda"])
        out["files"]["recording"] = str(_record(d / "recording.mcap", runs["main"]))
        (d / "metrics.json").write_text(json.dumps(out, indent=2, default=float))
    return out


def _record(path: Path, L: dict) -> Path:
    from depthguard.robot.youbot import load_youbot as _ly
    from depthguard.sim.mcap_log import write_mcap

    names = list(_ly().joint_names)
    idx = range(0, len(L["t"]), 3)
    ch = {
        "/joint_states": [(L["t"][i], {"name": names, "position": L["q"][i], "velocity": L["qdot"][i]}) for i in idx],
        "/proximity": [(L["t"][i], {"normalised": L["vnorm"][i], "distance": L["dist"][i]}) for i in idx],
        "/nsb": [(L["t"][i], {"sigma": L["sigma"][i], "lambda": L["lam"][i], "d_min": L["d_min"][i]}) for i in idx],
        "/end_effector": [(L["t"][i], {"desired": L["xd"][i], "actual": L["ee"][i]}) for i in idx],
        "/clearance": [(L["t"][i], {"true_min": L["clear"][i], "nearest": L["nearest"][i]}) for i in idx],
    }
    return write_mcap(path, ch)
