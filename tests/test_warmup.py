"""Cold start (issue 8 §5): the demo says that it compiles the kernels, once, and compiles them in parallel
processes; the cache stamp notices edited sources and deleted caches."""

from __future__ import annotations

import os
import time

import pytest

from depthguard.sim import warmup


def test_is_cached_follows_sources_and_cache_files(tmp_path, monkeypatch):
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)  # numba's default place, beside the modules
    pkg = tmp_path / "depthguard"
    (pkg / "k" / "__pycache__").mkdir(parents=True)
    src = pkg / "k" / "kern.py"
    src.write_text("import numba\n@numba.njit(cache=True)\ndef f(x):\n    return x\n")
    monkeypatch.setattr(warmup, "_root", lambda: pkg)
    monkeypatch.setitem(warmup.SOURCES, "g", ("k",))
    assert not warmup.is_cached("g")  # never compiled
    index = pkg / "k" / "__pycache__" / "kern.f-3.py311.nbi"
    index.write_bytes(b"")
    warmup._write_stamp("g")
    assert warmup.is_cached("g")
    index.unlink()  # `find src -name '*.nbi' | xargs rm`: cold again
    assert not warmup.is_cached("g")
    index.write_bytes(b"")
    assert warmup.is_cached("g")
    later = time.time() + 5
    os.utime(src, (later, later))  # an edited kernel is recompiled
    assert not warmup.is_cached("g")


def test_demo_announces_the_first_compilation(monkeypatch, capsys):
    pytest.importorskip("mujoco")
    from depthguard.sim import demo

    started: list = []

    class FakeBackground:
        def wait(self, announce=None):
            return 42.0

    monkeypatch.setattr(warmup, "is_cached", lambda g: g == "robot")
    monkeypatch.setattr(warmup, "compile_in_background", lambda groups: started.append(groups) or FakeBackground())
    demo._compile_kernels(["fusion", "robot"])
    out = capsys.readouterr().out
    assert started == [["fusion"]]
    assert "compiling the numba kernels (fusion)" in out and "once" in out and "cached" in out
    assert "kernels compiled in 42 s" in out
    monkeypatch.setattr(warmup, "is_cached", lambda g: True)
    demo._compile_kernels(["fusion", "robot"])
    assert capsys.readouterr().out == "" and len(started) == 1  # warm: silent, nothing started


def test_background_compile_runs_the_groups_in_child_processes():
    """With warm caches (the suite has run the kernels) a child loads them and exits 0 within seconds."""
    bg = warmup.compile_in_background(["depthspace"])
    messages: list[str] = []
    bg.wait(announce=messages.append)
    assert messages == [] and all(p.returncode == 0 for p in bg.procs.values())


def test_is_cached_looks_in_the_versioned_cache_folder(tmp_path, monkeypatch):
    pkg = tmp_path / "depthguard"
    (pkg / "k").mkdir(parents=True)
    (pkg / "k" / "kern.py").write_text("x = 1\n")
    cache = tmp_path / "cache"
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(cache))
    monkeypatch.setattr(warmup, "_root", lambda: pkg)
    monkeypatch.setitem(warmup.SOURCES, "g", ("k",))
    index = cache / "k_0123" / "kern.f-3.py311.nbi"
    index.parent.mkdir(parents=True)
    index.write_bytes(b"")
    warmup._write_stamp("g")
    assert warmup.is_cached("g")
    index.unlink()  # the versioned cache folder cleared: cold again
    assert not warmup.is_cached("g")
