"""Robot-mounted sensors (SAPHARI D4.1.1 §4-§5): optoelectronic proximity and contact taxels, Sharp IR
rangers with their data-sheet curves and timing, sensor mounts, the Gray-coded safety levels of the
proximity/contact skin, and the spring pseudo-energy of the protective buffer. Pure numpy; no simulator.
"""

from depthguard.sensors.buffer import energy_gradient, spring_energy, total_energy
from depthguard.sensors.graycode import (
    SkewedLines,
    binary_decode,
    binary_encode,
    count_glitches,
    gray_decode,
    gray_encode,
    simulate_lines,
)
from depthguard.sensors.levels import TABLE1_SPEEDS, LevelMap, LevelStepper, extra_stop_delay, hold_time
from depthguard.sensors.mount import SensorMount
from depthguard.sensors.sharp import GP2D120XJ00F, GP2Y0A21YK, AmbiguityTracker, IRRanger, SharpModel
from depthguard.sensors.taxel import ContactTaxel, ProximityTaxel

__all__ = [
    "energy_gradient",
    "spring_energy",
    "total_energy",
    "binary_decode",
    "binary_encode",
    "count_glitches",
    "gray_decode",
    "gray_encode",
    "simulate_lines",
    "SkewedLines",
    "TABLE1_SPEEDS",
    "LevelMap",
    "LevelStepper",
    "extra_stop_delay",
    "hold_time",
    "SensorMount",
    "GP2D120XJ00F",
    "GP2Y0A21YK",
    "AmbiguityTracker",
    "IRRanger",
    "SharpModel",
    "ContactTaxel",
    "ProximityTaxel",
]
