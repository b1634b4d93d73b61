"""Layout of the proximity/contact skin on a cylindrical link (SAPHARI D4.1.1 §4.1, Fig. 8).

The skin is ``n_modules`` modules of ``per_module`` optoelectronic elements (7 x 7 = 49 in the paper), each
module a strip along the link's axis at its own angle around the link, read by its own microcontroller.
Elements alternate proximity (``"P"``) and contact-force (``"C"``, under silicone) as set by ``pattern``,
so the skin gives mixed sensing points as in §4.1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from depthguard.sensors.mount import SensorMount

__all__ = ["SkinLayout"]


@dataclass(frozen=True)
class SkinLayout:
    """A cylindrical skin around the ``z`` axis of ``link``'s frame.

    Attributes:
        link: link (frame) name.  radius: skin surface radius, m.
        z0, pitch: axial position of the first element and element spacing, m.
        n_modules, per_module: modules and elements per module.
        pattern: element kinds along a module, ``"P"`` proximity / ``"C"`` contact (length ``per_module``).
        max_range: ray length of the proximity elements, m.
        angle0: angle of module 0 around the axis, rad.
    """

    link: str
    radius: float = 0.055
    z0: float = 0.09
    pitch: float = 0.035
    n_modules: int = 7
    per_module: int = 7
    pattern: str = "PCPCPCP"
    max_range: float = 0.15
    angle0: float = 0.0

    def __post_init__(self) -> None:
        if len(self.pattern) != self.per_module or set(self.pattern) - {"P", "C"}:
            raise ValueError(f"pattern must be {self.per_module} letters P/C, got {self.pattern!r}")
        if not (self.radius > 0 and self.pitch > 0 and self.n_modules > 0):
            raise ValueError("radius, pitch and n_modules must be positive")

    @property
    def n_elements(self) -> int:
        return self.n_modules * self.per_module

    def angles(self) -> np.ndarray:
        """(n_modules,) angle of each module around the axis, rad."""
        return self.angle0 + 2 * np.pi * np.arange(self.n_modules) / self.n_modules

    def kinds(self) -> np.ndarray:
        """(n_elements,) element kinds, module by module."""
        return np.array(list(self.pattern) * self.n_modules)

    def mounts(self) -> tuple[SensorMount, ...]:
        """One :class:`SensorMount` per element (module-major): on the surface, axis = outward normal."""
        out = []
        for m, phi in enumerate(self.angles()):
            n = (float(np.cos(phi)), float(np.sin(phi)), 0.0)
            for e in range(self.per_module):
                pos = (self.radius * n[0], self.radius * n[1], self.z0 + e * self.pitch)
                kind = "proximity" if self.pattern[e] == "P" else "contact"
                out.append(SensorMount(f"m{m}e{e}", self.link, pos, n, self.max_range, kind))
        return tuple(out)
