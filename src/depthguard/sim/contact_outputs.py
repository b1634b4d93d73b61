"""Figures and recording of the contact experiments (SAPHARI D4.1.1 Figs. 23-28).

* ``contact_<exp>.png``: residual components (Figs. 24 top left, 26), estimated force components with the
  observable part of the true force dashed (Figs. 24 top right, 27), Cartesian displacement of the contact
  point from its position at the onset (Figs. 24 bottom, 28); time 0 is the contact onset.
* ``depth_contact.png``: the depth image at the middle of the push with the estimated force drawn in red
  at the contact point (Figs. 23, 25).
* ``recording.mcap`` (ROS 2 messages, :mod:`depthguard.io.mcap_ros2`): ``/camera0/camera_info``,
  ``/camera0/depth`` (``sensor_msgs/Image`` 16UC1, 320×240, 10 Hz), ``/camera0/contact_overlay`` (rgb8 depth
  image with the force arrow, 10 Hz), ``/joint_states``, ``/residual`` and ``/contact`` (estimated and true
  contact points and forces, detection state; labelled ``std_msgs/Float64MultiArray``) at 100 Hz.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from depthguard.sim.contact_experiment import ContactLog, ExperimentSetup, match_contacts

__all__ = ["write_outputs", "overlay_image"]

FORCE_SCALE = 0.01  # m per N for the drawn arrows (40 N -> 0.4 m)


def _gray(depth: np.ndarray, near: float = 2.3, far: float = 4.5) -> np.ndarray:
    d = np.nan_to_num(depth, nan=far)
    g = (40 + 215 * (1.0 - np.clip((d - near) / (far - near), 0, 1))).astype(np.uint8)
    g[~np.isfinite(depth)] = 0
    return np.repeat(g[..., None], 3, axis=2)


def _line(img: np.ndarray, a: np.ndarray, b: np.ndarray, color=(255, 0, 0), width: int = 1) -> None:
    n = int(max(abs(b[0] - a[0]), abs(b[1] - a[1]), 1)) * 2
    for s in np.linspace(0, 1, n + 1):
        x, y = (1 - s) * a + s * b
        u0, v0 = int(x) - width // 2, int(y) - width // 2
        img[max(v0, 0) : max(v0 + width, 0), max(u0, 0) : max(u0 + width, 0)] = color


def overlay_image(camera, depth: np.ndarray, points: np.ndarray, forces: np.ndarray, step: int = 1) -> np.ndarray:
    """(H/step, W/step, 3) uint8: the depth image in gray with each force (k, 3) N drawn as a red arrow
    from its contact point (k, 3) m."""
    img = _gray(depth[::step, ::step])
    for p, f in zip(np.reshape(points, (-1, 3)), np.reshape(forces, (-1, 3)), strict=True):
        if not np.all(np.isfinite(p)) or np.linalg.norm(f) < 1e-6:
            continue
        a = camera.project(p)[:2] / step
        b = camera.project(p + FORCE_SCALE * f)[:2] / step
        if np.all(np.isfinite(a)) and np.all(np.isfinite(b)):
            _line(img, a, b, width=max(1, 3 // step))
            d = (b - a) / max(np.linalg.norm(b - a), 1e-9)
            for rot in (np.array([[0.87, -0.5], [0.5, 0.87]]), np.array([[0.87, 0.5], [-0.5, 0.87]])):
                _line(img, b, b - 8 / step * (rot @ d), width=max(1, 3 // step))
    return img


def _series(log: ContactLog, key: str, k: int) -> np.ndarray:
    """(T, 3) component k of a per-cycle list of (m, 3) arrays (NaN where absent)."""
    out = np.full((len(log.t), 3), np.nan)
    for i, a in enumerate(getattr(log, key)):
        if len(a) > k:
            out[i] = a[k]
    return out


def _observable_true(log: ContactLog) -> list[np.ndarray]:
    """Per cycle, the observable part P F of the true forces matched to the estimated contacts, (k, 3)."""

    out = []
    for i in range(len(log.t)):
        F, k = log.f_true[i], len(log.f_hat[i])
        if k == 0 or len(log.p_hat[i]) != k:
            out.append(np.zeros((0, 3)))
            continue
        match = match_contacts(log.p_hat[i], log.p_true[i], np.linalg.norm(F, axis=1) > 1.0)
        Fm = np.concatenate([F[j] if j is not None else np.zeros(3) for j in match])
        out.append((log.projector[i] @ Fm).reshape(-1, 3))
    return out


def _plot(path: Path, setup: ExperimentSetup, log: ContactLog, t0: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.array(log.t) - t0
    r = np.array(log.r)
    fig, ax = plt.subplots(3, 1, figsize=(8, 9), sharex=True)
    for j in range(r.shape[1]):
        ax[0].plot(t, r[:, j], label=f"r{j + 1}")
    ax[0].axhline(setup.r_th, color="k", lw=0.5, ls=":")
    ax[0].set_ylabel("residual [N m]")
    ax[0].legend(ncol=7, fontsize=7)
    colors = "rgb"
    pf = _observable_true(log)
    for k in range(max((len(f) for f in log.f_hat), default=0)):
        fh, ft = _series(log, "f_hat", k), np.array([f[k] if len(f) > k else np.full(3, np.nan) for f in pf])
        for c in range(3):
            ax[1].plot(t, fh[:, c], colors[c], ls="-" if k == 0 else "-.", label=f"F̂{'xyz'[c]} #{k + 1}")
            ax[1].plot(t, ft[:, c], colors[c], ls="--", lw=0.8)
        dp = _series(log, "disp", k)
        for c in range(3):
            ax[2].plot(t, dp[:, c], colors[c], ls="-" if k == 0 else "-.", label=f"e{'xyz'[c]} #{k + 1}")
    ax[1].set_ylabel("force [N] (dashed: true, observable part)")
    ax[1].legend(ncol=3, fontsize=7)
    ax[2].set_ylabel("contact point displacement [m]")
    ax[2].set_xlabel("time from contact onset [s]")
    ax[2].legend(ncol=3, fontsize=7)
    fig.suptitle(f"SAPHARI §6.3 {setup.name} admittance, {len(setup.hands)} contact(s), {setup.rate:g} Hz")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _mid_frame(setup: ExperimentSetup, log: ContactLog) -> int:
    tm = setup.hands[0].t_touch + 0.5 * setup.hands[0].duration
    return int(np.argmin([abs(f[0] - tm) for f in log.frames]))


def _cycle_at(log: ContactLog, t: float) -> int:
    return int(np.argmin(np.abs(np.array(log.t) - t)))


def _record(path: Path, setup: ExperimentSetup, log: ContactLog, camera) -> None:
    """The recording as ROS 2 messages: ``/camera0/depth`` (16UC1) and ``/camera0/contact_overlay`` (rgb8,
    the estimated force drawn at the contact point) at 10 Hz, 320 pixels wide, with ``/camera0/camera_info``;
    ``/joint_states``; ``/residual`` and ``/contact`` as labelled ``Float64MultiArray``."""
    from depthguard.io import ros2
    from depthguard.io.mcap_ros2 import Ros2McapWriter

    cam = camera.cam
    st = max(1, cam.width // 320)
    small = cam.strided(st)  # the camera of depth[::st, ::st]
    names = [f"lwr_joint_{i + 1}" for i in range(np.asarray(log.q[0]).size)] if log.q else []
    with Ros2McapWriter(path) as w:
        for n, (t, depth, _) in enumerate(log.frames):
            if n % 3:
                continue
            w.write("/camera0/depth", "sensor_msgs/msg/Image", ros2.image_msg(t, "camera0", depth[::st, ::st]), t)
            w.write("/camera0/camera_info", "sensor_msgs/msg/CameraInfo", ros2.camera_info_msg(t, "camera0", small), t)
            i = _cycle_at(log, t)
            ov = overlay_image(cam, depth, log.p_hat[i], log.f_hat[i], st)
            w.write("/camera0/contact_overlay", "sensor_msgs/msg/Image", ros2.rgb_image_msg(t, "camera0", ov), t)
        every = max(1, int(round(setup.rate / 100)))
        for i in range(0, len(log.t), every):
            t = log.t[i]
            w.write("/joint_states", "sensor_msgs/msg/JointState", ros2.joint_state_msg(t, names, log.q[i]), t)
            res = {"r": log.r[i], "tau_ext_true": log.tau_ext[i], "active": bool(log.active[i])}
            w.write("/residual", "std_msgs/msg/Float64MultiArray", ros2.labelled_array_msg(res), t)
            con = {"points": log.p_hat[i], "forces": log.f_hat[i], "true_points": log.p_true[i],
                   "true_forces": log.f_true[i]}  # fmt: skip
            w.write("/contact", "std_msgs/msg/Float64MultiArray", ros2.labelled_array_msg(con), t)


def write_outputs(out_dir: Path, setup: ExperimentSetup, log: ContactLog, camera, metrics: dict) -> dict[str, str]:
    """Write ``metrics.json``, the figures and ``recording.mcap`` into ``out_dir``; returns their paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    onsets = [o for o in log.onset_true if o is not None]
    files = {
        "plot": str(out_dir / f"contact_{setup.name}.png"),
        "depth": str(out_dir / "depth_contact.png"),
        "recording": str(out_dir / "recording.mcap"),
        "metrics": str(out_dir / "metrics.json"),
    }
    _plot(Path(files["plot"]), setup, log, min(onsets) if onsets else 0.0)
    if log.frames:
        n = _mid_frame(setup, log)
        t, depth, _ = log.frames[n]
        i = _cycle_at(log, t)
        plt.imsave(files["depth"], overlay_image(camera.cam, depth, log.p_hat[i], log.f_hat[i]))
    _record(Path(files["recording"]), setup, log, camera)
    Path(files["metrics"]).write_text(json.dumps(metrics, indent=2, default=float))
    return files
