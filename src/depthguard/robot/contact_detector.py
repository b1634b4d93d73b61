"""Contact detection on the generalized-momentum residual (SAPHARI D4.1.1 §6.1-6.2; the residual itself:
:mod:`depthguard.robot.residual`): a threshold on ``‖r‖`` (and optionally per joint) with hysteresis, and the
label of each contact at its onset, intentional or collision, from a classifier (:func:`default_classifier`:
a tracked hand near the contact point, else the rise rate of ``‖r‖``). Non-finite residuals count as contact.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from depthguard.validation import is_numeric_nest, positive_number, positive_numbers, real_number

__all__ = ["ContactDetector", "DetectionState", "ContactEvidence", "default_classifier"]

_F64 = np.dtype(np.float64)
_tuple_new = tuple.__new__


class ContactEvidence(NamedTuple):
    """What a classifier sees at a detection onset.

    Attributes:
        r: (n,) residual at onset, N m.
        r_rate: rise rate of ‖r‖ over the last cycle, N m/s.
        hand_distance: distance (m) from the contact point to the nearest tracked hand, or None.
    """

    r: np.ndarray
    r_rate: float
    hand_distance: float | None


def default_classifier(ev: ContactEvidence, rate_threshold: float = 400.0, hand_radius: float = 0.10) -> str:
    """The documented default rule (D4.1.1 leaves it open).

    * A tracked hand within ``hand_radius`` (m) of the contact point -> ``"intentional"`` (people touch the
      robot on purpose with their hands, §6.2);
    * otherwise the rise rate of ‖r‖: faster than ``rate_threshold`` N m/s -> ``"collision"`` (an impact),
      slower -> ``"intentional"`` (a deliberate push builds up its force).
    """
    if ev.hand_distance is not None and ev.hand_distance <= hand_radius:
        return "intentional"
    return "collision" if ev.r_rate > rate_threshold else "intentional"


class DetectionState(NamedTuple):
    """Output of :meth:`ContactDetector.step`: ``active`` (bool), ``onset``/``release`` (this cycle),
    ``label`` (``"intentional"``, ``"collision"`` or ``""`` when not in contact)."""

    active: bool
    onset: bool
    release: bool
    label: str


@dataclass
class ContactDetector:
    """Threshold detection on the residual with hysteresis (module docstring).

    Attributes:
        r_th: threshold on ‖r‖, N m (> 0).
        r_th_joint: optional (n,) per-joint thresholds on |r_i|, N m.
        release_ratio: release when below this fraction of the thresholds (0-1).
        release_cycles: consecutive cycles below the release level before release (>= 1).
        classifier: ``f(ContactEvidence) -> "intentional" | "collision"``.
    """

    r_th: float = 2.0
    r_th_joint: np.ndarray | None = None
    release_ratio: float = 0.5
    release_cycles: int = 4
    classifier: Callable[[ContactEvidence], str] = default_classifier

    def __post_init__(self) -> None:
        self.r_th = positive_number(self.r_th, "r_th")
        ratio = real_number(self.release_ratio, "release_ratio", "a number in (0, 1]")
        if not 0.0 < ratio <= 1.0:
            raise ValueError(f"release_ratio must be in (0, 1], got {self.release_ratio!r}")
        self.release_ratio = ratio
        c = self.release_cycles
        if isinstance(c, bool | np.bool_) or not (isinstance(c, int | np.integer) and c >= 1):
            raise ValueError(f"release_cycles must be an integer >= 1, got {c!r}")
        if self.r_th_joint is not None:
            rj = self.r_th_joint
            self.r_th_joint = positive_numbers(rj, np.size(rj), "r_th_joint") if np.ndim(rj) == 1 else None
            if self.r_th_joint is None or not self.r_th_joint.size:
                raise ValueError(f"r_th_joint must be finite numbers > 0 of shape (n,), got {rj!r}")
        self.reset()

    def reset(self) -> None:
        self.active, self.label, self._below, self._prev_norm = False, "", 0, 0.0

    def _over(self, r: np.ndarray, norm: float, ratio: float) -> bool:
        if norm > ratio * self.r_th:
            return True
        return self.r_th_joint is not None and bool(np.any(np.abs(r) > ratio * self.r_th_joint))

    def step(self, r: np.ndarray, dt: float, hand_distance: float | None = None) -> DetectionState:
        """Feed one residual ``r`` (n,) N m of period ``dt`` s. Non-finite ``r`` counts as a contact
        (safety: the caller cannot trust the robot state). ``ValueError`` naming the field: ``dt`` not a finite
        number > 0; ``r`` not a non-empty 1-D numeric array (of ``r_th_joint``'s length where that is set);
        ``hand_distance`` not a number >= 0 or None (NaN: no hand known, as None)."""
        if not (type(dt) is float and 0.0 < dt < math.inf):
            dt = positive_number(dt, "dt")
        rj = self.r_th_joint
        if type(r) is not np.ndarray or r.dtype is not _F64:
            r = np.asarray(r, float) if is_numeric_nest(r) else f"{r!r} (not numbers)"
        if type(r) is str or r.ndim != 1 or not r.size or (rj is not None and r.shape != rj.shape):
            got = r if type(r) is str else f"shape {r.shape}"
            raise ValueError(
                f"r must be a non-empty numeric array of shape ({'n' if rj is None else len(rj)},), got {got}"
            )
        if hand_distance is not None and not (type(hand_distance) is float and hand_distance >= 0.0):
            hand_distance = real_number(hand_distance, "hand_distance", "a distance >= 0 m or None")
            if hand_distance < 0:
                raise ValueError(f"hand_distance must be a distance >= 0 m or None, got {hand_distance!r}")
            hand_distance = None if math.isnan(hand_distance) else hand_distance
        norm = math.hypot(*r.tolist())  # no overflow below inf; NaN or inf -> not finite
        if not math.isfinite(norm):
            norm = math.inf
        rate = (norm - self._prev_norm) / dt if math.isfinite(norm) else math.inf
        self._prev_norm = norm if math.isfinite(norm) else self._prev_norm
        onset = release = False
        if not self.active:
            if not math.isfinite(norm) or self._over(r, norm, 1.0):
                self.active, onset, self._below = True, True, 0
                self.label = self.classifier(ContactEvidence(r.copy(), rate, hand_distance))
        else:
            self._below = self._below + 1 if math.isfinite(norm) and not self._over(r, norm, self.release_ratio) else 0
            if self._below >= self.release_cycles:
                self.active, release, self.label = False, True, ""
        return _tuple_new(DetectionState, (self.active, onset, release, self.label))  # (NamedTuple, no __new__ call)
