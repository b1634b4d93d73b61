"""Property tests of the scripted capsule people (sim.people), the ground truth of the simulated cell's metrics:
analytic two-link IK (triangle sides, the elbow circle and the documented "down and outwards" pole written here),
base/yaw as a rigid transform applied here, linear keyframe interpolation by a reference written here, the hand
speed against finite differences, and the capsules MuJoCo gets (segment_pose) against analytic point-segment
distances through ``mj_geomDistance``.

Faults these tests found (each pinned by an ``@example`` or a parametrized case that failed on the old code):

* ``person_segments``: a target beyond ~1e154 m overflowed ``|d|^2`` and put the hand on the shoulder with a
  1 cm forearm; NaN / inf targets, bases, yaws and floors gave NaN segments silently (an infinite yaw: an
  unnamed "math domain error"); wrong lengths were cut or broadcast unnamed.
* ``PersonScript``: NaN keyframe times were accepted (then ``state`` raised a bare ``AssertionError``), so
  were infinite ones and spans overflowing to inf (NaN states); ``state(nan)`` raised ``AssertionError``.
  At a keyframe's exact time the carried object was that keyframe's but the carry hand the previous one's.
* ``max_hand_speed``: differences straddled keyframes over a global grid, so a keyframe interval shorter than
  ``dt`` could read 0 m/s (a 60 m/s hand flick) and short intervals were averaged with their neighbours.
* ``SEGMENTS``: the torso (0.45) and leg (0.80) lengths did not match the posed capsules (0.41, 0.84).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st

from depthguard.sim.people import SEGMENTS, Keyframe, PersonScript, person_segments, segment_pose

NAN, INF = math.nan, math.inf
U, F, WRIST = 0.30, 0.33, 0.27  # upper arm, elbow to hand centre, elbow to wrist (documented dimensions)
RMAX, RMIN = 0.999 * (U + F), abs(U - F) + 1e-3
LENGTH = {s.name: s.length for s in SEGMENTS}
RADIUS = {s.name: s.radius for s in SEGMENTS}

coord = st.floats(-5.0, 5.0)
yaws = st.floats(-720.0, 720.0)
unit3 = st.tuples(*[st.floats(-1.0, 1.0)] * 3).filter(lambda v: 0.1 < math.hypot(*v))


# ------------------------------------------------------------------------------------------- references
def _frame(yaw: float):
    """Forward, left (unit, world) of a person facing ``yaw`` rad."""
    return np.array([math.cos(yaw), math.sin(yaw), 0.0]), np.array([-math.sin(yaw), math.cos(yaw), 0.0])


def _shoulder(base, yaw: float, fz: float, side: str) -> np.ndarray:
    sign = 1.0 if side == "l" else -1.0
    return np.array([base[0], base[1], fz + 1.45]) + sign * 0.20 * _frame(yaw)[1]


def _transform(p, base, yaw: float, fz: float) -> np.ndarray:
    """Body frame (origin on the floor under the base, x forward) to world."""
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([c * p[0] - s * p[1] + base[0], s * p[0] + c * p[1] + base[1], p[2] + fz])


def _unit(d) -> np.ndarray:
    d = np.asarray(d, float)
    d = d / np.abs(d).max()  # (no overflow for far targets)
    return d / np.linalg.norm(d)


def _check_arm(segs, side: str, shoulder) -> None:
    """Lengths of a posed arm: shoulder-elbow U, elbow-hand F, elbow-wrist 0.27 on the elbow-hand line."""
    s, e = segs[f"{side}_uarm"]
    e2, w = segs[f"{side}_farm"]
    h = segs[f"{side}_hand"][0]
    np.testing.assert_allclose(s, shoulder, atol=1e-12)
    np.testing.assert_array_equal(e, e2)
    assert np.linalg.norm(e - s) == pytest.approx(U, abs=1e-9)
    assert np.linalg.norm(h - e) == pytest.approx(F, abs=1e-9)
    np.testing.assert_allclose(w, e + (h - e) * (WRIST / F), atol=1e-9)


def _ref_state(kfs: list[Keyframe], t: float, fz: float):
    """Linear interpolation by the documented rules: clamp outside, a hand None at both ends is None, a hand
    None at one end starts (or ends) at the rest hand of that keyframe's pose."""
    if t <= kfs[0].t:
        a = b = kfs[0]
        s = 0.0
    elif t >= kfs[-1].t:
        a = b = kfs[-1]
        s = 0.0
    else:
        i = max(j for j in range(len(kfs) - 1) if kfs[j].t <= t)
        a, b = kfs[i], kfs[i + 1]
        s = (t - a.t) / (b.t - a.t)
    base = (1 - s) * np.array(a.base) + s * np.array(b.base)
    yaw = math.radians((1 - s) * a.yaw + s * b.yaw)
    hands = []
    for side, seg in (("left_hand", "l_hand"), ("right_hand", "r_hand")):
        ha, hb = getattr(a, side), getattr(b, side)
        if ha is None and hb is None:
            hands.append(None)
            continue

        def at(k, h, seg=seg):
            if h is not None:
                return np.array(h, float)
            return person_segments(np.array(k.base), math.radians(k.yaw), None, None, fz)[seg][0]

        hands.append((1 - s) * at(a, ha) + s * at(b, hb))
    return base, yaw, hands[0], hands[1]


# ------------------------------------------------------------------------------------------- IK
@settings(max_examples=60, deadline=None)
@given(
    base=st.tuples(coord, coord),
    yaw=st.floats(-7.0, 7.0),
    fz=st.floats(-2.0, 2.0),
    side=st.sampled_from("lr"),
    direction=unit3,
    r=st.floats(RMIN, RMAX),
)
@example(base=(0.0, 0.0), yaw=0.0, fz=-0.8, side="r", direction=(0.0, 0.0, -1.0), r=RMAX)
@example(base=(0.0, 0.0), yaw=0.0, fz=-0.8, side="r", direction=(0.0, 0.0, 1.0), r=RMIN)
def test_reachable_target_is_reached_with_elbow_down_and_out(base, yaw, fz, side, direction, r):
    sh = _shoulder(base, yaw, fz, side)
    u = _unit(direction)
    target = sh + r * u
    segs = person_segments(np.array(base), yaw, target if side == "l" else None, target if side == "r" else None, fz)
    np.testing.assert_allclose(segs[f"{side}_hand"][0], target, atol=1e-9)
    _check_arm(segs, side, sh)
    # the elbow lies on the circle of points U from the shoulder and F from the hand; the documented choice
    # is the one farthest along "down and outwards" (-z + 0.5 outward)
    cos_a = (U * U + r * r - F * F) / (2 * U * r)
    centre, radius = sh + U * cos_a * u, U * math.sqrt(max(0.0, 1 - cos_a * cos_a))
    e1 = np.cross(u, [1.0, 0, 0] if abs(u[0]) < 0.9 else [0, 1.0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    outward = (1.0 if side == "l" else -1.0) * _frame(yaw)[1]
    pole = np.array([0.0, 0.0, -1.0]) + 0.5 * outward
    if np.linalg.norm(pole - (pole @ u) * u) < 1e-3:
        return  # (the target straight along the pole: every elbow on the circle is equally down and out)
    phi = np.linspace(0.0, 2 * math.pi, 721)
    circle = centre + radius * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2)
    elbow = segs[f"{side}_uarm"][1]
    assert elbow @ pole >= np.max(circle @ pole) - 1e-9
    assert (elbow - centre) @ pole >= -1e-12


@settings(max_examples=60, deadline=None)
@given(
    base=st.tuples(coord, coord),
    yaw=st.floats(-7.0, 7.0),
    side=st.sampled_from("lr"),
    direction=unit3,
    r=st.one_of(st.floats(RMAX, 1e3), st.floats(1e3, 1e307), st.floats(0.0, RMIN)),
)
@example(base=(0.0, 0.0), yaw=0.0, side="r", direction=(1.0, 0.0, 0.0), r=1e200)  # hand was on the shoulder
@example(base=(0.0, 0.0), yaw=0.0, side="l", direction=(1.0, 1.0, 0.0), r=1e160)
@example(base=(1.0, 2.0), yaw=0.3, side="l", direction=(0.0, 1.0, 0.0), r=1.7e308)
@example(base=(0.0, 0.0), yaw=0.0, side="l", direction=(0.0, 0.0, 1.0), r=0.0)  # at the shoulder: 31 km below
def test_target_out_of_reach_gets_an_arm_pointing_at_it(base, yaw, side, direction, r):
    fz = -0.8
    sh = _shoulder(base, yaw, fz, side)
    u = _unit(direction)
    with np.errstate(over="ignore"):
        target = sh + r * u
    if not np.all(np.isfinite(target)):
        return
    segs = person_segments(np.array(base), yaw, target if side == "l" else None, target if side == "r" else None, fz)
    hand = segs[f"{side}_hand"][0]
    d = target - sh
    near = np.linalg.norm(d) if np.abs(d).max() < 1.0 else INF
    if near < 0.9e-6:  # within 1 um of the shoulder (documented): the folded arm's hand straight down
        np.testing.assert_allclose(hand, sh + [0.0, 0.0, -RMIN], atol=1e-12)
    elif near > 1.1e-6:  # (not at that threshold, where rounding decides)
        scale = np.abs(d).max()
        expect = min(max(scale * np.linalg.norm(d / scale), RMIN), RMAX)
        np.testing.assert_allclose(hand, sh + expect * _unit(d), atol=1e-9)
    _check_arm(segs, side, sh)


state_hand = st.one_of(st.none(), st.tuples(*[st.floats(-1e3, 1e3)] * 3), st.tuples(*[st.floats(-1e300, 1e300)] * 3))


@settings(max_examples=60, deadline=None)
@given(
    base=st.tuples(st.floats(-1e6, 1e6), st.floats(-1e6, 1e6)),
    yaw=st.floats(-1e4, 1e4),
    fz=st.floats(-1e6, 1e6),
    lh=state_hand,
    rh=state_hand,
)
@example(base=(0.0, 0.0), yaw=0.0, fz=-0.8, lh=(1e200, 0.0, 0.0), rh=(-1e300, 1e300, 1e300))
def test_segment_lengths_never_change(base, yaw, fz, lh, rh):
    segs = person_segments(np.array(base), yaw, lh, rh, fz)
    for name, (a, b) in segs.items():
        assert np.all(np.isfinite(a)) and np.all(np.isfinite(b)), name
        assert np.linalg.norm(b - a) == pytest.approx(LENGTH[name], abs=1e-6 * max(1.0, abs(fz), *np.abs(base))), name
    assert set(segs) == set(LENGTH)


@settings(max_examples=50, deadline=None)
@given(
    base=st.tuples(coord, coord),
    yaw=st.floats(-7.0, 7.0),
    fz=st.floats(-2.0, 2.0),
    lh=st.one_of(st.none(), st.tuples(*[st.floats(-2.0, 2.0)] * 3)),
    rh=st.one_of(st.none(), st.tuples(*[st.floats(-2.0, 2.0)] * 3)),
)
def test_base_yaw_and_floor_move_the_person_rigidly(base, yaw, fz, lh, rh):
    """Posing with body-frame targets at the origin, then transforming, equals posing with world targets."""
    body = person_segments(np.zeros(2), 0.0, lh, rh, 0.0)
    world = person_segments(
        np.array(base),
        yaw,
        None if lh is None else _transform(lh, base, yaw, fz),
        None if rh is None else _transform(rh, base, yaw, fz),
        fz,
    )
    for name, (a, b) in body.items():
        np.testing.assert_allclose(world[name][0], _transform(a, base, yaw, fz), atol=1e-9, err_msg=name)
        np.testing.assert_allclose(world[name][1], _transform(b, base, yaw, fz), atol=1e-9, err_msg=name)


_OK = {"base": np.zeros(2), "yaw": 0.0, "left_hand": None, "right_hand": None, "floor_z": -0.8}
_BAD_POSE = [
    ("base", np.array([NAN, 0.0])),
    ("base", np.array([0.0, INF])),
    ("base", np.array([2e6, 0.0])),
    ("base", np.zeros(3)),
    ("base", 1.0),
    ("base", [True, 0.0]),
    ("base", "ab"),
    ("yaw", NAN),
    ("yaw", INF),
    ("yaw", True),
    ("yaw", "0"),
    ("floor_z", NAN),
    ("floor_z", -INF),
    ("floor_z", 1e7),
    ("right_hand", np.array([NAN, 0.0, 0.0])),
    ("right_hand", np.array([INF, 0.0, 0.0])),
    ("left_hand", np.zeros(2)),
    ("left_hand", np.zeros(4)),
    ("left_hand", [0.5, "x", 0.5]),
]


@pytest.mark.parametrize(("field", "value"), _BAD_POSE, ids=[f"{f}-{i}" for i, (f, _) in enumerate(_BAD_POSE)])
def test_person_segments_refuses_bad_input_by_name(field, value):
    with pytest.raises(ValueError, match=field):
        person_segments(**{**_OK, field: value})


# ------------------------------------------------------------------------------------------- scripts
hand_kf = st.one_of(st.none(), st.tuples(st.floats(-1.0, 2.0), st.floats(-1.0, 1.0), st.floats(-0.5, 1.2)))


@st.composite
def scripts(draw, n_min=1, n_max=4, dt_min=0.001, yaw_step=1440.0):
    n = draw(st.integers(n_min, n_max))
    dts = draw(st.lists(st.floats(dt_min, 2.0), min_size=n, max_size=n))
    t0 = draw(st.floats(-5.0, 5.0))
    ts = [t0 + sum(dts[:i]) for i in range(n)]
    if any(b <= a for a, b in zip(ts, ts[1:], strict=False)):
        ts = [t0 + i for i in range(n)]
    yaw = [draw(yaws)]
    for _ in ts[1:]:
        yaw.append(yaw[-1] + draw(st.floats(-yaw_step, yaw_step)))
    return [
        Keyframe(
            t,
            (draw(st.floats(-2.0, 2.0)), draw(st.floats(-2.0, 2.0))),
            yaw[i],
            left_hand=draw(hand_kf),
            right_hand=draw(hand_kf),
            carry=draw(st.sampled_from([None, "box", "cup"])),
            carry_hand=draw(st.sampled_from(["left", "right"])),
        )
        for i, t in enumerate(ts)
    ]


@settings(max_examples=50, deadline=None)
@given(kfs=scripts(), probes=st.lists(st.floats(-0.2, 1.2), min_size=1, max_size=5), fz=st.floats(-1.0, 0.0))
def test_state_interpolates_linearly_and_clamps(kfs, probes, fz):
    p = PersonScript("p", kfs, floor_z=fz)
    t0, t1 = kfs[0].t, kfs[-1].t
    times = [t0 + q * (t1 - t0) - 0.5 * (q < 0) + 0.5 * (q > 1) for q in probes] + [k.t for k in kfs] + [-INF, INF]
    for t in times:
        base, yaw, lh, rh, carry, carry_hand = p.state(t)
        rb, ryaw, rlh, rrh = _ref_state(kfs, t, fz)
        np.testing.assert_allclose(base, rb, atol=1e-9)
        assert yaw == pytest.approx(ryaw, abs=1e-9)
        rest = person_segments(rb, ryaw, None, None, fz)
        for got, ref, seg in ((lh, rlh, "l_hand"), (rh, rrh, "r_hand")):
            # (None, an arm at rest, and its rest hand position are the same pose at a keyframe's time)
            if (got is None) != (ref is None):
                assert t in {k.t for k in kfs}
            got, ref = (rest[seg][0] if h is None else h for h in (got, ref))
            np.testing.assert_allclose(got, ref, atol=1e-9)
        # what is carried, and in which hand: the keyframe at or before t (the first one before it)
        k = max((k for k in kfs if k.t <= t), key=lambda k: k.t, default=kfs[0])
        assert (carry, carry_hand) == (k.carry, k.carry_hand)
        segs = p.segments(t)
        np.testing.assert_array_equal(segs["torso"][0], person_segments(base, yaw, lh, rh, fz)["torso"][0])


def test_carry_hand_is_the_keyframes_own_at_its_time():
    kfs = [Keyframe(0.0, (0, 0), carry="a", carry_hand="left"), Keyframe(1.0, (0, 0), carry="a"), Keyframe(2.0, (0, 0))]
    p = PersonScript("p", kfs)
    assert p.state(1.0)[4:] == ("a", "right")  # was ("a", "left") at t = 1 exactly, ("a", "right") after
    assert p.state(0.5)[4:] == ("a", "left")
    assert p.state(1.5)[4:] == ("a", "right")


_BAD_SCRIPTS = [
    ("empty", [], "at least one|non-empty"),
    ("unsorted", [Keyframe(1.0, (0, 0)), Keyframe(0.5, (0, 0))], "increase"),
    ("duplicate", [Keyframe(1.0, (0, 0)), Keyframe(1.0, (1, 0))], "increase"),
    ("overflowing span", [Keyframe(-1e308, (0, 0)), Keyframe(1e308, (0, 0))], "increase"),
    ("not keyframes", [(0.0, (0, 0))], "Keyframe"),
]


@pytest.mark.parametrize(("kfs", "match"), [(k, m) for _, k, m in _BAD_SCRIPTS], ids=[i for i, _, _ in _BAD_SCRIPTS])
def test_bad_scripts_refused_by_name(kfs, match):
    with pytest.raises(ValueError, match=match):
        PersonScript("bad", kfs)


_BAD_KEYFRAMES = [
    ("t", {"t": NAN}),
    ("t", {"t": INF}),
    ("t", {"t": True}),
    ("t", {"t": "1"}),
    ("base", {"base": (NAN, 0.0)}),
    ("base", {"base": (0.0, 0.0, 0.0)}),
    ("base", {"base": (1e7, 0.0)}),
    ("yaw", {"yaw": INF}),
    ("yaw", {"yaw": 1e300}),
    ("right_hand", {"right_hand": (0.0, NAN, 0.0)}),
    ("left_hand", {"left_hand": (0.0, 0.0)}),
    ("carry_hand", {"carry_hand": "both"}),
    ("carry", {"carry": 3}),
]


@pytest.mark.parametrize(("field", "kw"), _BAD_KEYFRAMES, ids=[f"{f}-{i}" for i, (f, _) in enumerate(_BAD_KEYFRAMES)])
def test_bad_keyframes_refused_by_name(field, kw):
    with pytest.raises(ValueError, match=field):
        Keyframe(**{"t": 0.0, "base": (0.0, 0.0), **kw})


def test_bad_queries_refused_by_name():
    p = PersonScript("p", [Keyframe(0.0, (0, 0)), Keyframe(1.0, (1, 0))])
    for t in (NAN, "0.5", True, None):
        with pytest.raises(ValueError, match="t must be"):
            p.state(t)
    for dt in (0.0, -0.01, NAN, INF):
        with pytest.raises(ValueError, match="dt"):
            p.max_hand_speed(dt)
    with pytest.raises(ValueError, match="hand"):
        p.hand_position(0.5, "middle")
    with pytest.raises(ValueError, match="floor_z"):
        PersonScript("p", [Keyframe(0.0, (0, 0))], floor_z=NAN)


# ------------------------------------------------------------------------------------------- hand speed
_SH_R = np.array([0.0, -0.2, 0.65])  # right shoulder of a person at the origin facing +x (floor -0.8)
# targets 0.1 m or more in front of that shoulder and within reach: a convex set, so every target on a line
# between two of them is reached too
reached = (
    st.tuples(st.floats(0.1, RMAX), st.floats(-RMAX, RMAX), st.floats(-RMAX, RMAX))
    .filter(lambda q: math.hypot(*q) <= RMAX)
    .map(lambda q: tuple(_SH_R + q))
)


def _fd_speed(p: PersonScript, times) -> float:
    h = np.array([[p.segments(t)["l_hand"][0], p.segments(t)["r_hand"][0]] for t in times])
    return float(np.max(np.linalg.norm(np.diff(h, axis=0), axis=2) / np.diff(times)[:, None]))


@settings(max_examples=30, deadline=None)
@given(
    dts=st.lists(st.floats(0.001, 0.3), min_size=1, max_size=4),
    pts=st.lists(reached, min_size=5, max_size=5),
    t0=st.floats(-1.0, 1.0),
)
@example(dts=[0.005, 0.005], pts=[(0.3, -0.2, 0.5), (0.3, 0.1, 0.5), (0.3, -0.2, 0.5)] * 2, t0=0.0)  # read 0
def test_max_hand_speed_exact_for_reached_targets(dts, pts, t0):
    """Base and yaw fixed, right-hand targets in front of the shoulder and within reach (a convex set, so
    every interpolated target is reached): the hand speed is |target step| / time step, exactly."""
    ts = [t0 + sum(dts[:i]) for i in range(len(dts) + 1)]
    kfs = [Keyframe(t, (0.0, 0.0), 0.0, right_hand=pts[i]) for i, t in enumerate(ts)]
    np.testing.assert_allclose(_shoulder((0, 0), 0.0, -0.8, "r"), _SH_R, atol=1e-12)
    p = PersonScript("p", kfs)
    expect = max(np.linalg.norm(np.subtract(pts[i + 1], pts[i])) / dts[i] for i in range(len(dts)))
    assert p.max_hand_speed() == pytest.approx(expect, rel=1e-6, abs=1e-8)


def _hands_and_reach(p: PersonScript, times):
    """Hand positions (N, 2, 3) and, per hand, -1 / 0 / 1 for a target nearer than RMIN / reached or at rest /
    beyond RMAX (N, 2), from the state and the shoulders written here."""
    hands, codes = [], []
    for t in times:
        segs = p.segments(t)
        hands.append([segs["l_hand"][0], segs["r_hand"][0]])
        base, yaw, lh, rh, _, _ = p.state(t)
        dist = [
            0.5 if h is None else np.linalg.norm(h - _shoulder(base, yaw, p.floor_z, sd))
            for h, sd in ((lh, "l"), (rh, "r"))
        ]
        codes.append([int(r > RMAX) - int(r < RMIN) for r in dist])
    return np.array(hands), np.array(codes)


@settings(max_examples=15, deadline=None)
@given(kfs=scripts(n_min=2, n_max=3, dt_min=0.3, yaw_step=90.0))
@example(  # a stretched arm swept past the body: its speed peaks between samples (read 0.17 % low, documented)
    kfs=[Keyframe(0.0, (1.0, 0.0), right_hand=(0.0, 0.0, 0.0)), Keyframe(0.5, (0.0, 0.0), right_hand=(2.0, 0.0, 0.0))]
)
@example(  # a target leaving the reach: the hand's speed jumps there (found by bisection)
    kfs=[Keyframe(0.0, (0.0, 0.0)), Keyframe(1.0, (0.0, 1.0), right_hand=(0.0, 0.0, 1.0))]
)
def test_max_hand_speed_bounds_finite_differences(kfs):
    """The reported speed is not below finite differences on a grid 8 times finer than ``dt`` within each
    interval (nor on a global one straddling keyframes), less the documented second-order reading of a peak
    between samples, ``s'' dt^2 / 8`` (``s''`` from the fine speeds, doubled for "about"; none across a reach
    change, where the code looks for the speed jump)."""
    p = PersonScript("p", kfs)
    dt, tol, fd = 0.01, 0.0, 0.0
    for a, b in zip([k.t for k in kfs], [k.t for k in kfs[1:]], strict=False):
        times = np.linspace(a, b, math.ceil((b - a) / (dt / 8)) + 1)
        hands, codes = _hands_and_reach(p, times)
        assume(np.all(codes >= 0))  # (no target nearer than RMIN: the documented exception)
        speed = np.linalg.norm(np.diff(hands, axis=0), axis=2) / np.diff(times)[:, None]  # (N-1, 2)
        fd = max(fd, float(speed.max()))
        same = (codes[:-3] == codes[1:-2]) & (codes[1:-2] == codes[2:-1]) & (codes[2:-1] == codes[3:])
        s2 = np.abs(np.diff(speed, 2, axis=0)) / (times[1] - times[0]) ** 2
        tol = max(tol, 2.0 * float(np.max(s2[same], initial=0.0)) * dt**2 / 8)
    reported = p.max_hand_speed(dt)
    assert reported >= fd - tol - 1e-9
    glob = np.arange(kfs[0].t - 0.0037, kfs[-1].t + 0.01, 0.0031)
    assert reported >= _fd_speed(p, glob) - tol - 1e-9


# ------------------------------------------------------------------------------------------- MuJoCo capsules
def _point_segment(p, a, b) -> float:
    d = b - a
    s = 0.0 if d @ d == 0 else min(1.0, max(0.0, (p - a) @ d / (d @ d)))
    return float(np.linalg.norm(p - (a + s * d)))


@pytest.fixture(scope="module")
def capsule_model():
    mujoco = pytest.importorskip("mujoco")
    rest = person_segments(np.zeros(2), 0.0, None, None)
    lines = ['<body name="probe" mocap="true"><geom name="probe" type="sphere" size="0.01"/></body>']
    for name, (a, b) in rest.items():  # as sim.cell builds them: half-lengths from the rest pose
        half = 0.5 * float(np.linalg.norm(b - a))
        g = f'type="sphere" size="{RADIUS[name]}"' if half < 1e-6 else f'type="capsule" size="{RADIUS[name]} {half!r}"'
        lines.append(f'<body name="{name}" mocap="true"><geom name="{name}" {g}/></body>')
    m = mujoco.MjModel.from_xml_string("<mujoco><worldbody>" + "".join(lines) + "</worldbody></mujoco>")
    return mujoco, m, mujoco.MjData(m)


@settings(max_examples=25, deadline=None)
@given(
    base=st.tuples(coord, coord),
    yaw=st.floats(-7.0, 7.0),
    lh=st.one_of(st.none(), st.tuples(*[st.floats(-2.0, 2.0)] * 3)),
    rh=st.one_of(st.none(), st.tuples(*[st.floats(-2.0, 2.0)] * 3)),
    probe=st.tuples(st.floats(-0.5, 0.5), st.floats(-0.5, 0.5), st.floats(-0.2, 1.2)),
)
@example(base=(0.0, 0.0), yaw=0.0, lh=(0.0, 0.2, -1.5), rh=None, probe=(0.0, 0.0, 0.0))  # arm straight down
def test_mujoco_capsules_match_the_segments(capsule_model, base, yaw, lh, rh, probe):
    """Capsules posed by ``segment_pose`` as the cell does: their ``mj_geomDistance`` to a probe sphere is the
    analytic point-segment distance minus the radii (so the true clearances are those of the segments)."""
    mujoco, m, d = capsule_model
    segs = person_segments(np.array(base), yaw, lh, rh)
    for name, (a, b) in segs.items():
        pos, quat = segment_pose(a, b)
        mid = m.body_mocapid[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, name)]
        d.mocap_pos[mid], d.mocap_quat[mid] = pos, quat
    p = np.array([base[0] + probe[0], base[1] + probe[1], probe[2]])
    d.mocap_pos[m.body_mocapid[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "probe")]] = p
    mujoco.mj_forward(m, d)
    fromto = np.zeros(6)
    probe_id = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "probe")
    for name, (a, b) in segs.items():
        g = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, name)
        got = mujoco.mj_geomDistance(m, d, probe_id, g, 10.0, fromto)
        ref = _point_segment(p, a, b) - RADIUS[name] - 0.01
        assert got == pytest.approx(ref, abs=1e-6), name
