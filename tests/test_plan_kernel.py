"""The compiled planning stage (control.plan_kernel) gives the numbers of the stage functions it replaces.

Two controllers run the same closed-loop cycle sequences: one through the compiled stage, one with it
switched off (``ctrl.compiled = None``: forward kinematics, control points, repulsion, body bounds, DLS,
SSM and SNS as separate calls). Every output of every cycle must agree to 1e-12, in each avoidance mode,
with distances that are finite, negative, zero, +inf, and obstacles that bring the monitor to REDUCED and
PROTECTIVE_STOP.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

pytest.importorskip("pinocchio")
pytest.importorskip("ruckig")

from depthguard.control import AvoidanceController, ControllerConfig, CycleInput  # noqa: E402
from depthguard.control.plan_kernel import plan_params  # noqa: E402
from depthguard.robot.control_points import ControlPointSet  # noqa: E402
from depthguard.robot.model import load_lwr4  # noqa: E402

POINTS = None


def _points() -> ControlPointSet:
    global POINTS
    if POINTS is None:
        POINTS = ControlPointSet.build(load_lwr4(), "ral-9")
    return POINTS


def _obstacle_inputs(points, q, obstacle, rng):
    """Distances (sphere surface to a point obstacle, minus noise; some +inf, some negative) and directions."""
    st = points.evaluate(q)
    diff = st.centres - obstacle
    norm = np.linalg.norm(diff, axis=1)
    d = norm - st.radii - rng.uniform(0.0, 0.05, len(norm))
    dirs = diff / norm[:, None]
    far = rng.random(len(d)) < 0.2
    d[far] = np.inf
    return d, np.where(far[:, None], rng.normal(size=dirs.shape), dirs)


def _run_pair(cfg: ControllerConfig, seed: int, n_cycles: int = 250):
    points = _points()
    model = points.model
    fast, slow = AvoidanceController(points, cfg), AvoidanceController(points, cfg)
    assert fast.compiled is not None
    slow.compiled = None
    rng = np.random.default_rng(seed)
    q = np.clip(rng.uniform(-1.5, 1.5, model.n_dof), model.q_min + 0.1, model.q_max - 0.1)
    qd = np.zeros(model.n_dof)
    xd = rng.uniform(-0.3, 0.3, 3)
    centre = points.evaluate(q).centres[rng.integers(0, points.n_points)]
    obstacle = centre + rng.normal(size=3) * 0.15
    statuses = set()
    for k in range(n_cycles):
        t = k * cfg.dt
        if k % 40 == 0:  # the obstacle moves, the task changes
            obstacle = obstacle + rng.normal(size=3) * 0.05
            xd = rng.uniform(-0.3, 0.3, 3)
        d, dirs = _obstacle_inputs(points, q, obstacle, rng)
        inp = CycleInput(t, q, qd, t, xd, d, dirs, t)
        a, b = fast.step(inp), slow.step(inp)
        for name in ("qdot_cmd", "q_cmd", "qddot_cmd", "qdot_target", "qdot_min", "qdot_max", "xdot_c"):
            np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=0, atol=1e-12, err_msg=f"{name} @ {k}")
        assert a.status == b.status and a.bound_limited == b.bound_limited
        assert abs(a.scale - b.scale) <= 1e-12
        if a.ssm is not None:
            assert a.ssm.state == b.ssm.state and a.ssm.binding == b.ssm.binding
            assert abs(a.ssm.scale - b.ssm.scale) <= 1e-12
            statuses.add(a.ssm.state.name)
        statuses.add(a.status.name)
        q, qd = a.q_cmd, a.qdot_cmd
    return statuses


@pytest.mark.parametrize("avoidance", ["repulsion", "ssm", "both"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_compiled_plan_equals_the_stage_functions(avoidance: str, seed: int) -> None:
    cfg = replace(ControllerConfig(), avoidance=avoidance)
    seen = _run_pair(cfg, seed)
    if avoidance != "repulsion":
        assert seen & {"REDUCED", "PROTECTIVE_STOP"}, seen  # the monitor's branches ran


def test_evading_stop_and_parameters_reach_the_kernel() -> None:
    """A configuration away from the defaults (steeper profiles, contact distance, larger DLS damping)."""
    cfg = replace(
        ControllerConfig(), avoidance="both", rho_ee=0.3, alpha_ee=9.0, v_rep_max=1.0, rho_body=0.25,
        alpha_body=4.0, contact_distance=0.01, dls_eps=0.2, dls_lambda_max=0.1,
    )  # fmt: skip
    _run_pair(cfg, 7)
    assert plan_params(cfg).tolist() == [1.0, 0.3, 9.0, 0.25, 4.0, 0.01, 0.2, 0.1]
