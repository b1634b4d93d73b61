"""Avoidance controller (ICRA'12 §V): SNS, body constraints (eqs. 12-14), end-effector repulsion
(eqs. 7, 10-11), jerk-limited on-line trajectory generation (Ruckig) and the 1 kHz control cycle.

:func:`sns_velocity` needs only numpy/numba; the cycle needs the ``robot`` extra (pinocchio, ruckig),
which is imported when a controller is built, not here.
"""

from depthguard.control.body import body_velocity_bounds, risk
from depthguard.control.cycle import (
    AvoidanceController,
    ControllerConfig,
    CycleInput,
    CycleOutput,
    CycleStatus,
    control_cycle,
)
from depthguard.control.sns import sns_velocity

__all__ = [
    "sns_velocity",
    "body_velocity_bounds",
    "risk",
    "AvoidanceController",
    "ControllerConfig",
    "CycleInput",
    "CycleOutput",
    "CycleStatus",
    "control_cycle",
]
