"""Scripted capsule people: torso, head, legs, upper and lower arms, hands; kinematic motion from keyframes.

A person is a set of capsule segments posed by :func:`person_segments` from a small state: where the
person stands on the floor (``base`` x, y and ``yaw``), and where each hand is (a world target, or
``None`` for an arm hanging at rest). The arms are posed by analytic two-link inverse kinematics with
the elbow bent towards "down and outwards" (``-z + 0.5 outward``, as far as the triangle allows). A
target within ``REACH_MAX`` (0.999 of the straight arm: the elbow never locks) and beyond ``REACH_MIN``
from the shoulder is reached exactly; one farther away gets a stretched arm pointing at it, one nearer
(the arm cannot fold that far) the folded arm's hand on the line to it (straight down for a target within
1 um of the shoulder). Base and yaw move the whole person rigidly; the segment lengths never change.

The motion is data: :class:`Keyframe` lists (times, base, yaw, hand targets, carried objects) read
from scenario files and interpolated linearly in time (:class:`PersonScript`); before the first
keyframe the person stands as in it, after the last as in the last. The speed of a hand is what the
keyframes imply; :meth:`PersonScript.max_hand_speed` reports it.

Bad input is refused with a ``ValueError`` naming the field: NaN or infinite numbers, bools or strings
for numbers, wrong lengths, keyframe times that do not increase, a base, floor or yaw beyond
``MAX_COORD`` (m or degrees; float spacing there would erode the segments). A hand target may be any
finite point.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from depthguard.validation import is_numeric_nest, real_number

__all__ = ["Segment", "SEGMENTS", "Keyframe", "PersonScript", "person_segments", "segment_pose"]


@dataclass(frozen=True)
class Segment:
    """A body segment: a capsule of ``radius`` m, or a sphere when ``length`` is 0."""

    name: str
    radius: float
    length: float


# Adult, about 1.75 m tall. Lengths between joint centres.
SEGMENTS: tuple[Segment, ...] = (
    Segment("torso", 0.15, 0.41),
    Segment("head", 0.11, 0.0),
    Segment("l_leg", 0.08, 0.84),
    Segment("r_leg", 0.08, 0.84),
    Segment("l_uarm", 0.05, 0.30),
    Segment("r_uarm", 0.05, 0.30),
    Segment("l_farm", 0.045, 0.27),
    Segment("r_farm", 0.045, 0.27),
    Segment("l_hand", 0.05, 0.0),
    Segment("r_hand", 0.05, 0.0),
)
_SEG = {s.name: s for s in SEGMENTS}
HIP_HEIGHT = 0.92  # above the floor
SHOULDER_HEIGHT = 1.45
SHOULDER_HALF_WIDTH = 0.20
UPPER_ARM = _SEG["l_uarm"].length
FORE_ARM = _SEG["l_farm"].length + 0.06  # wrist to hand centre included
REACH = UPPER_ARM + FORE_ARM
REACH_MAX = REACH * 0.999  # the hand's farthest distance from the shoulder
REACH_MIN = abs(UPPER_ARM - FORE_ARM) + 1e-3  # and its nearest
MAX_COORD = 1e6  # |base|, |floor_z| (m) and |yaw| (deg) at most


def _number(value: object, name: str, bound: float = math.inf) -> float:
    """``value`` as a finite float within ``bound`` (not a bool or a string), else ``ValueError`` naming it."""
    x = real_number(value, name, "a finite number")
    if not (math.isfinite(x) and abs(x) <= bound):
        limit = "" if bound == math.inf else f" within +-{bound:g}"
        raise ValueError(f"{name} must be a finite number{limit}, got {value!r}")
    return x


def _vector(value: object, n: int, name: str, bound: float = math.inf) -> np.ndarray:
    """``value`` as a finite float (n,) array within ``bound``, else ``ValueError`` naming it."""
    a = np.asarray(value, float) if is_numeric_nest(value) else None
    if a is None or a.shape != (n,) or not (np.all(np.isfinite(a)) and np.all(np.abs(a) <= bound)):
        limit = "" if bound == math.inf else f" within +-{bound:g}"
        raise ValueError(f"{name} must be {n} finite numbers{limit}, got {value!r}")
    return a


@dataclass(frozen=True)
class Keyframe:
    """The person's state at time ``t`` (s).

    Attributes:
        t: time, s.
        base: (x, y) floor position of the body centre, world m.
        yaw: heading, degrees (0 = facing +x).
        left_hand, right_hand: world (3,) hand targets in m, or ``None`` (arm at rest).
        carry: name of an object held in the right hand (left when ``carry_hand`` is "left"), or ``None``.
    """

    t: float
    base: tuple[float, float]
    yaw: float = 0.0
    left_hand: tuple[float, float, float] | None = None
    right_hand: tuple[float, float, float] | None = None
    carry: str | None = None
    carry_hand: str = "right"

    def __post_init__(self) -> None:
        _number(self.t, "keyframe t")
        _vector(self.base, 2, f"keyframe (t={self.t}) base", MAX_COORD)
        _number(self.yaw, f"keyframe (t={self.t}) yaw", MAX_COORD)
        for side in ("left_hand", "right_hand"):
            if getattr(self, side) is not None:
                _vector(getattr(self, side), 3, f"keyframe (t={self.t}) {side}")
        if self.carry is not None and not isinstance(self.carry, str):
            raise ValueError(f"keyframe (t={self.t}) carry must be an object name or None, got {self.carry!r}")
        if self.carry_hand not in ("left", "right"):
            raise ValueError(f"keyframe (t={self.t}) carry_hand must be 'left' or 'right', got {self.carry_hand!r}")


def _lerp(a, b, s):
    return None if a is None or b is None else tuple((1 - s) * np.asarray(a) + s * np.asarray(b))


@dataclass
class PersonScript:
    """A person's keyframed motion; :meth:`state` interpolates it linearly in time (an arm going from rest to a
    target, or back, moves on the straight line from its rest position at the one keyframe to the target)."""

    name: str
    keyframes: list[Keyframe]
    floor_z: float = -0.8
    _rest_cache: dict = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        if not isinstance(self.keyframes, list | tuple) or not self.keyframes:
            raise ValueError(f"person '{self.name}': keyframes must be a non-empty list of Keyframe")
        if not all(isinstance(k, Keyframe) for k in self.keyframes):
            raise ValueError(f"person '{self.name}': keyframes must be Keyframe objects, got {self.keyframes!r}")
        self.floor_z = _number(self.floor_z, f"person '{self.name}': floor_z", MAX_COORD)
        ts = [float(k.t) for k in self.keyframes]
        # (times increase, and by finite steps: an overflowing step would make the interpolation NaN)
        if not all(0.0 < b - a < math.inf for a, b in zip(ts, ts[1:], strict=False)):
            raise ValueError(f"person '{self.name}': keyframe times must increase (by finite steps), got {ts}")

    def _bracket(self, t: float) -> tuple[Keyframe, Keyframe, float]:
        ks = self.keyframes
        if t <= ks[0].t:
            return ks[0], ks[0], 0.0
        if t >= ks[-1].t:
            return ks[-1], ks[-1], 0.0
        for a, b in zip(ks, ks[1:], strict=False):
            if a.t <= t <= b.t:
                return a, b, (t - a.t) / (b.t - a.t)
        raise AssertionError

    def state(self, t: float) -> tuple[np.ndarray, float, np.ndarray | None, np.ndarray | None, str | None, str]:
        """(base (2,), yaw rad, left hand (3,) or None, right hand (3,) or None, carried object, carry hand).

        ``t`` (s) before the first keyframe gives the first keyframe's state, after the last the last's; NaN
        is refused. The carried object and its hand are those of the keyframe at or before ``t``."""
        t = real_number(t, "t", "a time in s")
        if math.isnan(t):
            raise ValueError("t must be a time in s, got nan")
        a, b, s = self._bracket(t)
        base = (1 - s) * np.asarray(a.base, float) + s * np.asarray(b.base, float)
        yaw = math.radians((1 - s) * a.yaw + s * b.yaw)
        hands = []
        for side in ("left_hand", "right_hand"):
            ha, hb = getattr(a, side), getattr(b, side)
            if ha is None and hb is None:
                hands.append(None)
                continue
            # an arm going from rest to a target (or back) starts from its rest position
            rest_a = _rest_hand(a, side, self.floor_z) if ha is None else np.asarray(ha, float)
            rest_b = _rest_hand(b, side, self.floor_z) if hb is None else np.asarray(hb, float)
            hands.append((1 - s) * rest_a + s * rest_b)
        k = a if s < 1.0 else b
        return base, yaw, hands[0], hands[1], k.carry, k.carry_hand

    def segments(self, t: float) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Segment name -> (start (3,), end (3,)) world m at time ``t`` (start == end for spheres)."""
        base, yaw, lh, rh, _, _ = self.state(t)
        return person_segments(base, yaw, lh, rh, self.floor_z)

    def hand_position(self, t: float, hand: str) -> np.ndarray:
        """World (3,) position of the ``"left"`` or ``"right"`` hand at time ``t``."""
        if hand not in ("left", "right"):
            raise ValueError(f"hand must be 'left' or 'right', got {hand!r}")
        return self.segments(t)[f"{hand[0]}_hand"][0]

    def max_hand_speed(self, dt: float = 0.01) -> float:
        """The largest hand speed in m/s over the script: finite differences over steps of at most ``dt`` s
        within each keyframe interval (none straddles a keyframe, so an interval shorter than ``dt`` counts
        in full), and the speeds (over 1e-6 s) on both sides of each keyframe and of each instant where a
        hand's target enters or leaves its reach (there the hand's speed jumps).

        Exact where a hand moves in a straight line at constant speed (a reached target moving linearly, a
        walk without turning); where its path curves (turning, an arm stretched towards a target out of
        reach) a peak inside a step may be read low by a second-order amount, about ``s'' dt^2 / 8`` (``s''``
        the hand speed's second time derivative). Not a bound near ``REACH_MIN``: a target passing through
        the shoulder whips the folded arm's hand around it, and only the samples see that."""
        dt = _number(dt, "dt")
        if not dt > 0.0:
            raise ValueError(f"dt must be a positive number of seconds, got {dt!r}")
        ts = [float(k.t) for k in self.keyframes]
        best = 0.0
        for a, b in zip(ts, ts[1:], strict=False):
            n = max(1, math.ceil((b - a) / dt))
            grid = [a + (b - a) * i / n for i in range(n)] + [b]
            hands = [self._hands(t) for t in grid]
            for i in range(n):
                best = max(best, _speed(hands[i], hands[i + 1], grid[i + 1] - grid[i]))
            codes = [self._reach_codes(t) for t in grid]
            edges = [(a, a), (b, b)]
            for i in range(n):
                if codes[i] != codes[i + 1]:  # a target entered or left the reach
                    edges.append(self._reach_change(grid[i], grid[i + 1], codes[i]))
            eps = min(1e-6, 0.5 * (b - a))
            for lo, hi in edges:
                t0, t1 = max(a, lo - eps), min(b, hi + eps)
                if t0 < lo:
                    best = max(best, _speed(self._hands(t0), self._hands(lo), lo - t0))
                if hi < t1:
                    best = max(best, _speed(self._hands(hi), self._hands(t1), t1 - hi))
        return best

    def _hands(self, t: float) -> np.ndarray:
        seg = self.segments(t)
        return np.array([seg["l_hand"][0], seg["r_hand"][0]])

    def _reach_change(self, lo: float, hi: float, code: tuple[int, int]) -> tuple[float, float]:
        """Bisection: the adjacent times (lo, hi) where the reach codes change from ``code``."""
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            if not lo < mid < hi:
                break
            lo, hi = (mid, hi) if self._reach_codes(mid) == code else (lo, mid)
        return lo, hi

    def _reach_codes(self, t: float) -> tuple[int, int]:
        """Per hand: -1 target nearer than ``REACH_MIN``, 1 beyond ``REACH_MAX``, else 0 (reached or at rest)."""
        base, yaw, lh, rh, _, _ = self.state(t)
        left = _frame(base, yaw)[1]
        out = []
        for h, sign in ((lh, 1.0), (rh, -1.0)):
            if h is None:
                out.append(0)
                continue
            d = h - (np.array([base[0], base[1], self.floor_z + SHOULDER_HEIGHT]) + sign * SHOULDER_HALF_WIDTH * left)
            dist = float(np.linalg.norm(d)) if np.abs(d).max() < 1e150 else math.inf
            out.append(int(dist > REACH_MAX) - int(dist < REACH_MIN))
        return out[0], out[1]


def _speed(h0: np.ndarray, h1: np.ndarray, dt: float) -> float:
    """The larger of the two hands' speeds between positions ``h0`` and ``h1`` (2, 3), ``dt`` s apart."""
    return float(np.max(np.linalg.norm(h1 - h0, axis=1))) / dt


def _frame(base: np.ndarray, yaw: float) -> tuple[np.ndarray, np.ndarray]:
    fwd = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    left = np.array([-math.sin(yaw), math.cos(yaw), 0.0])
    return fwd, left


def _rest_hand(k: Keyframe, side: str, floor_z: float) -> np.ndarray:
    return _rest_hand_at(k.base, k.yaw, side, floor_z)


def _rest_hand_at(base, yaw_deg: float, side: str, floor_z: float) -> np.ndarray:
    fwd, left = _frame(np.asarray(base, float), math.radians(yaw_deg))
    sign = 1.0 if side.startswith("left") else -1.0
    shoulder = np.array([base[0], base[1], floor_z + SHOULDER_HEIGHT]) + sign * SHOULDER_HALF_WIDTH * left
    return shoulder + 0.08 * fwd + sign * 0.05 * left - np.array([0, 0, REACH * 0.97])


def _arm_ik(shoulder: np.ndarray, target: np.ndarray, outward: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Elbow and hand positions reaching ``target`` from ``shoulder`` (two-link IK, elbow down/out)."""
    d = target - shoulder
    if abs(d[0]) < 1e150 and abs(d[1]) < 1e150 and abs(d[2]) < 1e150:
        dist = float(np.linalg.norm(d))
        # (at the shoulder: straight down; this was d / 1e-6, a hand 31 km below)
        u = d / dist if dist >= 1e-6 else np.array([0.0, 0.0, -1.0])
    else:  # (a far target: |d|^2 would overflow and leave no direction; scale it first)
        d = d / np.abs(d).max()
        dist, u = math.inf, d / np.linalg.norm(d)
    reach = min(dist, REACH_MAX)
    reach = max(reach, REACH_MIN)
    hand = shoulder + u * reach
    # elbow: law of cosines, bent towards "down and outwards" projected orthogonal to u
    cos_a = (UPPER_ARM**2 + reach**2 - FORE_ARM**2) / (2 * UPPER_ARM * reach)
    a = math.acos(max(-1.0, min(1.0, cos_a)))
    pole = np.array([0.0, 0.0, -1.0]) + 0.5 * outward
    pole = pole - (pole @ u) * u
    if np.linalg.norm(pole) < 1e-6:
        pole = outward - (outward @ u) * u
    pole /= max(np.linalg.norm(pole), 1e-9)
    elbow = shoulder + UPPER_ARM * (math.cos(a) * u + math.sin(a) * pole)
    return elbow, hand


def person_segments(
    base: np.ndarray,
    yaw: float,
    left_hand: np.ndarray | None,
    right_hand: np.ndarray | None,
    floor_z: float = -0.8,
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Pose all segments. Returns name -> (start (3,), end (3,)), world metres.

    ``base`` (2,) m and ``floor_z`` m within ``MAX_COORD``, ``yaw`` rad finite, hands ``None`` (at rest) or
    finite world (3,) targets (module docstring); anything else is a ``ValueError`` naming the argument."""
    base = _vector(base, 2, "base", MAX_COORD)
    yaw = _number(yaw, "yaw")
    floor_z = _number(floor_z, "floor_z", MAX_COORD)
    hands = {
        side: None if h is None else _vector(h, 3, f"{side}_hand")
        for side, h in (("left", left_hand), ("right", right_hand))
    }
    fwd, left = _frame(base, yaw)
    c = np.array([base[0], base[1], floor_z])
    out: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    hip = c + np.array([0, 0, HIP_HEIGHT + 0.1])
    neck = c + np.array([0, 0, SHOULDER_HEIGHT - 0.02])
    out["torso"] = (hip, neck)
    head = c + np.array([0, 0, SHOULDER_HEIGHT + 0.19])
    out["head"] = (head, head)
    for side, sign in (("l", 1.0), ("r", -1.0)):
        foot = c + sign * 0.11 * left + np.array([0, 0, 0.08])
        out[f"{side}_leg"] = (foot, foot + np.array([0, 0, HIP_HEIGHT - 0.08]))
        shoulder = c + np.array([0, 0, SHOULDER_HEIGHT]) + sign * SHOULDER_HALF_WIDTH * left
        target = hands["left" if side == "l" else "right"]
        if target is None:
            target = _rest_hand_at(base, math.degrees(yaw), "left_hand" if side == "l" else "right_hand", floor_z)
        elbow, hand = _arm_ik(shoulder, target, sign * left)
        wrist = elbow + (hand - elbow) * (_SEG["l_farm"].length / FORE_ARM)
        out[f"{side}_uarm"] = (shoulder, elbow)
        out[f"{side}_farm"] = (elbow, wrist)
        out[f"{side}_hand"] = (hand, hand)
    return out


def segment_pose(start: np.ndarray, end: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mocap pose (position (3,), quaternion (4,) w x y z) of a segment whose capsule lies along body z."""
    pos = 0.5 * (np.asarray(start) + np.asarray(end))
    d = np.asarray(end) - np.asarray(start)
    n = np.linalg.norm(d)
    if n < 1e-9:
        return pos, np.array([1.0, 0.0, 0.0, 0.0])
    z = d / n
    # quaternion rotating (0,0,1) onto z
    w = 1.0 + z[2]
    if w < 1e-9:
        return pos, np.array([0.0, 1.0, 0.0, 0.0])
    q = np.array([w, -z[1], z[0], 0.0])
    return pos, q / np.linalg.norm(q)
