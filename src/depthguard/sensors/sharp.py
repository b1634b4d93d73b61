"""Sharp infrared distance sensors of the youBot experiments (SAPHARI D4.1.1 §5.3).

Six GP2Y0A21YK (rated 10-80 cm) on the mobile base and four GP2D120XJ00F (rated 4-30 cm) on the arm.
Both are triangulation sensors with an analogue output that falls non-linearly with distance beyond a
peak near the minimum range and *also falls* for objects closer than the peak: one voltage can mean two
distances.

**Curves.** The far branches below are the typical output voltage against the distance of a white
reflector (reflectance 90 %), read off the data sheets' "analog output voltage vs distance to reflective
object" figures (Sharp, *GP2Y0A21YK0F Distance Measuring Sensor Unit*, data sheet E4-A00201EN, 2006,
Fig. 2; Sharp, *GP2D120XJ00F Distance Measuring Sensor*, data sheet, 2006, Fig. "Analog output
voltage vs. distance to reflective object"), to about +-0.05 V; the points agree within 0.061 V with the
common fit ``V = 20.99 / d[cm] + 0.19`` of the GP2Y0A21YK over 10-80 cm (the curve, linear between them,
lies up to 0.11 V above that convex fit, near 13 cm) and within 0.15 V with published GP2D120 readings
over 4-32 cm. The data sheet's specified output at 80 cm is 0.25-0.55 V (typ. 0.4 V).
Unit-to-unit spread is about +-10 %.
The near branch (closer than the peak) is not specified by the data sheets: it is modelled as linear from
``v_contact`` at 0 m up to the peak. It is used only to bound the distance from below.

**Ambiguity, handled on the safe side** (:class:`AmbiguityTracker`): the reading starts on the far branch
(check that nothing is within range at start, as the paper does for its initial configuration). When the
voltage may have reached that of the rated minimum range, the object may be closer than the peak: the
tracker switches to the near branch and reports the *smaller* of the two candidate distances until the
voltage is surely below ``v_contact``, the lowest voltage the near branch can produce, which only an object
on the far branch beyond ``d_far(v_contact)`` can give. Limit: an object that crosses, between two updates
(up to 48 ms), from beyond the minimum range to where the near branch's voltage is below that of the
minimum range, is not caught: 7 cm in one update for the GP2Y0A21 (safe up to about 1.4 m/s), 1.5 cm for
the GP2D120 (safe up to about 0.3 m/s; property-tested at the hand's 0.25 m/s).

**Reading tolerance** (``v_tol``): a reading within ``+-v_tol`` of the typical curve gives a distance never
above the true one inside the rated range (each branch is inverted at the end of the voltage interval that
is nearer, and the branch switches use the interval's ends). :class:`IRRanger` sets it to half an ADC step
plus 4 noise standard deviations; a larger noise excursion may over-report by about the excess over the
curve's slope. A reading no distance can give (outside ``[v_floor - v_tol, v_peak + v_tol]``: a negative,
NaN or infinite voltage, a broken or shorted line) and a saturated ADC count mean "obstacle present": 0 m.

**Timing** (:class:`IRRanger`): a new measurement about every 38.3 +- 9.6 ms (data sheet), the output held
in between, sampled by the microcontroller's 10-bit ADC (5 V reference) at about 300 Hz (§5.3).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from depthguard.validation import is_real_scalar

__all__ = ["SharpModel", "GP2Y0A21YK", "GP2D120XJ00F", "AmbiguityTracker", "IRRanger"]


def _real(x: object, name: str, lo: float = -math.inf) -> float:
    """``x`` as a float if it is a real number >= ``lo`` (NaN fails), else a ValueError naming ``name``."""
    if not is_real_scalar(x) or not x >= lo:
        raise ValueError(f"{name} must be a number >= {lo}, got {x!r}")
    return float(x)


@dataclass(frozen=True)
class SharpModel:
    """Voltage-distance curve of one Sharp sensor type.

    Attributes:
        name: the part number.
        d_table: (K,) increasing distances of the far branch, m (first entry = the peak).
        v_table: (K,) typical output voltage there, V (decreasing).
        d_min, d_max: rated measuring range, m.
        v_contact: output at 0 m of the (modelled) near branch, V.
        v_floor: output with nothing in range, V.
    """

    name: str
    d_table: tuple[float, ...]
    v_table: tuple[float, ...]
    d_min: float
    d_max: float
    v_contact: float
    v_floor: float = 0.25

    def __post_init__(self) -> None:
        dt, vt = np.asarray(self.d_table, float), np.asarray(self.v_table, float)
        if dt.ndim != 1 or dt.shape != vt.shape or dt.size < 2 or not np.all(np.isfinite(dt) & np.isfinite(vt)):
            raise ValueError("d_table and v_table must be finite sequences of the same length >= 2")
        if not (dt[0] > 0 and np.all(np.diff(dt) > 0) and np.all(np.diff(vt) < 0)):
            raise ValueError("d_table must be increasing from > 0 m and v_table decreasing")
        if not (dt[0] < self.d_min < self.d_max <= dt[-1]):
            raise ValueError(f"need d_table[0] < d_min < d_max <= d_table[-1], got d_min={self.d_min!r}")
        if not (0 <= self.v_floor < self.v_contact < np.interp(self.d_min, dt, vt)):
            raise ValueError("need 0 <= v_floor < v_contact < the voltage at d_min")

    @property
    def d_peak(self) -> float:
        return self.d_table[0]

    @property
    def v_peak(self) -> float:
        return self.v_table[0]

    def voltage(self, distance: np.ndarray) -> np.ndarray:
        """Typical output, V, for a reflector at ``distance`` (m; inf/NaN = nothing)."""
        d = np.asarray(distance, float)
        dt, vt = np.asarray(self.d_table), np.asarray(self.v_table)
        far = np.interp(d, dt, vt)
        beyond = np.maximum(vt[-1] * dt[-1] / np.where(d > 0, d, 1.0), self.v_floor)  # ~1/d past the table
        v = np.where(d > dt[-1], beyond, far)
        near = self.v_contact + (self.v_peak - self.v_contact) * np.clip(d, 0, None) / self.d_peak
        v = np.where(d < self.d_peak, near, v)
        return np.where(np.isfinite(d) & (d <= 1.5 * self.d_max), v, self.v_floor)

    def distance_far(self, v: np.ndarray) -> np.ndarray:
        """Far-branch distance, m, of output ``v`` (V); inf below the voltage at ``d_max``; 0 for a NaN or
        negative ``v`` (no output: no evidence of free space)."""
        v = np.asarray(v, float)
        dt, vt = np.asarray(self.d_table), np.asarray(self.v_table)
        d = np.interp(-v, -vt, dt)
        d = np.where(v < float(self.voltage(np.array([self.d_max]))[0]), np.inf, d)
        return np.where(v >= 0, d, 0.0)

    def voltage_scalar(self, d: float) -> float:
        """:meth:`voltage` for one distance (fast path for the 300 Hz loop)."""
        if not np.isfinite(d) or d > 1.5 * self.d_max:
            return self.v_floor
        if d < self.d_peak:
            return self.v_contact + (self.v_peak - self.v_contact) * max(d, 0.0) / self.d_peak
        if d > self.d_table[-1]:
            return max(self.v_table[-1] * self.d_table[-1] / d, self.v_floor)
        return float(np.interp(d, self.d_table, self.v_table))

    def distance_near(self, v: np.ndarray) -> np.ndarray:
        """Near-branch distance, m, of output ``v`` (V), clipped to [0, d_peak]; 0 for a NaN ``v``."""
        v = np.asarray(v, float)
        d = np.clip((v - self.v_contact) / (self.v_peak - self.v_contact), 0.0, 1.0) * self.d_peak
        return np.where(np.isnan(v), 0.0, d)


GP2Y0A21YK = SharpModel(
    name="GP2Y0A21YK",
    d_table=(0.06, 0.07, 0.08, 0.10, 0.15, 0.20, 0.25, 0.30, 0.35, 0.40, 0.50, 0.60, 0.70, 0.80),
    v_table=(3.15, 3.00, 2.75, 2.30, 1.65, 1.30, 1.08, 0.92, 0.80, 0.73, 0.60, 0.50, 0.45, 0.40),
    d_min=0.10,
    d_max=0.80,
    v_contact=1.5,
)
GP2D120XJ00F = SharpModel(
    name="GP2D120XJ00F",
    d_table=(0.03, 0.04, 0.05, 0.06, 0.08, 0.10, 0.12, 0.14, 0.16, 0.18, 0.20, 0.25, 0.30),
    v_table=(3.00, 2.75, 2.30, 1.95, 1.53, 1.25, 1.08, 0.93, 0.83, 0.74, 0.67, 0.53, 0.45),
    d_min=0.04,
    d_max=0.30,
    v_contact=1.5,
)


@dataclass
class AmbiguityTracker:
    """Branch tracking of one sensor's output (module docstring). ``near`` is the current branch;
    ``v_tol`` (V, >= 0) the tolerance of a reading about the typical curve (0: the curve exactly)."""

    model: SharpModel
    near: bool = False
    v_tol: float = 0.0

    def __post_init__(self) -> None:
        self.v_tol = _real(self.v_tol, "v_tol", 0.0)
        if not math.isfinite(self.v_tol):
            raise ValueError(f"v_tol must be a finite voltage >= 0 V, got {self.v_tol!r}")
        m = self.model
        self._v_dmin = float(m.voltage(np.array([m.d_min]))[0])
        self._v_dmax = float(m.voltage(np.array([m.d_max]))[0])
        self._v_lo, self._v_hi = m.v_floor - self.v_tol, m.v_peak + self.v_tol
        self._vt = -np.asarray(m.v_table, float)
        self._dt = np.asarray(m.d_table, float)

    def update(self, v: float) -> float:
        """Distance, m, to report for output ``v`` (V, a real number; else ValueError): never more than either
        candidate distance while the object may be closer than the peak; inf when nothing is in range; 0
        for a reading no distance can give (module docstring)."""
        if not is_real_scalar(v):
            raise ValueError(f"v must be a real number of volts, got {v!r}")
        if not self._v_lo <= v <= self._v_hi:  # NaN, +-inf, negative, above the peak: a fault
            self.near = True
            return 0.0
        m = self.model
        hi = v + self.v_tol  # the highest voltage the object may give: the nearest far-branch distance
        if not self.near and hi >= self._v_dmin:
            self.near = True
        elif self.near and hi < m.v_contact:
            self.near = False
        d_far = math.inf if hi < self._v_dmax else float(np.interp(-hi, self._vt, self._dt))
        if self.near:
            d_near = min(max((v - self.v_tol - m.v_contact) / (m.v_peak - m.v_contact), 0.0), 1.0) * m.d_peak
            return min(d_near, d_far)
        return d_far


@dataclass
class IRRanger:
    """One Sharp sensor with its timing: a new measurement every ``period +- jitter`` s, the output held
    in between, sampled by a 10-bit ADC (``vref`` V) whenever :meth:`sample` is called (about 300 Hz).

    Attributes:
        model: the sensor type.  period, jitter: measurement period and its +- spread, s.
        noise_v: output noise standard deviation, V.  rng: random generator (seeded for repeatability).
        v_tol: reading tolerance of the tracker, V (module docstring); None: half an ADC step + 4 ``noise_v``.
    """

    model: SharpModel
    period: float = 38.3e-3
    jitter: float = 9.6e-3
    noise_v: float = 0.01
    vref: float = 5.0
    bits: int = 10
    rng: np.random.Generator = field(default_factory=lambda: np.random.default_rng(0))
    t_next: float = 0.0
    v_tol: float | None = None
    v_out: float = field(default=np.nan, init=False)
    tracker: AmbiguityTracker = field(init=False)

    def __post_init__(self) -> None:
        if not (self.period > 0 and 0 <= self.jitter < self.period and math.isfinite(self.period)):
            raise ValueError(f"period must be > 0 and 0 <= jitter < period, got {self.period!r}, {self.jitter!r}")
        if not math.isfinite(_real(self.noise_v, "noise_v", 0.0)):
            raise ValueError(f"noise_v must be a finite voltage >= 0 V, got {self.noise_v!r}")
        if not (_real(self.vref, "vref", 0.0) > 0 and math.isfinite(self.vref)):
            raise ValueError(f"vref must be a finite voltage > 0 V, got {self.vref!r}")
        if isinstance(self.bits, bool) or not isinstance(self.bits, int | np.integer) or not 1 <= self.bits <= 32:
            raise ValueError(f"bits must be an integer in 1..32, got {self.bits!r}")
        if self.v_tol is None:
            self.v_tol = 0.5 * self.vref / (2**self.bits - 1) + 4.0 * self.noise_v
        self.tracker = AmbiguityTracker(self.model, v_tol=self.v_tol)
        self.v_out = self.model.v_floor

    def due(self, t: float) -> bool:
        """Whether a new measurement completes at time ``t`` (s): then pass the true distance to :meth:`sample`."""
        return t >= self.t_next

    def sample(self, t: float, true_distance: float | None) -> tuple[float, float]:
        """ADC sample at time ``t`` (s, finite; else ValueError): returns (output voltage as read, V; distance to
        report, m; 0 for a saturated ADC count, either end).

        ``true_distance`` (m, inf = nothing) is used only when a new measurement is due."""
        if not math.isfinite(_real(t, "t")):
            raise ValueError(f"t must be a finite time (s), got {t!r}")
        if true_distance is not None and (not is_real_scalar(true_distance)):
            raise ValueError(f"true_distance must be a number of metres or None, got {true_distance!r}")
        if self.due(t) and true_distance is not None:
            v = self.model.voltage_scalar(true_distance) + self.rng.normal(0.0, self.noise_v)
            self.v_out = v
            self.t_next = max(self.t_next, t) + self.period + self.rng.uniform(-self.jitter, self.jitter)
        full = 2**self.bits - 1
        count = min(max(round(self.v_out / self.vref * full), 0), full)
        v_read = count * self.vref / full
        if count in (0, full):  # clipped: the output may be anything beyond the ADC's range
            self.tracker.near = True
            return v_read, 0.0
        return v_read, self.tracker.update(v_read)

    def normalised(self, v: float) -> float:
        """Output normalised by the peak voltage (1 = closest measurable; Figs. 16, 18, 19)."""
        return float(v / self.model.v_peak)
