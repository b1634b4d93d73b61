"""Where a run's data comes from: the simulated cell, a ROS 2 bag, a live RealSense.

Every source yields :class:`Tick` objects in time order, one per control cycle of the robot (for a bag: one
per recorded joint state): the joint state, the desired end-effector velocity of the task, and the depth
frames that arrived since the previous tick. :meth:`command` hands the cycle's joint command back (the
simulated cell moves the arm with it; recorded sources ignore it).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import NamedTuple, Protocol

import numpy as np

from depthguard.camera import Camera

__all__ = ["Tick", "Source", "SimSource"]


class Tick(NamedTuple):
    """One control tick.

    Attributes:
        t: time, s (the source's clock).
        q, qdot: (n,) joint positions (rad) and velocities (rad/s) in the model's joint order; None = missing.
        t_joints: time stamp of ``q``, s.
        xdot_d: (3,) desired end-effector velocity, m/s.
        frames: one depth image (H, W) float32 m (NaN = no reading) per camera when a new frame set
            arrived at this tick, else None.
        t_frames: time stamp of ``frames``, s (of a set from several cameras: the oldest frame's in a bag).
        faults: camera faults detected by the source (e.g. ``{"camera0": "disconnected"}``), empty if none.
        q_frames: (n,) joint positions to self-filter ``frames`` with (and to place a carried camera), the joint
            state nearest to their stamps (a bag); None: ``q``.
    """

    t: float
    q: np.ndarray | None
    qdot: np.ndarray | None
    t_joints: float
    xdot_d: np.ndarray
    frames: list[np.ndarray] | None
    t_frames: float
    faults: dict
    q_frames: np.ndarray | None = None


class Source(Protocol):
    cameras: list[Camera]
    joint_names: tuple[str, ...]
    duration: float

    def ticks(self) -> Iterator[Tick]: ...

    def command(self, q_cmd: np.ndarray, qdot_cmd: np.ndarray) -> None: ...

    def close(self) -> None: ...


class SimSource:
    """The simulated cell of a scenario as a source (closed loop: the arm follows the commands).

    Args:
        scenario: a shipped scenario name or a scenario .toml path.
        quick: the scenario's CI form (low resolution, short).
        control_dt: control period, s (the cell file's controller rate).
        frame_period: camera period, s.
        cameras: how many of the scenario's cameras (None: the scenario's default; ``"ral"`` scenarios take a
            third one for 3, :func:`depthguard.sim.scenario_setup.build_scenario_cell`).
        people: False: the scenario's cell without its people (its ``remove_people`` variant: the empty cell
            of ``depthguard commission``).
        ssm: the cell runs speed and separation monitoring: the scenario's ``ssm_cameras`` placement where it
            has one (as ``depthguard scenario --ssm``).
    """

    def __init__(
        self,
        scenario: str,
        *,
        quick: bool = False,
        control_dt: float = 0.001,
        frame_period: float = 1.0 / 30.0,
        seed: int = 0,
        cameras: int | None = None,
        people: bool = True,
        ssm: bool = False,
    ) -> None:
        from depthguard.sim.depthcam import KinectSim
        from depthguard.sim.scenario_setup import build_scenario_cell, scenario_task, with_ssm_cameras
        from depthguard.sim.scenarios import load_scenario

        self.sc = load_scenario(scenario)
        if not people:
            self.sc["people"] = []
        self.sc = with_ssm_cameras(self.sc, ssm)
        self.cell, self.kin, ee0 = build_scenario_cell(self.sc, quick=quick, cameras=cameras)
        self.task = scenario_task(self.sc, ee0)
        self.cams = [KinectSim(self.cell.model, c, i, seed=seed + i) for i, c in enumerate(self.cell.cameras)]
        self.cameras = list(self.cell.cameras)
        self.joint_names = tuple(self.cell.joint_names)
        dur = self.sc.get("quick_duration", self.sc.get("duration", 10.0)) if quick else self.sc.get("duration", 10.0)
        self.duration = float(dur)
        self.control_dt = float(control_dt)
        self.frame_period = float(frame_period)
        self._cmd: tuple[np.ndarray, np.ndarray] | None = None

    def ticks(self) -> Iterator[Tick]:
        n_steps = int(round(self.duration / self.control_dt))
        next_frame = 0.0
        for k in range(n_steps):
            t = k * self.control_dt
            self.cell.update_people(t)
            q = self.cell.q()
            frames = None
            if t >= next_frame - 1e-9:
                next_frame += self.frame_period
                self.cell.forward()
                frames = [c.capture(self.cell.data) for c in self.cams]
            xdot = self.task.velocity(self.kin.evaluate(q).centres[0])
            self._cmd = None
            yield Tick(t, q, self.cell.qd(), t, xdot, frames, t, {})
            if self._cmd is None:  # nobody commanded: hold still
                self.cell.step(q, np.zeros_like(q))
            else:
                self.cell.step(*self._cmd)

    def command(self, q_cmd: np.ndarray, qdot_cmd: np.ndarray) -> None:
        self._cmd = (np.asarray(q_cmd, float), np.asarray(qdot_cmd, float))

    def close(self) -> None:
        for c in self.cams:
            c.close()
