"""Gray and natural-binary coding of the eight safety levels on three digital lines, with line skew
(SAPHARI D4.1.1 §4.3, Table 1).

The host sends a safety level 0-7 to the robot controller over three digital lines. The lines do not
switch at the same instant (different driver, level-converter and input-filter delays: the *skew*), and
the robot controller samples them at its own period. When several lines change for one level change, a
sample taken between the first and the last line switching reads a code that is neither the old nor the
new level: a **glitch**. In Gray code adjacent levels differ by exactly one line, so a host that only
ever steps to an adjacent level, and holds each level for at least ``skew + sampling period``, can never
produce a glitch. Natural binary has multi-line transitions (1->2, 3->4, 5->6 and back) and glitches
whenever a sample falls inside their skew window.

Bit ``i`` of a code is line ``i``. Table 1 writes the Gray code with line 2 first: level 3 = ``010``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from depthguard.validation import is_real_scalar

__all__ = [
    "N_LEVELS",
    "gray_encode",
    "gray_decode",
    "binary_encode",
    "binary_decode",
    "LineTrace",
    "simulate_lines",
    "count_glitches",
    "multibit_windows_sampled",
    "SkewedLines",
]

N_LEVELS = 8
_GRAY = np.array([0b000, 0b001, 0b011, 0b010, 0b110, 0b111, 0b101, 0b100], dtype=np.int64)
_GRAY_INV = np.argsort(_GRAY)


def _check_level(level: object, name: str = "level") -> np.ndarray:
    try:
        arr = np.asarray(level)
    except (ValueError, TypeError):  # a ragged nested sequence
        arr = np.asarray(None)
    if arr.dtype.kind not in "iu" or np.any(arr < 0) or np.any(arr >= N_LEVELS):
        raise ValueError(f"{name} must be integer(s) in 0..{N_LEVELS - 1}, got {level!r}")
    return arr.astype(np.int64)


def gray_encode(level: object) -> np.ndarray:
    """Gray code (int, bit i = line i) of ``level`` (int or int array, 0-7): Table 1."""
    return _GRAY[_check_level(level)]


def gray_decode(code: object) -> np.ndarray:
    """Level 0-7 of a 3-bit Gray ``code`` (int or int array)."""
    return _GRAY_INV[_check_level(code, "code")]


def binary_encode(level: object) -> np.ndarray:
    """Natural binary code of ``level`` (the identity on 0-7, validated)."""
    return _check_level(level).copy()


def binary_decode(code: object) -> np.ndarray:
    """Level of a natural-binary ``code`` (the identity on 0-7, validated)."""
    return _check_level(code, "code").copy()


class LineTrace(NamedTuple):
    """What the robot controller read.

    Attributes:
        t_sample: (S,) sampling instants, s.
        decoded: (S,) level decoded from the three sampled lines.
        sent: (S,) the last level the host had sent at each sample (before skew).
        previous: (S,) the level sent before that one.
    """

    t_sample: np.ndarray
    decoded: np.ndarray
    sent: np.ndarray
    previous: np.ndarray


def simulate_lines(
    t_change: np.ndarray,
    levels: np.ndarray,
    t_end: float,
    line_delays: tuple[float, float, float] = (0.0, 2.2e-3, 4.4e-3),
    sample_period: float = 2.0e-3,
    sample_phase: float = 0.0,
    code: str = "gray",
) -> LineTrace:
    """Sample three skewed digital lines that carry the level sequence ``levels``.

    Args:
        t_change: (M,) instants, s, at which the host writes ``levels[m]`` (increasing; ``t_change[0]``
            is the start, the lines hold ``levels[0]`` before it).
        levels: (M,) levels 0-7.
        t_end: last sampling instant, s.
        line_delays: (3,) delay of line 0, 1, 2 from the host's write to the line switching, s. The skew
            is ``max - min``.
        sample_period, sample_phase: the robot samples at ``sample_phase + k * sample_period``, s.
        code: ``"gray"`` or ``"binary"``.

    Returns:
        :class:`LineTrace`. A line switched at exactly a sampling instant is read as switched.
    """
    t_change, lv, delays = _check_sequence(t_change, levels, line_delays)
    _check_times(t_end, sample_period, sample_phase)
    if code not in ("gray", "binary"):
        raise ValueError(f"code must be 'gray' or 'binary', got {code!r}")
    codes = gray_encode(lv) if code == "gray" else binary_encode(lv)
    ts = sample_phase + sample_period * np.arange(int(np.floor((t_end - sample_phase) / sample_period)) + 1)
    ts = ts[ts >= t_change[0]]
    read = np.zeros(ts.size, dtype=np.int64)
    for bit in range(3):
        # the value of line `bit` at ts: that of the last write whose delayed switching is <= ts
        idx = np.searchsorted(t_change + delays[bit], ts, side="right") - 1
        val = (codes[np.maximum(idx, 0)] >> bit) & 1
        read |= val << bit
    decoded = gray_decode(read) if code == "gray" else binary_decode(read)
    i_sent = np.searchsorted(t_change, ts, side="right") - 1
    sent = lv[i_sent]
    previous = lv[np.maximum(i_sent - 1, 0)]
    return LineTrace(ts, decoded, sent, previous)


def _floats(x: object, name: str) -> np.ndarray:
    try:
        arr = np.asarray(x)
    except (ValueError, TypeError):  # a ragged nested sequence
        arr = np.asarray(None)
    if arr.dtype.kind not in "iuf":
        raise ValueError(f"{name} must be real numbers, got {x!r}")
    return arr.astype(float)


def _check_sequence(t_change: object, levels: object, line_delays: object) -> tuple[np.ndarray, ...]:
    """(t_change, levels, delays) validated as documented in :func:`simulate_lines`, else a ValueError."""
    t_change = _floats(t_change, "t_change")
    lv = _check_level(np.asarray(levels), "levels")
    if t_change.ndim != 1 or t_change.shape != lv.shape or t_change.size == 0:
        raise ValueError(
            f"t_change and levels must be 1-D of the same non-zero length, got {t_change.shape}, {lv.shape}"
        )
    if np.any(np.diff(t_change) < 0) or not np.all(np.isfinite(t_change)):
        raise ValueError("t_change must be finite and non-decreasing")
    delays = _floats(line_delays, "line_delays")
    if delays.shape != (3,) or np.any(delays < 0) or not np.all(np.isfinite(delays)):
        raise ValueError(f"line_delays must be 3 finite delays >= 0 s, got {line_delays!r}")
    return t_change, lv, delays


def _check_times(t_end: float, sample_period: float, sample_phase: float) -> None:
    if not (np.isfinite(sample_period) and sample_period > 0):
        raise ValueError(f"sample_period must be > 0 s, got {sample_period!r}")
    if not np.isfinite(t_end):
        raise ValueError(f"t_end must be a finite time (s), got {t_end!r}")
    if not np.isfinite(sample_phase):
        raise ValueError(f"sample_phase must be a finite time (s), got {sample_phase!r}")


def count_glitches(trace: LineTrace) -> int:
    """Samples that decode to a level that is neither the previous nor the current level sent."""
    return int(np.count_nonzero((trace.decoded != trace.sent) & (trace.decoded != trace.previous)))


def multibit_windows_sampled(
    t_change: np.ndarray,
    levels: np.ndarray,
    t_end: float,
    line_delays: tuple[float, float, float] = (0.0, 2.2e-3, 4.4e-3),
    sample_period: float = 2.0e-3,
    sample_phase: float = 0.0,
) -> dict[str, list[int]]:
    """For every multi-line *binary* transition ``"a->b"`` of the sequence: [occurrences, occurrences
    with at least one robot sample inside the skew window, i.e. after the first and before the last of
    its changing lines switched, and at most ``t_end``]."""
    t_change, lv, delays = _check_sequence(t_change, levels, line_delays)
    _check_times(t_end, sample_period, sample_phase)
    out: dict[str, list[int]] = {}
    for m in range(1, lv.size):
        a, b = int(lv[m - 1]), int(lv[m])
        diff = a ^ b
        bits = [i for i in range(3) if diff >> i & 1]
        if len(bits) < 2:
            continue
        d = sorted(delays[bits])
        lo, hi = t_change[m] + d[0], t_change[m] + d[-1]
        k0 = np.ceil((lo - sample_phase) / sample_period)
        t_first = sample_phase + k0 * sample_period  # the first sample at or after lo
        inside = t_first < hi and t_first <= t_end
        rec = out.setdefault(f"{a}->{b}", [0, 0])
        rec[0] += 1
        rec[1] += int(inside)
    return out


def _time(t: object) -> float:
    if not is_real_scalar(t):
        raise ValueError(f"time t must be a number of seconds, got {t!r}")
    return float(t)


class SkewedLines:
    """Online version of :func:`simulate_lines`: the host :meth:`write` s levels, the robot :meth:`read` s.

    Args:
        line_delays: (3,) switching delay of each line after a write, s.
        code: ``"gray"`` or ``"binary"``.
    """

    def __init__(self, line_delays: tuple[float, float, float] = (0.0, 2.2e-3, 4.4e-3), code: str = "gray") -> None:
        if code not in ("gray", "binary"):
            raise ValueError(f"code must be 'gray' or 'binary', got {code!r}")
        self.delays = np.asarray(line_delays, float)
        if self.delays.shape != (3,) or not np.all((self.delays >= 0) & np.isfinite(self.delays)):
            raise ValueError(f"line_delays must be 3 finite delays >= 0 s, got {line_delays!r}")
        self.code = code
        self.t_writes: list[float] = [-np.inf]
        self.levels: list[int] = [0]

    def write(self, t: float, level: int) -> None:
        """The host writes ``level`` (one integer 0-7) at time ``t`` (s, finite, non-decreasing)."""
        if _check_level(np.asarray(level)).ndim != 0:
            raise ValueError(f"level must be one integer in 0..{N_LEVELS - 1}, got {level!r}")
        t = _time(t)
        if not (math.isfinite(t) and t >= self.t_writes[-1]):
            raise ValueError(f"write time t must be finite and >= the last write ({self.t_writes[-1]} s), got {t!r}")
        self.t_writes.append(t)
        self.levels.append(int(level))

    def read(self, t: float) -> int:
        """The level the robot decodes from the three lines sampled at time ``t`` (s, not NaN)."""
        if math.isnan(_time(t)):
            raise ValueError("read time t must be a number of seconds, got nan")
        enc = gray_encode if self.code == "gray" else binary_encode
        code = 0
        for bit in range(3):
            k = len(self.t_writes) - 1
            while self.t_writes[k] + self.delays[bit] > t:
                k -= 1
            code |= ((int(enc(self.levels[k])) >> bit) & 1) << bit
        return int(gray_decode(code) if self.code == "gray" else binary_decode(code))
