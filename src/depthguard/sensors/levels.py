"""Safety levels of the proximity/contact skin (SAPHARI D4.1.1 §4.3, Table 1).

* :class:`LevelMap`: the host's mapping from the proximity signal (ADC counts of the proximity
  elements, rising as an object comes closer) and the contact flag to a *target* level: levels 0-6 from
  seven signal ranges, level 7 on contact. Going down a level needs the signal to fall ``hysteresis``
  counts below the threshold that raised it, and level 7 (stop) is left only when there is no contact and
  the signal is back below the *resume* threshold (the minimum safety distance), so the level does not
  chatter on a noisy signal.
* :class:`LevelStepper`: what the host writes on the lines. Gray code protects only transitions between
  adjacent levels, so the host moves one level per update towards the target and holds each level for at
  least ``hold_time = line skew + robot sampling period``: the robot then always samples every
  intermediate level once, from settled lines. The price is an extra stopping delay: a jump of ``n``
  levels reaches the last level ``(n - 1) * hold_time`` later than a direct jump would; from level 0 to
  level 7 that is ``6 * hold_time`` (38.4 ms with the defaults of :mod:`~depthguard.sensors.graycode`:
  skew 4.4 ms + sampling 2 ms = hold 6.4 ms). See :func:`extra_stop_delay`.
* :data:`TABLE1_SPEEDS`: Table 1's TCP speeds, m/s, the default level -> speed table.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from depthguard.validation import is_real_scalar

__all__ = ["TABLE1_SPEEDS", "LevelMap", "LevelStepper", "hold_time", "extra_stop_delay", "speed_for_level"]

#: Table 1: TCP linear speed per safety level 0-7, m/s (400, 320, 260, 200, 140, 80, 10, 0 mm/s).
TABLE1_SPEEDS: tuple[float, ...] = (0.400, 0.320, 0.260, 0.200, 0.140, 0.080, 0.010, 0.0)


def hold_time(line_skew: float, sample_period: float) -> float:
    """Minimum time, s, the host holds a level: the line skew plus one robot sampling period."""
    if not (np.isfinite(line_skew) and line_skew >= 0):
        raise ValueError(f"line_skew must be a finite time >= 0 s, got {line_skew!r}")
    if not (np.isfinite(sample_period) and sample_period > 0):
        raise ValueError(f"sample_period must be a finite time > 0 s, got {sample_period!r}")
    return float(line_skew + sample_period)


def _level(level: object, name: str = "level") -> int:
    """``level`` as an int if it is an integer 0-7 (not a bool, float or string), else a ValueError."""
    if isinstance(level, bool | np.bool_) or not isinstance(level, int | np.integer) or not 0 <= level <= 7:
        raise ValueError(f"{name} must be an integer in 0..7, got {level!r}")
    return int(level)


def extra_stop_delay(line_skew: float, sample_period: float, from_level: int = 0, to_level: int = 7) -> float:
    """Extra delay, s, of stepping one level at a time instead of jumping: ``(|to - from| - 1) * hold``."""
    n = abs(_level(to_level, "to_level") - _level(from_level, "from_level"))
    return max(n - 1, 0) * hold_time(line_skew, sample_period)


def speed_for_level(level: int, speeds: tuple[float, ...] = TABLE1_SPEEDS) -> float:
    """TCP speed, m/s, of ``level`` (an integer 0-7) from ``speeds`` (8 finite values >= 0, m/s)."""
    sp = np.asarray(speeds, float)
    if sp.shape != (8,) or not np.all(np.isfinite(sp) & (sp >= 0)):
        raise ValueError(f"speeds must be 8 finite speeds >= 0 m/s (levels 0-7), got {speeds!r}")
    return float(sp[_level(level)])


@dataclass
class LevelMap:
    """Proximity signal + contact -> target safety level, with hysteresis (§4.3).

    Attributes:
        thresholds: (6,) increasing signal values, counts: level ``l`` (1-6) is reached when the signal
            is >= ``thresholds[l - 1]``; below ``thresholds[0]`` the level is 0. Six thresholds make the
            seven ranges of levels 0-6.
        hysteresis: counts the signal must fall below a threshold before the level drops under it.
        resume_threshold: after a contact (level 7), motion resumes only when there is no contact and the
            signal is below ``resume_threshold - hysteresis`` (the minimum safety distance); default
            ``thresholds[0]``.
    """

    thresholds: tuple[float, ...]
    hysteresis: float = 8.0
    resume_threshold: float | None = None
    level: int = field(default=0, init=False)

    def __post_init__(self) -> None:
        th = np.asarray(self.thresholds, float)
        if th.shape != (6,) or not np.all(np.isfinite(th)) or np.any(np.diff(th) <= 0):
            raise ValueError(f"thresholds must be 6 finite, strictly increasing signal values, got {self.thresholds!r}")
        if not (np.isfinite(self.hysteresis) and self.hysteresis >= 0):
            raise ValueError(f"hysteresis must be >= 0 counts, got {self.hysteresis!r}")
        if self.resume_threshold is None:
            self.resume_threshold = float(th[0])
        self._th = th

    def raw_level(self, signal: float) -> int:
        """Level 0-6 of ``signal`` without hysteresis; NaN (no reading) counts as level 6 (safe side)."""
        if not np.isfinite(signal):
            return 6
        return int(np.searchsorted(self._th, signal, side="right"))

    def update(self, signal: float, contact: bool) -> int:
        """Advance the map with one sample (``signal`` a real number, NaN = no reading; else ValueError);
        returns the target level 0-7."""
        if not is_real_scalar(signal):
            raise ValueError(f"signal must be a real number of counts (NaN: no reading), got {signal!r}")
        if contact:
            self.level = 7
            return 7
        raw = self.raw_level(signal)
        if self.level == 7:
            if np.isfinite(signal) and signal < self.resume_threshold - self.hysteresis:
                self.level = raw
            return self.level
        if raw >= self.level:
            self.level = raw
        else:  # going down: each threshold must be undercut by the hysteresis (never up on a falling signal,
            # where the thresholds are closer together than the hysteresis)
            self.level = min(self.level, self.raw_level(signal + self.hysteresis))
        return self.level

    def reset(self) -> None:
        """Back to level 0."""
        self.level = 0


@dataclass
class LevelStepper:
    """The host's writer: one level per update towards the target, each held >= ``hold`` s (§4.3).

    Attributes:
        hold: minimum time between two writes, s (see :func:`hold_time`).
        level: the level on the lines now.
        t_last: time of the last write, s.
    """

    hold: float
    level: int = 0
    t_last: float = -np.inf

    def __post_init__(self) -> None:
        if not (np.isfinite(self.hold) and self.hold >= 0):
            raise ValueError(f"hold must be a finite time >= 0 s, got {self.hold!r}")

    def update(self, t: float, target: int) -> tuple[int, bool]:
        """Step towards ``target`` (0-7) at time ``t`` (s, finite, non-decreasing). Returns (level on the lines,
        written now)."""
        if isinstance(target, bool) or not isinstance(target, int | np.integer) or not 0 <= target <= 7:
            raise ValueError(f"target must be an integer in 0..7, got {target!r}")
        if not (math.isfinite(t) and t >= self.t_last):
            raise ValueError(f"time t must be finite and >= the last write ({self.t_last} s), got {t!r}")
        if int(target) == self.level or t - self.t_last < self.hold - 1e-12:
            return self.level, False
        self.level += 1 if target > self.level else -1
        self.t_last = t
        return self.level, True
