"""How close the evaluated distances stay to the truth: over-report, under-report and time at zero.

For every distance-stage call (every ``distance_period`` of simulated time) and every control point, the
loop logs the evaluated distance ``e`` (m, from the sphere's surface; ``inf`` when nothing lies within
ρ), the true clearance ``c`` of the same sphere to the nearest non-robot geom (people, boxes, table,
walls, floor; :class:`depthguard.sim.pointtruth.PointClearance`, coal; in the ``--ssm`` runs without the
room, floor and table, which their background model removes from the images on purpose) and the declared tolerance
``tol`` of that evaluation. The truth is *synchronous*: the obstacles as they were when the frame that
the call used was captured, the sphere where the call put it; the camera's frame latency (up to 33 ms of
a moving person) is a different error, handled by the controller's margins, and is left out here.

Over the samples with ``c < ρ`` (``e`` taken as ``min(e, ρ)``, "nothing within ρ" claims at least ρ; a NaN
truth counts as such a sample, and a NaN ``e`` or ``c`` makes ``max_over_report`` and ``median_under_report``
NaN: an evaluation that cannot be checked is never hidden):

* ``max_over_report`` = max(e - c) (m): how much the evaluation claims beyond the truth; the safety
  contract is ``e - c <= tol`` for every sample (``over_report_within_tolerance``);
* ``median_under_report`` = median(c - e) (m): how conservative the evaluation is, typically;
* ``time_at_zero_s``: simulated seconds during which some control point is evaluated at
  ``e <= 0.005`` m, or NaN (which the controllers read as contact), while its true clearance is ``c > 0.05`` m
  (a phantom contact: a speed-and-separation monitor would stop the robot for nothing); to 12 significant
  digits, so that one such call never reads 0.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["ZERO_EVAL", "ZERO_TRUE", "accuracy_metrics", "measured_bound_metrics", "under_report_series"]

ZERO_EVAL = 0.005  # m: an evaluated distance at or below this counts as "at zero"
ZERO_TRUE = 0.05  # m: ... while the true clearance exceeds this


def _arrays(log) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(t (T,), e (T, N), c (T, N), tol (T, N))`` from the log's flattened ``acc_*`` rows (N control points)."""
    t = np.asarray(log.acc_t, float).reshape(-1)
    n = len(log.point_names)
    out = [t]
    for field in ("acc_eval", "acc_true", "acc_tol"):
        v = np.asarray(getattr(log, field), float).reshape(-1)
        if v.size != len(t) * n:
            raise ValueError(
                f"{field} must hold len(acc_t) x len(point_names) = {len(t)} x {n} values (one per call and control"
                f" point), got {v.size}"
            )
        out.append(v.reshape(len(t), n))
    return out[0], out[1], out[2], out[3]


def under_report_series(log, rho: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(t (T,), under (T, N), at_zero (T,) bool)``: ``c - min(e, ρ)`` per call and point (NaN where
    ``c >= ρ``), and whether some point is at zero while its truth exceeds 5 cm."""
    t, e, c, _ = _arrays(log)
    em = np.minimum(e, rho)
    with np.errstate(invalid="ignore"):  # (inf - inf: NaN, reported as such)
        under = np.where(c < rho, c - em, np.nan)
    at_zero = np.any(_at_zero(e, c), axis=1) if len(t) else np.zeros(0, bool)
    return t, under, at_zero


def _at_zero(e: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Phantom contact per sample: evaluated at zero (``e <= ZERO_EVAL`` or NaN, read as contact by the
    controllers) while the truth exceeds ``ZERO_TRUE``."""
    return ~(e > ZERO_EVAL) & (c > ZERO_TRUE)


def _seconds(x: float) -> float:
    """A time (s) to 12 significant digits: no float noise such as 0.009000000000000001 in the JSON, and one
    call of any period never reads 0 (as it did rounded to 0.1 ms)."""
    return float(f"{float(x):.12g}")


def _excluded(log) -> str:
    groups = tuple(getattr(log, "acc_excluded_groups", ()))
    return f"; geom groups {list(groups)} left out (the background model removes them)" if groups else ""


def accuracy_metrics(log, rho: float, period: float) -> dict[str, Any]:
    """The comparison of evaluated and true distances of one run (see the module docstring).

    Args:
        log: a :class:`depthguard.sim.loop.SimLog` with its ``acc_*`` rows.
        rho: radius of surveillance ρ, m.
        period: simulated seconds between distance-stage calls.
    Returns:
        ``max_over_report``, ``median_under_report``, ``time_at_zero_s``, ``declared_tolerance`` (the
        largest tolerance over the compared samples), ``over_report_within_tolerance``,
        ``accuracy_samples`` and, per control point, ``accuracy_per_point`` (max over-report, median
        under-report, time at zero).
    """
    t, e, c, tol = _arrays(log)
    names = list(log.point_names)
    near = ~(c >= rho)  # (a NaN truth too: its sample is compared, and reads NaN)
    em = np.minimum(e, rho)
    with np.errstate(invalid="ignore"):  # (inf - inf, and medians of +-inf: NaN, reported as such)
        over = em - c
        zero = _at_zero(e, c)
        out: dict[str, Any] = {
            "max_over_report": float(np.max(over[near])) if near.any() else None,
            "median_under_report": float(np.median(-over[near])) if near.any() else None,
            "time_at_zero_s": _seconds(np.sum(np.any(zero, axis=1)) * period),
            "declared_tolerance": float(np.max(tol[near])) if near.any() else None,
            "over_report_within_tolerance": bool(np.all(over[near] <= tol[near])),
            "accuracy_samples": int(near.sum()),
            "accuracy_truth": "synchronous: obstacles at the frame's capture, spheres at the call (coal)"
            + _excluded(log),
        }
        per = {}
        for k, name in enumerate(names):
            m = near[:, k]
            per[name] = {
                "max_over_report": float(np.max(over[m, k])) if m.any() else None,
                "median_under_report": float(np.median(-over[m, k])) if m.any() else None,
                "time_at_zero_s": _seconds(np.sum(zero[:, k]) * period),
            }
        out["accuracy_per_point"] = per
    out["measured_bound"] = measured_bound_metrics(log, rho)
    return out


def measured_bound_metrics(log, rho: float) -> dict[str, Any] | None:
    """The evaluation against the measured bound ``b`` (:mod:`depthguard.sim.measured_bound`) on the sampled
    calls, over the samples with ``c < ρ``: ``median_unmeasured_under_report`` = median(c - b) (what the
    cameras leave unmeasured), ``median_excess_under_report`` = median(b - e) (what the distance stage adds to
    it), ``max_over_measured_bound`` = max(e - b) (m; the stage claiming free what no camera saw free: within
    the declared tolerance), ``samples`` and ``spacing_m`` (the bound's lattice). None without samples."""
    rows = list(getattr(log, "bound_row", ()))
    if not rows:
        return None
    _, e, c, tol = _arrays(log)
    b = np.asarray(log.bound, float)
    e, c, tol = np.minimum(e[rows], rho), c[rows], tol[rows]
    m = (c < rho) & np.isfinite(b)
    if not m.any():
        return {"samples": 0, "spacing_m": float(log.bound_spacing)}
    return {
        "samples": int(m.sum()),
        "spacing_m": float(log.bound_spacing),
        "median_unmeasured_under_report": float(np.median(c[m] - b[m])),
        "median_excess_under_report": float(np.median(b[m] - e[m])),
        "max_over_measured_bound": float(np.max(e[m] - b[m])),
        "over_measured_bound_within_tolerance": bool(np.all(e[m] - b[m] <= tol[m])),
    }
