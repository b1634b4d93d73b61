"""The demo's two runs (avoidance on, and off in a second process) each on its half of the CPUs, so that each
run's distance stage shares its query within its own half (``sidethread.usable_cpus``) instead of both runs
competing for every CPU; the demo's CPUs come back afterwards."""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import pytest

pytest.importorskip("mujoco")
from depthguard.sim import demo  # noqa: E402

needs_two = pytest.mark.skipif(
    not hasattr(os, "sched_setaffinity") or len(os.sched_getaffinity(0)) < 2,
    reason="needs Linux CPU affinity and at least two allowed CPUs",
)


@needs_two
def test_cpu_halves_split_the_allowed_cpus():
    before = os.sched_getaffinity(0)
    a, b = demo._cpu_halves()
    assert a and b and not (a & b) and a | b == before
    try:
        os.sched_setaffinity(0, {min(before)})
        assert demo._cpu_halves() is None
    finally:
        os.sched_setaffinity(0, before)


@needs_two
def test_each_run_of_the_demo_on_its_half(monkeypatch, tmp_path):
    seen: dict[bool, set] = {}

    def fake_run(name, avoidance, out_dir, **kw):
        seen[avoidance] = os.sched_getaffinity(0)
        return {"collision_steps": 0 if avoidance else 3, "out_dir": str(out_dir), "files": {}}

    def threads(cpus=None):  # (a thread in place of the spawned process: the same initializer)
        return ThreadPoolExecutor(max_workers=1, initializer=demo._set_cpus, initargs=(cpus,))

    import depthguard.sim.scenarios as scenarios

    monkeypatch.setattr(scenarios, "run_scenario", fake_run)
    monkeypatch.setattr(demo, "_compile_kernels", lambda groups: None)
    monkeypatch.setattr(demo, "_second_process", threads)
    before = os.sched_getaffinity(0)
    assert demo.run_demo(tmp_path) == 0
    a, b = demo._cpu_halves()
    assert seen == {True: a, False: b}
    assert os.sched_getaffinity(0) == before
