"""``depthguard commission``: the background model of a cell's empty workspace, for speed and separation
monitoring (docs/ssm.md, "The runner's background").

SSM protects people, but a depth camera sees the fixed cell (floor, walls, the table the robot stands on) like
any other surface, and the arm's lower control points lie within the protective distance of their own table:
without a background the monitor never lets the arm move. Commissioning records the *empty* cell once — the
robot may stand or move, **nobody may be in the cell** — and writes a background file
(:mod:`depthguard.io.background`): per camera the nearest valid non-robot depth seen over the frames (valid:
finite and at or beyond the camera's ``min_depth``; NaN where no frame gave one; each frame self-filtered with
the joint state of its stamp, as ``depthguard run`` does) among the pixel's *steady* readings (a reading
nearer than the pixel's median by more than the tolerance below came and went: someone passing, robot pixels
the self-filter missed; it would hide everything behind it for good and is left out, and the summary counts
those pixels as ``transient_pixels``) and the tolerance model of the pixel rule
(:mod:`depthguard.robot.background`). The cell file references it with ``[controller] background = "FILE"``;
``depthguard run`` and the distance node apply it when ``ssm = true``.

Frames: ``frames`` frame sets spread evenly over the source's duration (a bag; the simulated scenario), or the
first ``frames`` (a live camera). ``sim:SCENARIO`` is the scenario's cell without its people (its
``remove_people`` variant) with the arm following the scenario's task (a resolved-rate follower without
avoidance: nothing is there to avoid), so that the table behind the arm is seen too. A bag or a live camera
must be recorded with nobody in the cell: DepthGuard cannot tell a person from the background here, and
whatever stands in the cell while commissioning is hidden from the monitor afterwards.

The tolerance model: a simulated camera's own noise coefficient and quantization; for a bag or a live camera
``noise_coeff`` when given, else the camera's ``noise_coeff`` in the cell file, else the one measured from
the frames (per pixel the temporal standard deviation over the frame sets, ``c = median(σ / z²)`` over the
pixels valid in at least 80 % of them; at least 5 frame sets), and the camera's ``depth_scale`` as
quantization; ``margin`` on top (1 cm). The self-filter's margin is ``run``'s
(:func:`depthguard.runner.chain.self_filter_margins`: the cell file's camera ``noise_coeff``).
"""

from __future__ import annotations

import datetime as _dt
import os
import sys
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from depthguard.errors import InputError
from depthguard.io.background import BackgroundFile, write_background
from depthguard.io.cellfile import read_cell
from depthguard.robot.background import BACKGROUND_MARGIN, background_tolerance

__all__ = ["commission_cell", "check_out_file", "COMMISSION_FRAMES"]

#: Frame sets read by default.
COMMISSION_FRAMES = 30


def check_out_file(path: str | Path, what: str = "--out") -> Path:
    """``path`` as a file to write: not a folder, in a folder that exists and is writable; else
    :class:`InputError` naming it (checked before any work)."""
    p = Path(path)
    if p.is_dir():
        raise InputError(f"{what} '{p}' is a folder, expected a file name (e.g. {p / 'background.npz'})")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.exists():
        raise InputError(f"{what} '{p}': the folder '{parent}' does not exist")
    if not parent.is_dir():
        raise InputError(f"{what} '{p}': '{parent}' is not a folder")
    if not os.access(parent, os.W_OK) or (p.exists() and not os.access(p, os.W_OK)):
        raise InputError(f"{what} '{p}': not writable (permission denied)")
    return p


def default_background_path(cell_path: str | Path) -> Path:
    """``<cell>.background.npz`` next to the cell file."""
    return Path(cell_path).with_suffix(".background.npz")


class _Accumulator:
    """Per camera: the valid non-robot readings of every frame (for the background, :meth:`background`), their
    nearest, and the per-pixel moments for the noise. A valid reading is finite, > 0 and at or beyond the
    camera's near limit ``min_depth`` (m): a single spurious reading nearer than that (dust, a flying pixel)
    would otherwise become the pixel's background, and every reading behind it would be hidden from the monitor
    for good. Memory: one float32 image per frame, at most ``MAX_KEPT`` (30 frames of 640x480: 37 MB; 64: 79 MB);
    beyond that a uniform sample of the frames is kept (reservoir sampling, fixed seed): the background from a
    subset of the frames is never nearer than from all of them, the safe side."""

    MAX_KEPT = 64

    def __init__(self, shape: tuple[int, int], min_depth: float = 0.0) -> None:
        self.frames: list[np.ndarray] = []
        self.seen = 0
        self._rng = np.random.default_rng(0)
        self.near = np.full(shape, np.nan, np.float32)
        self.n = np.zeros(shape, np.int32)
        self.s = np.zeros(shape, np.float64)
        self.s2 = np.zeros(shape, np.float64)
        self.min_depth = float(min_depth)

    def add(self, depth: np.ndarray, robot: np.ndarray) -> None:
        """One frame: ``depth`` (H, W) m, ``robot`` (H, W) bool (the self-filter's robot pixels, left out)."""
        d = np.asarray(depth, np.float32)
        if d.shape != self.near.shape or np.shape(robot) != self.near.shape:
            raise ValueError(f"a frame of shape {d.shape} (robot mask {np.shape(robot)}) for {self.near.shape}")
        with np.errstate(invalid="ignore"):
            valid = np.isfinite(d) & (d > 0) & (d >= self.min_depth) & ~np.asarray(robot, bool)
        dn = np.where(valid, d, np.float32(np.nan))
        self.seen += 1
        if len(self.frames) < self.MAX_KEPT:
            self.frames.append(dn)
        else:  # (reservoir sampling: every frame is kept with probability MAX_KEPT / seen)
            j = int(self._rng.integers(0, self.seen))
            if j < self.MAX_KEPT:
                self.frames[j] = dn
        self.near = np.fmin(self.near, dn)
        self.n += valid
        dv = np.where(valid, d, 0.0).astype(np.float64)
        self.s += dv
        self.s2 += dv * dv

    def background(self, noise_coeff: float, quantization: float, margin: float) -> tuple[np.ndarray, int]:
        """(H, W) float32 background depth (m, NaN: none) and the number of pixels where something came and went.

        Per pixel the nearest *steady* valid reading: a reading nearer than the pixel's median valid reading
        ``m`` by more than the background tolerance ``tol(m) = 3 c m² + q + margin`` is something passing in
        front of the background (a person, a flying pixel at the arm's edge, robot pixels the self-filter
        missed) and is left out; the noise of a steady surface stays within it (3 σ). Whatever was in front
        of a pixel in fewer than half of its valid readings is therefore never hidden later: the written
        ``b >= m - tol(m)``, so the rule's threshold ``b - tol(b) >= m - 2 tol(m)``."""
        if not self.frames:
            return self.near.copy(), 0
        stack = np.stack(self.frames)
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # (all-NaN pixels: NaN median, no background)
            med = np.nanmedian(stack, axis=0)
            steady_from = med - background_tolerance(med, noise_coeff, quantization, margin)
            passing = stack < steady_from  # (False for NaN)
        bg = np.fmin.reduce(np.where(passing, np.float32(np.nan), stack), axis=0).astype(np.float32)
        return bg, int(np.count_nonzero(passing.any(axis=0)))

    def noise_coeff(self, frames: int) -> float | None:
        """``median(σ / z²)`` over the pixels valid in >= 80 % of ``frames`` (>= 5); None if not measurable."""
        keep = self.n >= max(5, int(np.ceil(0.8 * frames)))
        if frames < 5 or int(keep.sum()) < 100:
            return None
        n = self.n[keep].astype(float)
        mean = self.s[keep] / n
        var = np.maximum(self.s2[keep] / n - mean * mean, 0.0) * n / (n - 1)
        return float(np.median(np.sqrt(var) / (mean * mean)))


def _sim_follower(src):
    """Commands for the simulated arm: the scenario's task by damped least squares on the end effector
    (no avoidance: the commissioned cell is empty), within the joint limits."""
    kin, dt = src.kin, src.control_dt

    def command(q: np.ndarray, xdot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        J = kin.evaluate(q).jacobians[0]
        qdot = J.T @ np.linalg.solve(J @ J.T + 1e-3 * np.eye(3), np.asarray(xdot, float))
        q_cmd = np.clip(q + qdot * dt, kin.q_min + 0.02, kin.q_max - 0.02)
        return q_cmd, (q_cmd - q) / dt

    return command


def _progress(k: int, n: int, label: str) -> None:
    sys.stderr.write(f"\r{label:<24} frame set {k:3d}/{n}")
    sys.stderr.flush()


def _check_options(frames: int, margin: float, noise_coeff: float | None) -> int:
    """The command's numbers, checked (``InputError`` naming the option); returns ``frames`` as an int."""
    if isinstance(frames, bool) or not isinstance(frames, int | np.integer) or frames < 1:
        if not (isinstance(frames, float | np.floating) and float(frames).is_integer() and frames >= 1):
            raise InputError(f"--frames must be an integer >= 1, got {frames!r}")
    for name, v in (("--margin", margin), ("--noise-coeff", noise_coeff)):
        if v is None and name == "--noise-coeff":
            continue
        number = isinstance(v, int | float | np.integer | np.floating) and not isinstance(v, bool)
        if not (number and np.isfinite(v) and v >= 0):
            raise InputError(
                f"{name} must be a finite number >= 0 ({'m' if name == '--margin' else 'm^-1'}), got {v!r}"
            )
    return int(frames)


def _record(src, cell, model, source: str, frames: int, progress: bool, follow_task: bool):
    """``frames`` frame sets of ``src``, spread over its duration, each self-filtered at its joint state as
    ``run`` does, into one :class:`_Accumulator` per camera; returns them and the count taken."""
    from depthguard.robot.selffilter import self_filter
    from depthguard.runner.chain import self_filter_margins

    follow = _sim_follower(src) if follow_task else None
    cams = list(src.cameras)
    acc = [_Accumulator(c.shape, c.min_depth) for c in cams]
    spacing = float(getattr(src, "duration", np.inf)) / frames  # inf: a live camera, every frame set
    taken, t_first, n_ok = 0, None, len(model.joint_names)
    try:
        for tick in src.ticks():
            t_first = tick.t if t_first is None else t_first
            if follow is not None and tick.q is not None:
                src.command(*follow(tick.q, tick.xdot_d))
            # the robot where the frames saw it: the joint state nearest to their stamps (a bag), as `run` does
            q = tick.q if getattr(tick, "q_frames", None) is None else tick.q_frames
            if tick.frames is None or q is None or np.shape(q) != (n_ok,):
                continue
            if not np.all(np.isfinite(q)) or tick.faults:
                continue
            if np.isfinite(spacing) and tick.t - t_first < taken * spacing - 1e-9:
                continue
            margins = self_filter_margins(cell, cams, q, model) or [None] * len(cams)  # as `run` does
            for a, c, d, m in zip(acc, cams, tick.frames, margins, strict=True):
                if np.shape(d) != c.shape:
                    raise ValueError(f"{source}: a frame of shape {np.shape(d)} for a camera of {c.width}x{c.height}")
                kw = {} if m is None else {"margin": m}
                a.add(d, np.asarray(self_filter(c, d, q, model, **kw, with_depth=False)[0]))
            taken += 1
            if progress:
                _progress(taken, frames, f"commission {source}")
            if taken >= frames:
                break
    finally:
        src.close()
        if progress:
            sys.stderr.write("\n")
    if taken == 0:
        raise ValueError(f"{source}: no frame set with a joint state: nothing to commission from")
    return acc, taken


def _camera_entry(cc, c, a, taken: int, source: str, sim_cam, noise_coeff: float | None, margin: float) -> dict:
    """One camera's part of the summary: its tolerance model (a simulated camera's own noise and quantization;
    otherwise ``--noise-coeff``, the cell file's, or the one measured from the frames) and its figures."""
    measured = a.noise_coeff(taken)
    if sim_cam is not None:
        coeff, quant = float(sim_cam.noise_coeff), float(sim_cam.quantization)
    else:
        coeff = noise_coeff if noise_coeff is not None else (cc.noise_coeff or measured)
        if coeff is None:
            raise ValueError(
                f"{source}: camera '{cc.name}': the depth noise cannot be measured from {taken} frame set(s)"
                " (needs 5 or more with a steady view); give --noise-coeff (sigma = c z^2, e.g. 0.0014 for a"
                " Kinect v1)"
            )
        quant = float(cc.params.get("depth_scale", 0.001))
    a.near, passing = a.background(coeff, quant, margin)  # (what is written: the steady readings' nearest)
    valid = float(np.mean(np.isfinite(a.near)))
    med = float(np.nanmedian(a.near)) if valid > 0 else float("nan")
    return {
        "name": cc.name,
        "width": c.width,
        "height": c.height,
        "valid_fraction": valid,
        "median_depth_m": med,
        "noise_coeff": float(coeff),
        "noise_coeff_measured": measured,
        "quantization_m": quant,
        "margin_m": float(margin),
        "tolerance_at_median_depth_m": 3.0 * float(coeff) * med * med + quant + float(margin),
        "transient_pixels": passing,
    }


LOW_VALID_FRACTION = 0.5  # below this share of pixels with a background, a camera is reported
HIGH_TRANSIENT_FRACTION = 0.02  # above this share of pixels with a passing object, a camera is reported


def commission_warnings(entries: list[dict]) -> list[str]:
    """Warnings about the cameras' summary entries (see :func:`_camera_entry`): a camera with few background
    pixels (covered, or seeing only surfaces beyond its range: nothing is subtracted there, which is safe but
    leaves the cell's fixed objects as obstacles) or with many pixels where something passed (the cell was
    not empty: a person who stood still for half the frames or more is not detected and became background)."""
    out = []
    for e in entries:
        n = e["width"] * e["height"]
        if not e["valid_fraction"] >= LOW_VALID_FRACTION:
            out.append(
                f"camera '{e['name']}': only {100 * e['valid_fraction']:.0f} % of its pixels have a background"
                " (is it covered, or looking past its range?); nothing is subtracted at the others"
            )
        if e["transient_pixels"] > HIGH_TRANSIENT_FRACTION * n:
            out.append(
                f"camera '{e['name']}': something passed through {100 * e['transient_pixels'] / n:.1f} % of its"
                " pixels while recording; commission the cell again when it is empty (anything that stood still"
                " for half the frames or more became background)"
            )
    return out


def commission_cell(
    cell_path: str | Path,
    source: str,
    *,
    frames: int = COMMISSION_FRAMES,
    out: str | Path | None = None,
    quick: bool = False,
    progress: bool = False,
    noise_coeff: float | None = None,
    margin: float = BACKGROUND_MARGIN,
) -> dict[str, Any]:
    """Record the background of the empty cell of ``cell_path`` from ``source`` (``bag:PATH``,
    ``sim:SCENARIO``: its people-free cell, ``realsense``) over ``frames`` frame sets and write it to ``out``
    (default ``<cell>.background.npz``). Returns a JSON-ready summary; raises ``ValueError`` naming the problem."""
    from depthguard.runner import open_source
    from depthguard.runner.carried import refuse_carried_cameras
    from depthguard.runner.chain import load_cell_robot

    t0 = time.perf_counter()
    frames = _check_options(frames, margin, noise_coeff)
    cell = read_cell(cell_path)
    path = check_out_file(out if out is not None else default_background_path(cell.path))
    refuse_carried_cameras(cell, "`depthguard commission`", "the background of a moving camera moves with it")
    model = load_cell_robot(cell)
    links = frozenset(f.name for f in model.model.frames)
    src = open_source(source, cell, model.joint_names, quick=quick, links=links, people=False)
    kind = source.partition(":")[0]
    acc, taken = _record(src, cell, model, source, frames, progress, kind == "sim")
    entries, coeffs, quants = [], [], []
    for k, (cc, c, a) in enumerate(zip(cell.cameras, src.cameras, acc, strict=True)):
        sim_cam = src.cams[k] if kind == "sim" else None
        entry = _camera_entry(cc, c, a, taken, source, sim_cam, noise_coeff, margin)
        entries.append(entry)
        coeffs.append(entry["noise_coeff"])
        quants.append(entry["quantization_m"])
    bg = BackgroundFile(
        names=tuple(c.name for c in cell.cameras),
        depths=tuple(a.near for a in acc),
        noise_coeff=tuple(coeffs),
        quantization=tuple(quants),
        margin=tuple(float(margin) for _ in acc),
        date=_dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        frames=taken,
        source=source,
        valid_fraction=tuple(e["valid_fraction"] for e in entries),
    )
    write_background(path, bg)
    rel = os.path.relpath(path.resolve(), Path(cell.path).resolve().parent)
    return {
        "cell": cell.name,
        "source": source,
        "frames": taken,
        "cameras": entries,
        "warnings": commission_warnings(entries),
        "written": str(path),
        "cell_file_key": f'[controller] background = "{Path(rel).as_posix()}"',
        "wall_s": round(time.perf_counter() - t0, 3),
    }
