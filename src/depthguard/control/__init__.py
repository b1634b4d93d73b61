"""Avoidance controller (ICRA'12 §V): SNS, body constraints (eqs. 12-14), end-effector repulsion
(eqs. 7, 10-11), jerk-limited on-line trajectory generation (Ruckig) and the 1 kHz control cycle.

The cycle needs the ``robot`` extra (pinocchio, ruckig); :func:`sns_velocity` needs only numpy/numba.
"""

from depthguard.control.body import body_velocity_bounds, risk
from depthguard.control.sns import sns_velocity

__all__ = ["sns_velocity", "body_velocity_bounds", "risk"]
