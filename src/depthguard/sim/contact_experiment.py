"""The loop of the contact experiments (SAPHARI D4.1.1 §6.3): torque-controlled arm, Kinect, hands.

At the control rate (200 Hz by default, the paper's 5 ms cycle):

1. the joint controller of :class:`~depthguard.sim.contact_cell.ContactCell` runs the physics over one
   period with the last joint-velocity command and reports the mean motor torque τ;
2. the momentum residual (:class:`~depthguard.robot.residual.MomentumObserver`, exact model: the
   simulator and the observer share inertias, armature and damping) gives r; the detector thresholds it;
3. at 30 Hz a depth frame (640×480, Kinect v1 model, 2.8 m behind the robot at 1.6 m height) is
   self-filtered, the foreground found against the background image, and the hands located
   (:func:`~depthguard.robot.contact_point.locate_hands`); each hand's contact point is its nearest robot
   surface vertex (Algorithm 1), held fixed on its link between frames;
4. while a contact is detected, F̂ = (J_cᵀ)^# r (stacked for two hands) drives the admittance at the
   contact points, the end effector held in the null space; before the first contact the arm runs a fast
   end-effector circle (free motion, for false detections), after release the springs bring the contact
   points back.

Depth frames are ray cast (and given the sensor model) only inside the image box of the robot grown by
0.3 m; pixels outside it are copied from one noisy frame of the static background: the hand search
never looks there, and it keeps a 640×480 run within seconds.
"""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import dataclass, field

import numpy as np

from depthguard.control.admittance import SOFT, STIFF, AdmittanceParams, ContactAdmittance
from depthguard.robot.contact_force import estimate_contact_forces, point_jacobian
from depthguard.robot.contact_point import RobotSurface, contact_from_hand, foreground_mask, image_box, locate_hands
from depthguard.robot.residual import ContactDetector, MomentumObserver, RigidBodyDynamics
from depthguard.robot.selffilter import self_filter
from depthguard.sim.contact_cell import ContactCell, HandScript
from depthguard.sim.depthcam import KinectSim, cast_rays, kinect_camera

__all__ = ["ExperimentSetup", "ContactLog", "make_setup", "run_experiment", "match_contacts", "Q0"]

Q0 = (0.0, -1.1, 0.0, 1.5, 0.0, -0.9, 0.0)
CAMERA_EYE, CAMERA_TARGET = (-2.8, 0.0, 1.6), (0.3, 0.0, 0.45)


@dataclass
class ExperimentSetup:
    """One experiment: admittance parameters, hands, timing and observer settings."""

    name: str
    params: AdmittanceParams
    hands: list[HandScript]
    t_end: float
    t_free: float = 0.6
    rate: float = 200.0
    gain: float = 100.0
    r_th: float = 1.0
    free_radius: float = 0.06
    width: int = 640
    height: int = 480
    fps: float = 30.0
    seed: int = 0


def make_setup(name: str, contacts: int = 1, quick: bool = False, rate: float | None = None) -> ExperimentSetup:
    """Experiment 1 (``"soft"``: a hand pushes link 6 sideways for 0.74 s) or 2 (``"stiff"``: a hand
    pushes link 3 down along z for 5 s, 1.5 s with ``quick``); ``contacts=2`` adds a second hand on
    another link (link 3 for soft, link 6 for stiff) at the same time."""
    if name not in ("soft", "stiff"):
        raise ValueError(f"experiment must be 'soft' or 'stiff', got {name!r}")
    if contacts not in (1, 2):
        raise ValueError(f"contacts must be 1 or 2, got {contacts!r}")
    t_touch = 1.15
    side6 = HandScript("hand0", "lwr_link_6", 0.5, (0.0, 1.0, 0.0), 20.0, t_touch, 0.74, approach=0.1, v_approach=0.25)
    if name == "soft":
        hands = (
            [side6]
            if contacts == 1
            else [
                side6,
                HandScript(
                    "hand1", "lwr_link_3", 0.45, (0.0, 1.0, 0.0), 25.0, t_touch, 0.74, approach=0.1, v_approach=0.25
                ),
            ]
        )
        return ExperimentSetup("soft", SOFT, hands, t_end=t_touch + 0.74 + (1.2 if quick else 2.5), rate=rate or 200.0)
    hold = 1.5 if quick else 5.0
    push = HandScript("hand0", "lwr_link_3", 0.5, (0.0, 0.0, -1.0), 40.0, t_touch, hold, approach=0.1, v_approach=0.25)
    hands = (
        [push]
        if contacts == 1
        else [
            push,
            HandScript("hand1", "lwr_link_6", 0.5, (0.0, 1.0, 0.0), 20.0, t_touch, hold, approach=0.1, v_approach=0.25),
        ]
    )
    return ExperimentSetup("stiff", STIFF, hands, t_end=t_touch + hold + (0.6 if quick else 1.0), rate=rate or 200.0)


@dataclass
class ContactLog:
    """Everything recorded at the control rate (lists of arrays), plus the depth frames."""

    t: list = field(default_factory=list)
    q: list = field(default_factory=list)
    r: list = field(default_factory=list)
    tau_ext: list = field(default_factory=list)
    active: list = field(default_factory=list)
    label: list = field(default_factory=list)
    f_hat: list = field(default_factory=list)  # (k, 3) per cycle, k = number of estimated contacts
    f_true: list = field(default_factory=list)  # (h, 3) per hand
    p_hat: list = field(default_factory=list)  # (k, 3)
    p_true: list = field(default_factory=list)  # (h, 3)
    links_hat: list = field(default_factory=list)
    links_true: list = field(default_factory=list)
    projector: list = field(default_factory=list)
    n_unobservable: list = field(default_factory=list)
    disp: list = field(default_factory=list)  # (k, 3) admittance displacement of the contact points
    ee: list = field(default_factory=list)
    frames: list = field(default_factory=list)  # (t, depth (H, W) float32, hand positions)
    onset_true: list = field(default_factory=list)  # per hand: first physics time with |F| > 1 N
    timing: dict = field(default_factory=dict)


def _background(cell: ContactCell, sim: KinectSim) -> np.ndarray:
    """Exact depth of the static cell, without the robot and the hands (the tracker's background model;
    a real cell would take, e.g., the per-pixel farthest reading over frames with the robot moving)."""
    from depthguard.sim.depthcam import raycast_depth

    groups = np.ones(6, np.uint8)
    groups[1] = groups[2] = 0  # robot, people
    return raycast_depth(cell.model, cell.data, sim.camera, geomgroup=groups)


class _Camera:
    """Kinect frames ray cast in the robot's image box only, background elsewhere (module docstring)."""

    def __init__(self, cell: ContactCell, setup: ExperimentSetup) -> None:
        self.cam = kinect_camera(CAMERA_EYE, CAMERA_TARGET, width=setup.width, height=setup.height)
        self.sim = KinectSim(cell.model, self.cam, seed=setup.seed)
        self.cell = cell
        self.bg = _background(cell, self.sim)
        self.rays = self.sim._rays.reshape(-1, 3)
        z = np.nan_to_num(self.bg, nan=self.cam.max_depth)
        self.bg_margin = 0.03 + 4 * self.sim.noise_coeff * z * z  # 4 σ of the axial noise, plus 3 cm
        with np.errstate(invalid="ignore"):
            self.bg_frame = self.sim.sensor_effects(self.bg)

    def capture(self, spheres: np.ndarray, radii: np.ndarray) -> np.ndarray:
        """One depth frame (H, W) float32: ray cast and sensor model inside the robot's box grown by 0.3 m,
        a fixed noisy background frame outside it."""
        from depthguard.robot.contact_point import image_box

        cam = self.cam
        out = self.bg_frame.copy()
        u0, u1, v0, v1 = image_box(cam, spheres, radii + 0.3) or (0, 0, 0, 0)
        if u1 > u0 and v1 > v0:
            idx = (np.arange(v0, v1)[:, None] * cam.width + np.arange(u0, u1)[None, :]).ravel()
            dist = cast_rays(self.cell.model, self.cell.data, cam.position, self.rays[idx])[0]
            with np.errstate(invalid="ignore"):  # inf - inf at missing pixels in the edge test
                out[v0:v1, u0:u1] = self.sim.sensor_effects(dist.reshape(v1 - v0, u1 - u0))
        return out


def _contact_truth(cell: ContactCell) -> tuple[np.ndarray, np.ndarray, list[str]]:
    cs = cell.mean_contacts  # averaged over the control period, like the motor torque
    return np.array([c[0] for c in cs]), np.array([c[1] for c in cs]), [c[2] for c in cs]


def _free_target(setup: ExperimentSetup, ee0: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
    """End-effector circle (x-z plane) during the free-motion phase: position and velocity."""
    if t >= setup.t_free:
        return ee0, np.zeros(3)
    T, rad = setup.t_free, setup.free_radius
    x = t / T
    s = 2 * math.pi * x * x * x * (10 - 15 * x + 6 * x * x)  # smooth 0 -> 2π
    sd = 2 * math.pi * 30 * x * x * (1 - x) ** 2 / T
    off = rad * np.array([math.cos(s) - 1.0, 0.0, math.sin(s)])
    vel = rad * sd * np.array([-math.sin(s), 0.0, math.cos(s)])
    return ee0 + off, vel


def _set_contacts(adm: ContactAdmittance, surf: RobotSurface, q: np.ndarray, cps: list) -> None:
    """Give the admittance the contact points (vertices fixed on their links) posed at ``q``."""
    R, p = surf.model.joint_poses(q)
    world = [R[surf.joint[c.vertex]] @ c.local + p[surf.joint[c.vertex]] for c in cps]
    adm.set_contacts(q, [c.link for c in cps], world)


def _frame(camera: _Camera, surf: RobotSurface, q: np.ndarray, n_hands: int, log: ContactLog, t: float):
    """One depth frame: capture, self-filter, foreground, hands near the robot. Returns (vertices, hands)."""
    V, S = surf.pose(q)
    depth = camera.capture(S, surf.axis_radii)
    sf = self_filter(camera.cam, depth, q, surf.model, with_depth=False)
    box = image_box(camera.cam, S, surf.axis_radii + 0.2)
    fg = foreground_mask(depth, camera.bg, sf.mask, camera.bg_margin, box=box)
    hands = [h for h in locate_hands(camera.cam, depth, fg, S, surf.axis_radii, n_hands) if h.distance < 0.1]
    log.frames.append((t, depth, [h.position for h in hands]))
    return V, hands


def _log_cycle(log: ContactLog, cell: ContactCell, adm: ContactAdmittance, q, r, state, f_hat, truth, P, n_un) -> None:
    """Append one control cycle to the log."""
    robot = cell.robot
    f_true, p_true, l_true = truth
    log.t.append(cell.t)
    log.q.append(q)
    log.r.append(r)
    log.tau_ext.append(cell.tau_ext())
    log.active.append(state.active)
    log.label.append(state.label)
    log.f_hat.append(np.array(f_hat, copy=True))
    log.f_true.append(f_true)
    log.p_true.append(p_true)
    log.links_true.append(l_true)
    Rj, pj = robot.joint_poses(q)
    log.p_hat.append(np.array([Rj[c.joint] @ c.local + pj[c.joint] for c in adm.contacts]).reshape(-1, 3))
    log.links_hat.append([c.link for c in adm.contacts])
    log.projector.append(P)
    log.n_unobservable.append(n_un)
    log.disp.append(adm.errors() if adm.contacts else np.zeros((0, 3)))
    log.ee.append(robot.frame_pose(q)[1])


def run_experiment(setup: ExperimentSetup, progress: bool = False) -> tuple[ContactLog, ContactCell, _Camera]:
    """Run one experiment; returns the log, the cell and the camera (for outputs)."""
    cell = ContactCell(setup.hands, kinect_camera(CAMERA_EYE, CAMERA_TARGET, width=64, height=48), np.array(Q0))
    camera = _Camera(cell, setup)
    robot = cell.robot
    dt = 1.0 / setup.rate
    n_sub = max(1, round(dt / cell.model.opt.timestep))
    dt = n_sub * cell.model.opt.timestep
    obs = MomentumObserver(RigidBodyDynamics(robot, np.full(7, cell.armature), cell.damping), setup.gain, dt, "average")
    det = ContactDetector(r_th=setup.r_th)
    adm = ContactAdmittance(robot, setup.params)
    surf = RobotSurface(robot, spacing=0.01)
    n_hands = len(setup.hands)
    log = ContactLog()
    log.onset_true = [None] * n_hands
    q = cell.q()
    obs.update(q, cell.qd(), np.zeros(7))
    ee0 = robot.frame_pose(q)[1]
    qd_cmd = np.zeros(7)
    hands_seen: list = []
    contacts: list = []  # ContactPoint candidates (vertices fixed on their links)
    next_frame, t_frame, t_ctrl = 0.0, [], []
    steps = int(round(setup.t_end / dt))
    for _k in range(steps):
        tau = cell.step(qd_cmd, n_sub)
        t, q, qd = cell.t, cell.q(), cell.qd()
        c0 = time.perf_counter()
        r = obs.update(q, qd, tau)
        f_true, p_true, l_true = _contact_truth(cell)
        if t + 1e-9 >= next_frame:  # a depth frame (30 Hz)
            f0 = time.perf_counter()
            V, hands_seen = _frame(camera, surf, q, n_hands, log, t)
            t_frame.append(time.perf_counter() - f0)
            c0 += t_frame[-1]
            next_frame += 1.0 / setup.fps
            # candidate contact points (Algorithm 1); in contact they follow a hand that slides, and a
            # hand hidden from the camera keeps its last contact point
            cps = [contact_from_hand(surf, q, V, h.position) for h in hands_seen]
            if not det.active or len(cps) >= len(adm.contacts):
                contacts = cps
            if det.active and contacts:
                _set_contacts(adm, surf, q, contacts)
        hand_d = min((h.distance for h in hands_seen), default=None)
        state = det.step(r, dt, hand_d)
        if state.onset and contacts:
            _set_contacts(adm, surf, q, contacts)
        f_hat = np.zeros((len(adm.contacts), 3))
        P, n_un = np.eye(3 * max(1, len(adm.contacts))), 0
        if state.active and adm.contacts:
            R, p = robot.joint_poses(q)
            Js = [point_jacobian(robot, q, c.link, R[c.joint] @ c.local + p[c.joint]) for c in adm.contacts]
            est = estimate_contact_forces(Js, r)
            f_hat, P, n_un = est.forces, est.projector, est.unobservable.shape[1]
        ee_t, ee_v = _free_target(setup, ee0, t)
        if state.active and not adm.contacts:
            qd_cmd = np.zeros(7)  # contact but no contact point: stop (safety)
        else:
            qd_cmd = adm.step(q, f_hat, ee_t, dt, ee_v)
            if not state.active and adm.contacts and adm.settled():
                adm.clear()
                f_hat, P = np.zeros((0, 3)), np.eye(3)
        t_ctrl.append(time.perf_counter() - c0)
        _log_cycle(log, cell, adm, q, r, state, f_hat, (f_true, p_true, l_true), P, n_un)
        if progress and _k % int(setup.rate) == 0:
            print(f"  t = {t:5.2f} s  |r| = {np.linalg.norm(r):6.2f} N m  contact = {state.active}", flush=True)
    log.onset_true = list(cell.onset)
    log.timing = {
        "frame_ms_median": 1e3 * float(np.median(t_frame)) if t_frame else None,
        "control_us_median": 1e6 * float(np.median(t_ctrl)),  # residual, detection, estimate, admittance
        "control_us_p99": 1e6 * float(np.percentile(t_ctrl, 99)),
    }
    return log, cell, camera


def match_contacts(p_hat: np.ndarray, p_true: np.ndarray, touching: np.ndarray) -> list[int | None]:
    """For each estimated contact, the touching hand assigned to it (or None): the assignment with the
    smallest total distance (few contacts: all permutations)."""
    hands = [int(j) for j in np.flatnonzero(touching)]
    k = len(p_hat)
    cands = hands + [None] * k
    best, best_cost = [None] * k, np.inf
    for perm in set(itertools.permutations(cands, k)):
        if all(j is None for j in perm) and hands:
            continue
        n_none = sum(j is None for j in perm)
        if n_none > max(k - len(hands), 0):
            continue
        cost = sum(float(np.linalg.norm(p_true[j] - p_hat[a])) for a, j in enumerate(perm) if j is not None)
        if cost < best_cost:
            best, best_cost = list(perm), cost
    return best
