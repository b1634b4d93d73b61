"""Sharp infrared distance sensors of the youBot experiments (SAPHARI D4.1.1 §5.3).

Six GP2Y0A21YK (rated 10-80 cm) on the mobile base and four GP2D120XJ00F (rated 4-30 cm) on the arm.
Both are triangulation sensors with an analogue output that falls non-linearly with distance beyond a
peak near the minimum range and *also falls* for objects closer than the peak: one voltage can mean two
distances.

**Curves.** The far branches below are the typical output voltage against the distance of a white
reflector (reflectance 90 %), read off the data sheets' "analog output voltage vs distance to reflective
object" figures (Sharp, *GP2Y0A21YK0F Distance Measuring Sensor Unit*, data sheet E4-A00201EN, 2006,
Fig. 2; Sharp, *GP2D120XJ00F Distance Measuring Sensor*, data sheet, 2006, Fig. "Analog output
voltage vs. distance to reflective object"), to about +-0.05 V; they agree within 0.06 V with the
common fit ``V = 20.99 / d[cm] + 0.19`` of the GP2Y0A21YK over 10-80 cm and within 0.15 V with published
GP2D120 readings over 4-32 cm. The data sheet's specified output at 80 cm is 0.25-0.55 V (typ. 0.4 V).
Unit-to-unit spread is about +-10 %.
The near branch (closer than the peak) is not specified by the data sheets: it is modelled as linear from
``v_contact`` at 0 m up to the peak. It is used only to bound the distance from below.

**Ambiguity, handled on the safe side** (:class:`AmbiguityTracker`): the reading starts on the far branch
(check that nothing is within range at start, as the paper does for its initial configuration). When the
voltage reaches that of the rated minimum range, the object may be closer than the peak: the tracker
switches to the near branch and reports the *smaller* of the two candidate distances until the voltage
falls below ``v_contact``, the lowest voltage the near branch can produce, which only an object on the
far branch beyond ``d_far(v_contact)`` can give. Limit: an object that crosses, between two updates
(up to 48 ms), from beyond the minimum range to where the near branch's voltage is below that of the
minimum range, is not caught: 7 cm in one update for the GP2Y0A21 (safe up to about 1.4 m/s), 1.5 cm for
the GP2D120 (safe up to about 0.3 m/s; property-tested at the hand's 0.25 m/s).

**Timing** (:class:`IRRanger`): a new measurement about every 38.3 +- 9.6 ms (data sheet), the output held
in between, sampled by the microcontroller's 10-bit ADC (5 V reference) at about 300 Hz (§5.3).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["SharpModel", "GP2Y0A21YK", "GP2D120XJ00F", "AmbiguityTracker", "IRRanger"]


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
        """Far-branch distance, m, of output ``v`` (V); inf below the voltage at ``d_max``."""
        v = np.asarray(v, float)
        dt, vt = np.asarray(self.d_table), np.asarray(self.v_table)
        d = np.interp(-v, -vt, dt)
        return np.where(v < float(self.voltage(np.array([self.d_max]))[0]), np.inf, d)

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
        """Near-branch distance, m, of output ``v`` (V), clipped to [0, d_peak]."""
        v = np.asarray(v, float)
        return np.clip((v - self.v_contact) / (self.v_peak - self.v_contact), 0.0, 1.0) * self.d_peak


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
    """Branch tracking of one sensor's output (module docstring). ``near`` is the current branch."""

    model: SharpModel
    near: bool = False
    _v_dmin: float | None = field(default=None, init=False, repr=False)

    def update(self, v: float) -> float:
        """Distance, m, to report for output ``v`` (V): never more than either candidate distance while the
        object may be closer than the peak; inf when nothing is in range."""
        m = self.model
        if not np.isfinite(v):
            self.near = True
            return 0.0
        if self._v_dmin is None:
            self._v_dmin = float(m.voltage(np.array([m.d_min]))[0])
            self._v_dmax = float(m.voltage(np.array([m.d_max]))[0])
            self._vt = -np.asarray(m.v_table, float)
            self._dt = np.asarray(m.d_table, float)
        if not self.near and v >= self._v_dmin:
            self.near = True
        elif self.near and v < m.v_contact:
            self.near = False
        d_far = np.inf if v < self._v_dmax else float(np.interp(-v, self._vt, self._dt))
        if self.near:
            d_near = min(max((v - m.v_contact) / (m.v_peak - m.v_contact), 0.0), 1.0) * m.d_peak
            return min(d_near, d_far)
        return d_far


@dataclass
class IRRanger:
    """One Sharp sensor with its timing: a new measurement every ``period +- jitter`` s, the output held
    in between, sampled by a 10-bit ADC (``vref`` V) whenever :meth:`sample` is called (about 300 Hz).

    Attributes:
        model: the sensor type.  period, jitter: measurement period and its +- spread, s.
        noise_v: output noise standard deviation, V.  rng: random generator (seeded for repeatability).
    """

    model: SharpModel
    period: float = 38.3e-3
    jitter: float = 9.6e-3
    noise_v: float = 0.01
    vref: float = 5.0
    bits: int = 10
    rng: np.random.Generator = field(default_factory=lambda: np.random.default_rng(0))
    t_next: float = 0.0
    v_out: float = field(default=np.nan, init=False)
    tracker: AmbiguityTracker = field(init=False)

    def __post_init__(self) -> None:
        if not (self.period > 0 and 0 <= self.jitter < self.period):
            raise ValueError(f"period must be > 0 and 0 <= jitter < period, got {self.period!r}, {self.jitter!r}")
        self.tracker = AmbiguityTracker(self.model)
        self.v_out = self.model.v_floor

    def due(self, t: float) -> bool:
        """Whether a new measurement completes at time ``t`` (s): then pass the true distance to :meth:`sample`."""
        return t >= self.t_next

    def sample(self, t: float, true_distance: float | None) -> tuple[float, float]:
        """ADC sample at time ``t``: returns (output voltage as read, V; distance to report, m).

        ``true_distance`` (m, inf = nothing) is used only when a new measurement is due."""
        if self.due(t) and true_distance is not None:
            v = self.model.voltage_scalar(true_distance) + self.rng.normal(0.0, self.noise_v)
            self.v_out = v
            self.t_next = max(self.t_next, t) + self.period + self.rng.uniform(-self.jitter, self.jitter)
        full = 2**self.bits - 1
        v_read = min(max(round(self.v_out / self.vref * full), 0), full) * self.vref / full
        return v_read, self.tracker.update(v_read)

    def normalised(self, v: float) -> float:
        """Output normalised by the peak voltage (1 = closest measurable; Figs. 16, 18, 19)."""
        return float(v / self.model.v_peak)
