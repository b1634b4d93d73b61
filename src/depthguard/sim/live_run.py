"""A simulated run with the live view in the browser (``depthguard scenario NAME --view``).

:func:`run_loop_viewed` wraps :func:`depthguard.sim.loop.run_loop` for the cell scenarios and
``saphari-octree``: it serves :class:`depthguard.viz.live.LiveView` while the loop runs and closes it after.
"""

from __future__ import annotations

import sys

__all__ = ["open_view", "run_loop_viewed"]


def run_loop_viewed(view: int | None, cell, cams, kin, stage, ctrl, task, cfg):
    """:func:`depthguard.sim.loop.run_loop`, with the live view on port ``view`` while it runs (None: none)."""
    from depthguard.sim.loop import run_loop

    live = open_view(view, cfg.label, kin.model, cell.cameras, cfg.rho)
    try:
        return run_loop(cell, cams, kin, stage, ctrl, task, cfg, view=live)
    finally:
        if live is not None:
            live.close()


def open_view(port: int | None, name: str, model, cameras: list, rho: float):
    """The live view of a simulated run on 127.0.0.1:``port`` (None: no view); says where on stderr."""
    if port is None:
        return None
    from depthguard.viz.live import LiveView

    live = LiveView.for_scene(name, model, cameras, rho, port=port)
    print(f"live view: http://127.0.0.1:{live.port}", file=sys.stderr, flush=True)
    return live
