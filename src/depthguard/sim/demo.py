"""``make demo``: the RA-L'16 hexagon experiment in the simulated cell, avoidance on and off.

Runs ``ral-hexagon`` with two Kinects twice (avoidance on, with a progress bar, and off, in a second
process beside it when the machine has two cores or more), then prints a table comparing true minimum
clearance, collision steps, path error, task completion, stage rates and how close the evaluated distances
stay to the truth (max over-report, median under-report, phantom-contact time), and the paths of the plots
and recordings.

The first run on a new machine compiles the numba kernels first, in parallel processes, and says so
(:mod:`depthguard.sim.warmup`); they are cached on disk for later runs.

To keep it short on a 2-core machine the demo renders the depth images at the scenario's
``demo_resolution``, 320x240 (the Kinect's field of view at half its resolution; a 640x480 frame costs
about 15-20 ms per camera here with the room cast once, :mod:`depthguard.sim.raysplit`, and the fusion's
frame stage and queries grow with the pixels too), for ``demo_duration`` seconds of simulated time.
Everything else (rates, noise model, controller, fusion) is as in the full scenario.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import mujoco  # noqa: F401  (ImportError here lets the CLI fall back to the static demo)

__all__ = ["run_demo"]


def _get(res: dict, key: str | tuple[str, str]):
    """``res[key]``, or ``res[key[0]][key[1]]`` for a nested key; None where missing."""
    if isinstance(key, tuple):
        return (res.get(key[0]) or {}).get(key[1])
    return res.get(key)


def _fmt(v, unit: str = "", nd: int = 3) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.{nd}f}{unit}"
    return f"{v}{unit}"


def _cpu_halves() -> tuple[set[int], set[int]] | None:
    """The CPUs this process may use, in two halves: one for each run of the demo (each run's distance stage
    then uses the CPUs of its own half, :func:`depthguard.sidethread.usable_cpus`, instead of both runs
    competing for all of them). None where there are fewer than two or affinity is not supported."""
    try:
        allowed = sorted(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return None
    if len(allowed) < 2:
        return None
    half = len(allowed) // 2
    return set(allowed[:half]), set(allowed[half:])


def _set_cpus(cpus: set[int] | None) -> None:
    """This thread's CPUs (and those of the threads it starts), where the system allows it."""
    if cpus:
        try:
            os.sched_setaffinity(0, cpus)
        except OSError:
            pass


def _second_process(cpus: set[int] | None = None):
    """A one-worker process pool (spawned: a forked MuJoCo/numba process is not safe) on ``cpus``, or None."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    try:
        return ProcessPoolExecutor(
            max_workers=1, mp_context=multiprocessing.get_context("spawn"), initializer=_set_cpus, initargs=(cpus,)
        )
    except (OSError, ValueError):  # no process support here: run one after the other
        return None


def _compile_kernels(groups: list[str]) -> None:
    """First run only: compile the numba kernels in parallel processes, saying so (:mod:`.warmup`)."""
    from depthguard.sim.warmup import compile_in_background, is_cached

    cold = [g for g in groups if not is_cached(g)]
    if not cold:
        return
    print(
        f"First run: compiling the numba kernels ({', '.join(cold)}) in {len(cold)} parallel processes; "
        "this happens once, the machine code is cached on disk for later runs (about a minute on 2 cores) ...",
        flush=True,
    )
    bg = compile_in_background(cold)
    seconds = bg.wait(announce=lambda msg: print(msg, file=sys.stderr, flush=True))
    print(f"kernels compiled in {seconds:.0f} s\n", flush=True)


def run_demo(out_dir: str | Path | None = None) -> int:
    """Run the demo; return 0 when the avoidance run is collision-free and the run without avoidance
    collides (the demo shows what it claims), 1 otherwise."""
    from depthguard.sim.scenarios import run_scenario

    out = Path(out_dir) if out_dir is not None else Path("runs") / "demo"
    t0 = time.perf_counter()
    print("DepthGuard demo: RA-L'16 hexagon task, two simulated Kinects 4 m apart, a person carrying a box")
    print("(depth images 320x240 for speed; 1 kHz control, 30 Hz cameras, distance stage every 3 ms)\n")
    _compile_kernels(["fusion", "robot"])
    kwargs = dict(quick=True, cameras=2, variants=False, demo=True)
    # the run without avoidance goes to a second process (2 cores or more): the demo takes the time of one run;
    # each run on its half of the CPUs
    first, second = _cpu_halves() or (None, None)
    pool = _second_process(second) if (os.cpu_count() or 1) >= 2 else None
    mine = os.sched_getaffinity(0) if first else None
    off_job = None
    if pool is not None:
        _set_cpus(first)
        off_job = pool.submit(run_scenario, "ral-hexagon", avoidance=False, out_dir=out / "avoidance_off", **kwargs)
        print("(the run without avoidance runs beside it in a second process)", flush=True)
    try:
        on = run_scenario("ral-hexagon", avoidance=True, out_dir=out / "avoidance_on", progress=True, **kwargs)
        if off_job is not None:
            print("waiting for the run without avoidance ...", flush=True)
            off = off_job.result()
        else:
            off = run_scenario("ral-hexagon", avoidance=False, out_dir=out / "avoidance_off", progress=True, **kwargs)
    finally:
        if pool is not None:
            pool.shutdown(cancel_futures=True)
        _set_cpus(mine)
    rows = [
        ("true min clearance [m]", "min_clearance", "", 3),
        ("collision steps (1 ms)", "collision_steps", "", 0),
        ("time below 5 cm [s]", "time_below_margin_s", "", 2),
        ("path error RMS [m]", "path_error", "", 3),
        ("path error max [m]", "path_error_max", "", 3),
        ("task completion", "task_completion", "", 2),
        ("distance stage [Hz] median", "distance_hz_median", "", 0),
        ("distance stage [Hz] p99", "distance_hz_p99", "", 0),
        ("control cycle p99 [ms]", "control_ms_p99", "", 3),
        ("frame stage median [ms]", "frame_ms_median", "", 1),
        ("eval. vs true: max over-report [m]", "max_over_report", "", 3),
        ("eval. vs true: median under-report [m]", "median_under_report", "", 3),
        ("  of which unmeasured by any camera [m]", ("measured_bound", "median_unmeasured_under_report"), "", 3),
        ("  added by the fusion [m]", ("measured_bound", "median_excess_under_report"), "", 3),
        ("phantom contact (eval. 0, true > 5 cm) [s]", "time_at_zero_s", "", 2),
        ("wall time [s]", "wall_seconds", "", 1),
    ]
    print()
    print(f"{'':44s} {'avoidance ON':>14s} {'avoidance OFF':>14s}")
    for label, key, unit, nd in rows:
        print(f"{label:44s} {_fmt(_get(on, key), unit, nd):>14s} {_fmt(_get(off, key), unit, nd):>14s}")
    print(
        f"(over-report tolerance declared by the fusion: {_fmt(on.get('declared_tolerance'), ' m', 3)}; "
        "README: how the distances are computed)"
    )
    if (on.get("time_at_zero_s") or 0.0) > 0:
        print(
            "phantom contact with two cameras: a control sphere crossed space that neither camera measures "
            "(docs/phantom-zero.md);\n  `depthguard scenario ral-hexagon --cameras 3` adds a third camera."
        )
    for name, res in (("avoidance ON", on), ("avoidance OFF", off)):
        print(f"\n{name}: {res['out_dir']}")
        for k, v in res.get("files", {}).items():
            print(f"  {k:14s} {v}")
    ok = on["collision_steps"] == 0 and off["collision_steps"] > 0
    print(
        f"\ndemo finished in {time.perf_counter() - t0:.0f} s: "
        + (
            "avoidance kept the robot clear; without it the robot hit the box."
            if ok
            else "UNEXPECTED RESULT (see the metrics above)."
        )
    )
    sys.stdout.flush()
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(run_demo())
