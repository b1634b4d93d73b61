"""Speed and separation monitoring in the simulated cell: the monitor's record, its metrics and its plot.

Metrics only: the pipeline never sees anything computed here. :class:`SsmRecorder` wraps the simulated
controller (:class:`depthguard.sim.pipeline.Controller` with SSM on) and records, every control cycle, the
monitor's output (:class:`depthguard.control.ssm.SsmOutput`) and the *true* separation ``S_true`` of every
control point: the distance from its sphere (the controller's model at the true joint positions) to the
nearest obstacle geom of the simulator (:func:`sphere_clearance`; left out: the table, which carries the
robot and lies outside the monitored workspace, and the scenarios' fixed boxes, fixtures that the monitor's
background model holds: SSM protects people).

:func:`ssm_metrics` turns the record into the JSON keys of the ``--ssm`` scenarios:

* ``min_separation_margin``: min of ``S_true - S_p`` over the points and over the cycles in which the
  monitor allowed motion (``MONITOR_OK`` or ``REDUCED``), m; ``>= 0`` is the monitor's claim; null when the
  monitor never allowed motion or when nobody it protects is in the scene (``S_true`` = inf, e.g.
  ``icra-exp3``, whose only obstacle is a fixture of the background); NaN when a compared ``S_true`` or
  ``S_p`` is NaN (never hidden: likewise the true separations below);
* ``time_reduced_s`` / ``time_stopped_s``: time in ``REDUCED`` / ``PROTECTIVE_STOP``;
* ``protective_stops``, ``resumed`` (a stop ended and the robot moved again), the binding point, the
  largest ``S_p`` seen, the true separation while the robot moved (``..._while_moving``: any motion, the
  evading stop's backing away included; ``..._while_allowed``: motion the monitor allowed, ``MONITOR_OK`` or
  ``REDUCED``), and the SSM parameters with sources.
"""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from depthguard.control.ssm import MonitorState, SsmConfig, reaction_time

__all__ = ["sphere_clearance", "SsmRecorder", "ssm_metrics", "ssm_parameters", "plot_ssm", "PARAMETER_SOURCES"]

PARAMETER_SOURCES = {
    "v_h_near": "ISO 13855 §6.2: 2.0 m/s where S_p <= 0.5 m",
    "v_h_far": "ISO 13855 §6.2: 1.6 m/s beyond 0.5 m",
    "near_limit": "ISO 13855 §6.2: 0.5 m",
    "v_h_floor": "ISO 13855 walking speed: floor under a measured obstacle speed",
    "camera_period": "depth camera frame period (30 Hz Kinect / RealSense)",
    "processing_latency": "self-filter + distance stage (2-6 ms measured at 640x480 in the simulated cell; 10 ms)",
    "communication_latency": "transport between the stages (0: one process)",
    "control_period": "one controller cycle (1 kHz)",
    "intrusion": "C: ISO 13855 §6.3, 8 (d - 14) mm with d = 20 mm (a finger lost to 4 px hole filling at 3 m)",
    "sensor_uncertainty": "Z_d: 3 sigma Kinect depth noise at 3 m (Khoshelham & Elberink 2012) + 1 cm bound tolerance",
    "robot_uncertainty": "Z_r: joint encoder and kinematic calibration error at the tool",
    "hysteresis": "a protective stop ends when S >= S_p + hysteresis for every point",
    "sensing_range": "range of the monitor's distances: [avoidance] ssm_range, default max(rho, 0.6 m) (the "
    "repulsion keeps rho); +inf counts as this",
}

_PLANE, _HFIELD, _SPHERE, _CAPSULE, _ELLIPSOID, _CYLINDER, _BOX, _MESH = range(8)  # mjtGeom


def sphere_clearance(model, data, geoms: np.ndarray, centres: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """True clearance (N,) m from each sphere (``centres`` (N, 3), ``radii`` (N,)) to the nearest of ``geoms``.

    Exact for sphere, capsule, box and plane geoms (negative = penetration depth, exact for spheres, capsules
    and planes, a lower bound inside boxes); cylinders count as the capsule around them, ellipsoids as their
    bounding sphere, and meshes and height fields as their bounding box (``geom_aabb``), which under-reports
    (the safe side for a margin). Reads ``data.geom_xpos`` and ``geom_xmat`` as they are (call
    ``mj_kinematics`` first when the state changed). ``inf`` if no geom.

    Raises:
        ValueError: ``geoms`` not integer geom ids in ``[0, ngeom)``, a geom of another type (SDF), ``centres``
            not (N, 3) or ``radii`` not (N,) with no negative radius.
    """
    g = np.asarray(geoms)
    if g.size == 0:
        g = np.zeros(0, int)
    elif g.ndim != 1 or g.dtype.kind not in "iu" or g.min() < 0 or g.max() >= model.ngeom:
        raise ValueError(f"geoms must be a (G,) array of integer geom ids in [0, {model.ngeom}), got {geoms!r}")
    return _clearance(model, g, data.geom_xpos[g], data.geom_xmat[g].reshape(-1, 3, 3), centres, radii)


def _spheres(centres, radii) -> tuple[np.ndarray, np.ndarray]:
    """``centres`` as (N, 3) and ``radii`` as (N,) floats; ValueError naming the one of another form."""
    c, r = np.asarray(centres, float), np.asarray(radii, float)
    if c.ndim != 2 or c.shape[1] != 3:
        raise ValueError(f"centres must be an (N, 3) array of sphere centres in m, got shape {c.shape}")
    if r.shape != (len(c),) or (r < 0).any():  # (a NaN radius passes: its clearance reads NaN)
        raise ValueError(f"radii must be an ({len(c)},) array of radii >= 0 m (one per centre), got {radii!r}")
    return c, r


def _clearance(model, g, pos, mat, centres, radii) -> np.ndarray:
    """:func:`sphere_clearance` with the geoms' world positions (G, 3) and rotations (G, 3, 3) given."""
    c, r = _spheres(centres, radii)
    best = np.full(len(c), np.inf)
    if len(g) == 0:
        return best - r
    kind = model.geom_type[g]
    count = np.bincount(kind, minlength=_MESH + 1)  # geoms per mjtGeom type
    if len(count) > _MESH + 1:  # (mjtGeom 0..7 are these; 8 is an SDF)
        k = int(np.argmax(kind > _MESH))
        raise ValueError(
            "geoms must be plane, hfield, sphere, capsule, ellipsoid, cylinder, box or mesh geoms, got geom "
            f"{int(g[k])} of mjtGeom type {int(kind[k])}"
        )
    for types, fn, field in _SHAPES:
        if count[types[0]] or count[types[-1]]:
            sel = (kind == types[0]) | (kind == types[-1])
            best = np.minimum(best, fn(c, pos[sel], mat[sel], getattr(model, field)[g[sel]]).min(axis=1))
    return best - r


def _to_spheres(c, pos, mat, size):
    """Distance (N, G) to sphere geoms (``size[:, 0]`` their radii)."""
    return np.linalg.norm(c[:, None, :] - pos[None], axis=2) - size[None, :, 0]


def _to_bounding(c, pos, mat, rbound):
    return np.linalg.norm(c[:, None, :] - pos[None], axis=2) - rbound[None, :]


def _to_planes(c, pos, mat, size):
    """Signed distance (N, G) to MuJoCo planes: infinite, solid below, normal along the local z axis."""
    return np.einsum("ngi,gi->ng", c[:, None, :] - pos[None], mat[:, :, 2])


def _to_aabbs(c, pos, mat, aabb):
    """Distance (N, G) to the geoms' bounding boxes (``geom_aabb`` (G, 6): centre and half sizes, geom frame)."""
    return _to_boxes(c, pos + np.einsum("gij,gj->gi", mat, aabb[:, :3]), mat, aabb[:, 3:])


def _to_capsules(c, pos, mat, size):
    axis = mat[:, :, 2]  # local z in world
    half = size[:, 1]
    rel = c[:, None, :] - pos[None]  # (N, G, 3)
    s = np.clip(np.einsum("ngi,gi->ng", rel, axis), -half[None], half[None])
    return np.linalg.norm(rel - s[..., None] * axis[None], axis=2) - size[None, :, 0]


def _to_boxes(c, pos, mat, size):
    rel = c[:, None, :] - pos[None]
    local = np.abs(np.einsum("ngi,gij->ngj", rel, mat))  # world -> box frame: R^T rel
    q = local - size[None, :, :3]
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=2)
    return outside + np.minimum(q.max(axis=2), 0.0)


# (geom types, distance (N, G) from points to those geoms, never above the truth, and the model's field that
# it reads per geom)
_SHAPES = (
    ((_SPHERE,), _to_spheres, "geom_size"),
    ((_CAPSULE, _CYLINDER), _to_capsules, "geom_size"),
    ((_BOX,), _to_boxes, "geom_size"),
    ((_ELLIPSOID,), _to_bounding, "geom_rbound"),
    ((_PLANE,), _to_planes, "geom_size"),
    ((_MESH, _HFIELD), _to_aabbs, "geom_aabb"),
)


class SsmRecorder:
    """Wraps a simulated :class:`~depthguard.sim.pipeline.Controller` and records the monitor every cycle.

    Has the wrapped controller's ``step`` (same arguments and result); everything else is passed through.

    Args:
        ctrl: the controller (built with ``ssm=True``).
        cell: the simulated cell (ground truth for the metrics only).
        exclude: obstacle geoms left out of ``S_true`` (the table: the robot's mount; the scenarios add the
            fixed boxes, which the monitor's background holds).
    """

    def __init__(self, ctrl, cell, exclude: tuple[str, ...] = ("table",), frame_period: float = 1.0 / 30.0) -> None:
        self.ctrl, self.cell = ctrl, cell
        self.ssm_config = getattr(getattr(ctrl, "_c", None), "config", None)
        self.ssm_config = getattr(self.ssm_config, "ssm", None) or SsmConfig()
        self.geoms = np.array([g for g in cell.obstacle_geoms if cell.geom_names[g] not in exclude], int)
        keys = ("t", "state", "scale", "binding", "dist", "s_p", "s_true", "s_capture", "qd")
        self.rows: dict[str, list] = {k: [] for k in keys}
        self.frame_period = frame_period
        self._next_frame = 0.0
        self._frames: list[tuple[float, np.ndarray, np.ndarray]] = []  # (t, pos, mat) of the obstacle geoms

    def __getattr__(self, name: str):
        return getattr(self.ctrl, name)

    def step(self, t, q, qd, xdot, cp, distances, directions, t_distances, avoid: bool = True, **monitor):
        """The wrapped controller's step (``monitor``: its ``monitor_distances`` / ``monitor_directions``);
        records the cycle (see the class docstring)."""
        import mujoco

        res = self.ctrl.step(t, q, qd, xdot, cp, distances, directions, t_distances, avoid, **monitor)
        out = self.ctrl.last_output
        m = getattr(out, "ssm", None)
        mujoco.mj_kinematics(self.cell.model, self.cell.data)  # mocap poses of time t (set before the step)
        r = self.rows
        r["t"].append(t)
        r["state"].append(-1 if m is None else int(m.state))
        r["scale"].append(0.0 if m is None else float(m.scale))
        r["binding"].append(-1 if m is None else int(m.binding))
        N = len(cp.radii)
        r["dist"].append(np.full(N, np.nan) if m is None else np.array(m.separation, float))
        r["s_p"].append(np.full(N, np.nan) if m is None else np.array(m.s_p, float))
        m_, d_ = self.cell.model, self.cell.data
        r["s_true"].append(sphere_clearance(m_, d_, self.geoms, cp.centres, cp.radii))
        if t >= self._next_frame - 1e-9:  # the loop's frame schedule: the obstacles as the cameras saw them
            self._next_frame += self.frame_period
            self._frames = [*self._frames[-3:], (t, d_.geom_xpos[self.geoms].copy(), d_.geom_xmat[self.geoms].copy())]
        seen = [f for f in self._frames if f[0] <= t_distances + 1e-9]
        if seen:  # the frame behind the distances of this cycle
            _, pos, mat = seen[-1]
            r["s_capture"].append(_clearance(m_, self.geoms, pos, mat.reshape(-1, 3, 3), cp.centres, cp.radii))
        else:
            r["s_capture"].append(np.full(N, np.nan))
        r["qd"].append(float(np.max(np.abs(out.qdot_cmd))) if out is not None else 0.0)
        return res

    def arrays(self) -> dict[str, np.ndarray]:
        """The record as arrays: t (T,), state (T,), scale (T,), binding (T,), dist/s_p/s_true/s_capture (T, N),
        qd (T,)."""
        return {k: np.asarray(v) for k, v in self.rows.items()}


def ssm_parameters(cfg: SsmConfig | None = None) -> dict[str, Any]:
    """The SSM parameters with their values and sources, and the reaction time T_r they give (JSON-ready)."""
    cfg = cfg or SsmConfig()
    vals = asdict(cfg)
    out: dict[str, Any] = {k: {"value": v, "source": PARAMETER_SOURCES.get(k, "")} for k, v in vals.items()}
    out["reaction_time_s"] = {
        "value": reaction_time(cfg),
        "source": "max(camera period, age of the distances) + processing + communication + control period"
        " (from the capture)",
    }
    out["C_plus_Zd_plus_Zr"] = cfg.constant_terms
    return out


def ssm_metrics(rec: SsmRecorder, dt: float, names: tuple[str, ...], cfg: SsmConfig | None = None) -> dict[str, Any]:
    """The ``--ssm`` metrics of one run (module docstring) from the recorder of that run."""
    cfg = cfg or rec.ssm_config
    a = rec.arrays()
    state, s_true, s_p = a["state"], a["s_true"], a["s_p"]
    allowed = (state == MonitorState.MONITOR_OK) | (state == MonitorState.REDUCED)
    with np.errstate(invalid="ignore"):  # (inf - inf: NaN, never hidden)
        margin = s_true - s_p
        cap = np.where(allowed[:, None], a["s_capture"] - s_p, np.inf)
    per_point = np.where(allowed[:, None], margin, np.inf).min(axis=0) if len(state) else np.array([])
    k = int(np.argmin(per_point)) if _seen(per_point) else -1  # (argmin: the first NaN, if any)
    stopped = state == MonitorState.PROTECTIVE_STOP
    starts = np.flatnonzero(stopped[1:] & ~stopped[:-1]) + 1
    ends = np.flatnonzero(~stopped[1:] & stopped[:-1]) + 1
    moving = a["qd"] > 1e-3
    resumed = any(np.any(moving[e:] & allowed[e:]) for e in ends)
    sep = s_true.min(axis=1) if len(state) else np.array([])
    cap = np.where(np.isnan(cap), np.inf, cap)
    return {
        "ssm": True,
        "min_separation_margin": float(per_point[k]) if k >= 0 else None,
        "binding_point": names[k] if k >= 0 else None,
        "min_separation_margin_at_capture": float(cap.min()) if _seen(cap) else None,
        "time_reduced_s": float(np.sum(state == MonitorState.REDUCED) * dt),
        "time_stopped_s": float(np.sum(stopped) * dt),
        "protective_stops": int(len(starts) + (1 if len(state) and stopped[0] else 0)),
        "resumed": bool(resumed),
        "min_scale": float(a["scale"][allowed].min()) if allowed.any() else 0.0,
        "max_s_p": float(np.nanmax(s_p)) if np.isfinite(s_p).any() else None,
        "min_true_separation": _finite_min(sep),
        "min_true_separation_while_moving": _finite_min(sep[moving]) if moving.any() else None,
        # moving with the task allowed (an evading stop also moves the arm, away from whoever came near)
        "min_true_separation_while_allowed": _finite_min(sep[moving & allowed]) if (moving & allowed).any() else None,
        "ssm_parameters": ssm_parameters(cfg),
    }


def _seen(x: np.ndarray) -> bool:
    """Whether ``x`` holds anything but ``+inf`` (nobody in the scene): a value, ``-inf`` or NaN."""
    return bool(np.any(~(np.asarray(x) == np.inf)))


def _finite_min(x: np.ndarray) -> float | None:
    """The minimum of ``x`` (m) as a float; None when ``x`` is empty or all ``+inf`` (nobody in the scene; JSON
    has no inf). NaN when ``x`` holds a NaN and ``-inf`` when it holds ``-inf``: an unknown or impossible
    separation is never hidden behind None or behind the smaller of the others."""
    return float(np.min(x)) if _seen(x) else None


def plot_ssm(out_dir: str | Path, rec: SsmRecorder, names: tuple[str, ...], point: str | None, title: str) -> str:
    """``ssm.png``: true and measured separation and S_p of the binding point over time, the monitor's state
    and scale below; the whole record next to it as ``ssm_record.npz``. Returns the png's path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    a = rec.arrays()
    k = names.index(point) if point in names else 0
    t = a["t"]
    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(8, 5.5), sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    ax.plot(t, a["s_true"][:, k], "k-", lw=1.5, label="S_true (simulator)")
    ax.plot(t, np.where(np.isfinite(a["dist"][:, k]), a["dist"][:, k], np.nan), "b-", lw=0.8, label="S measured")
    ax.plot(t, a["s_p"][:, k], "r-", lw=1.2, label="S_p (ISO/TS 15066)")
    for val, col in ((MonitorState.REDUCED, "orange"), (MonitorState.PROTECTIVE_STOP, "red")):
        on = a["state"] == val
        ax.fill_between(t, 0, 1, where=on, color=col, alpha=0.15, transform=ax.get_xaxis_transform(), lw=0)
    top = np.nanmax(a["s_p"][:, k]) if np.isfinite(a["s_p"][:, k]).any() else 1.0
    ax.set_ylim(min(0.0, float(np.nanmin(a["s_true"][:, k]))), 2.5 * top)
    ax.set_ylabel("separation [m]")
    ax.set_title(f"{title}: control point {names[k]} (orange: reduced, red: protective stop)", fontsize=9)
    ax.legend(fontsize=7, loc="upper right")
    ax2.plot(t, a["scale"], "g-")
    ax2.set_ylabel("SSM scale")
    ax2.set_xlabel("t [s]")
    ax2.set_ylim(-0.05, 1.05)
    fig.tight_layout()
    path = Path(out_dir) / "ssm.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    np.savez_compressed(Path(out_dir) / "ssm_record.npz", names=np.array(names), **a)
    return str(path)
