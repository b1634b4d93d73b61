"""``depthguard bench net-latency``: frame -> distances -> joint command latency across node processes.

Starts the nodes of the ``ral-hexagon`` cell (``examples/cells/sim-hexagon.toml``: two 640x480 cameras at
30 Hz, hybrid mode, 1 kHz controller) as separate processes on loopback: ``sim`` (the camera and robot
drivers), ``camera0``, ``camera1``, ``distance`` and ``controller``, and reads the time stamps of the
rmw_zenoh attachments (publication times, one clock) from their event logs:

* ``prepared_to_distances``: a camera node published its prepared frame -> the distance node published the
  distances computed from it (transport between two processes, CDR decoding, fusion and queries);
* ``raw_to_distances``: the driver published the raw frame -> distances published (adds the self-filter);
* ``distances_to_command``: distances published -> the first joint command published with them;
* baseline: the distance stage's own compute time (fusion + queries) in the distance node, same run.
"""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from depthguard.bench.timing import machine_info

__all__ = ["run_net_latency_benchmark"]

_CELL = Path(__file__).resolve().parents[3] / "examples" / "cells" / "sim-hexagon.toml"


def _stats(x: list[float]) -> dict[str, float | int | None]:
    a = np.asarray(x, float) * 1e3
    if a.size == 0:
        return {"n": 0, "median_ms": None, "p99_ms": None}
    return {"n": int(a.size), "median_ms": float(np.median(a)), "p99_ms": float(np.percentile(a, 99))}


def _read(path: Path) -> list[dict]:
    if not path.exists():
        return []
    return [json.loads(x) for x in path.read_text().splitlines() if x.strip()]


def run_net_latency_benchmark(quick: bool = False, cell: str | Path | None = None) -> dict:
    """Run the nodes for 20 s (``quick``: 8 s, 160x120 images) after start-up; returns the JSON summary."""
    src = Path(cell) if cell else _CELL
    duration = 8.0 if quick else 20.0
    tmp = Path(tempfile.mkdtemp(prefix="dg-net-"))
    port = random.randint(31000, 36000)
    text = src.read_text() + f"\n[network]\nbase_port = {port}\nconnect = []\n"
    cpath = tmp / "cell.toml"
    cpath.write_text(text)
    env = {**os.environ}
    env["PYTHONPATH"] = os.pathsep.join([str(Path(__file__).resolve().parents[2]), env.get("PYTHONPATH", "")])
    procs = []
    names = ["sim", "camera0", "camera1", "distance", "controller"]
    warm = 25.0 if not quick else 20.0
    for n in names:
        extra = ["--source", "sim:ral-hexagon"] + (["--quick"] if quick else []) if n == "sim" else []
        cmd = [sys.executable, "-m", "depthguard.cli", "node", n, "--cell", str(cpath), *extra]
        cmd += ["--log", str(tmp / f"{n}.log"), "--duration", str(warm + duration)]
        procs.append(subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
    try:
        t_end = time.time() + warm + duration + 30
        for p in procs:
            p.wait(max(1.0, t_end - time.time()))
    except subprocess.TimeoutExpired:
        pass
    finally:
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
                p.wait(10)
    dist = [r for r in _read(tmp / "distance.log") if r.get("ev") == "distances"]
    t_meas = (dist[-1]["pub"] - duration) if dist else 0.0
    dist = [r for r in dist if r["pub"] >= t_meas]
    raw: dict[float, float] = {}
    for cam in ("camera0", "camera1"):
        for r in _read(tmp / f"{cam}.log"):
            if r.get("ev") == "prepared":
                raw[r["stamp"]] = max(raw.get(r["stamp"], 0.0), r["pub_raw"])
    cmds = [r for r in _read(tmp / "controller.log") if r.get("ev") == "command" and r["pub"] >= t_meas]
    prepared = [r["pub"] - r["frame_pub"] for r in dist]
    from_raw = [r["pub"] - raw[r["stamp"]] for r in dist if r["stamp"] in raw]
    out = {
        "benchmark": "net-latency",
        "machine": machine_info(),
        "parameters": {
            "cell": str(src),
            "images": "160x120" if quick else "640x480",
            "cameras": 2,
            "processes": names,
            "transport": "zenoh peer-to-peer, tcp loopback",
            "measured_s": duration,
            "load_1min": os.getloadavg()[0],
        },
        "prepared_to_distances": _stats(prepared),
        "raw_to_distances": _stats(from_raw),
        "distances_to_command": _stats([r["pub"] - r["dist_pub"] for r in cmds]),
        "baseline_distance_compute": _stats([r["compute"] for r in dist]),
        "frame_sets": len(dist),
    }
    b = out["baseline_distance_compute"]["median_ms"]
    p = out["prepared_to_distances"]["median_ms"]
    out["ratio_prepared_to_distances_vs_compute"] = (p / b) if (p and b) else None
    return out
