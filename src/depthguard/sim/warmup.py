"""Compile the numba kernels of the simulated pipeline once, in parallel, before a run.

The first run on a new machine compiles every numba kernel (about a minute on a 2-core machine); numba
caches the machine code on disk (``cache=True``) so later runs load it in well under a second. Compiled
lazily inside the run, the kernels would compile one after the other, on one core, with nothing on screen.
:func:`compile_in_background` instead starts one process per kernel group (fusion, single-camera depth
space, robot + controller); each calls the public API once on a tiny scene with the dtypes and layouts of
the real run, so numba writes exactly the specialisations that the run then loads from its cache. The
caller keeps building its scene meanwhile and calls :meth:`BackgroundCompile.wait` before the loop starts.

Run ``python -m depthguard.sim.warmup [GROUP ...]`` to compile by hand (e.g. after an install).
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

__all__ = ["GROUPS", "BackgroundCompile", "compile_in_background", "is_cached", "warm"]


def _cameras(n: int):
    from depthguard.camera import Camera, look_at

    eyes = [(1.75, -0.95, 1.5), (-0.75, 1.85, 1.5)][:n]
    out = []
    for eye in eyes:
        R, t = look_at(np.array(eye), np.array([0.0, 0.0, 0.35]))
        out.append(
            Camera(width=40, height=30, fx=33.0, fy=33.0, cx=20.0, cy=15.0, R=R, t=t, min_depth=0.5, max_depth=4.5)
        )
    return out


def _frame_inputs(cameras) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """float32 depth images with holes and bool robot masks, as the simulated cameras and self-filter give."""
    depths, masks = [], []
    for cam in cameras:
        d = np.full(cam.shape, 2.5, dtype=np.float32)
        d[5:20, 10:25] = 1.8
        d[0, :5] = np.nan
        m = np.zeros(cam.shape, dtype=bool)
        m[12:18, 14:20] = True
        depths.append(d)
        masks.append(m)
    return depths, masks


def _points() -> tuple[np.ndarray, np.ndarray]:
    centres = np.array([[0.5, 0.2, 0.55], [0.3, 0.0, 0.6], [0.1, 0.1, 0.3]])
    return centres, np.array([0.12, 0.08, 0.06])


def _warm_fusion() -> None:
    from concurrent.futures import ThreadPoolExecutor

    from depthguard.depthgrid import DepthGridFusion
    from depthguard.robot.model import load_lwr4

    cams = _cameras(2)
    fusion = DepthGridFusion(cams, dd=0.01, workspace=(-1.2, 1.2, -1.2, 1.2, -0.3, 1.5))
    depths, masks = _frame_inputs(cams)
    fusion.update(depths, masks)
    centres, radii = _points()
    with ThreadPoolExecutor(1) as side:  # (the query shared with a side thread: its own kernels)
        for mode in ("min", "all", "hybrid"):
            fusion.query(centres, radii, rho=0.4, mode=mode, alpha=6.0)
            fusion.query(centres, radii, rho=0.4, mode=mode, alpha=6.0, side=side)
    model = load_lwr4()
    _warm_frame_corrections(cams[0], depths[0], masks[0], model, np.array([0.0, -0.3, 0.0, 1.6, 0.0, -0.8, 0.0]))


def _warm_depthspace() -> None:
    from depthguard.depthspace import prepare_frame, query_distances

    cam = _cameras(1)[0]
    depths, masks = _frame_inputs([cam])
    frame = prepare_frame(cam, depths[0], masks[0])
    centres, radii = _points()
    for mode in ("min", "all", "hybrid"):
        query_distances(frame, centres, radii, rho=0.4, mode=mode, alpha=6.0)


def _warm_frame_corrections(cam, depth, mask, model, q) -> None:
    """The per-frame kernels of the simulated pipeline outside the fusion: the robot-interior corrections
    (:mod:`depthguard.robot.interior`) and the simulated Kinect's projector shadow."""
    from depthguard.robot.interior import interior_capsules, principal_robot_pixels, robot_windows
    from depthguard.sim.depthcam import projector_shadow

    a, b, r = interior_capsules(model, q)
    principal_robot_pixels(cam, depth, mask, a, b, r, margin=0.03)
    robot_windows(cam, a, b, r, margin=0.03)
    projector_shadow(np.where(np.isfinite(depth), depth, np.inf).astype(np.float64), float(cam.fx), 0.075)


def _warm_robot() -> None:
    from depthguard.control import AvoidanceController, ControllerConfig, CycleInput
    from depthguard.robot.control_points import ControlPointSet
    from depthguard.robot.model import load_lwr4
    from depthguard.robot.selffilter import self_filter

    model = load_lwr4()
    q = np.array([0.0, -0.3, 0.0, 1.6, 0.0, -0.8, 0.0])
    cam = _cameras(1)[0]
    self_filter(cam, _frame_inputs([cam])[0][0], q, model)
    for preset in ("ral-9", "icra-exp3"):
        points = ControlPointSet.build(model, preset)
        cps = points.evaluate(q)
        ctrl = AvoidanceController(points, ControllerConfig(rho_body=0.3))
        n = cps.centres.shape[0]
        qdot = np.zeros(7)
        for k, d in enumerate((np.full(n, np.inf), np.full(n, 0.05), np.linspace(0.01, 0.5, n))):
            t = 1e-3 * k
            dirs = np.tile([0.0, 0.0, 1.0], (n, 1))
            out = ctrl.step(CycleInput(t, q, qdot, t, np.array([0.3, -0.2, 0.1]), d, dirs, t))
            q, qdot = out.q_cmd, out.qdot_cmd


#: Where each group's kernels live (package folders or modules under ``depthguard/``), for :func:`is_cached`.
SOURCES: dict[str, tuple[str, ...]] = {
    "fusion": ("depthgrid", "depthspace.py", "kernels", "robot/interior.py", "sim/depthcam.py"),
    "depthspace": ("depthspace.py", "kernels/pixels.py"),
    "robot": ("robot", "control"),
}

#: Kernel groups, compiled in parallel processes.
GROUPS: dict[str, Callable[[], None]] = {
    "fusion": _warm_fusion,
    "depthspace": _warm_depthspace,
    "robot": _warm_robot,
}


def _root():
    from pathlib import Path

    return Path(__file__).resolve().parent.parent


def _stamp_path(group: str):
    return _root() / "__pycache__" / f"depthguard-warmup-{group}.json"


def _group_state(group: str) -> dict:
    """Modification times of the group's sources and the numba cache index files beside them."""
    root = _root()
    files = []
    for rel in SOURCES[group]:
        p = root / rel
        files += sorted(p.rglob("*.py")) if p.is_dir() else [p]
    sources = {str(f.relative_to(root)): f.stat().st_mtime_ns for f in files if f.is_file()}
    cache = os.environ.get("NUMBA_CACHE_DIR")  # depthguard.kernelcache: one folder per version of the sources
    if cache:
        stems = {f.stem for f in files}
        index = sorted(str(i.relative_to(cache)) for i in Path(cache).rglob("*.nbi") if i.name.split(".")[0] in stems)
    else:
        index = sorted(
            str(i.relative_to(root)) for f in files for i in (f.parent / "__pycache__").glob(f"{f.stem}.*.nbi")
        )
    return {"sources": sources, "index": index}


def is_cached(group: str) -> bool:
    """True when ``group`` was compiled by this module since its sources last changed and its cache index
    files are still there (``NUMBA_CACHE_DIR``, see :mod:`depthguard.kernelcache`, or numba's default
    ``__pycache__`` beside the modules). A wrong
    False costs a few seconds (the child processes load the cache and exit); a wrong True (caches kept
    elsewhere) means lazy compilation inside the run, as without this module."""
    import json

    try:
        stamp = json.loads(_stamp_path(group).read_text())
    except (OSError, ValueError):
        return False
    now = _group_state(group)
    return stamp.get("sources") == now["sources"] and set(stamp.get("index", [])) <= set(now["index"])


def _write_stamp(group: str) -> None:
    import json

    try:
        _stamp_path(group).parent.mkdir(exist_ok=True)
        _stamp_path(group).write_text(json.dumps(_group_state(group)))
    except OSError:
        pass  # a read-only install: numba caches elsewhere, and the warm-up simply runs each time


def warm(groups: list[str] | None = None) -> None:
    """Compile (or load from the cache) the kernels of ``groups`` in this process (all by default)."""
    for name in groups or list(GROUPS):
        GROUPS[name]()


class BackgroundCompile:
    """Kernel compilation running in child processes (see :func:`compile_in_background`)."""

    def __init__(self, procs: dict[str, subprocess.Popen], t0: float) -> None:
        self.procs, self.t0 = procs, t0

    def wait(self, announce: Callable[[str], None] | None = None) -> float:
        """Wait until every group has compiled; return the seconds since the start. A group that failed is
        reported through ``announce`` and left to compile lazily in the run itself."""
        for name, p in self.procs.items():
            _, err = p.communicate()
            if p.returncode != 0 and announce is not None:
                last = (err or b"").decode(errors="replace").strip().splitlines()[-1:]
                announce(f"(background compilation of {name!r} failed: {last}; compiling in the run instead)")
        return time.perf_counter() - self.t0


def compile_in_background(groups: list[str] | None = None) -> BackgroundCompile:
    """Start one process per kernel group; returns at once. Warm caches make each process take ~2 s."""
    env = dict(os.environ)
    src = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    env["PYTHONPATH"] = os.pathsep.join(p for p in (src, env.get("PYTHONPATH", "")) if p)
    procs = {
        name: subprocess.Popen(
            [sys.executable, "-m", "depthguard.sim.warmup", name],
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
        )
        for name in groups or list(GROUPS)
    }
    return BackgroundCompile(procs, time.perf_counter())


if __name__ == "__main__":
    for _group in sys.argv[1:] or list(GROUPS):
        warm([_group])
        _write_stamp(_group)
