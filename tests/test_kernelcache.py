"""The compiled kernels live in a folder named after a hash of the sources (depthguard.kernelcache)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from depthguard.kernelcache import source_hash

ROOT = Path(__file__).resolve().parents[1]


def test_the_hash_changes_with_any_source_file(tmp_path):
    (tmp_path / "a.py").write_text("x = 1\n")
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "b.py").write_text("y = 2\n")
    h0 = source_hash(tmp_path)
    assert len(h0) == 16 and h0 == source_hash(tmp_path)
    (tmp_path / "sub" / "b.py").write_text("y = 3\n")  # a module other than the caller's
    assert source_hash(tmp_path) != h0


def test_numba_caches_in_the_versioned_folder(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["XDG_CACHE_HOME"] = str(tmp_path)
    env["PYTHONPATH"] = str(ROOT / "src")
    code = "import numba, depthguard, depthguard.kernelcache as k; print(numba.config.CACHE_DIR)"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    folder = Path(out.stdout.strip())
    assert folder.parent == tmp_path / "depthguard" / "numba" and folder.is_dir()
    assert folder.name == source_hash(ROOT / "src" / "depthguard")
