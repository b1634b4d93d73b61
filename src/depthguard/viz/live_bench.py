"""``depthguard bench view``: does the live view slow the controller? Controller cycle times with and without it.

The simulated ral-hexagon cell runs through the runner (``--realtime``, the scenario's quick form) twice:
without the view (baseline) and with :class:`~depthguard.viz.live.LiveView` attached and, where playwright
and headless Chromium are installed, a browser connected to it. Each controller cycle (``Chain.control``)
is timed; the result is the median and p99 of both runs and their ratio.
"""

from __future__ import annotations

import random
import time
from pathlib import Path

import numpy as np

from depthguard.bench.timing import machine_info

__all__ = ["run_view_benchmark"]

_CELL = Path(__file__).resolve().parents[3] / "examples" / "cells" / "sim-hexagon.toml"


def _once(with_view: bool, duration: float) -> tuple[list[float], dict]:
    from depthguard.io.cellfile import read_cell
    from depthguard.runner import open_source
    from depthguard.runner.chain import Chain, load_cell_robot
    from depthguard.runner.run import run_chain

    cell = read_cell(_CELL)
    model = load_cell_robot(cell)
    src = open_source("sim:ral-hexagon", cell, model.joint_names, quick=True)
    src.duration = duration
    chain = Chain(cell, src.cameras, model)
    times: list[float] = []
    inner = chain.control

    def timed(*a):
        t0 = time.perf_counter()
        out = inner(*a)
        times.append(time.perf_counter() - t0)
        return out

    chain.control = timed  # type: ignore[method-assign]
    sinks, info, browser = [], {"client": False}, None
    if with_view:
        from depthguard.viz.live import LiveView

        port = random.randint(18100, 18900)
        view = LiveView(cell, model, chain.points, chain.cameras, port=port)
        sinks.append(view)
        browser = _browser(port, view, info)
    try:
        run_chain(cell, src, chain, realtime=True, sinks=sinks)
    finally:
        if browser is not None:
            browser[1].close()
            browser[0].stop()
    if with_view:
        info["draws"] = sinks[0].draws
    return times[20:], info


def _browser(port: int, view, info: dict):
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        return None
    exe = "/usr/bin/chromium-headless-shell"
    if not Path(exe).exists():
        return None
    pw = sync_playwright().start()
    args = ["--no-sandbox", "--disable-gpu", "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]
    b = pw.chromium.launch(executable_path=exe, args=args)
    b.new_page().goto(f"http://127.0.0.1:{port}")
    t0 = time.time()
    while not view.server.get_clients() and time.time() - t0 < 30:
        time.sleep(0.1)
    info["client"] = bool(view.server.get_clients())
    return pw, b


def _stats(x: list[float]) -> dict:
    a = np.asarray(x) * 1e3
    return {"n": int(a.size), "median_ms": float(np.median(a)), "p99_ms": float(np.percentile(a, 99))}


def run_view_benchmark(quick: bool = False) -> dict:
    """Controller cycle time without / with the live view (2 s of sim time; ``quick``: 1 s)."""
    duration = 1.0 if quick else 2.0
    base, _ = _once(False, duration)
    view, info = _once(True, duration)
    b, v = _stats(base), _stats(view)
    return {
        "benchmark": "view",
        "machine": machine_info(),
        "parameters": {"cell": str(_CELL), "scenario": "ral-hexagon (quick, 160x120)", "sim_s": duration, **info},
        "controller_cycle_without_view": b,
        "controller_cycle_with_view": v,
        "ratio_p99": v["p99_ms"] / b["p99_ms"],
        "ratio_median": v["median_ms"] / b["median_ms"],
    }
