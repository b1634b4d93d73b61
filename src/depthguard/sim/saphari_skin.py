"""Scenario ``saphari-skin``: the proximity/contact skin with Gray-coded safety levels (SAPHARI D4.1.1
§4.3, Table 1, Fig. 11).

A UR5 follows a circular TCP path at 400 mm/s. A hand approaches the 49-element skin on its forearm at
0.25 m/s, touches it and withdraws (:mod:`~depthguard.sim.skin_cell`). Every 1 ms the host reads the skin,
maps the strongest proximity signal and the contact flags to a target level (:class:`LevelMap`, hysteresis),
and steps the three lines one level at a time, each held ``line skew + robot sampling period``
(:class:`LevelStepper`). The lines switch with per-line delays and the robot controller samples them every
2 ms (:class:`SkewedLines`), decodes the level, and ramps its path speed (acceleration ``a_max``) to the
Table 1 speed of that level. The same line writes are decoded as natural binary to count its glitches.
With ``avoidance=False`` the robot ignores the lines (always 400 mm/s).

Metrics (JSON): ``max_speed_at_contact_mm_s`` (measured TCP speed at the first step with true contact),
``gray_code_glitches``, ``binary_code_glitches``, ``online_gray_glitches`` (glitches in what the robot
actually read in the loop), ``binary_multibit_transitions`` (occurrences and how many had a robot sample
inside their skew window), ``detection_to_stop_s`` (first proximity detection to a
measured TCP speed below 1 mm/s), ``contact_to_stop_s``, ``resume_s`` (end of contact to TCP speed above
10 mm/s again), ``full_speed_s``, ``extra_stop_delay_s`` (worst case of one-level stepping, 0 -> 7); and
the common keys: ``collision_steps`` = 1 ms steps with the hand touching the skin (the touch is intended
here), ``min_clearance`` (palm-skin, m, negative = pressed in), ``task_completion`` (path length travelled
over the nominal at 400 mm/s), ``path_error`` (RMS distance of the TCP from the circle, m),
``distance_hz_median`` = null (no distance stage: the skin is read at the host's 1 kHz).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from depthguard.sensors.graycode import SkewedLines, count_glitches, multibit_windows_sampled, simulate_lines
from depthguard.sensors.levels import TABLE1_SPEEDS, LevelMap, LevelStepper, extra_stop_delay, hold_time
from depthguard.sensors.taxel import SKIN_REFLECTIVITY, ContactTaxel, ProximityTaxel
from depthguard.sim.skin_cell import HandScript, SkinCell

__all__ = ["SkinParams", "run_skin", "skin_metrics", "run"]


@dataclass
class SkinParams:
    """Parameters of the skin experiment (SI units)."""

    duration: float = 2.0
    dt: float = 1e-3  # host and simulation step
    io_period: float = 2e-3  # robot controller's sampling of the digital lines
    io_phase: float = 0.3e-3
    line_delays: tuple[float, float, float] = (0.0, 2.2e-3, 4.4e-3)
    speeds: tuple[float, ...] = TABLE1_SPEEDS
    a_max: float = 4.0  # TCP path acceleration limit, m/s^2
    level_distances: tuple[float, ...] = (0.050, 0.040, 0.032, 0.025, 0.020, 0.016)  # levels 1-6 on skin, m
    hysteresis: float = 4.0  # counts
    q0: tuple[float, ...] = (0.0, -1.9, 1.9, -1.57, -1.57, 0.0)
    centre: tuple[float, float, float] = (0.40, 0.11, 0.36)
    radius: float = 0.10
    clik_gain: float = 50.0
    hands: tuple[HandScript, ...] = field(default_factory=lambda: (HandScript(),))
    hand_module: int = 2
    seed: int = 0
    avoidance: bool = True


def _circle(params: SkinParams, s: float) -> tuple[np.ndarray, np.ndarray]:
    c, r = np.asarray(params.centre), params.radius
    a = s / r
    return c + r * np.array([np.cos(a), np.sin(a), 0.0]), np.array([-np.sin(a), np.cos(a), 0.0])


def _robot_step(robot, params: SkinParams, q: np.ndarray, s: float, s_dot: float, v_cmd: float):
    """The robot controller's 1 ms: path speed ramped to ``v_cmd`` at ``a_max``, path parameter, CLIK."""
    s_dot += float(np.clip(v_cmd - s_dot, -params.a_max * params.dt, params.a_max * params.dt))
    s += s_dot * params.dt
    x_d, tang = _circle(params, s)
    _, p = robot.frame_pose(q)
    J = robot.frame_jacobian(q)[:3]
    qdot = J.T @ np.linalg.solve(J @ J.T + 1e-8 * np.eye(3), tang * s_dot + params.clik_gain * (x_d - p))
    return q + params.dt * qdot, s, s_dot


def run_skin(params: SkinParams, progress: bool = False) -> dict:
    """Simulate the experiment; returns the time series (dict of arrays) and the line writes."""
    from depthguard.robot.model import RobotModel
    from depthguard.sim.skin_cell import ur5_urdf_path

    rng = np.random.default_rng(params.seed)
    cell = SkinCell(hand_module=params.hand_module)
    robot = RobotModel.from_urdf(ur5_urdf_path(), ee_frame="tool0")
    prox, cont = ProximityTaxel(), ContactTaxel()
    lmap = LevelMap(tuple(prox.counts_at(x, SKIN_REFLECTIVITY) for x in params.level_distances), params.hysteresis)
    skew = max(params.line_delays) - min(params.line_delays)
    stepper = LevelStepper(hold=hold_time(skew, params.io_period))
    lines = SkewedLines(params.line_delays, "gray")
    q = np.array(params.q0, float)
    # start on the path: converge the CLIK onto the circle's start point
    for _ in range(300):
        x_d, _ = _circle(params, 0.0)
        _, p = robot.frame_pose(q)
        q = q + np.linalg.pinv(robot.frame_jacobian(q)[:3]) @ (x_d - p)
    n = int(round(params.duration / params.dt))
    log = {
        k: np.zeros(n) for k in ("t", "signal", "target", "sent", "read", "v_cmd", "v_path", "v_tcp", "gap", "clear")
    }
    log["contact"] = np.zeros(n, bool)
    log["q"] = np.zeros((n, 6))
    log["tcp"] = np.zeros((n, 3))
    log["dev"] = np.zeros(n)
    s, s_dot, level_read = 0.0, params.speeds[0], 0
    writes_t, writes_l = [0.0], [0]
    lines.write(0.0, 0)
    cell.set_state(q, params.hands[0].far_gap)
    tcp_prev = cell.tcp()
    next_io = params.io_phase
    online_glitches = 0
    for i in range(n):
        t = i * params.dt
        gap = min(h.gap(t) for h in params.hands)
        cell.set_state(q, gap)
        r = cell.ranges()
        counts = prox.counts(np.where(cell.is_prox, r, np.inf), SKIN_REFLECTIVITY, rng)
        force = cont.force(np.where(np.isfinite(r), -r, 0.0))
        contact = bool(np.any(cont.in_contact(cont.counts(force, rng))[~cell.is_prox]))
        signal = float(counts[cell.is_prox].max())
        target = lmap.update(signal, contact)
        level, wrote = stepper.update(t, target)
        if wrote:
            lines.write(t, level)
            writes_t.append(t)
            writes_l.append(level)
        while next_io <= t + 1e-12:  # the robot controller samples the lines
            level_read = lines.read(next_io)
            k = int(np.searchsorted(writes_t, next_io, side="right")) - 1  # last write at or before the sample
            online_glitches += level_read not in (writes_l[k], writes_l[max(k - 1, 0)])
            next_io += params.io_period
        v_cmd = params.speeds[level_read] if params.avoidance else params.speeds[0]
        q, s, s_dot = _robot_step(robot, params, q, s, s_dot, v_cmd)
        tcp = cell.tcp()
        rad = np.linalg.norm((tcp - np.asarray(params.centre))[:2])
        for k, v in (
            ("t", t), ("signal", signal), ("target", target), ("sent", level), ("read", level_read),
            ("v_cmd", v_cmd), ("v_path", s_dot), ("v_tcp", np.linalg.norm(tcp - tcp_prev) / params.dt),
            ("gap", gap), ("clear", cell.clearance()),
        ):  # fmt: skip
            log[k][i] = v
        log["contact"][i] = contact
        log["q"][i] = q
        log["tcp"][i] = tcp
        log["dev"][i] = np.hypot(rad - params.radius, tcp[2] - params.centre[2])
        tcp_prev = tcp
        if progress and i % 500 == 0:
            print(f"  t = {t:.2f} s  level {level}  signal {signal:.0f}", flush=True)
    log["v_tcp"][0] = log["v_tcp"][1]
    log["writes_t"], log["writes_l"] = np.array(writes_t), np.array(writes_l)
    log["online_glitches"] = online_glitches
    log["thresholds"] = np.array(lmap.thresholds)
    return log


def _first(mask: np.ndarray, start: int = 0) -> int | None:
    idx = np.flatnonzero(mask[start:])
    return int(idx[0]) + start if idx.size else None


def skin_metrics(log: dict, params: SkinParams) -> dict:
    """The scenario's JSON metrics (module docstring) from a :func:`run_skin` log."""
    t, dt = log["t"], params.dt
    touch = log["clear"] <= 0.0
    i_c = _first(touch)
    i_det = _first(log["sent"] >= 1)
    stopped = log["v_tcp"] < 1e-3
    i_stop = _first(stopped, i_det) if i_det is not None else None
    i_stop_c = _first(stopped, i_c) if i_c is not None else None
    i_free = _first(~touch, i_c) if i_c is not None else None
    i_res = _first(log["v_tcp"] > 0.010, i_free) if i_free is not None else None
    i_full = _first(log["v_tcp"] > 0.395, i_free) if i_free is not None else None
    skew = max(params.line_delays) - min(params.line_delays)
    args = (log["writes_t"], log["writes_l"], float(t[-1]), params.line_delays, params.io_period, params.io_phase)
    gray = simulate_lines(*args, code="gray")
    binary = simulate_lines(*args, code="binary")
    nominal = params.speeds[0] * (t[-1] + dt)
    travelled = float(np.sum(log["v_tcp"]) * dt)

    def dtime(a, b):
        return None if a is None or b is None else float((b - a) * dt)

    return {
        "collision_steps": int(np.count_nonzero(touch)),
        "min_clearance": float(np.min(log["clear"])),
        "task_completion": float(min(travelled / nominal, 1.0)) if params.avoidance else 1.0,
        "path_error": float(np.sqrt(np.mean(log["dev"] ** 2))),
        "distance_hz_median": None,
        "max_speed_at_contact_mm_s": None if i_c is None else float(log["v_tcp"][i_c] * 1e3),
        "gray_code_glitches": count_glitches(gray),
        "binary_code_glitches": count_glitches(binary),
        "binary_multibit_transitions": multibit_windows_sampled(*args),
        "online_gray_glitches": int(log["online_glitches"]),
        "detection_to_stop_s": dtime(i_det, i_stop),
        "contact_to_stop_s": dtime(i_c, i_stop_c),
        "resume_s": dtime(i_free, i_res),
        "full_speed_s": dtime(i_free, i_full),
        "hold_time_s": hold_time(skew, params.io_period),
        "extra_stop_delay_s": extra_stop_delay(skew, params.io_period),
        "line_delays_s": list(params.line_delays),
        "io_period_s": params.io_period,
        "max_level": int(log["sent"].max()),
    }


def run(name: str, quick: bool, avoidance: bool, out_dir: str | None, progress: bool, options: dict) -> dict:
    """CLI entry (``depthguard scenario saphari-skin``): the quick run has one touch (2 s), the full one
    two touches (4.5 s)."""
    params = SkinParams(avoidance=avoidance)
    if not quick:
        params.duration = 4.5
        params.hands = (HandScript(), HandScript(t0=2.2, start_gap=0.15, hold=0.6))
    t0 = time.perf_counter()
    log = run_skin(params, progress)
    out = {"scenario": name, "quick": quick, "avoidance": avoidance, **skin_metrics(log, params)}
    out["wall_s"] = time.perf_counter() - t0
    if out_dir:
        from depthguard.viz.saphari_plots import plot_skin

        d = Path(out_dir)
        d.mkdir(parents=True, exist_ok=True)
        out["files"] = plot_skin(d, log, params)
        out["files"]["recording"] = str(_record(d / "recording.mcap", log))
        import json

        (d / "metrics.json").write_text(json.dumps(out, indent=2, default=float))
    return out


def _record(path: Path, log: dict) -> Path:
    from depthguard.sim.mcap_log import write_mcap

    idx = range(0, len(log["t"]), 10)
    ch = {
        "/joint_states": [(log["t"][i], {"position": log["q"][i]}) for i in idx],
        "/skin/signal": [
            (log["t"][i], {"proximity_counts": log["signal"][i], "contact": bool(log["contact"][i])}) for i in idx
        ],
        "/safety_level": [
            (log["t"][i], {"target": int(log["target"][i]), "sent": int(log["sent"][i]), "read": int(log["read"][i])})
            for i in idx
        ],
        "/tcp": [
            (log["t"][i], {"position": log["tcp"][i], "speed_cmd": log["v_cmd"][i], "speed": log["v_tcp"][i]})
            for i in idx
        ],
        "/hand": [(log["t"][i], {"gap": log["gap"][i], "clearance": log["clear"][i]}) for i in idx],
    }
    return write_mcap(path, ch)
