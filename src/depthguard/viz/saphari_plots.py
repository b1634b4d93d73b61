"""Plots of the SAPHARI robot-mounted-sensor experiments (matplotlib, non-interactive).

* ``fig11.png``: the skin's proximity signal against the safety-level thresholds, the levels, and the
  commanded / measured TCP speed (SAPHARI D4.1.1 Fig. 11);
* ``graycode.png``: the levels the host wrote and what the robot decoded from the skewed lines, Gray code
  against natural binary, with a zoom on each multi-line binary transition;
* ``sensors_energy.png``: normalised outputs of the relevant proximity sensors and the pseudo-energy over
  time (Figs. 16, 18, 19); ``joint_velocities.png``: commanded joint velocities (Fig. 16 left, chattering);
  ``snapshots.png``: top and side views of the robot at several instants (Figs. 15, 17, 20).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from depthguard.sensors.graycode import simulate_lines

__all__ = ["plot_skin", "plot_nsb", "plot_chattering"]


def _mpl():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_skin(out: Path, log: dict, params) -> dict[str, str]:
    """Write ``fig11.png`` and ``graycode.png`` for a skin run; returns {name: path}."""
    return {"fig11": _fig11(out, log), "graycode": _graycode(out, log, params)}


def _fig11(out: Path, log: dict) -> str:
    plt = _mpl()
    t = log["t"]
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(13, 4.5))
    a1.plot(t, log["signal"], color="tab:blue", lw=1.2, label="proximity signal (max of elements)")
    for k, th in enumerate(log["thresholds"]):
        a1.axhline(th, color="0.6", lw=0.7, ls="--")
        a1.text(t[-1], th, f" L{k + 1}", va="center", fontsize=7, color="0.4")
    a1.set_yscale("symlog", linthresh=50)
    a1.set_xlabel("t [s]")
    a1.set_ylabel("signal [ADC counts]")
    b1 = a1.twinx()
    b1.step(t, log["target"], where="post", color="tab:orange", lw=1, label="target level")
    b1.step(t, log["sent"], where="post", color="tab:red", lw=1.2, label="level on the lines")
    c = np.flatnonzero(log["contact"])
    if c.size:
        b1.fill_between(t, 0, 7.5, where=log["contact"], color="tab:red", alpha=0.12, label="contact")
    b1.set_ylim(-0.2, 7.8)
    b1.set_ylabel("safety level")
    h1, l1 = a1.get_legend_handles_labels()
    h2, l2 = b1.get_legend_handles_labels()
    a1.legend(h1 + h2, l1 + l2, fontsize=7, loc="upper left")
    a1.set_title("proximity signal and safety levels")
    a2.plot(t, log["v_cmd"] * 1e3, color="tab:red", lw=1.2, label="commanded (Table 1 of the decoded level)")
    a2.plot(t, log["v_tcp"] * 1e3, color="tab:green", lw=1.0, label="measured TCP speed")
    a2.set_xlabel("t [s]")
    a2.set_ylabel("TCP speed [mm/s]")
    a2.legend(fontsize=7)
    a2.grid(True, alpha=0.3)
    a2.set_title("TCP linear speed")
    fig.suptitle("saphari-skin: SAPHARI D4.1.1 Fig. 11")
    fig.tight_layout()
    p = out / "fig11.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    return str(p)


def _graycode(out: Path, log: dict, params) -> str:
    plt = _mpl()
    t = log["t"]
    args = (log["writes_t"], log["writes_l"], float(t[-1]), params.line_delays, params.io_period, params.io_phase)
    g = simulate_lines(*args, code="gray")
    b = simulate_lines(*args, code="binary")
    wt, wl = log["writes_t"], log["writes_l"]
    multi = [k for k in range(1, len(wl)) if bin(int(wl[k - 1]) ^ int(wl[k])).count("1") > 1]
    ncol = max(1, min(len(multi), 6))
    fig = plt.figure(figsize=(14, 6.5))
    ax = fig.add_subplot(2, 1, 1)
    ax.step(wt, wl, where="post", color="k", lw=1.2, label="level written by the host")
    ax.plot(g.t_sample, g.decoded, ".", ms=2, color="tab:blue", label="robot reads, Gray code")
    bad = (b.decoded != b.sent) & (b.decoded != b.previous)
    ax.plot(b.t_sample[bad], b.decoded[bad], "x", ms=7, color="tab:red", label=f"binary glitches ({bad.sum()})")
    ax.set_ylabel("level")
    ax.set_xlabel("t [s]")
    ax.legend(fontsize=8, loc="upper right")
    ax.set_title(
        f"same skewed lines (delays {np.round(np.array(params.line_delays) * 1e3, 1).tolist()} ms, "
        f"robot samples every {params.io_period * 1e3:g} ms): Gray never glitches, binary does"
    )
    for j, k in enumerate(multi[:ncol]):
        sub = fig.add_subplot(2, ncol, ncol + j + 1)
        t0 = wt[k]
        sel = (g.t_sample > t0 - 0.004) & (g.t_sample < t0 + 0.010)
        sub.step((wt - t0) * 1e3, wl, where="post", color="k", lw=1)
        sub.plot((g.t_sample[sel] - t0) * 1e3, g.decoded[sel], "o", ms=4, color="tab:blue", label="Gray")
        sub.plot((b.t_sample[sel] - t0) * 1e3, b.decoded[sel], "x", ms=6, color="tab:red", label="binary")
        sub.axvspan(min(params.line_delays) * 1e3, max(params.line_delays) * 1e3, color="0.85")
        sub.set_xlim(-4, 10)
        sub.set_ylim(-0.5, 7.5)
        sub.set_title(f"{int(wl[k - 1])} -> {int(wl[k])}", fontsize=9)
        sub.set_xlabel("ms after the write", fontsize=8)
        if j == 0:
            sub.legend(fontsize=7)
    fig.tight_layout()
    p = out / "graycode.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    return str(p)


def _hull(ax, pts2: np.ndarray, **kw) -> None:
    from scipy.spatial import ConvexHull

    try:
        h = ConvexHull(pts2)
    except Exception:  # degenerate (flat) outline
        return
    v = pts2[np.r_[h.vertices, h.vertices[:1]]]
    ax.fill(v[:, 0], v[:, 1], **kw)


def _box_corners(o) -> np.ndarray:
    c, h = np.asarray(o.centre), np.asarray(o.half)
    return np.array([c + h * [sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])


def plot_nsb(out: Path, runs: dict, obstacles, title: str, outlines: dict | None = None) -> dict[str, str]:
    """Write ``sensors_energy.png``, ``joint_velocities.png`` and ``snapshots.png`` for NSB runs
    (``runs`` = {name: log}, "main" first; ``outlines`` = {name: (times, robot corner lists)})."""
    files = {"sensors_energy": _sensors_energy(out, runs["main"], title)}
    files["joint_velocities"] = _joint_velocities(out, runs["main"], title)
    if outlines:
        files["snapshots"] = _snapshots(out, runs["main"], obstacles, title, outlines["main"])
    if outlines and "no box" in outlines:
        files["fig14"] = _fig14(out, obstacles, title, outlines)
    return files


def _sensors_energy(out: Path, L: dict, title: str) -> str:
    plt = _mpl()
    t = L["t"]
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(11, 6.5), sharex=True)
    seen = np.isfinite(L["dist"]).any(axis=0)
    for k in np.flatnonzero(seen):
        a1.plot(t, L["vnorm"][:, k], lw=1, label=f"sensor {k + 1}")
    a1.set_ylabel("normalised output")
    a1.set_ylim(0, 1.05)
    a1.legend(fontsize=7, ncol=5, loc="upper left")
    a1.set_title("relevant proximity sensors (output / peak output)")
    a2.plot(t, L["sigma"], color="tab:red", lw=1.2, label="pseudo-energy sigma (eq. 5.2)")
    a2.set_ylabel("sigma [m^2]")
    a2.set_xlabel("t [s]")
    b2 = a2.twinx()
    b2.plot(t, L["clear"], color="tab:gray", lw=0.8, label="true clearance")
    b2.axhline(0, color="k", lw=0.5)
    b2.set_ylabel("clearance [m]")
    a2.legend(fontsize=7, loc="upper left")
    b2.legend(fontsize=7, loc="upper right")
    fig.suptitle(f"{title}: Figs. 16/18/19")
    fig.tight_layout()
    p = out / "sensors_energy.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    return str(p)


def _joint_velocities(out: Path, L: dict, title: str) -> str:
    plt = _mpl()
    t = L["t"]
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(11, 6), sharex=True)
    for j, lab in enumerate(("x", "y", "theta")):
        a1.plot(t, L["qdot"][:, j], lw=1, label=lab)
    for j in range(5):
        a2.plot(t, L["qdot"][:, 3 + j], lw=1, label=f"arm {j + 1}")
    a1.set_ylabel("base [m/s, rad/s]")
    a2.set_ylabel("arm [rad/s]")
    a2.set_xlabel("t [s]")
    a1.legend(fontsize=7)
    a2.legend(fontsize=7, ncol=5)
    a1.plot(t, L["lam"] * np.abs(L["qdot"][:, :3]).max(), color="0.7", lw=0.8, ls=":", label="lambda (scaled)")
    fig.suptitle(f"{title}: commanded joint velocities")
    fig.tight_layout()
    p = out / "joint_velocities.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    return str(p)


def _snapshots(out: Path, L: dict, obstacles, title: str, main_outlines) -> str:
    plt = _mpl()
    times, shots = main_outlines
    ncol = len(shots)
    fig, axes = plt.subplots(2, ncol, figsize=(3.2 * ncol, 4.6), squeeze=False)
    xd, ee = L["xd"], L["ee"]
    for c, (tc, corners) in enumerate(zip(times, shots, strict=True)):
        upto = L["t"] <= tc + 1e-9
        for r, (i, j, lab) in enumerate(((0, 1, "top (x-y)"), (0, 2, "side (x-z)"))):
            ax = axes[r, c]
            for o in obstacles:
                _hull(ax, _box_corners(o)[:, [i, j]], color="tab:brown", alpha=0.45, lw=0)
            for cc in corners:
                _hull(ax, cc[:, [i, j]], color="tab:blue", alpha=0.35, lw=0)
            ax.plot(xd[:, i], xd[:, j], "k--", lw=0.7)
            ax.plot(ee[upto, i], ee[upto, j], color="tab:red", lw=1.2)
            ax.set_xlim(-0.4, 1.9)
            ax.set_ylim(*((-0.6, 0.6) if r == 0 else (0.0, 0.8)))
            ax.set_aspect("equal")
            ax.tick_params(labelsize=6)
            ax.set_title(f"t = {tc:.1f} s, {lab}", fontsize=8)
    fig.suptitle(f"{title}: snapshots (blue robot, brown obstacles, red end-effector trace, dashed plan)")
    fig.tight_layout()
    p = out / "snapshots.png"
    fig.savefig(p, dpi=100)
    plt.close(fig)
    return str(p)


def _fig14(out: Path, obstacles, title: str, outlines: dict) -> str:
    plt = _mpl()
    fig, ax = plt.subplots(figsize=(9, 4))
    for o in obstacles:
        _hull(ax, _box_corners(o)[:, [0, 2]], color="tab:brown", alpha=0.45, lw=0)
    for name, col in (("no box", "tab:green"), ("main", "tab:blue")):
        for cc in outlines[name][1][-1]:
            _hull(ax, cc[:, [0, 2]], color=col, alpha=0.3, lw=0)
        ax.plot([], [], color=col, lw=6, alpha=0.5, label="without the box" if name == "no box" else "with the box")
    ax.set_aspect("equal")
    ax.legend(fontsize=8)
    ax.set_title(f"{title}: final configurations without and with the box (Fig. 14), side view")
    fig.tight_layout()
    p = out / "fig14.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    return str(p)


def plot_chattering(out: Path, runs: dict, measures: dict) -> str:
    """``chattering.png``: lambda(d) and the commanded joint accelerations of case 3 for each weighting
    function (5.10-5.12), with the chattering measure of each."""
    plt = _mpl()
    kinds = [k for k in ("switch", "arctan", "linear") if k in runs]
    fig, axes = plt.subplots(len(kinds), 1, figsize=(11, 2.6 * len(kinds)), sharex=True, squeeze=False)
    for ax, k in zip(axes[:, 0], kinds, strict=True):
        L = runs[k]
        t = L["t"]
        qdd = np.diff(L["qdot"], axis=0) / (t[1] - t[0])
        ax.plot(t[1:], np.abs(qdd).sum(axis=1), lw=0.7, color="tab:purple", label="sum |qddot| (all joints)")
        ax.set_ylabel("[units/s^2]")
        b = ax.twinx()
        b.plot(t, L["lam"], lw=0.8, color="tab:orange", label="lambda(d)")
        b.set_ylim(-0.05, 1.05)
        b.set_ylabel("lambda")
        ax.set_title(f"{k}: chattering {measures[k]:.0f} units/s^3", fontsize=9)
        ax.legend(fontsize=7, loc="upper left")
        b.legend(fontsize=7, loc="upper right")
    axes[-1, 0].set_xlabel("t [s]")
    fig.suptitle(
        "saphari-nsb case 3: commanded joint accelerations with eqs. 5.10 (switch), 5.11 (arctan), 5.12 (linear)"
    )
    fig.tight_layout()
    p = out / "chattering.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    return str(p)
