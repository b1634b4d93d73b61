"""Optoelectronic taxels of the proximity/contact skin (SAPHARI D4.1.1 §4.1).

Each element is an infrared LED and a photodetector. Two resistors are the whole conditioning circuit:
``r_led`` sets the LED forward current ``I_f = (vcc - v_led) / r_led`` and ``r_pd`` turns the
photocurrent into a voltage, read by the module's 10-bit ADC (PIC16F690, ``vref`` = 5 V).

* **Proximity element** (no cover): the light reflected by an object at distance ``d`` gives a
  photocurrent inversely proportional to the squared distance,
  ``I_pd = eta * I_f * rho / (d + d0)^2`` (``rho`` the surface reflectivity, ``d0`` the LED-PD
  geometry offset that keeps it finite at contact), so ``V = min(r_pd * I_pd + v_dark, v_sat)``. The
  defaults give a range of about 5 cm on human skin (``rho`` = 0.6): 20 counts at 5 cm (the level-1
  threshold of the default level map), saturation at about 3 mm.
* **Contact-force element** (under a deformable silicone layer of thickness ``h``): a force ``F``
  compresses the layer by ``delta`` with a stiffening spring ``F = k * delta / (1 - delta / h)``
  (monotone, ``delta < h`` always), which brings the layer's reflecting inner face closer to the
  LED-PD pair: ``V = r_pd * eta * I_f * rho_in / (h - delta + g0)^2``.

Noise: Gaussian, ``noise_counts`` standard deviation, added before the 10-bit quantisation. All
functions are vectorised over arrays of distances/forces.

Safety: a darker surface reflects less and reads *farther*; :meth:`ProximityTaxel.distance_lower_bound`
inverts the signal with the lowest reflectivity expected, which never over-reports the distance of a
surface at least that bright.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ProximityTaxel", "ContactTaxel", "SKIN_REFLECTIVITY"]

#: Diffuse infrared reflectivity assumed for human skin (nominal).
SKIN_REFLECTIVITY = 0.6


def _adc(v: np.ndarray, vref: float, bits: int, noise_counts: float, rng: np.random.Generator | None) -> np.ndarray:
    full = 2**bits - 1
    c = v / vref * full
    if noise_counts > 0 and rng is not None:
        c = c + rng.normal(0.0, noise_counts, size=np.shape(c))
    return np.clip(np.round(c), 0, full).astype(np.int64)


@dataclass(frozen=True)
class ProximityTaxel:
    """Proximity element: distance (m) -> ADC counts (see the module docstring for the model).

    Attributes:
        vcc, v_led: supply and LED forward voltage, V.  r_led, r_pd: the two resistors, ohm.
        eta: optical coupling, m^2 (photocurrent per LED current at unit reflectivity and 1 m).
        d0: geometry offset, m.  v_dark: dark/ambient output, V.  v_sat: output saturation, V.
        vref, bits: ADC reference (V) and resolution.  noise_counts: noise standard deviation, counts.
        max_range: beyond this distance the element reports nothing (rays are cast this far), m.
    """

    vcc: float = 5.0
    v_led: float = 1.2
    r_led: float = 150.0
    r_pd: float = 10_000.0
    eta: float = 2.02e-6
    d0: float = 0.005
    v_dark: float = 0.01
    v_sat: float = 4.8
    vref: float = 5.0
    bits: int = 10
    noise_counts: float = 1.0
    max_range: float = 0.15

    @property
    def led_current(self) -> float:
        """LED forward current, A."""
        return (self.vcc - self.v_led) / self.r_led

    def voltage(self, distance: np.ndarray, reflectivity: float = SKIN_REFLECTIVITY) -> np.ndarray:
        """Output voltage, V, for objects at ``distance`` (m, >= 0; inf/NaN = nothing in range)."""
        d = np.asarray(distance, float)
        seen = np.isfinite(d) & (d <= self.max_range)
        dd = np.where(seen, np.maximum(d, 0.0), 1.0)
        v = self.r_pd * self.eta * self.led_current * reflectivity / (dd + self.d0) ** 2
        return np.minimum(np.where(seen, v, 0.0) + self.v_dark, self.v_sat)

    def counts(
        self, distance: np.ndarray, reflectivity: float = SKIN_REFLECTIVITY, rng: np.random.Generator | None = None
    ) -> np.ndarray:
        """10-bit ADC counts for objects at ``distance`` (m); noisy when ``rng`` is given."""
        return _adc(self.voltage(distance, reflectivity), self.vref, self.bits, self.noise_counts, rng)

    def counts_at(self, distance: float, reflectivity: float = SKIN_REFLECTIVITY) -> float:
        """Noise-free, unquantised signal (counts) at ``distance``: to place level thresholds."""
        return float(self.voltage(np.array([distance]), reflectivity)[0] / self.vref * (2**self.bits - 1))

    def distance_lower_bound(self, counts: np.ndarray, min_reflectivity: float = 0.3) -> np.ndarray:
        """Distance, m, that the signal ``counts`` implies for the darkest expected surface: a lower bound
        of the true distance of any surface with reflectivity >= ``min_reflectivity``. inf when the
        signal is at the dark level (nothing seen); 0 at saturation (of the output or of the ADC) and for a
        NaN or negative signal (no ADC gives one: a fault). Noise is not bounded: filter first."""
        c = np.asarray(counts, float)
        v = (c + 0.5) / (2**self.bits - 1) * self.vref - self.v_dark  # +0.5: the rounding's worst case
        k = self.r_pd * self.eta * self.led_current * min_reflectivity
        with np.errstate(divide="ignore", invalid="ignore"):
            d = np.sqrt(k / v) - self.d0
        d = np.where(c <= round(self.v_dark / self.vref * (2**self.bits - 1)), np.inf, d)
        sat = np.floor(min(self.v_sat, self.vref) / self.vref * (2**self.bits - 1))  # the ADC clips at vref
        return np.where((c >= sat) | np.isnan(c) | (c < 0), 0.0, np.maximum(d, 0.0))


@dataclass(frozen=True)
class ContactTaxel:
    """Contact-force element under a silicone layer: force (N) -> deformation (m) -> ADC counts.

    Attributes:
        thickness: silicone layer thickness ``h``, m.  stiffness: initial layer stiffness ``k``, N/m.
        g0: distance of the layer's inner face from the LED-PD pair at rest beyond ``h``, m.
        gain: ``r_pd * eta * I_f * rho_in``, V m^2.  vref, bits, noise_counts: as for the proximity element.
        contact_force: force, N, above which the element reports contact.
    """

    thickness: float = 0.003
    stiffness: float = 2000.0
    g0: float = 0.002
    gain: float = 2.0e-5
    vref: float = 5.0
    bits: int = 10
    noise_counts: float = 1.0
    contact_force: float = 0.3

    def deformation(self, force: np.ndarray) -> np.ndarray:
        """Layer compression, m, under ``force`` (N, negative = 0): ``delta = F h / (k h + F)`` < h; its limit
        h for an infinite force, and for NaN (safe side: contact)."""
        f = np.asarray(force, float)
        f = np.where(np.isnan(f), np.inf, np.maximum(f, 0.0))
        with np.errstate(divide="ignore"):  # F = 0: h / inf = 0; F = inf: h / 1 = h; never above h by rounding
            return self.thickness / (self.stiffness * self.thickness / f + 1.0)

    def force(self, deformation: np.ndarray) -> np.ndarray:
        """Force, N, that compresses the layer by ``deformation`` (m, clipped to [0, 0.99 h])."""
        dl = np.clip(np.asarray(deformation, float), 0.0, 0.99 * self.thickness)
        return self.stiffness * dl / (1.0 - dl / self.thickness)

    def voltage(self, force: np.ndarray) -> np.ndarray:
        """Output voltage, V (monotone increasing in force)."""
        gap = self.thickness - self.deformation(force) + self.g0
        return np.minimum(self.gain / gap**2, self.vref)

    def counts(self, force: np.ndarray, rng: np.random.Generator | None = None) -> np.ndarray:
        """10-bit ADC counts under ``force`` (N); noisy when ``rng`` is given."""
        return _adc(self.voltage(force), self.vref, self.bits, self.noise_counts, rng)

    def contact_counts(self) -> float:
        """Signal (counts, unquantised) at ``contact_force``: the contact threshold."""
        return float(self.voltage(np.array([self.contact_force]))[0] / self.vref * (2**self.bits - 1))

    def in_contact(self, counts: np.ndarray) -> np.ndarray:
        """Boolean contact flags of ADC ``counts``."""
        return np.asarray(counts) >= self.contact_counts()
