"""Scenario ``ssm-approach``: a person walks straight at the working robot; speed and separation monitoring.

``depthguard scenario ssm-approach [--quick] [--no-avoidance] [--out DIR] --json``

The end effector sweeps back and forth along y (0.4 m/s) in front of one Kinect (the ICRA'12 placement).
A person walks in from +y at 1.6 m/s (ISO 13855 walking speed), the right arm held out in front, towards a
spot where the hand lies inside the sweep, stands there, and leaves at ``LEAVE_AT`` s. The person never
walks into the robot: they halt as soon as their true clearance to the robot falls below
``HALT_CLEARANCE`` (0.15 m, read from the simulator after every step, :class:`HaltingPerson`), so that
only motion of the robot can cause contact.

* With SSM (the default; the controller in ``avoidance="ssm"`` mode, no repulsion, body bounds on):
  the monitor slows and then stops the robot before the true separation falls below ``C + Z_d + Z_r``;
  it stays stopped while the person stands within ``S_p`` and resumes after the person has left.
* With ``--no-avoidance`` the robot keeps sweeping into the halted person: the scenario collides.

The metrics are those of :func:`depthguard.sim.scenario_metrics.compute_metrics` and
:func:`depthguard.sim.ssm_metrics.ssm_metrics` (``min_separation_margin``, ``time_reduced_s``,
``time_stopped_s``, ``resumed``, the SSM parameters with their sources).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from depthguard.sim.people import Keyframe, PersonScript

__all__ = ["SCENARIO", "HaltingPerson", "run"]

WALK_SPEED = 1.6  # m/s, ISO 13855
HALT_CLEARANCE = 0.15  # m: the person halts when closer than this to the robot
LEAVE_AT = 3.8  # s
_START_Y, _STOP_Y = 2.55, 0.95  # person base y: start, arm's reach from the sweep
_HAND = (0.45, -0.53, 0.45)  # right hand relative to the base (x, y offset; z world), arm held out forward

SCENARIO: dict[str, Any] = {
    "name": "ssm-approach",
    "description": "A person walks straight at the sweeping robot at 1.6 m/s and stops at arm's reach; "
    "speed and separation monitoring (ISO/TS 15066) stops the robot and resumes after the person leaves",
    "cameras": "icra",
    "resolution": [640, 480],
    "quick_resolution": [160, 120],
    "duration": 7.0,
    "quick_duration": 7.0,
    "q0": [0.0, -0.3, 0.0, 1.6, 0.0, -0.8, 0.0],
    "ee_start": [0.45, -0.30, 0.45],
    "control_points": "ral-9",
    "mode": "hybrid",
    "avoidance": {"rho": 0.6, "rho_body": 0.3, "vmax": 1.0, "alpha": 6.0, "mode": "ssm"},
    "task": {
        "kind": "cycle",
        "speed": 0.4,
        "tol": 0.03,
        "kp": 8.0,
        "waypoints": [[0.45, 0.40, 0.45], [0.45, -0.30, 0.45]],
    },
}


def _approach_keyframes(t0: float) -> list[Keyframe]:
    """Walk from ``_START_Y`` to ``_STOP_Y`` at ``WALK_SPEED`` from ``t0``, facing -y, hand held out."""
    t1 = t0 + (_START_Y - _STOP_Y) / WALK_SPEED

    def kf(t: float, y: float) -> Keyframe:
        return Keyframe(t, (0.6, y), -90.0, right_hand=(_HAND[0], y + _HAND[1], _HAND[2]))

    return [kf(0.0, _START_Y), kf(t0, _START_Y), kf(t1, _STOP_Y)]


class HaltingPerson(PersonScript):
    """A keyframed person who halts where they are once their true clearance to the robot falls below
    ``halt_clearance`` m, and walks back out at ``leave_at`` s (hand lowered over 0.4 s, then at
    ``speed`` m/s to the first keyframe's spot).

    ``clearance`` (a callable returning the current true clearance, m) is connected once the cell
    exists (:func:`_connect`); it is read only while the person approaches, once per new time step.
    """

    def __init__(self, name: str, keyframes: list[Keyframe], floor_z: float, halt_clearance: float,
                 leave_at: float, speed: float = WALK_SPEED) -> None:  # fmt: skip
        self.approach = PersonScript(name, keyframes, floor_z)
        self.halt_clearance, self.leave_at, self.speed = halt_clearance, leave_at, speed
        self.clearance = None
        self.halted_at: float | None = None
        self._t_last = -np.inf
        self._leave: PersonScript | None = None
        back = (keyframes[-1].base[1] - keyframes[0].base[1]) ** 2 + (keyframes[-1].base[0] - keyframes[0].base[0]) ** 2
        end = Keyframe(leave_at + 0.4 + float(np.sqrt(back)) / speed, keyframes[0].base, keyframes[0].yaw)
        super().__init__(name, [*keyframes, end], floor_z)

    def _check(self, t: float) -> None:
        if t <= self._t_last:
            return
        self._t_last = t
        if self.halted_at is None and t < self.leave_at and self.clearance is not None:
            if self.clearance() < self.halt_clearance:
                self.halted_at = t

    def _leave_script(self) -> PersonScript:
        if self._leave is None:
            ts = min(self.halted_at if self.halted_at is not None else self.leave_at, self.leave_at)
            base, yaw, lh, rh, _, _ = self.approach.state(ts)
            b = (float(base[0]), float(base[1]))
            yd = float(np.degrees(yaw))
            home = self.approach.keyframes[0]
            dist = float(np.hypot(home.base[0] - b[0], home.base[1] - b[1]))
            hand = None if rh is None else tuple(rh)
            self._leave = PersonScript(self.name, [
                Keyframe(self.leave_at, b, yd, right_hand=hand),
                Keyframe(self.leave_at + 0.4, b, yd),
                Keyframe(self.leave_at + 0.4 + dist / self.speed, home.base, home.yaw),
            ], self.floor_z)  # fmt: skip
        return self._leave

    def state(self, t: float):
        """As :meth:`PersonScript.state`, with the halt and the way out (class docstring)."""
        self._check(t)
        if t >= self.leave_at:
            return self._leave_script().state(t)
        if self.halted_at is not None:
            return self.approach.state(self.halted_at)
        return self.approach.state(t)


def _connect(cell) -> None:
    """Put the halting person into the cell and give it its true clearance (metrics-side ground truth)."""
    from depthguard.sim.truth import TrueClearance

    truth = TrueClearance(cell, distmax=1.0)

    def clearance() -> float:
        truth.evaluate()
        return truth.last_dynamic

    for i, p in enumerate(cell.spec.people):
        hp = HaltingPerson(p.name, p.keyframes, p.floor_z, HALT_CLEARANCE, LEAVE_AT)
        hp.clearance = clearance
        cell.spec.people[i] = hp


def run(name: str = "ssm-approach", quick: bool = False, avoidance: bool = True, out_dir=None,
        progress: bool = False, options: dict | None = None) -> dict[str, Any]:  # fmt: skip
    """Run the scenario (module docstring); returns the JSON-ready metrics (``cli.EXTRA_SCENARIOS`` entry).

    ``options`` may hold ``duration`` (s, shortens the run; used by the tests), besides the CLI's keys.
    """
    from depthguard.sim.scenario_metrics import compute_metrics
    from depthguard.sim.scenarios import _run_one
    from depthguard.sim.ssm_metrics import plot_ssm, ssm_metrics, ssm_parameters

    sc = dict(SCENARIO, people=[])
    if (options or {}).get("duration"):
        sc["duration"] = sc["quick_duration"] = float(options["duration"])
    person = {"name": "dave", "keyframes": []}
    sc["people"] = [person]
    t_walk = 0.25  # s: the hand reaches the sweep while the end effector is on its way towards it
    person["keyframes"] = [
        {"t": k.t, "base": list(k.base), "yaw": k.yaw, "right_hand": list(k.right_hand)}
        for k in _approach_keyframes(t_walk)
    ]
    t0 = time.perf_counter()
    cell, log, task, cfg = _run_one(
        sc, quick=quick, avoidance=avoidance, cameras=None, progress=progress,
        label=f"{name} ({'ssm' if avoidance else 'no avoid'})", ssm=True, setup=_connect,
        view=(options or {}).get("view"),
    )  # fmt: skip
    person_script = cell.spec.people[0]
    res: dict[str, Any] = {
        "scenario": name,
        "description": SCENARIO["description"],
        "quick": quick,
        "avoidance": avoidance,
        "avoidance_mode": "ssm" if avoidance else "off",
        "cameras": len(cell.cameras),
        "resolution": [cell.cameras[0].width, cell.cameras[0].height],
        "control_points": list(log.point_names),
        "person_walk_speed": WALK_SPEED,
        "person_halt_clearance": HALT_CLEARANCE,
        "person_halted_at_s": person_script.halted_at,
        "person_leaves_at_s": LEAVE_AT,
    }
    res.update(compute_metrics(log, task, cfg))
    if log.ssm is not None:
        res.update(ssm_metrics(log.ssm, cfg.control_dt, log.point_names))
    else:
        res.update({"ssm": False, "min_separation_margin": None, "time_reduced_s": 0.0, "time_stopped_s": 0.0,
                    "resumed": False, "ssm_parameters": ssm_parameters()})  # fmt: skip
    res["wall_seconds_total"] = round(time.perf_counter() - t0, 2)
    if out_dir is not None:
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        res["out_dir"] = str(out)
        if log.ssm is not None:
            res["files"] = {"ssm": plot_ssm(out, log.ssm, log.point_names, res.get("binding_point"), name)}
        (out / "metrics.json").write_text(json.dumps(res, indent=2, default=float))
    return res
