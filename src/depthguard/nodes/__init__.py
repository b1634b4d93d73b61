"""DepthGuard as ROS 2 nodes on Zenoh: ``depthguard node NAME --cell CELL.toml``.

* ``sim``: the simulated cell as robot and camera drivers (joint states, raw depth images; takes the joint
  command; driver-side watchdog), :mod:`depthguard.nodes.sim`;
* one node per camera (its name in the cell file): self-filter and frame preparation,
  :mod:`depthguard.nodes.camera`;
* ``distance``: fusion and distance queries, :mod:`depthguard.nodes.distance`;
* ``controller``: the avoidance controller at the control rate, :mod:`depthguard.nodes.controller`;
* ``monitor``: one JSON line per second, :mod:`depthguard.nodes.monitor`.

The wire format is rmw_zenoh's (:mod:`depthguard.io.rmw_zenoh`); topics and rates are listed in the README.
"""

from __future__ import annotations

import sys
from typing import Any

from depthguard.io.cellfile import read_cell

__all__ = ["run_node"]


def run_node(
    name: str,
    cell_path: str,
    *,
    source: str | None = None,
    quick: bool = False,
    duration: float | None = None,
    log: str | None = None,
    domain: int | None = None,
    connect: list[str] | None = None,
    watchdog: float = 0.05,
    rt_priority: int | None = None,
) -> dict[str, Any]:
    """Run node ``name`` of the cell file until ``duration`` s (None: until SIGTERM / Ctrl-C).

    ``rt_priority``: run the node's threads with ``SCHED_FIFO`` at this priority (1-99) where the system
    allows it (:func:`~depthguard.nodes.common.realtime_scheduling`); the summary's ``scheduling`` says what
    the node got."""
    from depthguard.nodes.common import realtime_scheduling

    scheduling = realtime_scheduling(rt_priority)
    if rt_priority is not None and not scheduling.startswith("SCHED_FIFO"):
        print(f"depthguard node {name}: --rt-priority {rt_priority}: {scheduling}", file=sys.stderr)
    try:
        out = _run_node(name, cell_path, source, quick, duration, log, domain, connect, watchdog)
    except BaseException:
        _close_sessions()  # (a node that failed in its set-up leaves no Zenoh session keeping the process)
        raise
    return {**out, "scheduling": scheduling}


def _close_sessions() -> None:
    try:
        from depthguard.io.zenoh_transport import close_open_nodes
    except ImportError:  # pragma: no cover - no Zenoh: no session to close
        return
    close_open_nodes()


def _run_node(name, cell_path, source, quick, duration, log, domain, connect, watchdog) -> dict[str, Any]:
    cell = read_cell(cell_path)
    kw: dict[str, Any] = dict(duration=duration, log=log, domain=domain, connect=connect)
    if name == "sim":
        from depthguard.nodes.sim import run_sim_node

        if not source or not source.startswith("sim:"):
            raise ValueError(f"node 'sim' needs --source sim:SCENARIO, got {source!r}")
        return run_sim_node(cell, source[4:], quick=quick, watchdog=watchdog, **kw)
    if name in [c.name for c in cell.cameras]:
        from depthguard.nodes.camera import run_camera_node

        return run_camera_node(cell, name, **kw)
    if name == "distance":
        from depthguard.nodes.distance import run_distance_node

        return run_distance_node(cell, **kw)
    if name == "controller":
        from depthguard.nodes.controller import run_controller_node

        return run_controller_node(cell, **kw)
    if name == "monitor":
        from depthguard.nodes.monitor import run_monitor_node

        return run_monitor_node(cell, **kw)
    known = ["sim", *[c.name for c in cell.cameras], "distance", "controller", "monitor"]
    raise ValueError(f"node name must be one of {known}, got {name!r}")
