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
