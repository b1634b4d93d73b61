"""``depthguard run``'s chain under hostile input streams (property test).

Random sequences of ticks from a source that misbehaves: joint states missing, NaN / inf, of the wrong
size; depth frames missing, of another size, full of NaN / inf / negative values, with stamps that jump
back or far ahead; desired velocities with NaN. Whatever the stream, ``run_chain`` never raises, every
joint command is finite and within the joint limits, and a tick whose joint state is unusable is a stop.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

pytest.importorskip("pinocchio")

from depthguard.io.cellfile import read_cell  # noqa: E402
from depthguard.robot.model import load_lwr4  # noqa: E402
from depthguard.runner.chain import Chain  # noqa: E402
from depthguard.runner.run import RunLog, run_chain  # noqa: E402
from depthguard.runner.sources import Tick  # noqa: E402
from depthguard.sim.depthcam import kinect_camera  # noqa: E402

CELL = """
[cell]
name = "hostile"
[robot]
model = "lwr4"
control_points = "ral-9"
[[cameras]]
name = "cam"
width = 80
height = 60
fx = 65.0
fy = 65.0
cx = 40.0
cy = 30.0
min_depth = 0.5
max_depth = 4.5
eye = [1.6, 0.2, 0.8]
target = [0.0, 0.0, 0.6]
[distance]
rho = 0.5
mode = "hybrid"
[controller]
joint_timeout = 0.005
"""

Q0 = np.array([0.0, 0.3, 0.0, 0.6, 0.0, -0.4, 0.0])


class ListSource:
    def __init__(self, ticks: list[Tick]) -> None:
        self._ticks = ticks
        self.commands: list[tuple[np.ndarray, np.ndarray]] = []

    def ticks(self):
        yield from self._ticks

    def command(self, q_cmd, qdot_cmd) -> None:
        self.commands.append((q_cmd, qdot_cmd))

    def close(self) -> None:
        pass


_q_kind = st.sampled_from(["ok", "ok", "ok", "none", "nan", "inf", "short"])
_frame_kind = st.sampled_from(["none", "none", "ok", "nan", "inf", "negative", "small", "wide"])
_t_kind = st.sampled_from(["ok", "ok", "ok", "back", "ahead", "nan"])


def _q(kind: str, rng: np.random.Generator):
    q = Q0 + rng.normal(0, 0.05, 7)
    if kind == "none":
        return None
    if kind == "nan":
        q[rng.integers(7)] = np.nan
    elif kind == "inf":
        q[rng.integers(7)] = -np.inf
    elif kind == "short":
        q = q[:5]
    return q


def _frame(kind: str, rng: np.random.Generator, shape: tuple[int, int]):
    if kind == "none":
        return None
    d = rng.uniform(0.6, 3.0, shape).astype(np.float32)
    if kind == "nan":
        d[rng.random(shape) < 0.5] = np.nan
    elif kind == "inf":
        d[rng.random(shape) < 0.3] = np.inf
    elif kind == "negative":
        d[rng.random(shape) < 0.3] = -1.0
    elif kind == "small":
        d = d[: shape[0] // 2, : shape[1] // 2].copy()
    elif kind == "wide":
        d = np.zeros((shape[0], shape[1] + 3), np.float32)
    return [d]


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    p = tmp_path_factory.mktemp("cell") / "cell.toml"
    p.write_text(CELL)
    cell = read_cell(p)
    model = load_lwr4()
    cam = kinect_camera((1.6, 0.2, 0.8), (0.0, 0.0, 0.6), width=80, height=60)
    return cell, model, cam


@settings(max_examples=25, deadline=None)
@given(
    st.lists(st.tuples(_q_kind, _frame_kind, _t_kind), min_size=5, max_size=40),
    st.integers(0, 2**31 - 1),
)
def test_run_never_raises_and_commands_stay_within_the_limits(setup, steps, seed):
    cell, model, cam = setup
    rng = np.random.default_rng(seed)
    ticks = []
    t = 0.0
    for qk, fk, tk in steps:
        t += 0.001
        tj = {"ok": t, "back": t - 0.5, "ahead": t + 5.0, "nan": np.nan}[tk]
        q = _q(qk, rng)
        qd = None if q is None else np.zeros(np.shape(q))
        xd = np.array([0.0, 0.0, np.nan]) if tk == "nan" else np.array([0.05, 0.0, 0.0])
        ticks.append(Tick(t, q, qd, tj, xd, _frame(fk, rng, cam.shape), tj, {}))
    src = ListSource(ticks)
    chain = Chain(cell, [cam], model)
    log = RunLog()
    run_chain(cell, src, chain, log=log)  # must not raise
    assert len(src.commands) == len(ticks)
    for q_cmd, qd_cmd in src.commands:
        assert np.all(np.isfinite(q_cmd)) and np.all(np.isfinite(qd_cmd))
        assert np.all(q_cmd >= model.q_min - 1e-9) and np.all(q_cmd <= model.q_max + 1e-9)
        assert np.all(np.abs(qd_cmd) <= model.v_max + 1e-9)
    for status, (qk, _, _) in zip(log.status, steps, strict=True):
        if qk != "ok":
            assert status.startswith("STOP"), status
