"""``depthguard scenario saphari-contact-soft|saphari-contact-stiff``: SAPHARI D4.1.1 §6.3, Experiments 1-2.

The loop is :mod:`depthguard.sim.contact_experiment`; this module computes the metrics (JSON contract)
and writes the figures and the recording (:mod:`depthguard.sim.contact_outputs`).

Metrics (ground truth from MuJoCo's contact forces, never seen by the estimator):

* ``detection_delay_ms``: from the contact onset (first 1 ms physics step with a true contact force
  above 1 N) to the first control cycle with ``‖r‖ > r_th``;
* ``force_error_rms_n``: RMS over the detected contact (true force above 1 N) of ``‖F̂ - P F‖``, with
  ``P`` the projector onto the observable forces (the range of ``J_c``; stacked for two contacts); a hand
  in contact without an estimated contact point counts with its whole force;
* ``force_error_steady_rel``: in the steady part of the push (0.25 s after the touch to the start of the
  release ramp), mean ``‖F̂ - P F‖`` over mean ``‖F‖`` (the applied force, not only its observable part);
* ``contact_point_error_m``: mean distance between the estimated contact points and the simulator's
  (matched by nearest point) while in contact; ``contact_point_error_max_m`` the largest;
* ``false_detections``: detection onsets while no hand touches (the free motion included);
* ``peak_displacement_m``: largest admittance displacement of a contact point from its onset position.

Also ``observable_fraction`` (``‖P F‖/‖F‖`` in the steady part: the pushes are mostly observable),
``unobservable_directions``, ``most_loaded_joint`` (1-based, from the residual), ``classification``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from depthguard.sim.contact_experiment import ContactLog, ExperimentSetup, make_setup, match_contacts, run_experiment

__all__ = ["run", "compute_metrics"]


def _errors(log: ContactLog, i: int) -> tuple[float, float, list[float], float]:
    """(force error norm, applied force norm, contact point errors, observable fraction) at cycle i."""
    F, Pt = log.f_true[i], log.p_true[i]
    fn = np.linalg.norm(F, axis=1)
    touching = fn > 1.0
    ph, fh = log.p_hat[i], log.f_hat[i]
    match = match_contacts(ph, Pt, touching)
    Fm = np.concatenate([F[j] if j is not None else np.zeros(3) for j in match]) if match else np.zeros(0)
    P = log.projector[i] if len(match) else np.zeros((0, 0))
    err_vec = fh.ravel() - P @ Fm if len(match) else np.zeros(0)
    missed = sum(fn[j] for j in np.flatnonzero(touching) if j not in match)
    err = float(np.linalg.norm(err_vec)) + float(missed)
    cp = [float(np.linalg.norm(ph[a] - Pt[j])) for a, j in enumerate(match) if j is not None]
    total = float(np.linalg.norm(F[touching].ravel()))
    obs = float(np.linalg.norm(P @ Fm)) / max(float(np.linalg.norm(Fm)), 1e-12) if len(match) else 0.0
    return err, total, cp, obs


def _null_basis(log: ContactLog, t: np.ndarray, tm: float) -> list[list[float]]:
    """Unit force directions (3k each, stacked) the residual cannot see, at the cycle nearest ``tm``."""
    i = int(np.argmin(np.abs(t - tm)))
    w, V = np.linalg.eigh(np.eye(len(log.projector[i])) - log.projector[i])
    return [np.round(V[:, j], 4).tolist() for j in np.flatnonzero(w > 0.5)]


def _ee_drift(log: ContactLog, active: np.ndarray) -> float:
    """Largest end-effector displacement during detected contacts from its position at their onset, m."""
    ee, worst, ref = np.array(log.ee), 0.0, None
    for i, a in enumerate(active):
        ref = (ee[i] if ref is None else ref) if a else None
        if a:
            worst = max(worst, float(np.linalg.norm(ee[i] - ref)))
    return worst


def compute_metrics(setup: ExperimentSetup, log: ContactLog) -> dict:
    """The JSON metrics of one run (module docstring)."""
    t = np.array(log.t)
    active = np.array(log.active)
    ftot = np.array([np.linalg.norm(f, axis=1).sum() for f in log.f_true])
    onsets = [o for o in log.onset_true if o is not None]
    onset = min(onsets) if onsets else None
    det_idx = np.flatnonzero(active & (t >= (onset or np.inf) - 1e-9))
    delay = round(float(1e3 * (t[det_idx[0]] - onset)), 3) if onset is not None and len(det_idx) else None
    rising = np.flatnonzero(active[1:] & ~active[:-1]) + 1
    rising = np.concatenate([[0], rising]) if active[0] else rising
    false_det = int(sum(ftot[i] < 0.5 for i in rising))
    t_on = max(h.t_touch for h in setup.hands) + 0.25
    t_off = min(h.t_touch + h.duration - h.rise for h in setup.hands)
    errs, tots, cps, obs_f, steady_e, steady_f, loads = [], [], [], [], [], [], []
    for i in np.flatnonzero(active & (ftot > 1.0)):
        e, tot, cp, of = _errors(log, i)
        errs.append(e)
        tots.append(tot)
        cps.extend(cp)
        if t_on <= t[i] <= t_off:
            steady_e.append(e)
            steady_f.append(tot)
            obs_f.append(of)
            loads.append(np.abs(log.r[i]))
    disp = [float(np.linalg.norm(d, axis=1).max()) for d in log.disp if len(d)]
    labels = sorted({lb for lb in log.label if lb})
    return {
        "experiment": setup.name,
        "contacts": len(setup.hands),
        "rate_hz": setup.rate,
        "detection_delay_ms": delay,
        "force_error_rms_n": float(np.sqrt(np.mean(np.square(errs)))) if errs else None,
        "force_error_steady_rel": float(np.mean(steady_e) / np.mean(steady_f)) if steady_e else None,
        "contact_point_error_m": float(np.mean(cps)) if cps else None,
        "contact_point_error_max_m": float(np.max(cps)) if cps else None,
        "false_detections": false_det,
        "peak_displacement_m": max(disp) if disp else 0.0,
        "applied_force_n": float(np.mean(steady_f)) if steady_f else None,
        "observable_fraction": float(np.mean(obs_f)) if obs_f else None,
        "unobservable_directions": int(max(log.n_unobservable)) if log.n_unobservable else 0,
        "most_loaded_joint": int(np.argmax(np.mean(loads, axis=0))) + 1 if loads else None,
        "unobservable_basis_mid_push": _null_basis(log, t, 0.5 * (t_on + t_off)),
        "classification": labels,
        "r_th_nm": setup.r_th,
        "observer_gain": setup.gain,
        "admittance": {"mass": setup.params.mass, "damping": setup.params.damping, "stiffness": setup.params.stiffness},
        "ee_drift_max_m": _ee_drift(log, active),
        "depth_frames": len(log.frames),
        "timing": log.timing,
        "notes": "force errors compare the observable projection of the applied force (range of J_c); "
        "the pushes are mostly observable (observable_fraction)",
    }


def run(
    name: str,
    quick: bool = False,
    avoidance: bool = True,
    out_dir: str | Path | None = None,
    progress: bool = False,
    options: dict | None = None,
) -> dict:
    """CLI entry (``depthguard.cli.EXTRA_SCENARIOS``): ``name`` is ``saphari-contact-soft`` or ``-stiff``;
    ``options`` may hold ``contacts`` (1 or 2) and ``rate`` (Hz); ``avoidance`` is not used here."""
    options = options or {}
    kind = name.rsplit("-", 1)[-1]
    contacts = options.get("contacts") or 1
    rate = options.get("rate")
    if rate is not None and not (50.0 <= float(rate) <= 1000.0):
        raise ValueError(f"rate must be between 50 and 1000 Hz, got {rate!r}")
    setup = make_setup(kind, contacts=int(contacts), quick=quick, rate=float(rate) if rate else None)
    log, cell, camera = run_experiment(setup, progress=progress)
    metrics = compute_metrics(setup, log)
    if out_dir is not None:
        from depthguard.sim.contact_outputs import write_outputs

        metrics["files"] = write_outputs(Path(out_dir), setup, log, camera, metrics)
    return metrics
