"""Outputs of ``saphari-octree``: SAPHARI Fig. 1 / Fig. 6 plots, OctoMap files of the last frame, and the
octree and reachability grid as extra channels of the run's MCAP recording.

Recording channels (JSON, like the rest of :mod:`depthguard.sim.recorder`):

* ``/octree`` (``depthguard.OctreeNodes``): node size ``res`` (m) and the centres (m, world) of the
  ``occupied`` and ``occluded`` nodes (and ``unseen`` ones in conservative mode), every 15th frame;
* ``/reachability`` (``depthguard.ReachabilityGrid``): cell size, horizon, and the reachable cells as
  ``[x, y, z, t_min]`` rows (m, s), every 15th frame.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["write_outputs", "plot_reachability", "plot_octree"]


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_reachability(path: Path, grid, title: str = "") -> None:
    """SAPHARI Fig. 1: reachable cells coloured by the minimum time to reach them (3-D scatter)."""
    plt = _plt()
    idx = np.argwhere(grid.reachable)
    c = grid.box.centres(idx)
    t = grid.time[grid.reachable]
    fig = plt.figure(figsize=(7, 6))
    ax = fig.add_subplot(projection="3d")
    keep = np.random.default_rng(0).random(len(c)) < min(1.0, 20000 / max(len(c), 1))
    sc = ax.scatter(c[keep, 0], c[keep, 1], c[keep, 2], c=t[keep], cmap="viridis", s=4, alpha=0.35)
    fig.colorbar(sc, ax=ax, shrink=0.7, label="minimum time to reach [s]")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ax.set_title(title or f"reachability grid, T = {grid.horizon} s, {grid.box.res} m cells")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_octree(path: Path, box, kind: np.ndarray, title: str = "") -> None:
    """SAPHARI Fig. 6: the obstacle octree, occupied nodes red, occluded orange (unseen grey, conservative)."""
    plt = _plt()
    fig = plt.figure(figsize=(7, 6))
    ax = fig.add_subplot(projection="3d")
    for k, colour, label in ((3, "0.7", "unseen"), (2, "orange", "occluded"), (1, "red", "occupied")):
        c = box.centres(np.argwhere(kind == k))
        if len(c) > 30000:
            c = c[np.random.default_rng(k).random(len(c)) < 30000 / len(c)]
        if len(c):
            ax.scatter(c[:, 0], c[:, 1], c[:, 2], c=colour, s=3, alpha=0.5 if k == 1 else 0.15, label=label)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title(title or f"obstacle octree, {box.res} m nodes")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _recording_extra(stage):
    """The octree (occupied red, occluded orange, unseen grey) and the reachability grid (coloured by the time
    to reach, blue = now, white = the horizon) as ``visualization_msgs/MarkerArray`` cube lists on
    ``/octree`` and ``/reachability``."""
    from depthguard.io import ros2

    def extra(w) -> None:
        types = ros2.typestore().types
        box = stage.backend.box
        colours = {1: (0.9, 0.1, 0.1, 0.8), 2: (1.0, 0.55, 0.0, 0.5), 3: (0.5, 0.5, 0.5, 0.25)}
        for t, kind, grid in stage.snapshots:
            ms = [
                ros2.cube_list_marker(t, "octree", k, box.centres(np.argwhere(kind == k)), box.res, colours[k])
                for k in (1, 2, 3)
            ]
            w.write(
                "/octree",
                "visualization_msgs/msg/MarkerArray",
                types["visualization_msgs/msg/MarkerArray"](markers=ms),
                t,
            )
            if grid is not None:
                r = grid.reachable
                f = np.clip(grid.time[r] / max(grid.horizon, 1e-9), 0.0, 1.0)[:, None]
                rgba = np.column_stack([f, f, np.ones_like(f), np.full_like(f, 0.3)])
                m = ros2.cube_list_marker(t, "reachability", 0, grid.box.centres(np.argwhere(r)), grid.box.res, rgba)
                w.write(
                    "/reachability",
                    "visualization_msgs/msg/MarkerArray",
                    types["visualization_msgs/msg/MarkerArray"](markers=[m]),
                    t,
                )

    return extra


def write_outputs(out: Path, cell, log, stage, runs: dict, name: str) -> dict[str, str]:
    """Plots, OctoMap files and the recording; returns {what: path} (errors as text when a part is missing)."""
    files: dict[str, str] = {}
    try:
        from depthguard.viz.plots import plot_run

        files.update(plot_run(out, runs, name))
        if stage.reach is not None:
            plot_reachability(out / "reachability_fig1.png", stage.reach)
            files["reachability_fig1"] = str(out / "reachability_fig1.png")
        if stage.backend.frame is not None:
            plot_octree(out / "octree_fig6.png", stage.backend.box, stage.backend.frame.kind)
            files["octree_fig6"] = str(out / "octree_fig6.png")
    except ImportError as exc:
        files["plots_error"] = f"plots skipped: {exc} (pip install depthguard[viz])"
    try:
        from depthguard.io.octomap import write_octomap

        for k, p in write_octomap(stage.backend.frame, out / "octomap").items():
            files[k] = str(p)
    except ImportError as exc:
        files["octomap_error"] = f"OctoMap files skipped: {exc}"
    try:
        from depthguard.sim.recorder import record_run

        files["recording"] = str(record_run(out / "recording.mcap", cell, log, extra=_recording_extra(stage)))
    except ImportError as exc:
        files["recording_error"] = f"recording skipped: {exc} (pip install depthguard[sim])"
    return files
