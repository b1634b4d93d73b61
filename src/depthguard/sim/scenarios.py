"""Scenarios: the papers' experiments as data files, run end to end, with metrics, plots and a recording.

A scenario is a TOML file in ``depthguard/data/scenarios/`` (see ``README.md`` there for the fields):
camera placement, robot start, control points, avoidance parameters, the end-effector task, boxes and
keyframed people. :func:`run_scenario` builds the cell, runs the three-rate loop
(:mod:`depthguard.sim.loop`) and returns the metrics as one JSON-ready dict; with ``out_dir`` it also
writes ``metrics.json``, the plots and ``recording.mcap`` there.

Metrics: :mod:`depthguard.sim.scenario_metrics`.
"""

from __future__ import annotations

import copy
import json
import time
import tomllib
from importlib import resources
from pathlib import Path
from typing import Any

from depthguard.sim.scenario_metrics import compute_metrics, ssm_keys
from depthguard.sim.scenario_setup import build_scenario_cell, scenario_task, with_ssm_cameras

__all__ = ["list_scenarios", "load_scenario", "run_scenario", "compute_metrics"]


def _scenario_dir():
    return resources.files("depthguard").joinpath("data/scenarios")


def list_scenarios() -> list[str]:
    """Names of the shipped scenarios."""
    return sorted(p.name[:-5] for p in _scenario_dir().iterdir() if p.name.endswith(".toml"))


def load_scenario(name_or_path: str | Path) -> dict[str, Any]:
    """Read a scenario by name (shipped) or path (.toml) and check every field
    (:func:`~depthguard.sim.scenario_schema.validate_scenario`).

    Raises:
        InputError: (a ``ValueError``) one line naming the file and the problem.
    """
    from depthguard.errors import InputError
    from depthguard.io.files import check_input_file
    from depthguard.sim.scenario_schema import validate_scenario

    p = Path(name_or_path)
    if p.suffix == ".toml" or len(p.parts) > 1:
        source = str(check_input_file(p, "scenario"))
        raw = p.read_bytes()
    else:
        ref = _scenario_dir().joinpath(f"{name_or_path}.toml")
        if not ref.is_file():
            raise InputError(f"unknown scenario {str(name_or_path)!r}; known: {list_scenarios()} or a .toml file")
        source, raw = f"scenario {str(name_or_path)!r} ({ref})", ref.read_bytes()
    try:
        data = tomllib.loads(raw.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise InputError(f"{source}: not UTF-8 text (byte {exc.start}): expected TOML") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{source}: bad TOML: {exc}") from None
    validate_scenario(data, source)
    return data


def _set_path(d: dict, dotted: str, value: Any) -> None:
    keys = dotted.split(".")
    for k in keys[:-1]:
        d = d.setdefault(k, {})
    d[keys[-1]] = value


def _run_one(
    sc: dict,
    *,
    quick: bool,
    avoidance: bool,
    cameras: int | None,
    progress: bool,
    label: str,
    seed: int = 0,
    demo: bool = False,
    camera_backend: str = "auto",
    backend: str = "depthspace",
    octree_res: float = 0.05,
    ssm: bool = False,
    setup=None,
    view: int | None = None,
):
    from depthguard.sim.depthcam import KinectSim
    from depthguard.sim.live_run import run_loop_viewed
    from depthguard.sim.loop import LoopConfig
    from depthguard.sim.pipeline import Controller

    if ssm and cameras is None:  # SSM needs a cell without blind pockets near the robot (docs/ssm.md)
        cameras = sc.get("ssm_camera_count")
    sc = with_ssm_cameras(sc, ssm)  # ... and cameras whose views hold the protective zone
    cell, kin, ee0 = build_scenario_cell(sc, quick=quick, cameras=cameras, demo=demo)
    if setup is not None:  # e.g. reactive people (depthguard.sim.ssm_approach)
        setup(cell)
    av = sc.get("avoidance", {})
    cams = [KinectSim(cell.model, c, i, seed=seed + i, backend=camera_backend) for i, c in enumerate(cell.cameras)]

    stage = _distance_stage(sc, cell, kin, backend, octree_res)
    ctrl = Controller(
        kin,
        cell.q(),
        rho=float(av.get("rho", 0.4)),
        vmax=float(av.get("vmax", 2.0)),
        alpha=float(av.get("alpha", 6.0)),
        rho_body=float(av.get("rho_body", av.get("rho", 0.4))),
        alpha_body=float(av.get("alpha", 6.0)),
        ssm=ssm and avoidance,
        ssm_config=_ssm_config(av, backend) if ssm and avoidance else None,
        avoidance_mode=av.get("mode") if ssm and avoidance else None,
    )
    if ssm and avoidance:  # the monitor's own distances without the empty cell; its record (metrics only)
        from depthguard.sim.background import background_stages, fixture_names
        from depthguard.sim.ssm_metrics import SsmRecorder

        monitor = _distance_stage(sc, cell, kin, backend, octree_res, _ssm_range(av))
        stage = background_stages(stage, monitor, cell, cams)
        ctrl = SsmRecorder(ctrl, cell, exclude=("table", *fixture_names(cell)))
    task = scenario_task(sc, ee0)
    duration = float(sc.get("quick_duration", sc.get("duration", 10.0)) if quick else sc.get("duration", 10.0))
    if demo:
        duration = float(sc.get("demo_duration", duration))
    cfg = LoopConfig(
        duration=duration,
        avoid=avoidance,
        rho=float(av.get("rho", 0.4)),
        vmax=float(av.get("vmax", 2.0)),
        alpha=float(av.get("alpha", 6.0)),
        pivot=bool(av.get("pivot", False)),
        dv_max=float(av.get("dv_max", 0.5)),
        pivot_c=float(av.get("c", 5.0)),
        progress=progress,
        label=label,
        distance_period=float(sc.get("distance_period", 0.003)),
    )
    log = run_loop_viewed(view, cell, cams, kin, stage, ctrl, task, cfg)
    log.ssm = ctrl if ssm and avoidance else None
    for c in cams:
        c.close()
    return cell, log, task, cfg


def _distance_stage(sc: dict, cell, kin, backend: str, octree_res: float, ssm_range: float | None = None):
    """The scenario's distance stage: the depth space / depth grid (its monitor's distances up to ``ssm_range``
    when given) or, with ``backend="octree"``, the octree (:func:`_octree_stage`; within ρ only)."""
    if backend != "depthspace":
        return _octree_stage(sc, cell, kin, octree_res)
    from depthguard.sim.pipeline import DistanceStage

    av = sc.get("avoidance", {})
    return DistanceStage(
        cell.cameras,
        rho=float(av.get("rho", 0.4)),
        mode=sc.get("mode", "hybrid"),
        alpha=float(av.get("alpha", 6.0)),
        workspace=tuple(sc.get("workspace", (-1.2, 1.2, -1.2, 1.2, -0.3, 1.5))),
        ssm_range=ssm_range,
    )


def _octree_stage(sc: dict, cell, kin, res: float):
    """``--backend octree``: the SAPHARI §3 octree (conservative mode) over the workspace, C(t) from the arm."""
    from depthguard.octree.grid import VoxelBox
    from depthguard.sim.octree_stage import OctreeStage

    w = tuple(sc.get("workspace", (-1.2, 1.2, -1.2, 1.2, -0.3, 1.5)))
    av = sc.get("avoidance", {})
    box = VoxelBox.around([w[0], w[2], w[4]], [w[1], w[3], w[5]], res)
    return OctreeStage(
        cell, cell.cameras, box, reach_model=kin.model, mode="conservative", rho=float(av.get("rho", 0.4)),
        dist_mode=sc.get("mode", "hybrid"), alpha=float(av.get("alpha", 6.0)),
    )  # fmt: skip


def run_scenario(
    name: str,
    *,
    quick: bool = False,
    avoidance: bool = True,
    cameras: int | None = None,
    out_dir: str | Path | None = None,
    progress: bool = False,
    variants: bool = True,
    demo: bool = False,
    backend: str = "depthspace",
    octree_res: float = 0.05,
    ssm: bool = False,
    placement: str | None = None,
    view: int | None = None,
) -> dict[str, Any]:
    """Run a scenario; return its metrics (the object ``depthguard scenario NAME --json`` prints).

    Args:
        name: a shipped scenario name (:func:`list_scenarios`) or a path to a .toml file.
        quick: the CI form: reduced resolution and duration (``quick_*`` fields of the file).
        avoidance: False runs the same scenario with the avoidance switched off (the robot ignores the
            distances), which should collide: that proves the scenario tests something.
        cameras: use only the first N cameras of the placement (1 or 2 for "ral").
        out_dir: where to write ``metrics.json``, the plots and ``recording.mcap``; None writes nothing.
        progress: draw a progress bar on stderr.
        variants: also run the file's ``[[variants]]`` (e.g. without the pivot, without the person) and
            report their metrics under ``"variants"``.
        demo: use the file's ``demo_duration`` and ``demo_resolution`` (``make demo``).
        backend: ``"depthspace"`` (depth space / depth grid) or ``"octree"`` (SAPHARI §3 octree, conservative
            mode, nodes of ``octree_res`` m over the scenario's workspace, C(t) from the arm's reachability).
        ssm: speed and separation monitoring (ISO/TS 15066) on top of the repulsion; adds the keys of
            :func:`depthguard.sim.ssm_metrics.ssm_metrics` and ``ssm.png``. Off when ``avoidance`` is False.
        placement: a camera placement of :func:`depthguard.sim.depthcam.placement` instead of the file's
            ``cameras`` (e.g. ``"ral-rolled"``; None: the file's).
        view: serve the live view (:class:`depthguard.viz.live.LiveView`) of the main run on this port of
            127.0.0.1 while it runs (None: no view).
    Returns:
        A JSON-ready dict with top-level ``collision_steps``, ``min_clearance``, ``task_completion``,
        ``path_error``, ``distance_hz_median`` and the rest of the metrics.
    """

    sc = _with_placement(load_scenario(name), placement)
    if out_dir is not None:  # check the output folder before the run, not after it
        from depthguard.io.files import prepare_out_dir

        prepare_out_dir(out_dir)
    t0 = time.perf_counter()
    run_kw = dict(
        quick=quick, avoidance=avoidance, cameras=cameras, progress=progress, backend=backend,
        octree_res=octree_res, ssm=ssm,
    )  # fmt: skip
    label = f"{sc['name']} ({'avoid' if avoidance else 'no avoid'})"
    cell, log, task, cfg = _run_one(sc, label=label, demo=demo, view=view, **run_kw)
    result = _result_header(sc, cell, log, quick, avoidance)
    result.update(compute_metrics(log, task, cfg))
    result.update(ssm_keys(log, cfg, ssm and avoidance))
    runs = {"main": (log, task)}
    if variants and avoidance:
        result["variants"] = _run_variants(sc, run_kw, runs)
    result["wall_seconds_total"] = round(time.perf_counter() - t0, 2)
    if out_dir is not None:
        _write_outputs(Path(out_dir), sc, cell, log, runs, result)
    return result


def _with_placement(sc: dict, placement: str | None) -> dict:
    """The scenario with another camera placement (:data:`depthguard.sim.depthcam.PLACEMENTS`; None: its own)."""
    if placement is None:
        return sc
    from depthguard.sim.depthcam import PLACEMENTS

    if placement not in PLACEMENTS:
        raise ValueError(f"placement must be one of {', '.join(PLACEMENTS)}, got {placement!r}")
    return {**sc, "cameras": placement}


def _result_header(sc: dict, cell, log, quick: bool, avoidance: bool) -> dict[str, Any]:
    """The keys of :func:`run_scenario`'s result that describe the run rather than measure it."""
    return {
        "scenario": sc["name"],
        "placement": sc.get("cameras"),
        "description": sc.get("description", ""),
        "quick": quick,
        "avoidance": avoidance,
        "cameras": len(cell.cameras),
        "resolution": [cell.cameras[0].width, cell.cameras[0].height],
        "control_points": list(log.point_names),
        "parameters": sc.get("avoidance", {}),
        "people_max_hand_speed": {p.name: round(p.max_hand_speed(), 3) for p in cell.spec.people},
    }


def _run_variants(sc: dict, run_kw: dict, runs: dict) -> dict[str, Any]:
    """Run the scenario's ``[[variants]]`` (settings changed, people or boxes removed) with the main run's
    arguments; returns their metrics by name and adds their logs to ``runs``."""
    out = {}
    for v in sc.get("variants", []):
        sv = copy.deepcopy(sc)
        for k, val in v.get("set", {}).items():
            _set_path(sv, k, val)
        if v.get("remove_people"):
            sv["people"] = []
        if v.get("remove_boxes"):
            sv["boxes"] = []
        _, vlog, vtask, vcfg = _run_one(sv, label=f"{sc['name']} [{v['name']}]", **run_kw)
        out[v["name"]] = {**compute_metrics(vlog, vtask, vcfg), **ssm_keys(vlog, vcfg, run_kw["ssm"])}
        runs[v["name"]] = (vlog, vtask)
    return out


def _write_outputs(out: Path, sc: dict, cell, log, runs: dict, result: dict) -> None:
    """``metrics.json``, the plots and ``recording.mcap`` of a run in ``out``; ``result`` gains ``out_dir``,
    ``files`` and, when an extra is missing, ``plots_error`` / ``recording_error``."""
    out.mkdir(parents=True, exist_ok=True)
    result["out_dir"] = str(out)
    files = {}
    try:
        from depthguard.viz.plots import plot_run

        files.update(plot_run(out, runs, sc["name"], float(sc.get("avoidance", {}).get("rho", 0.4))))
    except ImportError as exc:  # matplotlib missing
        result["plots_error"] = f"plots skipped: {exc} (pip install depthguard[viz])"
    try:
        from depthguard.sim.recorder import record_run

        files["recording"] = str(record_run(out / "recording.mcap", cell, log))
    except ImportError as exc:
        result["recording_error"] = f"recording skipped: {exc} (pip install depthguard[sim])"
    if getattr(log, "ssm", None) is not None:
        from depthguard.sim.ssm_metrics import plot_ssm

        files["ssm"] = plot_ssm(out, log.ssm, log.point_names, result.get("binding_point"), sc["name"])
    result["files"] = files
    (out / "metrics.json").write_text(json.dumps(result, indent=2, default=float))


def _ssm_range(av: dict) -> float:
    """The range of the distances that the monitor gets (``[avoidance] ssm_range``, default max(ρ, 0.6 m)):
    ``S_p`` at task speed (0.33-0.40 m in these scenarios) exceeds the repulsion's ρ (0.3-0.4 m), and a
    monitor that takes "nothing within ρ" as ρ would stop the arm with nobody near (docs/ssm.md)."""
    from depthguard.control.ssm import SSM_RANGE

    return max(float(av.get("ssm_range", SSM_RANGE)), float(av.get("rho", 0.4)))


def _ssm_config(av: dict, backend: str = "depthspace"):
    """The monitor's configuration in the simulated cell: the defaults, with the range of its distances
    (the octree backend answers within ρ only)."""
    from depthguard.control.ssm import SsmConfig

    rng = _ssm_range(av) if backend == "depthspace" else float(av.get("rho", 0.4))
    return SsmConfig(sensing_range=rng)
