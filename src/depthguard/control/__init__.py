"""Avoidance controller: SNS, body constraints (ICRA'12 eqs. 12-14), end-effector repulsion (eqs. 10-11),
jerk-limited on-line trajectory generation (Ruckig) and the 1 kHz control cycle."""

from depthguard.control.sns import sns_velocity

__all__ = ["sns_velocity"]
