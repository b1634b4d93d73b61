"""A worker thread that runs part of a computation beside the calling thread, each on a CPU of its own.

The depth grid's frame stage runs the secondary cameras' part on a worker thread while the caller runs the
principal camera's part (:meth:`depthguard.depthgrid.DepthGridFusion.update`, ``side=``). At camera rate
the process idles between frames, and after such an idle Linux often wakes the worker on the caller's own
CPU: the two parts then share one core until the scheduler moves one of them. On the 2-core benchmark VM
the frame stage of the ``ral-hexagon`` cell took 5.0-5.4 ms paced at 30 Hz against 2.9-3.2 ms back to back
(BENCHMARKS.md, "Frame stage: the side thread on a CPU of its own").

:meth:`SideThread.beside` holds the caller on the CPU it is running on and the worker on the other CPUs the
caller may use, for the duration of the ``with`` block; the caller's CPU mask is then restored, so the
caller's other work (and any thread it starts later) is not confined. Where CPU affinity cannot be set (not
Linux, one allowed CPU, a container that refuses it) it is a plain worker thread.
"""

from __future__ import annotations

import contextlib
import ctypes
import itertools
import os
from collections.abc import Callable, Iterator
from concurrent.futures import Executor, Future, ThreadPoolExecutor
from typing import TypeVar

T = TypeVar("T")

__all__ = ["SideThread", "run_parts", "usable_cpus"]


def _cpu_getter() -> Callable[[], int] | None:
    try:
        fn = ctypes.CDLL(None, use_errno=True).sched_getcpu
    except (OSError, AttributeError):
        return None
    fn.restype = ctypes.c_int
    fn.argtypes = []
    return fn


_SCHED_GETCPU = _cpu_getter() if hasattr(os, "sched_setaffinity") else None


def _set_affinity(cpus: set[int]) -> bool:
    try:
        os.sched_setaffinity(0, cpus)  # (0: the calling thread, on Linux)
    except OSError:
        return False
    return True


class _Pinned(Executor):
    """``submit`` of a :class:`SideThread` inside :meth:`SideThread.beside`: the job first moves its thread
    to ``cpus``."""

    def __init__(self, pool: ThreadPoolExecutor, cpus: set[int]) -> None:
        self._pool, self._cpus = pool, cpus

    def submit(self, fn, /, *args, **kwargs) -> Future:
        def job():
            _set_affinity(self._cpus)
            return fn(*args, **kwargs)

        return self._pool.submit(job)


class SideThread:
    """One worker thread (module docstring). ``name``: the worker thread's name prefix."""

    def __init__(self, name: str = "depthguard-side") -> None:
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix=name)

    @contextlib.contextmanager
    def beside(self) -> Iterator[Executor]:
        """An executor whose jobs run on the worker, on another CPU than the caller's, while the block lasts."""
        if _SCHED_GETCPU is None:
            yield self._pool
            return
        allowed = os.sched_getaffinity(0)
        here = int(_SCHED_GETCPU())
        if len(allowed) < 2 or here not in allowed or not _set_affinity({here}):
            yield self._pool
            return
        try:
            yield _Pinned(self._pool, allowed - {here})
        finally:
            _set_affinity(allowed)

    def shutdown(self) -> None:
        """Stop the worker thread (after its jobs)."""
        self._pool.shutdown(wait=True)


def usable_cpus() -> int:
    """How many CPUs the calling thread may run on: its affinity mask where the system has one (``taskset``,
    cpusets), else the machine's CPU count."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def run_parts(fn: Callable[[int], T], n: int, side: Executor | None = None) -> list[T]:
    """``[fn(0), ..., fn(n - 1)]``, computed by this thread and ``side``'s worker together: each takes the next
    part not yet taken until none is left (``fn`` must release the GIL to gain anything: a numba kernel
    with ``nogil``). This thread never waits for the worker to start: when it has done every part itself (the
    worker still asleep, or busy elsewhere), it returns at once and the worker's job finds nothing left.
    It waits only for a part that the worker took and is computing. Without ``side``: one part after the
    other here. An exception of ``fn`` is raised here, from either thread."""
    out: list = [None] * n
    done = [False] * n
    take = itertools.count()  # (next() is atomic in CPython: each part is taken once)

    def work() -> None:
        while (k := next(take)) < n:
            out[k] = fn(k)
            done[k] = True

    job = side.submit(work) if side is not None and n > 1 else None
    try:
        work()
    finally:
        if job is not None and not all(done):
            job.result()  # (a part the worker took: wait for it, or raise its error)
    return out
