"""Plots of simulated runs (matplotlib, non-interactive), after the papers' figures.

* ``ee_paths.png``: end-effector paths, actual and nominal, with commanded Cartesian velocities
  (green arrows), for the run and its variants (ICRA'12 Figs. 11, 13, 14; the elbow's path too);
* ``distances.png``: evaluated minimum distance and true minimum clearance over time (RA-L'16 Fig. 15);
* ``distance_rate.png``: instantaneous and average wall-clock frequency of the distance stage
  (ICRA'12 Fig. 16);
* ``under_report.png``: true clearance minus evaluated distance per control point over time (where the
  truth is below ρ; negative = over-report), with the time spent at a phantom zero shaded
  (:mod:`depthguard.sim.accuracy`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["plot_run"]


def _mpl():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_run(out_dir: str | Path, runs: dict, title: str, rho: float = 0.4) -> dict[str, str]:
    """Write the plots for ``runs`` = {name: (SimLog, Task)} ("main" first). Returns {plot: path}."""
    plt = _mpl()
    out = Path(out_dir)
    files: dict[str, str] = {}
    colours = ["tab:red", "tab:blue", "tab:purple", "tab:orange"]

    # ---------------------------------------------------------------- end-effector paths
    fig, axes = plt.subplots(1, 2, figsize=(12, 5))
    for (name, (log, task)), col in zip(runs.items(), colours, strict=False):
        ee = np.asarray(log.ee)
        el = np.asarray(log.elbow)
        for ax, (i, j, lab) in zip(axes, ((0, 1, "x-y (top view)"), (1, 2, "y-z (front view)")), strict=True):
            main = name == "main"
            ax.plot(ee[:, i], ee[:, j], color=col, lw=1.5, ls="-" if main else "--", label=f"end effector ({name})")
            ax.plot(el[:, i], el[:, j], color=col, lw=1.0, ls=":" if main else "-.", label=f"elbow ({name})")
            if main:
                path = task.path()
                ax.plot(path[:, i], path[:, j], "k--", lw=1, label="nominal path")
                xd = np.asarray(log.xdot_cmd)
                step = max(1, len(ee) // 60)
                ax.quiver(
                    ee[::step, i],
                    ee[::step, j],
                    xd[::step, i],
                    xd[::step, j],
                    color="tab:green",
                    angles="xy",
                    scale_units="xy",
                    scale=4.0,
                    width=0.003,
                    label="commanded velocity",
                )
            ax.set_title(lab)
            ax.set_aspect("equal", adjustable="datalim")
            ax.grid(True, alpha=0.3)
    axes[0].set_xlabel("x [m]")
    axes[0].set_ylabel("y [m]")
    axes[1].set_xlabel("y [m]")
    axes[1].set_ylabel("z [m]")
    axes[1].legend(fontsize=7, loc="best")
    fig.suptitle(f"{title}: end-effector paths")
    fig.tight_layout()
    p = out / "ee_paths.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    files["ee_paths"] = str(p)

    # ---------------------------------------------------------------- distances over time
    log, _ = runs["main"]
    t = np.asarray(log.t)
    fig, ax = plt.subplots(figsize=(10, 4))
    ev = np.asarray(log.eval_points, float)
    for k in range(ev.shape[1]):
        ax.plot(
            t,
            np.where(np.isfinite(ev[:, k]), ev[:, k], np.nan),
            lw=0.6,
            alpha=0.5,
            color="tab:green" if k else "tab:blue",
        )
    ax.plot(
        t,
        np.where(np.isfinite(log.eval_min), log.eval_min, np.nan),
        color="tab:blue",
        lw=1.5,
        label="evaluated minimum distance (sphere surfaces; thin: each control point, blue = end effector)",
    )
    ax.plot(t, np.asarray(log.true_min), color="k", lw=1.5, label="true minimum clearance (mj_geomDistance)")
    if getattr(log, "true_dynamic", None):
        ax.plot(
            t,
            np.asarray(log.true_dynamic),
            color="tab:orange",
            lw=1.2,
            label="true clearance to people and boxes (table excluded)",
        )
    ax.axhline(0.0, color="tab:red", lw=1)
    ax.axhline(0.05, color="tab:red", lw=0.7, ls="--", label="5 cm margin")
    ax.set_xlabel("simulated time [s]")
    ax.set_ylabel("distance [m]")
    ax.set_ylim(-0.1, 0.6)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7, loc="upper right")
    ax.set_title(f"{title}: evaluated and true distances")
    fig.tight_layout()
    p = out / "distances.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    files["distances"] = str(p)

    # ---------------------------------------------------------------- distance-stage frequency
    fig, ax = plt.subplots(figsize=(10, 3.5))
    wd = np.asarray(log.wall_distance)
    td = np.asarray(log.t_distance)
    if len(wd):
        inst = 1.0 / np.maximum(wd, 1e-9)
        avg = np.cumsum(inst) / np.arange(1, len(inst) + 1)
        ax.plot(td, inst, color="tab:blue", lw=0.4, label="instantaneous (1 / call time)")
        ax.plot(td, avg, color="tab:red", lw=1.5, label="running average")
        ax.set_yscale("log")
    ax.set_xlabel("simulated time [s]")
    ax.set_ylabel("distance-stage rate [Hz] (wall clock)")
    ax.grid(True, alpha=0.3, which="both")
    ax.legend(fontsize=8)
    ax.set_title(f"{title}: computation frequency of the distances and repulsive vectors")
    fig.tight_layout()
    p = out / "distance_rate.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    files["distance_rate"] = str(p)
    if getattr(runs["main"][0], "acc_t", None):
        files["under_report"] = str(plot_under_report(out / "under_report.png", runs["main"][0], title, rho))
    return files


def plot_under_report(path: str | Path, log, title: str, rho: float = 0.4) -> Path:
    """Under-report (true clearance minus evaluated distance) of every control point over time, and at the
    calls sampled for the measured bound the part of it that no camera measures (black crosses)."""
    from depthguard.sim.accuracy import under_report_series

    plt = _mpl()
    t, under, at_zero = under_report_series(log, rho)
    fig, ax = plt.subplots(figsize=(10, 4))
    for k, name in enumerate(log.point_names):
        ax.plot(t, under[:, k], lw=1.2 if k == 0 else 0.6, color="tab:blue" if k == 0 else None, label=name)
    if at_zero.any():
        dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
        ax.fill_between(
            t,
            0,
            1,
            where=at_zero,
            step="post",
            color="tab:red",
            alpha=0.15,
            transform=ax.get_xaxis_transform(),
            label=f"phantom zero ({at_zero.sum() * dt:.2f} s)",
        )
    rows = list(getattr(log, "bound_row", ()))
    if rows:  # the part of it that no camera measures (depthguard.sim.measured_bound)
        b = np.asarray(log.bound, float)
        c = np.asarray(log.acc_true, float).reshape(len(t), -1)[rows]
        tb = np.repeat(t[rows][:, None], b.shape[1], axis=1)
        ok = np.isfinite(b) & (c < rho)
        ax.scatter(
            tb[ok],
            (c - b)[ok],
            s=14,
            marker="x",
            color="k",
            lw=0.8,
            zorder=5,
            label="of which unmeasured (true - measured bound)",
        )
    ax.axhline(0.0, color="k", lw=0.8)
    ax.set_xlabel("simulated time [s]")
    ax.set_ylabel("true clearance - evaluated distance [m]")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=6, loc="upper right", ncol=2)
    ax.set_title(f"{title}: under-report per control point (true clearance < ρ; below 0 = over-report)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)
