"""The monitor node: what the cell is doing, once a second, as one JSON line.

Subscribes the controller status, the distances and the joint command; prints per second the latest status,
the smallest distance, the message rates, which DepthGuard nodes are alive (their liveliness tokens) and
how many samples the subscriptions dropped (duplicates, reordered or stale stamps, unlisted publishers).
"""

from __future__ import annotations

import sys
import threading
import time

import numpy as np

from depthguard.io.cellfile import CellFile
from depthguard.io.rmw_zenoh import parse_liveliness_token
from depthguard.nodes.common import StopFlag, Topics, json_line, open_node

__all__ = ["live_nodes", "run_monitor_node"]


def live_nodes(keys: list[str]) -> tuple[list[str], int]:
    """The names of the live nodes among liveliness key expressions (their ``NN`` tokens), sorted, and the
    number of ``NN`` tokens that are not rmw_zenoh's form (another participant's, ignored: one such token
    must not stop the monitor)."""
    names, malformed = set(), 0
    for k in keys:
        if "/NN/" not in k:
            continue
        try:
            names.add(parse_liveliness_token(k).node)
        except ValueError:
            malformed += 1
    return sorted(names), malformed


def run_monitor_node(
    cell: CellFile, *, duration: float | None = None, log: str | None = None, stop: StopFlag | None = None, **kw
) -> dict:
    """Run the monitor until ``duration`` s or SIGTERM; prints one JSON line per second to stdout: the latest
    status and smallest distance, the message rates (Hz, over the time since the previous line), the live
    nodes, the drops, and ``malformed_tokens`` when liveliness tokens not of rmw_zenoh's form were seen
    (:func:`live_nodes`)."""
    stop = stop if stop is not None else StopFlag()
    top = Topics.of(cell)
    node = open_node(cell, "monitor", **kw)
    lock = threading.Lock()
    count = {"status": 0, "distances": 0, "command": 0}
    last: dict = {"status": None, "d_min": None}

    def on_status(msg, att, recv_ns):
        with lock:
            count["status"] += 1
            last["status"] = str(msg.status)

    def on_dist(msg, att, recv_ns):
        d = np.array([p.distance for p in msg.points], float)
        with lock:
            count["distances"] += 1
            last["d_min"] = float(np.min(d)) if d.size else None

    def on_cmd(msg, att, recv_ns):
        with lock:
            count["command"] += 1

    subs = [
        node.subscribe(top.status, "depthguard_msgs/msg/ControllerStatus", on_status),
        node.subscribe(top.distances, "depthguard_msgs/msg/ControlPointDistances", on_dist),
        node.subscribe(top.command, "sensor_msgs/msg/JointState", on_cmd),
    ]
    t_start = time.time()
    t_last = t_start
    lines = 0
    try:
        while not stop and (duration is None or time.time() - t_start < duration):
            stop.wait(1.0)
            toks = [str(r.ok.key_expr) for r in node.session.liveliness().get(f"@ros2_lv/{node.domain}/**") if r.ok]
            alive, malformed = live_nodes(toks)
            with lock:
                now = time.time()
                span = max(now - t_last, 1e-3)  # the last line may cover less than a second (stopped)
                hz = {k: round(c / span, 2) for k, c in count.items()}
                rec = {"t": round(now, 3), **last, "hz": hz, "nodes": alive}
                t_last = now
                for k in count:
                    count[k] = 0
            rec["dropped"] = {s.topic: dict(s.dropped) for s in subs if s.dropped}
            if malformed:
                rec["malformed_tokens"] = malformed
            sys.stdout.write(json_line(rec) + "\n")  # (strict JSON: no distance within range is null)
            sys.stdout.flush()
            lines += 1
    finally:
        node.close()
    return {"lines": lines}
