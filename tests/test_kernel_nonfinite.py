"""The distance kernels with NaN / ±inf depths and +inf sentinels (+inf means "nothing" in the kernels).

* no kernel of the distance modules is compiled with fast-math flags that assume finite values
  (``nnan``, ``ninf`` or ``fastmath=True``, which implies both);
* compiled and plain-Python runs of every kernel agree on inputs full of non-finite values
  (``tests/nonfinite_case.py``), and the answers are well formed: distances >= 0 or +inf, never NaN.
"""

from __future__ import annotations

import importlib
import os
import pkgutil
import subprocess
import sys
from pathlib import Path

import numpy as np
from numba.core.registry import CPUDispatcher

import depthguard.depthgrid
from depthguard.depthspace import PointDistances

HERE = Path(__file__).parent


def _kernel_modules():
    names = ["depthguard.depthspace"]
    names += [m.name for m in pkgutil.walk_packages(depthguard.depthgrid.__path__, "depthguard.depthgrid.")]
    try:
        import depthguard.kernels as kernels  # the shared kernel parts, where present
    except ImportError:
        pass
    else:
        names += [m.name for m in pkgutil.walk_packages(kernels.__path__, "depthguard.kernels.")]
    return [importlib.import_module(n) for n in names]


def test_no_kernel_assumes_finite_math():
    seen = 0
    for mod in _kernel_modules():
        for name, obj in vars(mod).items():
            if not isinstance(obj, CPUDispatcher) or obj.py_func.__module__ != mod.__name__:
                continue
            seen += 1
            fm = obj.targetoptions.get("fastmath", False)
            assert fm is not True, f"{mod.__name__}.{name}: fastmath=True assumes no NaN and no inf"
            flags = set(fm.flags if hasattr(fm, "flags") else (fm or ()))
            assert not flags & {"nnan", "ninf", "fast"}, f"{mod.__name__}.{name}: fastmath {sorted(flags)}"
    assert seen >= 10


def test_compiled_and_python_runs_agree_on_non_finite_inputs(tmp_path):
    sys.path.insert(0, str(HERE))
    try:
        import nonfinite_case
    finally:
        sys.path.remove(str(HERE))
    compiled = nonfinite_case.run(0)
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    subprocess.run(
        [sys.executable, str(HERE / "nonfinite_case.py"), str(tmp_path / "py.npz"), "0"], env=env, check=True
    )
    plain = np.load(tmp_path / "py.npz")
    assert set(plain.files) == set(compiled)
    for key, a in compiled.items():
        b = plain[key]
        assert a.shape == b.shape, key
        if a.dtype.kind == "f":
            assert np.array_equal(np.isnan(a), np.isnan(b)), key
            assert np.array_equal(np.isinf(a), np.isinf(b)), key
            np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-6, err_msg=key)
        else:
            assert np.array_equal(a, b), key
    for key, a in compiled.items():  # the direction lattice leaves every distance as it was, NaN-free
        if "_lattice_distance" in key:
            full = compiled[key.replace("_lattice_", "_frustum_" if key.startswith("ds_") else "_")]
            assert np.array_equal(a, full), key
    for key, a in compiled.items():
        if key.endswith("_distance"):
            assert not np.isnan(a).any() and np.all(a >= 0.0), key
            found = np.isfinite(a)
            direction = compiled[key.replace("_distance", "_direction")]
            assert np.allclose(np.linalg.norm(direction[found], axis=1), 1.0), key
            assert np.isnan(direction[~found]).all(), key
    assert len([k for k in compiled if k.endswith("_distance")]) >= len(PointDistances._fields)
