"""The controller node's warm-up: every kernel the controller's cycle uses must be loaded before the node's
real-time loop starts (a first use inside the loop stalled the node for 5-7 s, three times: once the moving
path, once the braking kernel at the first resume, once read-only joint positions, a new type for the
kernels, at the first resume)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# Run in a fresh interpreter (nothing else has used a kernel there): warm up, then drive a new controller
# through inputs the warm-up does not use verbatim (read-only arrays among them, as the controller node's
# decoded joint states are) and list every compiled kernel that gained a signature.
_PROBE = r"""
import json, sys
import numpy as np
from numba.core.dispatcher import Dispatcher
from depthguard.control.cycle import AvoidanceController, CycleInput
from depthguard.io.cellfile import read_cell
from depthguard.control.warmup import warm_up
from depthguard.runner.chain import _controller_config, cell_control_points, load_cell_robot

def signatures():
    return {f"{m}.{a}": len(v.signatures) for m, mod in list(sys.modules.items()) if m.startswith("depthguard")
            and mod is not None for a, v in list(vars(mod).items()) if isinstance(v, Dispatcher)}

cell = read_cell(sys.argv[1])
model = load_cell_robot(cell)
points, cfg = cell_control_points(cell, model), _controller_config(cell)
met = warm_up(points, cfg, model)
before = signatures()
N, n = points.n_points, len(model.joint_names)
rng = np.random.default_rng(3)
dirs = rng.normal(size=(N, 3)); dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
lo, hi = np.asarray(model.q_min, float), np.asarray(model.q_max, float)
seen = set()
for case in range(8):
    ctrl = AvoidanceController(points, cfg)
    q, qd = lo + (0.1 + 0.1 * case) * (hi - lo), np.zeros(n)
    for k in range(int(1.5 * (cfg.resume_time + cfg.distance_timeout) / cfg.dt) + 200):
        t = k * cfg.dt
        d = [rng.uniform(0.0, 0.6, N), np.full(N, np.inf), np.zeros(N), None][case % 4] if k > 20 else None
        stale = case >= 4 and 60 < k < 60 + int(2 * cfg.distance_timeout / cfg.dt)
        mon = (d, dirs) if case == 5 and d is not None else (None, None)
        xd = np.zeros(3) if case % 2 else np.array([0.0, -0.03, 0.01])
        qq, qqd, dd, ddirs = q.copy(), qd.copy(), None if d is None else d.copy(), dirs.copy()
        if case % 2:  # read-only, as a ROS message's arrays are when decoded in place
            for a in (qq, qqd, dd, ddirs):
                if a is not None:
                    a.setflags(write=False)
        out = ctrl.step(CycleInput(t, qq if k > 5 else None, qqd if k > 5 else None, t if k > 5 else -np.inf, xd,
                        dd, ddirs if d is not None else None, 0.0 if stale else t, *mon))
        seen.add(out.status.name)
        if k > 5:
            q, qd = np.asarray(out.q_cmd, float), np.asarray(out.qdot_cmd, float)
after = signatures()
new = sorted(k for k, v in after.items() if v != before.get(k, 0))
print(json.dumps({"warm_up": met, "seen": sorted(seen), "new": new}))
"""


def test_warm_up_walks_the_stopped_braking_resuming_and_moving_paths():
    from depthguard.control.warmup import warm_up
    from depthguard.io.cellfile import read_cell
    from depthguard.runner.chain import _controller_config, cell_control_points, load_cell_robot

    cell = read_cell(ROOT / "examples/cells/sim-hexagon.toml")
    model = load_cell_robot(cell)
    points, config = cell_control_points(cell, model), _controller_config(cell)
    met = warm_up(points, config, model)
    need = {"STOP_INVALID_INPUT", "OK", "STOP_STALE_DISTANCES", "STOP_RESUME_WAIT", "STOP_STALE_JOINTS"}
    assert need <= set(met), met
    assert warm_up(points, config, model, cycles=0) == []


@pytest.mark.slow
def test_no_kernel_is_first_used_after_the_warm_up():
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    cell = str(ROOT / "examples/cells/sim-hexagon.toml")
    # twice: a kernel compiled from its source as part of another one gains a signature there, one loaded from
    # the cache does not, so the first run fills the kernel cache and the second one, loading, is the check
    for _ in range(2):
        res = subprocess.run([sys.executable, "-c", _PROBE, cell], env=env, capture_output=True, text=True, timeout=600)
        assert res.returncode == 0, res.stderr[-2000:]
    out = json.loads(res.stdout.strip().splitlines()[-1])
    assert {"OK", "STOP_STALE_DISTANCES", "STOP_RESUME_WAIT"} <= set(out["seen"]), out["seen"]  # (it tested them)
    assert out["new"] == [], f"kernels first used after the warm-up (inside a node's loop): {out['new']}"
