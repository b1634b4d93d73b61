"""``depthguard run``: the whole chain (self-filter, distances, controller) on the simulated cell, a ROS 2 bag
or a live RealSense, from one cell file; see :mod:`depthguard.runner.run`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from depthguard.io.cellfile import CellFile, read_cell, refuse_align

__all__ = ["open_source", "run_cell"]


def _check_sim_cameras(cell: CellFile, cameras: list, scenario: str) -> None:
    if len(cell.cameras) != len(cameras):
        raise ValueError(f"{cell.path}: {len(cell.cameras)} camera(s) but scenario {scenario!r} has {len(cameras)}")
    for cc, cam in zip(cell.cameras, cameras, strict=True):
        if cc.R is None:
            continue
        mine = cc.build()
        if np.abs(mine.position - cam.position).max() > 1e-3 or np.abs(mine.R - cam.R).max() > 1e-3:
            raise ValueError(
                f"{cell.path}: camera '{cc.name}' is at {np.round(mine.position, 3).tolist()} but scenario"
                f" {scenario!r} puts it at {np.round(cam.position, 3).tolist()}"
            )


def open_source(
    spec: str,
    cell: CellFile,
    joint_names: tuple[str, ...],
    *,
    quick: bool = False,
    links: frozenset[str] = frozenset(),
    people: bool = True,
):
    """A source from ``bag:PATH``, ``sim:SCENARIO`` or ``realsense``. ``links``: the robot's frame names (a
    bag's TF that reaches one of them carries the camera on that link). ``people=False``: the simulated
    scenario's cell without its people (``depthguard commission``; recorded sources are what they are)."""
    kind, _, arg = spec.partition(":")
    if kind == "sim":
        refuse_align(cell, "the simulated cell")
        carried = [f"'{c.name}' on '{c.parent}'" for c in cell.cameras if c.parent != "world"]
        if carried:
            raise ValueError(
                f"{cell.path}: the simulated cell has world cameras only; the cell file carries {', '.join(carried)}"
            )
        from depthguard.runner.sources import SimSource

        try:  # as many of the scenario's cameras as the cell file has ("ral": a third one for 3)
            dt = 1.0 / float(cell.controller["rate"])
            ssm = bool(cell.controller.get("ssm", False))
            src = SimSource(arg, quick=quick, control_dt=dt, cameras=len(cell.cameras), people=people, ssm=ssm)
        except ValueError as exc:
            if "cameras must be" not in str(exc):
                raise
            raise ValueError(f"{cell.path}: {len(cell.cameras)} camera(s) in the cell file; {exc}") from None
        _check_sim_cameras(cell, src.cameras, arg)
        if tuple(src.joint_names) != tuple(joint_names):
            raise ValueError(
                f"{cell.path}: the robot's joints {joint_names} are not the simulated arm's {src.joint_names}"
            )
        return src
    if kind == "bag":
        from depthguard.runner.bag import BagSource

        return BagSource(Path(arg), cell, joint_names, links)
    if kind == "realsense":
        from depthguard.runner.realsense import RealSenseSource

        return RealSenseSource(cell, joint_names)
    raise ValueError(f"--source must be bag:PATH, sim:SCENARIO or realsense, got {spec!r}")


def run_cell(
    cell_path: str | Path,
    source: str,
    *,
    quick: bool = False,
    realtime: bool = False,
    out_dir: str | Path | None = None,
    progress: bool = False,
    log: Any = None,
    transport: str = "none",
    zenoh_domain: int | None = None,
    zenoh_connect: list[str] | None = None,
    view: bool = False,
) -> dict[str, Any]:
    """Run the chain of ``cell_path`` on ``source``; returns the summary (see :func:`run.run_chain`).

    ``transport="zenoh"`` also publishes the topics on Zenoh (:mod:`depthguard.nodes.runpub`; ROS domain
    ``zenoh_domain``, endpoints ``zenoh_connect``); ``view`` serves the live view (:mod:`depthguard.viz.live`).
    """
    from depthguard.runner.chain import Chain, background_applied, load_cell_robot
    from depthguard.runner.run import run_chain

    cell = read_cell(cell_path)
    model = load_cell_robot(cell)
    src = open_source(source, cell, model.joint_names, quick=quick, links=frozenset(f.name for f in model.model.frames))
    sinks: list[Any] = []
    try:  # (a source, session or web server left open would keep a device or the process busy)
        chain = Chain(cell, src.cameras, model, parents=getattr(src, "camera_parents", None))
        if transport not in ("none", "zenoh"):
            raise ValueError(f"--transport must be 'none' or 'zenoh', got {transport!r}")
        if transport == "zenoh":
            from depthguard.nodes.runpub import ZenohRunPublisher

            sinks.append(ZenohRunPublisher(cell, chain, domain=zenoh_domain, connect=zenoh_connect))
        if view:
            from depthguard.viz.live import LiveView

            sinks.append(LiveView(cell, model, chain.points, chain.local_cameras))  # (it places carried cameras)
    except BaseException:
        for s in sinks:
            s.close()
        src.close()
        if transport == "zenoh":
            from depthguard.io.zenoh_transport import close_open_nodes

            close_open_nodes()
        raise
    summary = run_chain(
        cell, src, chain, realtime=realtime, out_dir=out_dir, progress=progress, label=source, log=log, sinks=sinks
    )
    summary = {"cell": cell.name, "source": source, **summary, "background": background_applied(cell)}
    if transport == "zenoh":
        summary["zenoh_published"] = dict(sinks[0].count)
    return summary
