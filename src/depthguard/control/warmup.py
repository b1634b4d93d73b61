"""Warming up the avoidance controller before a real-time loop (the controller node, ``run --realtime``).

Its cycle calls compiled kernels (numba) that are loaded from the kernel cache, or compiled, on their first
call; inside a real-time loop that first call once stalled the controller node for 6-7 s (twice: the moving
path, and the braking kernel at the first resume). :func:`warm_up` drives a throwaway controller through every
path of the cycle on synthetic input first; ``tests/test_controller_warmup.py`` checks that afterwards no
kernel is used for the first time.
"""

from __future__ import annotations

import numpy as np

from depthguard.control.cycle import AvoidanceController, CycleInput

__all__ = ["warm_up", "start_position"]


def start_position(q_min: np.ndarray, q_max: np.ndarray) -> np.ndarray:
    """Joint positions (n,) strictly inside the limits ``q_min``, ``q_max`` (n,), rad or m (∓inf allowed),
    wherever ``q_min < q_max``: the midpoint of a bounded joint (``0.5 lo + 0.5 hi``: no overflow), 0 for a
    joint unbounded both ways (a continuous joint), and ``max(1, |limit| / 1000)`` inside the one finite
    limit of a joint bounded on one side (``clip(0, lo, hi)`` put such a joint exactly on its limit when
    ``lo > 0``)."""
    lo, hi = np.asarray(q_min, dtype=float), np.asarray(q_max, dtype=float)
    fin_lo, fin_hi = np.isfinite(lo), np.isfinite(hi)
    lo0, hi0 = np.where(fin_lo, lo, 0.0), np.where(fin_hi, hi, 0.0)
    q = np.zeros_like(lo)
    q = np.where(fin_lo & fin_hi, 0.5 * lo0 + 0.5 * hi0, q)
    q = np.where(fin_lo & ~fin_hi, lo0 + np.maximum(1.0, np.abs(lo0) * 1e-3), q)
    return np.where(~fin_lo & fin_hi, hi0 - np.maximum(1.0, np.abs(hi0) * 1e-3), q)


def warm_up(points, config, model, cycles: int = 300) -> list[str]:
    """Run a throwaway controller through every path of its cycle on synthetic input, so that every compiled
    kernel is loaded (or compiled) before the node's first real cycle: a first use inside the real-time loop
    stalled the node for 6-7 s twice (the braking kernel, first used at the first resume).

    The phases, ``cycles`` simulated cycles each (more where a timeout or the resume latch must pass first;
    the robot at :func:`start_position`, an obstacle 0.3 m from every
    sphere unless said): no input yet (STOP_INVALID_INPUT); joint states only; every input fresh with a slow
    task velocity (OK, moving); the distances going stale (STOP_STALE_DISTANCES, jerk-limited braking); fresh
    again (STOP_RESUME_WAIT, for ``resume_time``, then OK); the monitor's own distances; no task velocity and
    nothing within range; obstacles at contact (SCALED or a stop); the joint states going stale
    (STOP_STALE_JOINTS). Returns the status names met, in order of first appearance (``[]`` when
    ``cycles`` is 0)."""
    if cycles <= 0:
        return []
    ctrl = AvoidanceController(points, config)
    q = start_position(model.q_min, model.q_max)
    qd, task = np.zeros_like(q), np.array([0.02, 0.0, 0.0])
    N = points.n_points
    near, none, touch = np.full(N, 0.3), np.full(N, np.inf), np.linspace(0.0, 0.05, N)
    up = np.tile([0.0, 0.0, 1.0], (N, 1))

    def past(seconds: float) -> int:  # cycles to run past a timeout or the latch, then ``cycles`` more
        return int(np.ceil(float(seconds) / config.dt)) + cycles

    # (cycles, joints fresh, task velocity, distances or None, distances fresh, with the monitor's)
    phases = [
        (cycles, None, task, None, False, False),
        (cycles, True, task, None, False, False),
        (cycles, True, task, near, True, False),
        (past(config.distance_timeout), True, task, near, False, False),
        (past(config.resume_time), True, task, near, True, False),
        (cycles, True, task, near, True, True),
        (cycles, True, np.zeros(3), none, True, False),
        (cycles, True, task, touch, True, False),
        (past(config.joint_timeout), False, task, near, True, False),
    ]
    seen: list[str] = []
    t, k = 0.0, 0
    t_joints = t_dist = -np.inf
    for n, joints, xd, d, fresh, monitor in phases:
        for _ in range(n):
            t = k * config.dt
            t_joints = t if joints else t_joints
            t_dist = t if fresh else t_dist
            mon = (d, up) if monitor else (None, None)
            inp = CycleInput(t, q if joints is not None else None, qd if joints is not None else None, t_joints,
                             xd, d, up if d is not None else None, t_dist, *mon)  # fmt: skip
            out = ctrl.step(inp)
            if joints is not None and out.q_cmd is not None:  # (a perfect robot follows the command)
                q, qd = np.asarray(out.q_cmd, float), np.asarray(out.qdot_cmd, float)
            if out.status.name not in seen:
                seen.append(out.status.name)
            k += 1
    return seen
