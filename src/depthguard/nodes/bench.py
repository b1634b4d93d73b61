"""``depthguard bench net-latency``: frame -> distances -> joint command latency across node processes.

The ``ral-hexagon`` cell (``examples/cells/sim-hexagon.toml``: two 640x480 cameras at 30 Hz, hybrid mode,
1 kHz controller): the ``distance`` and ``controller`` nodes run as their own processes on loopback; the
time stamps of the rmw_zenoh attachments (publication times, one clock) come from their event logs:

* ``frame_to_distances``: the prepared frame set (depth 32FC1 + robot mask, as the camera nodes publish it)
  published -> the distance node published the distances computed from it (transport between two
  processes, CDR decoding, fusion and queries);
* ``distances_to_command``: distances published -> the controller node published the first joint command
  that used them; ``frame_to_command``: both; ``command_statuses``: the controller's status at those
  commands (``OK`` when it moved the arm);
* baseline: the distance stage's own compute time (fusion + queries) in the distance node, same run;
* ``frame_to_distances_parts``: where the time goes, from the distance node's log: ``transport`` (frame set
  published -> its last message reaches the node's callback), ``wait`` (CDR decoding, pairing by stamp and
  the node's thread waking up -> the distance stage starts on it; split into ``decode_and_pair``, the last
  message's callback, and ``wake_and_take``), ``compute`` (split into ``compute_update``, the frame stage
  with the self-filter margins, and ``compute_query``, the queries) and ``publish`` (-> the distances
  published);
* ``in_process``: the same computation on the same frame sets in this process, before the nodes start:
  ``back_to_back`` (one frame set after the other) and ``paced`` (one per camera period, the process idle in
  between, as in the node); their difference is what idling between frames costs on the machine;
  ``back_to_back_update`` and ``paced_update``: their frame stages;
* ``cpu_percent_of_one_core``: the CPU time (user + system) each process used over the measurement, per
  second of it, from ``/proc`` (empty where there is none);
* ``shared_memory``: of the image samples the distance node received, the fraction that came through Zenoh's
  shared memory (Zenoh puts messages over 3 KB there by default between processes of one host).

The frames come from this process (rendered once from the simulated cell, self-filtered, then published at
the cameras' rate with fresh stamps), so that the simulator's rendering does not load the machine. As
``docs/nodes.md`` advises, the controller node runs with ``SCHED_FIFO`` (``--rt-priority 80``) and this
process's publishing loop, the robot driver's stand-in, with ``SCHED_FIFO`` 70, where the system allows it;
``parameters.scheduling`` says what each got.
"""

from __future__ import annotations

import collections
import json
import os
import random
import signal
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from depthguard.bench.timing import machine_info

__all__ = ["run_net_latency_benchmark"]

_CELL = Path(__file__).resolve().parents[3] / "examples" / "cells" / "sim-hexagon.toml"
_IMAGE = "sensor_msgs/msg/Image"
# SCHED_FIFO priorities where the system allows them: the controller above the robot driver (here: this
# process, which publishes the joint states), both above the distance node (docs/nodes.md, "Latency and CPUs")
_RT_CONTROLLER = 80
_RT_DRIVER = 70


def _stats(x: list[float]) -> dict[str, float | int | None]:
    a = np.asarray(x, float) * 1e3
    if a.size == 0:
        return {"n": 0, "median_ms": None, "p99_ms": None}
    return {"n": int(a.size), "median_ms": float(np.median(a)), "p99_ms": float(np.percentile(a, 99))}


def _read(path: Path) -> list[dict]:
    if not path.exists():
        return []
    return [json.loads(x) for x in path.read_text().splitlines() if x.strip()]


def _frames(quick: bool, cell, n_sets: int):
    """``n_sets`` frame sets of the simulated ral-hexagon cell with their joint states and robot masks."""
    from depthguard.robot.selffilter import self_filter
    from depthguard.runner import open_source
    from depthguard.runner.chain import load_cell_robot

    model = load_cell_robot(cell)
    src = open_source("sim:ral-hexagon", cell, model.joint_names, quick=quick)
    out = []
    for tick in src.ticks():
        if tick.frames is not None:
            masks = [
                np.asarray(self_filter(c, d, tick.q, model, with_depth=False)[0])
                for c, d in zip(src.cameras, tick.frames, strict=True)
            ]
            out.append((tick.q.copy(), tick.frames, masks))
            if len(out) >= n_sets:
                break
    src.close()
    return model.joint_names, out


def _restamped(payload: bytes, t: float) -> bytes:
    """A serialised message whose first field is a ``std_msgs/Header`` (an Image), with its stamp set to ``t``:
    the stamp's ``sec`` (int32) and ``nanosec`` (uint32) follow the 4-byte CDR encapsulation header."""
    ns = int(round(t * 1e9))
    out = bytearray(payload)
    out[4:12] = struct.pack("<iI" if payload[1] == 1 else ">iI", ns // 1_000_000_000, ns % 1_000_000_000)
    return bytes(out)


def _frame_set_cdr(cell, frames: list, masks: list) -> tuple[list[bytes], list[bytes]]:
    """The serialised masks and depth images (32FC1) of one frame set, stamped 0 (:func:`_restamped`)."""
    from depthguard.io import ros2

    cams = cell.cameras
    mask_cdr = [ros2.serialize(ros2.mask_msg(0.0, c.name, m), _IMAGE) for c, m in zip(cams, masks, strict=True)]
    depth_cdr = [
        ros2.serialize(ros2.image_msg(0.0, c.name, d, "32FC1"), _IMAGE) for c, d in zip(cams, frames, strict=True)
    ]
    return mask_cdr, depth_cdr


def _publish(cell, names, sets, duration: float, stop_when) -> None:
    """Publish the prepared frames (as the camera nodes do) at the cameras' rate and joint states at 500 Hz.

    The images are serialised once per frame set and only restamped when published, so that this loop never
    holds the joint states back by more than the 5 ms joint timeout of the controller (serialising four
    640x480 images per frame in this loop did: the controller then stopped on stale joint states at every
    frame and never reached ``OK``)."""
    from depthguard.io import ros2
    from depthguard.io.rmw_zenoh import QOS_SENSOR_DATA
    from depthguard.nodes.common import Topics, open_node

    top = Topics.of(cell)
    node = open_node(cell, "sim")
    pd = {c.name: node.publisher(top.depth[c.name], "sensor_msgs/msg/Image", QOS_SENSOR_DATA) for c in cell.cameras}
    pm = {c.name: node.publisher(top.mask[c.name], "sensor_msgs/msg/Image", QOS_SENSOR_DATA) for c in cell.cameras}
    pj = node.publisher(top.joint_states, "sensor_msgs/msg/JointState")
    cdr = [_frame_set_cdr(cell, frames, masks) for _, frames, masks in sets]
    period = 1.0 / float(cell.cameras[0].rate)
    t0 = time.time()
    k, next_frame = 0, t0 + 1.0
    try:
        while time.time() - t0 < duration and not stop_when():
            q = sets[k % len(sets)][0]
            now = time.time()
            pj.publish(ros2.joint_state_msg(now, names, q, np.zeros_like(q)))
            if now >= next_frame:
                next_frame += period
                mask_cdr, depth_cdr = cdr[k % len(sets)]
                for c, m in zip(cell.cameras, mask_cdr, strict=True):
                    pm[c.name].put_cdr(_restamped(m, now))
                for c, d in zip(cell.cameras, depth_cdr, strict=True):
                    pd[c.name].put_cdr(_restamped(d, now))
                k += 1
            time.sleep(0.002)
    finally:
        node.close()


def run_net_latency_benchmark(quick: bool = False, cell: str | Path | None = None, network: str = "") -> dict:
    """Measure for 20 s (``quick``: 8 s, 160x120 images) once the distance node answers.

    ``network``: more lines for the cell's ``[network]`` table (TOML, absolute paths), for example the TLS
    certificates (one per node: the ``sim`` node publishes the frames) to measure what TLS and Zenoh's access
    control cost."""
    from depthguard.io.cellfile import per_node_certificates, read_cell

    src = Path(cell) if cell else _CELL
    duration = 8.0 if quick else 20.0
    tmp = Path(tempfile.mkdtemp(prefix="dg-net-"))
    port = random.randint(31000, 36000)
    cpath = tmp / "cell.toml"
    cpath.write_text(src.read_text() + f"\n[network]\nbase_port = {port}\nconnect = []\n{network}\n")
    cellf = read_cell(cpath)
    names, sets = _frames(quick, cellf, 6)
    in_process = _in_process_compute(cellf, sets, n=40 if quick else 90)
    nodes = ["distance", "controller"]
    procs = [_start_node(n, cpath, tmp) for n in nodes]
    marks: dict[str, float] = {}

    pids = {
        **{n: p.pid for n, p in zip(nodes, procs, strict=True)},
        "frames and joint states (this process)": os.getpid(),
    }
    cpu: dict[str, tuple] = {}

    def warmed() -> bool:  # (the controller node logs its warm-up, which compiles its kernels on a new machine)
        if "t" not in marks and len(_read(tmp / "distance.log")) >= 10:
            if any(r.get("ev") == "warm_up" for r in _read(tmp / "controller.log")):
                marks["t"] = time.time()
                cpu["start"] = _cpu_sample(pids)
        done = "t" in marks and time.time() - marks["t"] > duration
        if done and "end" not in cpu:
            cpu["end"] = _cpu_sample(pids)
        return done

    from depthguard.nodes.common import realtime

    try:
        with realtime(_RT_DRIVER) as got:  # (this thread's policy comes back afterwards)
            scheduling = {"frames and joint states (this process)": got}
            _publish(cellf, names, sets, 180.0 + duration, warmed)
    finally:
        _stop(procs)
    t_meas = marks.get("t", np.inf)
    dist = [r for r in _read(tmp / "distance.log") if r.get("ev") == "distances" and r["pub"] >= t_meas]
    cmds = [r for r in _read(tmp / "controller.log") if r.get("ev") == "command" and r["pub"] >= t_meas]
    out = {
        "benchmark": "net-latency",
        "machine": machine_info(),
        "parameters": {
            "cell": str(src),
            "images": "160x120" if quick else "640x480",
            "cameras": 2,
            "mode": cellf.distance["mode"],
            "processes": ["frames (camera nodes' output, this process)", *nodes],
            "transport": "zenoh peer-to-peer, "
            + ("tls" if cellf.network.get("tls_certificate") else "tcp")
            + " loopback"
            + (", access control" if per_node_certificates(cellf.network) else ""),
            "measured_s": duration,
            "load_1min": os.getloadavg()[0],
            "scheduling": {**scheduling, "controller": _summary(tmp / "controller.out").get("scheduling")},
        },
        **_latencies(dist, cmds),
        "in_process": in_process,
        "cpu_percent_of_one_core": _cpu_percent(cpu),
        "shared_memory": _shm_fraction(_read(tmp / "distance.log")),
        "frame_sets": len(dist),
    }
    b = out["baseline_distance_compute"]["median_ms"]
    p = out["frame_to_distances"]["median_ms"]
    out["ratio_frame_to_distances_vs_compute"] = (p / b) if (p and b) else None
    return out


def _latencies(dist: list[dict], cmds: list[dict]) -> dict:
    """The latency figures (module docstring) from the distance node's ``distances`` and the controller node's
    ``command`` log events of the measurement."""
    return {
        "frame_to_distances": _stats([r["pub"] - r["frame_pub"] for r in dist]),
        "distances_to_command": _stats([r["pub"] - r["dist_pub"] for r in cmds]),
        "frame_to_command": _stats(_chain(dist, cmds)),
        "command_statuses": dict(collections.Counter(str(c.get("status")) for c in cmds)),
        "baseline_distance_compute": _stats([r["compute"] for r in dist]),
        "frame_to_distances_parts": {
            "transport": _stats([r["recv"] - r["frame_pub"] for r in dist]),
            "wait": _stats([r["start"] - r["recv"] for r in dist]),
            "compute": _stats([r["compute"] for r in dist]),
            # (the compute's two parts: the frame stage, with the self-filter margins; the queries)
            "compute_update": _stats([r["update"] for r in dist if r.get("update") is not None]),
            "compute_query": _stats([r["compute"] - r["update"] for r in dist if r.get("update") is not None]),
            "publish": _stats([r["pub"] - r["start"] - r["compute"] for r in dist]),
            # (the wait's two parts: the last message's decoding and pairing; the node's thread taking the set)
            "decode_and_pair": _stats([r["ready"] - r["recv"] for r in dist]),
            "wake_and_take": _stats([r["start"] - r["ready"] for r in dist]),
        },
    }


def _start_node(name: str, cell_path: Path, tmp: Path) -> subprocess.Popen:
    """``depthguard node NAME`` as a process of this checkout, its event log and summary in ``tmp``; the
    controller with ``--rt-priority`` (as docs/nodes.md advises)."""
    env = {**os.environ}
    env["PYTHONPATH"] = os.pathsep.join([str(Path(__file__).resolve().parents[2]), env.get("PYTHONPATH", "")])
    cmd = [
        sys.executable,
        "-m",
        "depthguard.cli",
        "node",
        name,
        "--cell",
        str(cell_path),
        "--log",
        str(tmp / f"{name}.log"),
    ]
    rt = ["--rt-priority", str(_RT_CONTROLLER)] if name == "controller" else []
    with open(tmp / f"{name}.out", "wb") as out:
        return subprocess.Popen(cmd + rt, env=env, stdout=out, stderr=subprocess.DEVNULL)


def _stop(procs: list[subprocess.Popen]) -> None:
    """SIGTERM each node process (they print their summary), then kill what has not ended after 15 s."""
    for p in procs:
        p.send_signal(signal.SIGTERM)
        try:
            p.wait(15)
        except subprocess.TimeoutExpired:
            p.kill()


def _in_process_compute(cell, sets, n: int) -> dict:
    """The distance node's computation (:func:`~depthguard.nodes.distance._frame_set_distances`) on the frame
    sets in this process: ``back_to_back`` and ``paced`` at the cameras' period (median, p99 ms)."""
    from depthguard.nodes.distance import _frame_set_distances, frame_set_cameras
    from depthguard.runner.chain import cell_control_points, cell_distance_stage, load_cell_robot

    model = load_cell_robot(cell)
    points = cell_control_points(cell, model)
    cams = frame_set_cameras([c.build() for c in cell.cameras], sets[0][1], model, [], {})
    stage = cell_distance_stage(cell, cams)
    period = 1.0 / float(cell.cameras[0].rate)
    out = {}
    for name, pause in (("back_to_back", 0.0), ("paced", period)):
        times, updates = [], []
        for i in range(n + 5):
            q, depths, masks = sets[i % len(sets)]
            depths, masks = [d.copy() for d in depths], [m.copy() for m in masks]  # fresh, as decoded
            marks = [time.perf_counter()]
            _frame_set_distances(stage, cell, cams, points, depths, masks, q, q, marks)
            dt = time.perf_counter() - marks[0]
            if i >= 5:
                times.append(dt)
                updates.append(marks[1] - marks[0])
            time.sleep(max(0.0, pause - dt))
        out[name] = _stats(times)
        out[name + "_update"] = _stats(updates)
    return out


def _cpu_sample(pids: dict[str, int]) -> tuple[float, dict[str, float]]:
    """``(now, CPU seconds)``: a monotonic time (s) and the CPU time (user + system, s) each process has used
    so far, from ``/proc`` (Linux; none elsewhere)."""
    out = {}
    for name, pid in pids.items():
        try:
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        out[name] = (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # (utime, stime)
    return time.monotonic(), out


def _cpu_percent(cpu: dict[str, tuple]) -> dict[str, float]:
    """Each process's CPU use over the measurement, in % of one core (from :func:`_cpu_sample` at its start
    and end)."""
    if "start" not in cpu or "end" not in cpu:
        return {}
    (t0, a), (t1, b) = cpu["start"], cpu["end"]
    return {k: 100.0 * (b[k] - a[k]) / (t1 - t0) for k in a if k in b and t1 > t0}


def _shm_fraction(log: list[dict]) -> float | None:
    """Of the image samples (depths and masks) the distance node received, the fraction in shared memory."""
    summary = [r for r in log if r.get("ev") == "summary"]
    if not summary:
        return None
    got = [v for k, v in summary[-1]["shared_memory_samples"].items() if "joint" not in k]
    n = sum(v[1] for v in got)
    return sum(v[0] for v in got) / n if n else None


def _summary(path: Path) -> dict:
    """A node's JSON summary (the last line it printed), or {} when there is none."""
    lines = path.read_text().splitlines() if path.exists() else []
    try:
        return json.loads(lines[-1]) if lines else {}
    except json.JSONDecodeError:
        return {}


def _chain(dist: list[dict], cmds: list[dict]) -> list[float]:
    by_pub = {round(r["pub"], 6): r["frame_pub"] for r in dist}
    return [c["pub"] - by_pub[round(c["dist_pub"], 6)] for c in cmds if round(c["dist_pub"], 6) in by_pub]
