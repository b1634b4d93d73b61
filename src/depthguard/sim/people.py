"""Scripted capsule people: torso, head, legs, upper and lower arms, hands; kinematic motion from keyframes.

A person is a set of capsule segments posed by :func:`person_segments` from a small state: where the
person stands on the floor (``base`` x, y and ``yaw``), and where each hand is (a world target, or
``None`` for an arm hanging at rest). The arms are posed by analytic two-link inverse kinematics with
the elbow pointing down and outwards; a target out of reach gets a stretched arm pointing at it.

The motion is data: :class:`Keyframe` lists (times, base, yaw, hand targets, carried objects) read
from scenario files and interpolated linearly in time (:class:`PersonScript`). The speed of a hand is
what the keyframes imply; :meth:`PersonScript.max_hand_speed` reports it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Segment", "SEGMENTS", "Keyframe", "PersonScript", "person_segments", "segment_pose"]


@dataclass(frozen=True)
class Segment:
    """A body segment: a capsule of ``radius`` m, or a sphere when ``length`` is 0."""

    name: str
    radius: float
    length: float


# Adult, about 1.75 m tall. Lengths between joint centres.
SEGMENTS: tuple[Segment, ...] = (
    Segment("torso", 0.15, 0.45),
    Segment("head", 0.11, 0.0),
    Segment("l_leg", 0.08, 0.80),
    Segment("r_leg", 0.08, 0.80),
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


def _lerp(a, b, s):
    return None if a is None or b is None else tuple((1 - s) * np.asarray(a) + s * np.asarray(b))


@dataclass
class PersonScript:
    """A person's keyframed motion; :meth:`state` interpolates it linearly (hands: rest <-> target eased)."""

    name: str
    keyframes: list[Keyframe]
    floor_z: float = -0.8
    _rest_cache: dict = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        if not self.keyframes:
            raise ValueError(f"person '{self.name}': needs at least one keyframe")
        ts = [k.t for k in self.keyframes]
        if any(b <= a for a, b in zip(ts, ts[1:], strict=False)):
            raise ValueError(f"person '{self.name}': keyframe times must increase, got {ts}")

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
        """(base (2,), yaw rad, left hand (3,) or None, right hand (3,) or None, carried object, carry hand)."""
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
        carry = a.carry if s < 1.0 else b.carry
        return base, yaw, hands[0], hands[1], carry, a.carry_hand

    def segments(self, t: float) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Segment name -> (start (3,), end (3,)) world m at time ``t`` (start == end for spheres)."""
        base, yaw, lh, rh, _, _ = self.state(t)
        return person_segments(base, yaw, lh, rh, self.floor_z)

    def hand_position(self, t: float, hand: str) -> np.ndarray:
        return self.segments(t)[f"{hand[0]}_hand"][0]

    def max_hand_speed(self, dt: float = 0.01) -> float:
        """The largest hand speed in m/s over the script, sampled every ``dt`` s."""
        t0, t1 = self.keyframes[0].t, self.keyframes[-1].t
        ts = np.arange(t0, t1 + dt, dt)
        best = 0.0
        prev = None
        for t in ts:
            seg = self.segments(float(t))
            cur = np.concatenate([seg["l_hand"][0], seg["r_hand"][0]])
            if prev is not None:
                best = max(best, np.linalg.norm(cur[:3] - prev[:3]) / dt, np.linalg.norm(cur[3:] - prev[3:]) / dt)
            prev = cur
        return float(best)


def _frame(base: np.ndarray, yaw: float) -> tuple[np.ndarray, np.ndarray]:
    fwd = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    left = np.array([-math.sin(yaw), math.cos(yaw), 0.0])
    return fwd, left


def _rest_hand(k: Keyframe, side: str, floor_z: float) -> np.ndarray:
    fwd, left = _frame(np.asarray(k.base, float), math.radians(k.yaw))
    sign = 1.0 if side.startswith("left") else -1.0
    shoulder = np.array([k.base[0], k.base[1], floor_z + SHOULDER_HEIGHT]) + sign * SHOULDER_HALF_WIDTH * left
    return shoulder + 0.08 * fwd + sign * 0.05 * left - np.array([0, 0, REACH * 0.97])


def _arm_ik(shoulder: np.ndarray, target: np.ndarray, outward: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Elbow and hand positions reaching ``target`` from ``shoulder`` (two-link IK, elbow down/out)."""
    d = target - shoulder
    dist = float(np.linalg.norm(d))
    if dist < 1e-6:
        d, dist = np.array([0.0, 0.0, -1.0]), 1e-6
    u = d / dist
    reach = min(dist, REACH * 0.999)
    reach = max(reach, abs(UPPER_ARM - FORE_ARM) + 1e-3)
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
    """Pose all segments. Returns name -> (start (3,), end (3,)), world metres."""
    base = np.asarray(base, float)
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
        target = left_hand if side == "l" else right_hand
        if target is None:
            k = Keyframe(0.0, (base[0], base[1]), math.degrees(yaw))
            target = _rest_hand(k, "left_hand" if side == "l" else "right_hand", floor_z)
        elbow, hand = _arm_ik(shoulder, np.asarray(target, float), sign * left)
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
