"""DepthGuard's nodes as real processes on Zenoh (loopback only), and what happens when they fail.

One set of processes (``sim`` driver, ``camera0``, ``camera1``, ``distance``, ``controller``) runs for the
module; each test injects one fault and watches the controller's status topic from a subscriber of its own:

* the distance node killed, then restarted: the controller stops the arm (STOP_STALE_DISTANCES) within its
  stale-data timeout, keeps running, and resumes (OK) after its resume latch once distances come back;
* a camera node frozen (SIGSTOP: its session stops answering, as in a network partition) then continued:
  the same stop and resume;
* a network partition simulated by closing the session: the distance node's process closes its Zenoh
  session and later opens a new one (``tests/partition_node.py``): the same stop and resume;
* the controller node killed: the driver's watchdog holds the arm (the sim node's log);
* an unlisted publisher of distances: ignored and reported by the controller;
* duplicated and reordered distances (replayed while the distance node is frozen): dropped, the same stop
  and resume;
* a slow consumer (the distance node running a fifth of the time): the same stop, no backlog, and resume;
* bad inputs on the open topics (a joint state stamped an hour ahead, images of a size the camera cannot
  have, rgb8 raw images): every node keeps running and the arm keeps moving (``test_node_inputs.py`` has
  the property tests of the same guards).

The test cell relaxes the timeouts to what a 2-core shared CI machine can keep (controller 250 Hz,
joint timeout 0.1 s, distance timeout 0.3 s); duplicated / reordered samples are also tested at the
transport level in ``test_rmw_zenoh.py``.
"""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

pytest.importorskip("zenoh")

pytestmark = pytest.mark.slow  # (no longer xfail: 5 of 5 runs passed on 2026-12-02, 2 of them beside the
# heaviest property tests in a second worker, after the net and browser tests; see tests/test_live_view.py)

ROOT = Path(__file__).resolve().parents[1]
D_TIMEOUT = 0.3
MOVING = ("OK", "SCALED")  # (the controller runs and moves the arm: a start-up is complete)


def _cell(tmp: Path, network: str = "") -> Path:
    """The relaxed test cell; ``network``: more lines for its ``[network]`` table (TLS, for example)."""
    text = (ROOT / "examples/cells/sim-hexagon.toml").read_text()
    text = text.replace("joint_timeout = 0.005", "joint_timeout = 0.1")
    text = text.replace("distance_timeout = 0.1", f"distance_timeout = {D_TIMEOUT}")
    text = text.replace("rate = 1000.0", "rate = 250.0")
    port = random.randint(24000, 30000)
    text += f'\n[network]\nbase_port = {port}\nconnect = []\npublishers = ["distance", "controller"]\n{network}\n'
    p = tmp / "cell.toml"
    p.write_text(text)
    return p


class System:
    def __init__(self, tmp: Path, network: str = "") -> None:
        self.tmp, self.cell = tmp, _cell(tmp, network)
        self.procs: dict[str, subprocess.Popen] = {}
        self.env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}

    def start(self, name: str) -> None:
        extra = ["--source", "sim:ral-hexagon", "--quick"] if name == "sim" else []
        cmd = [sys.executable, "-m", "depthguard.cli", "node", name, "--cell", str(self.cell), *extra]
        cmd += ["--log", str(self.tmp / f"{name}.log"), "--duration", "400"]
        out = open(self.tmp / f"{name}.out", "a")  # noqa: SIM115
        self.procs[name] = subprocess.Popen(cmd, env=self.env, stdout=out, stderr=subprocess.DEVNULL)

    def stop(self, name: str, sig=signal.SIGTERM) -> None:
        p = self.procs.pop(name)
        p.send_signal(sig)
        try:
            p.wait(15)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()

    def close(self) -> None:
        for name in list(self.procs):
            p = self.procs[name]
            p.send_signal(signal.SIGCONT)
            self.stop(name)


class StatusWatch:
    """Our own subscriber of the controller status (received wall time, status name)."""

    def __init__(self, cell_path: Path, name: str = "test_watch", tls: dict | None = None) -> None:
        from depthguard.io.cellfile import read_cell
        from depthguard.io.zenoh_transport import ZenohNode
        from depthguard.nodes.common import Topics, _endpoint, node_names

        cell = read_cell(cell_path)
        base = cell.network["base_port"]
        peers = [_endpoint(cell, base + k) for k in range(len(node_names(cell)))]
        self.node = ZenohNode(name, domain=0, listen=[], connect=peers, tls=tls)
        self.cell = cell
        self.events: list[tuple[float, str]] = []
        self.lock = threading.Lock()
        self.node.subscribe(Topics.of(cell).status, "depthguard_msgs/msg/ControllerStatus", self._on, check_order=False)

    def _on(self, msg, att, recv_ns):
        with self.lock:
            self.events.append((recv_ns * 1e-9, str(msg.status)))

    def wait_for(self, status: str | tuple[str, ...], after: float, timeout: float) -> float | None:
        """The receive time of the first status in ``status`` (a name or several) at or after ``after``."""
        wanted = (status,) if isinstance(status, str) else status
        end = time.time() + timeout
        while time.time() < end:
            with self.lock:
                for t, s in self.events:
                    if t >= after and s in wanted:
                        return t
            time.sleep(0.02)
        return None

    def close(self) -> None:
        self.node.close()


@pytest.fixture(scope="module")
def system(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("nodes")
    sysm = System(tmp)
    watch = None
    try:
        for n in ("sim", "camera0", "camera1", "distance", "controller"):
            sysm.start(n)
        watch = StatusWatch(sysm.cell)
        t_ok = watch.wait_for(MOVING, 0.0, 120.0)
        if t_ok is None:
            pytest.fail(f"the nodes never moved the arm; statuses seen: {sorted({s for _, s in watch.events})}")
        yield sysm, watch
    finally:
        if watch is not None:
            watch.close()
        sysm.close()


def _fault_and_recover(system, name: str, kill: bool) -> None:
    sysm, watch = system
    assert watch.wait_for("OK", time.time() - 0.5, 30.0), "not OK before the fault"
    t_fault = time.time()
    if kill:
        sysm.stop(name, signal.SIGKILL)
    else:
        os.kill(sysm.procs[name].pid, signal.SIGSTOP)
    t_stop = watch.wait_for("STOP_STALE_DISTANCES", t_fault, 10.0)
    assert t_stop is not None, f"no stale-data stop after {name} {'killed' if kill else 'frozen'}"
    # the data was at most one frame set plus the pipeline old at the fault; the stop comes within the timeout
    assert t_stop - t_fault <= D_TIMEOUT + 0.5, f"stop {t_stop - t_fault:.3f} s after the fault"
    assert sysm.procs["controller"].poll() is None, "the controller node must keep running"
    time.sleep(0.5)
    with watch.lock:
        late = [s for t, s in watch.events if t > t_stop + 0.1]
    assert late and all(s.startswith("STOP") for s in late), f"moved again without data: {set(late)}"
    t_back = time.time()
    if kill:
        sysm.start(name)
    else:
        os.kill(sysm.procs[name].pid, signal.SIGCONT)
    t_ok = watch.wait_for("OK", t_back, 90.0)
    assert t_ok is not None, f"never resumed after {name} came back"
    with watch.lock:
        between = [s for t, s in watch.events if t_back <= t < t_ok]
    assert "STOP_RESUME_WAIT" in between, "resumed without the resume latch"


def _controller_report_and_restart(sysm, watch) -> dict:
    """Stop the controller node (SIGTERM: it prints its report), start it again and wait until it moves the
    arm (a status from the new process: the old one's last statuses must not count); returns the report."""
    sysm.stop("controller")
    out = [json.loads(x) for x in (sysm.tmp / "controller.out").read_text().splitlines() if x.startswith("{")]
    t_start = time.time()
    sysm.start("controller")
    assert watch.wait_for(MOVING, t_start, 90.0), "the restarted controller never moved the arm"
    return out[-1]


def test_distance_node_killed_and_restarted(system):
    _fault_and_recover(system, "distance", kill=True)


def test_camera_node_frozen_and_continued(system):
    _fault_and_recover(system, "camera0", kill=False)


def test_distance_session_closed_then_opened_again(system):
    """A network partition simulated by closing the session: the distance node's process closes its Zenoh
    session (SIGUSR1 to ``tests/partition_node.py``) and lives on without one, then opens a new session
    (SIGUSR2), which the other nodes' connection retries find again. The same stop and resume as a kill."""
    sysm, watch = system
    sysm.stop("distance")
    out_path = sysm.tmp / "partition.out"
    cmd = [sys.executable, str(ROOT / "tests" / "partition_node.py"), str(sysm.cell), str(sysm.tmp / "distance.log")]
    sysm.procs["distance"] = proc = subprocess.Popen(  # (the node for the rest of the module)
        cmd,
        env=sysm.env,
        stdout=open(out_path, "a"),
        stderr=subprocess.DEVNULL,  # noqa: SIM115
    )

    def events(kind: str) -> list[float]:
        lines = out_path.read_text().splitlines()
        return [json.loads(x)["t"] for x in lines if x.startswith("{") and json.loads(x)["ev"] == kind]

    assert watch.wait_for(MOVING, time.time(), 90.0), "the arm never moved with the partition node"
    t_fault = time.time()
    proc.send_signal(signal.SIGUSR1)
    t_stop = watch.wait_for("STOP_STALE_DISTANCES", t_fault, 10.0)
    assert t_stop is not None and t_stop - t_fault <= D_TIMEOUT + 0.5, "no timely stop once the session closed"
    time.sleep(1.0)
    closed = [t for t in events("closed") if t >= t_fault]
    assert closed and proc.poll() is None, "the node's session did not close, or its process ended"
    assert sysm.procs["controller"].poll() is None, "the controller node must keep running"
    with watch.lock:
        late = [s for t, s in watch.events if t > t_stop + 0.1]
    assert late and all(s.startswith("STOP") for s in late), f"moved again without a session: {set(late)}"
    t_back = time.time()
    proc.send_signal(signal.SIGUSR2)
    t_ok = watch.wait_for("OK", t_back, 90.0)
    assert t_ok is not None, "never resumed after the session opened again"
    assert [t for t in events("open") if t >= t_back], "no new session"
    with watch.lock:
        assert "STOP_RESUME_WAIT" in [s for t, s in watch.events if t_back <= t < t_ok], "resumed without latch"


def test_unlisted_distance_publisher_is_ignored_and_reported(system):
    from depthguard.io import ros2
    from depthguard.nodes.common import Topics

    sysm, watch = system
    pub = watch.node.publisher(Topics.of(watch.cell).distances, "depthguard_msgs/msg/ControlPointDistances")
    time.sleep(1.5)
    for _ in range(5):
        msg = ros2.distances_msg(time.time(), ["ee"], [[0, 0, 0]], [0.1], [10.0], [[1.0, 0, 0]])
        pub.publish(msg)
        time.sleep(0.05)
    time.sleep(0.5)
    out = _controller_report_and_restart(sysm, watch)
    assert out["rejected_publishers"] == ["test_watch"]
    assert out["dropped"].get("publisher not allowed", 0) >= 5


def test_replayed_and_reordered_distances_do_not_keep_the_arm_moving(system):
    """Duplicated and reordered messages, real processes. While the distance node is frozen, a peer keeps
    sending (a) exact copies of the node's last samples (its attachment: GID and sequence number) and (b) the
    same payloads from a second publisher under the listed name ``distance``, oldest last (header stamps
    going back). The controller drops both, stops the arm within its stale-data timeout, keeps running, and
    resumes through its latch when the node continues; its report counts both kinds of drop."""
    from depthguard.io.rmw_zenoh import topic_keyexpr
    from depthguard.io.zenoh_transport import ZenohNode
    from depthguard.nodes.common import Topics, _endpoint, node_names

    sysm, watch = system
    assert watch.wait_for("OK", time.time() - 0.5, 60.0), "not OK before the fault"
    top = Topics.of(watch.cell)
    key = topic_keyexpr(0, top.distances, "depthguard_msgs/msg/ControlPointDistances")
    seen: list[tuple[bytes, bytes]] = []
    tap = watch.node.session.declare_subscriber(
        key, lambda s: seen.append((s.payload.to_bytes(), s.attachment.to_bytes()))
    )
    base = watch.cell.network["base_port"]
    peers = [_endpoint(watch.cell, base + k) for k in range(len(node_names(watch.cell)))]
    impostor = ZenohNode("distance", domain=0, listen=[], connect=peers)  # (a listed name, no TLS here)
    try:
        pub = impostor.publisher(top.distances, "depthguard_msgs/msg/ControlPointDistances")
        end = time.time() + 10
        while len(seen) < 20 and time.time() < end:
            time.sleep(0.05)
        assert len(seen) >= 20, "too few distance samples seen to replay"
        t_fault = time.time()
        os.kill(sysm.procs["distance"].pid, signal.SIGSTOP)
        time.sleep(0.05)
        copies = list(seen[-20:])
        end = t_fault + 2.5
        while time.time() < end:
            for payload, att in copies[-5:]:  # (a) exact duplicates
                watch.node.session.put(key, payload, attachment=att)
            for payload, _ in reversed(copies):  # (b) a fresh publisher, stamps going back
                pub.put_cdr(payload)
            time.sleep(0.02)
        t_stop = watch.wait_for("STOP_STALE_DISTANCES", t_fault, 0.1)
        assert t_stop is not None and t_stop - t_fault <= D_TIMEOUT + 0.5, "no timely stop under replayed data"
        with watch.lock:
            late = [s for t, s in watch.events if t > t_stop + 0.1]
        assert late and all(x.startswith("STOP") for x in late), f"moved on replayed data: {set(late)}"
        assert sysm.procs["controller"].poll() is None, "the controller node must keep running"
    finally:
        os.kill(sysm.procs["distance"].pid, signal.SIGCONT)
        tap.undeclare()
        impostor.close()
    t_back = time.time()
    t_ok = watch.wait_for("OK", t_back, 90.0)
    assert t_ok is not None, "never resumed after the distance node continued"
    with watch.lock:
        assert "STOP_RESUME_WAIT" in [s for t, s in watch.events if t_back <= t < t_ok], "resumed without latch"
    dropped = _controller_report_and_restart(sysm, watch)["dropped"]
    assert dropped.get("duplicate or reordered sequence number", 0) >= 5, dropped
    assert dropped.get("stale or reordered stamp", 0) >= 19, dropped


def test_slow_distance_node_works_on_the_newest_frames(system):
    """A slow consumer: the distance node runs 0.1 s in every 0.7 s (SIGSTOP / SIGCONT) for 4 s, far slower
    than the frames come. The controller stops the arm on stale distances and keeps running; the node builds
    no backlog: once it runs freely again its results are about one frame set old, not the queued frames of
    the slow phase; and the controller resumes through its latch."""
    sysm, watch = system
    assert watch.wait_for("OK", time.time() - 0.5, 60.0), "not OK before the slow phase"
    pid = sysm.procs["distance"].pid
    t_slow = time.time()
    try:
        while time.time() - t_slow < 4.0:
            os.kill(pid, signal.SIGSTOP)
            time.sleep(0.6)  # (twice the distance timeout: the results of the short runs are stale)
            os.kill(pid, signal.SIGCONT)
            time.sleep(0.1)
    finally:
        os.kill(pid, signal.SIGCONT)
    t_free = time.time()
    assert watch.wait_for("STOP_STALE_DISTANCES", t_slow, 0.5) is not None, "no stale-data stop while slow"
    assert sysm.procs["controller"].poll() is None and sysm.procs["distance"].poll() is None
    t_ok = watch.wait_for("OK", t_free, 90.0)
    assert t_ok is not None, "never resumed after the slow phase"
    time.sleep(max(1.0, t_free + 2.5 - time.time()))
    with watch.lock:  # the statuses since the slow phase began, each change once (published on change)
        seq = [s for t, s in watch.events if t >= t_slow]
    changes = [s for i, s in enumerate(seq) if i == 0 or s != seq[i - 1]]
    assert all(not (a == "STOP_STALE_DISTANCES" and b == "OK") for a, b in zip(changes, changes[1:], strict=False)), (
        f"resumed without the latch: {changes}"
    )
    log = [json.loads(x) for x in (sysm.tmp / "distance.log").read_text().splitlines() if '"distances"' in x]
    # (the node skipped frames in the slow phase: after a stop it went on from a frame set far newer than its
    # last one, where a queue would have gone on from the next; a result delivered stale, because a stop fell
    # in its compute, happens by chance only and is not asked for)
    stamps = [r["stamp"] for r in sorted(log, key=lambda r: r["pub"]) if t_slow < r["pub"] < t_free + 0.3]
    jumps = [b - a for a, b in zip(stamps, stamps[1:], strict=False)]
    assert jumps and max(jumps) > D_TIMEOUT, f"no frames skipped in the slow phase (nothing was tested): {jumps}"
    ages = [r["pub"] - r["stamp"] for r in log if r["pub"] > t_free + 1.0]
    assert len(ages) >= 5, f"only {len(ages)} results after the slow phase"
    ages.sort()
    # (a queue of the slow phase's frames would keep ages of seconds; 2 cores shared with the whole system)
    assert ages[len(ages) // 2] < 0.25, f"results {ages[len(ages) // 2]:.3f} s old (median) after the slow phase"


def test_bad_inputs_from_an_open_peer_neither_stop_the_nodes_nor_hold_the_arm(system):
    """Images and joint states are open topics (any admitted peer may publish them). A peer sends (a) one
    joint state stamped an hour ahead, (b) for 2 s, depth images of 100x100 pixels (not a scaled image of
    the camera's) with their masks on camera0's prepared topics, and (c) rgb8 images on camera0's raw topic.
    Every node keeps running; the future joint state is dropped by the controller (counted), so it never
    refuses its inputs or holds the arm for the hour; the distance node skips the bad frame sets (logged);
    and the arm is moving again once the bad images stop. Before this was guarded, (b) stopped the distance
    node and (a) held the arm for the hour."""
    import numpy as np

    from depthguard.io import ros2
    from depthguard.io.rmw_zenoh import QOS_SENSOR_DATA
    from depthguard.nodes.camera import mask_msg
    from depthguard.nodes.common import Topics
    from depthguard.runner.chain import load_cell_robot

    sysm, watch = system
    assert watch.wait_for("OK", time.time() - 0.5, 60.0), "not OK before the bad inputs"
    top = Topics.of(watch.cell)
    pub_js = watch.node.publisher(top.joint_states, "sensor_msgs/msg/JointState")
    pub_d = watch.node.publisher(top.depth["camera0"], "sensor_msgs/msg/Image", QOS_SENSOR_DATA)
    pub_m = watch.node.publisher(top.mask["camera0"], "sensor_msgs/msg/Image", QOS_SENSOR_DATA)
    pub_raw = watch.node.publisher(top.raw["camera0"], "sensor_msgs/msg/Image", QOS_SENSOR_DATA)
    time.sleep(1.5)  # (the graph: the nodes learn the new publishers)
    t0 = time.time()
    names = list(load_cell_robot(watch.cell).joint_names)
    pub_js.publish(ros2.joint_state_msg(t0 + 3600.0, names, np.zeros(len(names)), np.zeros(len(names))))
    while time.time() < t0 + 2.0:
        now = time.time()
        pub_d.publish(ros2.image_msg(now, "camera0", np.full((100, 100), 1.5, np.float32), "32FC1"))
        pub_m.publish(mask_msg(now, "camera0", np.zeros((100, 100), bool)))
        rgb = ros2.image_msg(now, "camera0", np.ones((120, 160)))
        rgb.encoding = "rgb8"
        pub_raw.publish(rgb)
        time.sleep(1 / 15)
    for name in ("sim", "camera0", "camera1", "distance", "controller"):
        assert sysm.procs[name].poll() is None, f"the {name} node stopped on bad inputs"
    assert watch.wait_for("OK", time.time(), 60.0), "the arm never moved again after the bad inputs"
    with watch.lock:
        assert "STOP_INVALID_INPUT" not in [s for t, s in watch.events if t >= t0], "the future joint state was taken"
    skipped = [json.loads(x) for x in (sysm.tmp / "distance.log").read_text().splitlines() if '"skipped"' in x]
    assert any("not a scaled" in r["reason"] for r in skipped), "the distance node never saw a bad frame set"
    bad = [x for x in (sysm.tmp / "camera0.log").read_text().splitlines() if '"bad_frame"' in x]
    assert bad, "the camera node never saw an rgb8 frame"
    report = _controller_report_and_restart(sysm, watch)
    assert report["dropped_by_topic"][top.joint_states].get("stamp in the future", 0) >= 1, report


def test_controller_killed_driver_watchdog_holds_the_arm(system):
    sysm, watch = system
    assert watch.wait_for("OK", time.time() - 0.5, 60.0), "controller not back"
    t_kill = time.time()
    sysm.stop("controller", signal.SIGKILL)
    end, after = time.time() + 6.0, []
    while time.time() < end:  # until the arm is at rest (on a busy machine the sim node lags behind)
        time.sleep(0.25)
        recs = [json.loads(x) for x in (sysm.tmp / "sim.log").read_text().splitlines() if '"js"' in x]
        after = [r for r in recs if r["t"] > t_kill]
        if after and after[-1]["t"] > t_kill + 1.5 and after[-1]["qd_max"] < 0.05:
            break
    assert after, "the sim node stopped publishing"
    held = [r for r in after if r["held"]]
    assert held, "the driver watchdog never held the arm"
    assert held[0]["t"] - t_kill <= 0.05 + 0.5, "watchdog too late"
    assert after[-1]["qd_max"] < 0.05, f"arm still moving at {after[-1]['qd_max']} rad/s"
