"""SideThread: the worker beside the caller on another CPU, the caller's CPU mask restored afterwards."""

from __future__ import annotations

import os

import pytest

from depthguard import sidethread
from depthguard.sidethread import SideThread


@pytest.fixture
def side():
    worker = SideThread("test-side")
    yield worker
    worker.shutdown()


needs_affinity = pytest.mark.skipif(
    sidethread._SCHED_GETCPU is None or len(os.sched_getaffinity(0)) < 2,
    reason="needs Linux CPU affinity and at least two allowed CPUs",
)


@needs_affinity
def test_caller_and_worker_run_on_different_cpus_and_the_callers_mask_comes_back(side):
    before = os.sched_getaffinity(0)
    for _ in range(20):  # (the caller may be on any CPU when the block starts)
        with side.beside() as ex:
            mine = os.sched_getaffinity(0)
            theirs = ex.submit(os.sched_getaffinity, 0).result()
            assert len(mine) == 1 and mine <= before
            assert theirs == before - mine
            assert ex.submit(lambda: sidethread._SCHED_GETCPU()).result() not in mine
        assert os.sched_getaffinity(0) == before


@needs_affinity
def test_the_mask_comes_back_when_the_job_fails(side):
    before = os.sched_getaffinity(0)
    with pytest.raises(ZeroDivisionError):
        with side.beside() as ex:
            ex.submit(lambda: 1 / 0).result()
    assert os.sched_getaffinity(0) == before


@needs_affinity
def test_one_allowed_cpu_gives_a_plain_worker(side):
    before = os.sched_getaffinity(0)
    one = {min(before)}
    try:
        os.sched_setaffinity(0, one)
        with side.beside() as ex:
            assert os.sched_getaffinity(0) == one
            assert ex.submit(lambda: 6 * 7).result() == 42
        assert os.sched_getaffinity(0) == one
    finally:
        os.sched_setaffinity(0, before)


def test_a_refused_affinity_gives_a_plain_worker(monkeypatch, side):
    """A container that refuses sched_setaffinity: no error, the jobs still run."""

    def refuse(pid, cpus):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setaffinity", refuse, raising=False)
    with side.beside() as ex:
        assert ex.submit(lambda: 6 * 7).result() == 42


def test_without_cpu_affinity_it_is_a_plain_worker(monkeypatch, side):
    monkeypatch.setattr(sidethread, "_SCHED_GETCPU", None)
    with side.beside() as ex:
        assert ex.submit(lambda: 6 * 7).result() == 42


# ---------------------------------------------------------------- run_parts


def test_run_parts_gives_every_part_once_in_order_from_both_threads():
    import threading
    import time
    from concurrent.futures import ThreadPoolExecutor

    calls, who = [], {}

    def fn(k):
        calls.append(k)
        who[k] = threading.get_ident()
        time.sleep(0.02)  # (long enough for the worker to take parts too)
        return k * k

    with ThreadPoolExecutor(1) as ex:
        assert sidethread.run_parts(fn, 6, ex) == [0, 1, 4, 9, 16, 25]
    assert sorted(calls) == list(range(6))
    assert len(set(who.values())) == 2  # both threads worked
    assert sidethread.run_parts(fn, 3) == [0, 1, 4]  # (no side: all here)


def test_run_parts_does_not_wait_for_a_busy_worker():
    """The worker is busy elsewhere for 1 s: this thread does every part and returns at once."""
    import threading
    import time
    from concurrent.futures import ThreadPoolExecutor

    release = threading.Event()
    with ThreadPoolExecutor(1) as ex:
        ex.submit(release.wait, 1.0)
        t0 = time.perf_counter()
        assert sidethread.run_parts(lambda k: k + 1, 4, ex) == [1, 2, 3, 4]
        assert time.perf_counter() - t0 < 0.5
        release.set()


def test_run_parts_raises_the_workers_error():
    import threading
    import time
    from concurrent.futures import ThreadPoolExecutor

    here = threading.get_ident()

    def fn(k):
        if threading.get_ident() != here:
            raise ZeroDivisionError(f"part {k}")
        time.sleep(0.05)  # (this thread is slow: the worker takes a part)
        return k

    with ThreadPoolExecutor(1) as ex:
        with pytest.raises(ZeroDivisionError, match="part"):
            sidethread.run_parts(fn, 2, ex)
        with pytest.raises(ValueError, match="mine"):
            sidethread.run_parts(lambda k: (_ for _ in ()).throw(ValueError("mine")), 1, ex)
