"""Where a sensor sits on the robot: a link, a position and an optical axis in that link's frame."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["SensorMount", "check_mounts"]


@dataclass(frozen=True)
class SensorMount:
    """A sensor fixed to ``link``.

    Attributes:
        name: sensor name.
        link: name of the link (a frame of the robot model) it is mounted on.
        position: (3,) position in the link frame, m (``dp_k^i`` of SAPHARI eq. 5.13's notation).
        axis: (3,) unit optical axis in the link frame (eq. 5.14): the sensor measures the range ``d_k``
            along it, so ``v_dk`` is this axis expressed in the world frame.
        max_range: farthest range reported, m (beyond: nothing, inf).
        kind: sensor type, e.g. ``"GP2Y0A21YK"``.
    """

    name: str
    link: str
    position: tuple[float, float, float]
    axis: tuple[float, float, float]
    max_range: float
    kind: str = ""

    def __post_init__(self) -> None:
        p = np.asarray(self.position, float)
        a = np.asarray(self.axis, float)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise ValueError(f"sensor '{self.name}': position must be 3 finite numbers (m), got {self.position!r}")
        if a.shape != (3,) or not np.all(np.isfinite(a)) or abs(np.linalg.norm(a) - 1.0) > 1e-3:
            raise ValueError(f"sensor '{self.name}': axis must be a unit 3-vector, got {self.axis!r}")
        if not (np.isfinite(self.max_range) and self.max_range > 0):
            raise ValueError(f"sensor '{self.name}': max_range must be > 0 m, got {self.max_range!r}")


def check_mounts(mounts: object) -> tuple[SensorMount, ...]:
    """Return ``mounts`` as a non-empty tuple of :class:`SensorMount` with unique names, or raise."""
    try:
        ms = tuple(mounts)  # type: ignore[arg-type]
    except TypeError:
        raise ValueError(f"mounts must be a sequence of SensorMount, got {mounts!r}") from None
    if not ms or not all(isinstance(m, SensorMount) for m in ms):
        raise ValueError("mounts must be a non-empty sequence of SensorMount")
    names = [m.name for m in ms]
    if len(set(names)) != len(names):
        raise ValueError(f"sensor names must be unique, got {names}")
    return ms
