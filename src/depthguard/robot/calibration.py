"""Camera extrinsics from the arm itself (SAPHARI D4.1.1 §3.3): register the depth points that lie on the
robot to the robot's own surface model, over several arm poses at once.

For every pose i (joint positions ``q_i`` and one depth frame):

1. the surface model ``M_i``: points sampled on the robot's collision geometry at ``q_i`` (world frame),
   only those whose outward normal faces the camera (the surfaces it can see);
2. the measured points ``S_i``: pixels inside the predicted silhouette of the robot (grown by a margin) whose
   depth lies within ``band`` of the predicted depth, back-projected and moved to the world with the current
   estimate of the extrinsics.

One rigid correction ``C`` (world frame) minimises the Generalized-ICP cost summed over all poses:
``sum_i sum_k gicp(M_i, C s_ik)``. The per-point linearisation (correspondences, covariances, Jacobians) is
``small_gicp``'s ``GICPFactor``; the factors of all poses go into one Gauss-Newton system, so that no single
pose's symmetries (a straight arm seen side-on) are left undetermined. Coarse to fine: the selection band and
the correspondence distance shrink over the rounds. The result carries its fitness (inlier RMSE and fraction);
:func:`calibrate_extrinsics` refuses (``accepted=False``) above the thresholds instead of returning a wrong
transform.

A camera carried by a robot link (a sensor on a mobile platform, SAPHARI §3.3, or on an arm link before the
moving joints) is calibrated in that link's frame (``link=``), provided the link stays still over the
poses (the platform parked, the joints up to the link held): then the link frame is one fixed frame of the
world, the world calibration runs in it, and its result is moved into the link frame. A link that moves
between the poses is refused (the background would move with the camera, and the robot pixels could not be
found from the arm's motion alone).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace

import numpy as np

from depthguard.camera import Camera
from depthguard.robot.calibration_checks import (
    MIN_CAMERA_OBSERVABILITY,
    MIN_OBSERVABILITY,
    SAME_POSE_RAD,
    _check_inputs,
    _distinct_poses,
    observability_refusal,
)

__all__ = ["CalibrationResult", "calibrate_extrinsics", "capsule_surface_points", "still_link_pose"]

LINK_STILL_M = 1e-3  # m: a carrying link that moves more than this between the poses is refused
LINK_STILL_RAD = np.deg2rad(0.1)


@dataclass(frozen=True)
class CalibrationResult:
    """Outcome of a calibration.

    Attributes:
        R, t: (3, 3), (3,) the estimated extrinsics (``P_C = R P_W + t``).
        rmse: inlier RMSE of the measured points to the robot surface, m.
        inlier_fraction: share of the selected points within ``inlier_distance`` of the surface.
        n_points: measured points used in the last round (all poses).
        iterations: Gauss-Newton iterations in all rounds.
        accepted: True when ``rmse`` and ``inlier_fraction`` pass the thresholds.
        message: why it was refused, or "ok".
    """

    R: np.ndarray
    t: np.ndarray
    rmse: float
    inlier_fraction: float
    n_points: int
    iterations: int
    accepted: bool
    message: str

    @property
    def camera_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Camera centre (3,) and camera-to-world rotation (3, 3)."""
        return -self.R.T @ self.t, self.R.T


def capsule_surface_points(
    a: np.ndarray, b: np.ndarray, radius: np.ndarray, spacing: float = 0.01
) -> tuple[np.ndarray, np.ndarray]:
    """Points (P, 3) and outward unit normals (P, 3) on the surfaces of capsules (segments ``a``-``b``, (L, 3)
    each, ``radius`` (L,), m), about ``spacing`` m apart."""
    pts, nrm = [], []
    for ai, bi, r in zip(np.asarray(a, float), np.asarray(b, float), np.asarray(radius, float), strict=True):
        axis = bi - ai
        length = float(np.linalg.norm(axis))
        u = axis / length if length > 1e-9 else np.array([0.0, 0.0, 1.0])
        e1 = np.cross(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(u, e1)
        n_phi = max(8, int(np.ceil(2 * np.pi * r / spacing)))
        phi = np.linspace(0, 2 * np.pi, n_phi, endpoint=False)
        ring = np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2  # (n_phi, 3)
        n_len = max(2, int(np.ceil(length / spacing)) + 1)
        s = np.linspace(0.0, length, n_len)
        pts.append((ai + s[:, None, None] * u + r * ring[None]).reshape(-1, 3))
        nrm.append(np.broadcast_to(ring[None], (n_len, n_phi, 3)).reshape(-1, 3))
        n_th = max(2, int(np.ceil(0.5 * np.pi * r / spacing)))
        for centre, sign in ((ai, -1.0), (bi, 1.0)):  # hemispherical caps
            th = np.linspace(0.0, 0.5 * np.pi, n_th + 1)[1:]
            d = (np.cos(th)[:, None, None] * ring[None] + sign * np.sin(th)[:, None, None] * u).reshape(-1, 3)
            pts.append(centre + r * d)
            nrm.append(d)
    return np.concatenate(pts), np.concatenate(nrm)


def _pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """4x4 camera-to-world from extrinsics ``P_C = R P_W + t``."""
    T = np.eye(4)
    T[:3, :3] = R.T
    T[:3, 3] = -R.T @ t
    return T


def _visible_model(camera: Camera, model, q: np.ndarray, spacing: float) -> np.ndarray:
    a, b, r = model.link_capsules(q)
    p, n = capsule_surface_points(a, b, r, spacing)
    facing = np.einsum("ij,ij->i", n, camera.position - p) > 0
    return p[facing]


def moving_pixels(depths: list[np.ndarray], min_change: float = 0.04, noise_coeff: float = 1.4e-3) -> list[np.ndarray]:
    """Robot pixels of each frame found without any pose guess: the background is static across the poses
    and the arm is not, so where a frame reads clearly nearer than the median over all frames (the
    background, when the arm covers the pixel in fewer than half of the frames) it shows the robot.
    "Clearly": by ``min_change`` m or 4 standard deviations of the depth noise ``noise_coeff z^2``, whichever
    is larger. Returns (H, W) bool per frame."""
    D = np.stack([np.where(np.isfinite(d) & (d > 0), d, np.nan) for d in depths]).astype(float)
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a pixel without any reading: its median is NaN
        bg = np.nanmedian(D, axis=0) if np.isfinite(D).any() else np.full(D.shape[1:], np.nan)
        thr = np.maximum(min_change, 4.0 * noise_coeff * bg * bg)
        return [np.nan_to_num(bg - d, nan=0.0) > np.nan_to_num(thr, nan=np.inf) for d in D]


def _select_measured(
    camera: Camera, depth: np.ndarray, model_pts: np.ndarray, band: float, moving: np.ndarray | None = None
) -> np.ndarray:
    """Camera-frame points of ``depth`` (H, W) within ``band`` of the predicted robot surface's depth, inside its
    silhouette grown by ``band`` (in pixels at the predicted depth)."""
    H, W = camera.shape
    pc = camera.world_to_camera(model_pts)
    front = pc[:, 2] > 1e-6
    pc = pc[front]
    u = np.floor(camera.fx * pc[:, 0] / pc[:, 2] + camera.cx).astype(np.int64)
    v = np.floor(camera.fy * pc[:, 1] / pc[:, 2] + camera.cy).astype(np.int64)
    ok = (u >= 0) & (u < W) & (v >= 0) & (v < H)
    pred = np.full((H, W), np.inf)
    np.minimum.at(pred, (v[ok], u[ok]), pc[ok, 2])
    # grow the predicted depth map by the band (in pixels) with a min filter
    from scipy.ndimage import minimum_filter

    finite = pred[np.isfinite(pred)]
    if finite.size == 0:
        return np.zeros((0, 3))
    grow = int(np.ceil(band * camera.fx / max(float(np.median(finite)), 1e-3))) * 2 + 3
    pred_g = minimum_filter(pred, size=grow, mode="constant", cval=np.inf)
    d = np.asarray(depth, float)
    # the min-filtered prediction is the nearest robot surface around the pixel: the measured robot lies from
    # there to one link diameter (<= 0.15 m) behind it
    sel = np.isfinite(d) & (d > 0) & np.isfinite(pred_g) & (d > pred_g - band) & (d < pred_g + band + 0.15)
    if moving is not None:
        sel &= moving
    vv, uu = np.nonzero(sel)
    z = d[vv, uu]
    x = (uu + 0.5 - camera.cx) * z / camera.fx
    y = (vv + 0.5 - camera.cy) * z / camera.fy
    return np.stack([x, y, z], axis=1)  # camera frame


def _gicp_round(
    targets, sources, T0: np.ndarray, max_dist: float, iters: int, kind: str = "GICP"
) -> tuple[np.ndarray, int]:
    """Gauss-Newton over all poses' factors (small_gicp ``GICPFactor`` or point-to-point ``ICPFactor``);
    returns the correction and the iterations."""
    import small_gicp as sg
    from scipy.spatial.transform import Rotation

    factor = sg.GICPFactor() if kind == "GICP" else sg.ICPFactor()
    rej = sg.DistanceRejector()
    rej.set_max_distance(max_dist)
    T = T0.copy()
    it = 0
    for it in range(1, iters + 1):  # noqa: B007 - the count is reported
        Hs, bs = np.zeros((6, 6)), np.zeros(6)
        for (tgt, tree), src in zip(targets, sources, strict=True):
            for i in range(src.size()):
                ok, Hi, bi, _ = factor.linearize(tgt, src, tree, T, i, rej)
                if ok:
                    Hs += Hi
                    bs += np.asarray(bi).ravel()
        if not np.any(Hs):
            break
        delta = np.linalg.solve(Hs + 1e-6 * np.eye(6), -bs)
        dT = np.eye(4)
        dT[:3, :3] = Rotation.from_rotvec(delta[:3]).as_matrix()
        dT[:3, 3] = delta[3:]
        T = T @ dT
        if np.linalg.norm(delta[:3]) < 1e-5 and np.linalg.norm(delta[3:]) < 1e-5:
            break
    return T, it


def _moving_points(camera: Camera, depth: np.ndarray, moving: np.ndarray) -> np.ndarray:
    vv, uu = np.nonzero(moving & np.isfinite(depth))
    z = np.asarray(depth, float)[vv, uu]
    return np.stack([(uu + 0.5 - camera.cx) * z / camera.fx, (vv + 0.5 - camera.cy) * z / camera.fy, z], axis=1)


def still_link_pose(model, link: str, qs: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """World pose ``(R_l (3, 3), p_l (3,))`` of ``link`` over the joint positions ``qs``; ``ValueError`` naming
    the motion when the link moves by more than 1 mm or 0.1 degrees between them."""
    for i, q in enumerate(qs):
        if not np.all(np.isfinite(np.asarray(q, float))):
            raise ValueError(f"the joint state of calibration pose {i} is not finite: {np.asarray(q).tolist()}")
    poses = [model.frame_pose(np.asarray(q, float), link) for q in qs]
    R0, p0 = (np.asarray(a, float) for a in poses[0])
    for i, (R, p) in enumerate(poses[1:], start=1):
        dp = float(np.linalg.norm(np.asarray(p, float) - p0))
        da = float(np.arccos(np.clip((np.trace(np.asarray(R, float) @ R0.T) - 1.0) / 2.0, -1.0, 1.0)))
        if dp > LINK_STILL_M or da > LINK_STILL_RAD:
            raise ValueError(
                f"the camera's link {link!r} moves between the calibration poses (pose {i}: {dp * 1000:.1f} mm,"
                f" {np.rad2deg(da):.2f} deg from pose 0): hold the joints up to it still (park the platform) and"
                " move only the joints after it"
            )
    return R0, p0


def calibrate_extrinsics(
    camera: Camera,
    frames: list[tuple[np.ndarray, np.ndarray]],
    model,
    *,
    link: str | None = None,
    coarse: tuple[float, ...] = (0.8, 0.4, 0.2, 0.1),
    fine: tuple[float, ...] = (0.05, 0.025, 0.012),
    spacing: float = 0.008,
    max_points_per_pose: int = 1200,
    inlier_distance: float = 0.01,
    max_rmse: float = 0.006,
    min_inlier_fraction: float = 0.6,
    iterations: int = 15,
    seed: int = 0,
    min_observability: float = MIN_OBSERVABILITY,
    min_camera_observability: float = MIN_CAMERA_OBSERVABILITY,
) -> CalibrationResult:
    """Estimate the extrinsics of ``camera`` (its pose is the initial guess) from ``frames``.

    Coarse rounds (point-to-point ICP, correspondence distances ``coarse``) use the pixels that the arm's
    motion reveals (:func:`moving_pixels`), so no background enters them whatever the initial guess; fine
    rounds (GICP, ``fine``) keep those of them within the distance of the predicted robot surface.

    Args:
        camera: intrinsics and the initial guess of the extrinsics (``P_C = R P_W + t``; with ``link``,
            ``P_C = R P_L + t`` in the link's frame, and so is the result).
        frames: ``(depth (H, W) m, q (n,))`` per arm pose; at least 5 (``ValueError``), of which at least 5
            distinct (else refused, "too few poses": two configurations in six frames were accepted 40 mm
            off) that move the arm widely (so that
            every pixel shows the background in some frame) and break its symmetries.
        model: the :class:`depthguard.robot.model.RobotModel` (its collision capsules are the surface model).
        link: None for a camera fixed in the world, or the robot link that carries it; that link must stay
            still over the poses (:func:`still_link_pose`, else ``ValueError``).
        spacing: surface sampling of the model, m. max_points_per_pose: measured points kept per pose.
        inlier_distance, max_rmse, min_inlier_fraction: the acceptance test.
        min_observability: the result is also refused (``"refused: degenerate geometry ..."``) when the robot
            surface seen leaves a direction of the camera pose undetermined (:func:`_observability`: e.g. only
            straight links all parallel to one axis, which slide along it unseen), whatever its fitness.
        min_camera_observability: the result is also refused (``"refused: the robot seen fixes the camera's
            position poorly ..."``) when the same measure taken with rotations about the camera centre is below
            this: the robot small or at the image's edge, where turning the camera and shifting it keep the seen
            surface in place (:func:`~depthguard.robot.calibration_checks.observability_refusal`; accepted results
            were 18 mm off at 0.0004).

    ``ValueError`` (naming the frame or the setting) for a depth image that is not ``camera.shape``, a joint
    state that is not finite or not of the model's joints, and settings that are not positive finite numbers.
    """
    _check_inputs(camera, frames, model, locals())
    if link is not None:  # the link frame is a fixed world frame here: calibrate in the world, move back
        settings = {k: v for k, v in locals().items() if k not in ("camera", "frames", "model", "link")}
        return _in_link_frame(camera, frames, model, link, settings)
    if len(frames) < 5:
        raise ValueError(f"calibration needs at least 5 arm poses, got {len(frames)}")
    n_distinct = _distinct_poses([q for _, q in frames])
    if n_distinct < 5:  # (with fewer, a fit can look good and be centimetres off)
        return CalibrationResult(
            np.asarray(camera.R, float), np.asarray(camera.t, float), np.inf, 0.0, 0, 0, False,
            f"refused: too few poses: {n_distinct} distinct arm poses among {len(frames)} frames (at least 5 that"
            f" differ by {SAME_POSE_RAD} rad or more in some joint are needed)",
        )  # fmt: skip
    rng = np.random.default_rng(seed)
    moving = moving_pixels([d for d, _ in frames])
    R, t = np.asarray(camera.R, float), np.asarray(camera.t, float)
    total_it, n_pts = 0, 0
    for k, band in enumerate((*coarse, *fine)):
        T_wc = _pose(R, t)
        keep = max_points_per_pose // 3 if k < len(coarse) else max_points_per_pose
        targets, sources = _round_clouds(
            camera.with_pose(R, t), frames, moving, model, band if k >= len(coarse) else None, keep, spacing, rng
        )
        if len(sources) < 3:
            return CalibrationResult(R, t, np.inf, 0.0, 0, total_it, False, "refused: too few poses show the robot")
        kind = "ICP" if k < len(coarse) else "GICP"
        C, it = _gicp_round(targets, sources, np.eye(4), max_dist=band, iters=iterations, kind=kind)
        total_it += it
        T_new = C @ T_wc
        R, t = T_new[:3, :3].T, -T_new[:3, :3].T @ T_new[:3, 3]
        n_pts = sum(s.size() for s in sources)
    rmse, frac = _fitness(camera.with_pose(R, t), frames, model, spacing, fine[-1], inlier_distance, moving)
    ok = rmse <= max_rmse and frac >= min_inlier_fraction
    message = _verdict(ok, rmse, frac, max_rmse, min_inlier_fraction)
    if ok:
        seen = _seen_surface(camera.with_pose(R, t), frames, model, spacing, inlier_distance, moving)
        refusal = observability_refusal(
            *seen, camera.with_pose(R, t).position, min_observability, min_camera_observability
        )
        ok, message = (False, refusal) if refusal else (ok, message)
    return CalibrationResult(R, t, float(rmse), float(frac), int(n_pts), total_it, bool(ok), message)


def _seen_surface(cam: Camera, frames, model, spacing: float, inlier: float, moving) -> tuple[np.ndarray, np.ndarray]:
    """The measured robot points (P, 3) in the world that lie within ``inlier`` m of the robot model's surface
    facing the camera, over all poses, and the model's outward unit normals (P, 3) there."""
    from scipy.spatial import cKDTree

    T_wc = _pose(cam.R, cam.t)
    S, N = [np.zeros((0, 3))], [np.zeros((0, 3))]
    for (depth, q), mv in zip(frames, moving, strict=True):
        a, b, r = model.link_capsules(np.asarray(q, float))
        p, n = capsule_surface_points(a, b, r, spacing * 0.5)
        facing = np.einsum("ij,ij->i", n, cam.position - p) > 0
        p, n = p[facing], n[facing]
        s_c = _moving_points(cam, depth, mv)
        if len(s_c) == 0 or len(p) == 0:
            continue
        s_w = s_c @ T_wc[:3, :3].T + T_wc[:3, 3]
        d, idx = cKDTree(p).query(s_w)
        keep = d < inlier
        S.append(s_w[keep])
        N.append(n[idx[keep]])
    return np.concatenate(S), np.concatenate(N)


def _round_clouds(cam: Camera, frames, moving, model, band: float | None, keep: int, spacing: float, rng):
    """Per pose, the robot surface model (``small_gicp`` target and tree) and the measured points in the world
    (source) of one round: the motion-revealed pixels (``band`` None: coarse rounds) or those of them within
    ``band`` of the predicted surface (fine rounds), at most ``keep`` per pose. Poses with fewer than 20 points
    on either side are left out."""
    import small_gicp as sg

    T_wc = _pose(cam.R, cam.t)
    targets, sources = [], []
    for (depth, q), mv in zip(frames, moving, strict=True):
        m = _visible_model(cam, model, np.asarray(q, float), spacing)
        s_c = _moving_points(cam, depth, mv) if band is None else _select_measured(cam, depth, m, band, mv)
        if len(s_c) > keep:
            s_c = s_c[rng.choice(len(s_c), keep, replace=False)]
        if len(s_c) < 20 or len(m) < 20:
            continue
        tgt, tree = sg.preprocess_points(m, downsampling_resolution=spacing * 0.5, num_neighbors=10)
        s_w = s_c @ T_wc[:3, :3].T + T_wc[:3, 3]
        src, _ = sg.preprocess_points(s_w, downsampling_resolution=1e-4, num_neighbors=10)
        targets.append((tgt, tree))
        sources.append(src)
    return targets, sources


def _verdict(ok: bool, rmse: float, frac: float, max_rmse: float, min_frac: float) -> str:
    if ok:
        return "ok"
    return (
        f"refused: inlier RMSE {rmse * 1000:.1f} mm (max {max_rmse * 1000:.1f}) and inlier fraction {frac:.2f}"
        f" (min {min_frac:.2f}); start closer to the true pose or add poses, and keep everything but the arm"
        " still over the poses (a person walking through the view moves like the arm)"
    )


def _in_link_frame(camera: Camera, frames, model, link: str, opts: dict) -> CalibrationResult:
    """:func:`calibrate_extrinsics` of a camera on a still ``link`` (extrinsics in the link's frame)."""
    R_l, p_l = still_link_pose(model, link, [q for _, q in frames])
    R_w = np.asarray(camera.R, float) @ R_l.T  # P_C = R P_L + t with P_L = R_lᵀ (P_W - p_l)
    world = calibrate_extrinsics(camera.with_pose(R_w, np.asarray(camera.t, float) - R_w @ p_l), frames, model, **opts)
    return replace(world, R=world.R @ R_l, t=world.t + world.R @ p_l)  # P_C = R_w (R_l P_L + p_l) + t_w


def _fitness(cam: Camera, frames, model, spacing: float, band: float, inlier: float, moving) -> tuple[float, float]:
    from scipy.spatial import cKDTree

    d_all = []
    T_wc = _pose(cam.R, cam.t)
    for (depth, q), mv in zip(frames, moving, strict=True):
        m = _visible_model(cam, model, np.asarray(q, float), spacing * 0.5)
        s_c = _moving_points(cam, depth, mv)
        if len(s_c) == 0:
            continue
        s_w = s_c @ T_wc[:3, :3].T + T_wc[:3, 3]
        d_all.append(cKDTree(m).query(s_w)[0])
    if not d_all:
        return np.inf, 0.0
    d = np.concatenate(d_all)
    inl = d < inlier
    if not inl.any():
        return np.inf, 0.0
    return float(np.sqrt(np.mean(d[inl] ** 2))), float(inl.mean())
