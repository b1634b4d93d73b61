"""Command line: a thin layer over the library (``depthguard --help``).

Errors (bad files, bad options) go to stderr with exit code 2.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import NoReturn

import numpy as np


class _Exit(Exception):
    """Raised by commands for a clean error exit."""


class _Parser(argparse.ArgumentParser):
    """Usage errors as one line on stderr (exit code 2), like every other error of the command line."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())} (see {self.prog} --help)\n")


def _parse_workspace(text: str) -> tuple[float, ...]:
    try:
        vals = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--workspace must be xmin,xmax,ymin,ymax,zmin,zmax numbers, got {text!r}"
        ) from None
    if len(vals) != 6 or any(vals[2 * i] >= vals[2 * i + 1] for i in range(3)):
        raise argparse.ArgumentTypeError(
            f"--workspace must be xmin,xmax,ymin,ymax,zmin,zmax with min < max, got {text!r}"
        ) from None
    return vals


def _positive_float(text: str) -> float:
    try:
        x = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
    if not (np.isfinite(x) and x > 0):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
    return x


def _positive_int(text: str) -> int:
    try:
        x = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if x < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    return x


# ----------------------------------------------------------------------------------------------- distance
def _cmd_distance(args: argparse.Namespace) -> int:
    from depthguard.io import read_camera, read_depth, read_mask, read_points

    if len(args.camera) != len(args.depth):
        raise _Exit(
            f"give one --depth per --camera: got {len(args.camera)} camera(s) and {len(args.depth)} depth image(s)"
        ) from None
    if args.mask and len(args.mask) != len(args.camera):
        raise _Exit(
            f"give one --mask per --camera (in the same order): got {len(args.mask)} for {len(args.camera)}"
        ) from None
    cameras = [read_camera(p) for p in args.camera]
    depths = [read_depth(p, cam) for p, cam in zip(args.depth, cameras, strict=True)]
    masks = (
        [read_mask(p, cam) for p, cam in zip(args.mask, cameras, strict=True)] if args.mask else [None] * len(cameras)
    )
    points = read_points(args.points)
    if not points:
        raise _Exit(f"{args.points}: the points file holds no points") from None
    names = [p.name for p in points]
    centres = np.array([p.position for p in points])
    radii = np.array([p.radius for p in points])

    if args.backend == "octree":
        query = _octree_query(args, cameras, depths, masks, centres, radii)
    elif len(cameras) == 1:
        from depthguard.depthspace import prepare_frame, query_distances

        frame = prepare_frame(cameras[0], depths[0], masks[0], invalid=args.invalid, fill_radius=args.fill_radius)

        def query():
            return query_distances(frame, centres, radii, rho=args.rho, mode=args.mode, model=args.model)
    else:
        try:
            from depthguard.depthgrid import DepthGridFusion
        except ImportError:
            raise _Exit(
                "several cameras need the depth-grid fusion module (depthguard.depthgrid), not installed"
            ) from None
        fusion = DepthGridFusion(
            cameras, dd=args.grid_dd, workspace=args.workspace, fill_radius=args.fill_radius, map_mode=args.grid_map
        )
        fusion.update(depths, masks, invalid=args.invalid)

        def query():
            return fusion.query(centres, radii, rho=args.rho, mode=args.mode)

    result = query()
    out: dict = {"points": result.to_json(names)}
    if args.repeat:
        from depthguard.bench.timing import time_calls

        t = time_calls(query, args.repeat)
        out["timing"] = {"us_median": t["us_median"], "us_p99": t["us_p99"]}
    if args.json:
        print(json.dumps(out))
    else:
        print(f"{'point':>12} {'distance [m]':>13} {'obstacle px':>12}  direction (world)")
        for p in out["points"]:
            d = f"{p['distance']:13.4f}" if p["distance"] is not None else f"{'none':>13}"
            dirn = np.array2string(np.array(p["direction"]), precision=3) if p["direction"] else "-"
            print(f"{p['name']:>12} {d} {p['obstacle_pixels']:12d}  {dirn}")
        if "timing" in out:
            print(f"query time: median {out['timing']['us_median']:.1f} us, p99 {out['timing']['us_p99']:.1f} us")
    return 0


def _octree_query(args, cameras, depths, masks, centres, radii):
    """``--backend octree``: conservative fusion over ``--workspace`` (default: the box within ρ of the points)."""
    from depthguard.octree.backend import OctreeBackend, box_around_points
    from depthguard.octree.fusion import CameraObservation
    from depthguard.octree.grid import VoxelBox, check_res

    res = check_res(args.octree_res, "--octree-res")
    if args.workspace:
        w = args.workspace
        box = VoxelBox.around([w[0], w[2], w[4]], [w[1], w[3], w[5]], res)
        if box.size > 50_000_000:
            raise _Exit(f"--workspace holds {box.size} nodes at --octree-res {res}: use a smaller box")
    else:
        box = box_around_points(centres, radii, args.rho, res)
    backend = OctreeBackend(box, mode="conservative", invalid=args.invalid, fill_radius=args.fill_radius)
    backend.update([CameraObservation(c, d, m) for c, d, m in zip(cameras, depths, masks, strict=True)])

    def query():
        return backend.query(centres, radii, rho=args.rho, mode=args.mode)

    return query


# ----------------------------------------------------------------------------------------------- scenario
# Scenarios implemented outside ``depthguard.sim.scenarios`` (the TOML-driven depth-camera scenarios).
# Each entry is "module:function"; the function is called as
# ``fn(name=..., quick=..., avoidance=..., out_dir=..., progress=..., options=dict)`` and returns the JSON dict.
# ``options`` holds the scenario flags below (cameras, backend, octree_res, case, lambda_, contacts, rate, ssm, view).
EXTRA_SCENARIOS: dict[str, str] = {
    "saphari-octree": "depthguard.sim.saphari_octree:run",
    "saphari-skin": "depthguard.sim.saphari_skin:run",
    "saphari-nsb": "depthguard.sim.saphari_nsb:run",
    "saphari-contact-soft": "depthguard.sim.saphari_contact:run",
    "saphari-contact-stiff": "depthguard.sim.saphari_contact:run",
    "ssm-approach": "depthguard.sim.ssm_approach:run",
}

# Benchmarks implemented in their own modules: "module:function", called as ``fn(quick=bool) -> dict``.
EXTRA_BENCHES: dict[str, str] = {
    "octree": "depthguard.bench.octree:run_octree_benchmark",
    "proximity": "depthguard.bench.proximity:run_proximity_benchmark",
    "contact": "depthguard.bench.contact:run_contact_benchmark",
    "net-latency": "depthguard.nodes.bench:run_net_latency_benchmark",
    "view": "depthguard.viz.live_bench:run_view_benchmark",
}


def _load_entry(spec: str, what: str):
    """Import ``module:function``; a missing module or extra becomes a clean error."""
    import importlib

    mod_name, fn_name = spec.split(":")
    try:
        mod = importlib.import_module(mod_name)
    except ImportError as exc:
        raise _Exit(f"{what} is not available: {exc} (pip install 'depthguard[all]')") from None
    return getattr(mod, fn_name)


def _scenario_options(args: argparse.Namespace) -> dict:
    keys = ("cameras", "backend", "octree_res", "case", "lambda_", "contacts", "rate", "ssm", "view")
    return {k: getattr(args, k, None) for k in keys}


def _cmd_scenario(args: argparse.Namespace) -> int:
    if args.out:  # before any work: a bad --out must not cost a whole run
        from depthguard.io.files import prepare_out_dir

        prepare_out_dir(args.out, "--out folder")
    if args.name == "pivot":
        from depthguard.pivot_scenario import run_pivot_scenario

        res = run_pivot_scenario()
        out = {k: {"min_distance": v["min_distance"], "collided": v["collided"]} for k, v in res.items()}
        if args.out:
            _save_pivot_plot(res, Path(args.out))
    elif args.name in EXTRA_SCENARIOS:
        run = _load_entry(EXTRA_SCENARIOS[args.name], f"scenario {args.name!r}")
        out = run(
            name=args.name,
            quick=args.quick,
            avoidance=not args.no_avoidance,
            out_dir=args.out,
            progress=not args.json,
            options=_scenario_options(args),
        )
    else:
        try:
            from depthguard.sim.scenarios import run_scenario
        except ImportError as exc:
            raise _Exit(f"scenario {args.name!r} needs the simulator: pip install 'depthguard[sim]' ({exc})") from None
        out = run_scenario(
            args.name,
            quick=args.quick,
            avoidance=not args.no_avoidance,
            cameras=args.cameras,
            out_dir=args.out,
            progress=not args.json,
            **({"backend": "octree", "octree_res": args.octree_res or 0.05} if args.backend == "octree" else {}),
            ssm=bool(getattr(args, "ssm", False)),
        )
    if args.json:
        print(json.dumps(out, default=float))
    else:
        print(json.dumps(out, indent=2, default=float))
    return 0


def _save_pivot_plot(res: dict, out_dir: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    fig, axes = plt.subplots(2, 1, figsize=(7, 5), sharex=True)
    for ax, key in zip(axes, ("direct", "pivot"), strict=True):
        tp, to = res[key]["trace_point"], res[key]["trace_obstacle"]
        ax.plot(to[:, 0], to[:, 1] + to[:, 2], "b-", label="obstacle (1 m/s)")
        ax.plot(tp[:, 0], tp[:, 1] + tp[:, 2], "r-", lw=2, label="control point (max 0.8 m/s)")
        ax.set_title(
            f"{key}: min distance {res[key]['min_distance']:.3f} m" + (" (collision)" if res[key]["collided"] else "")
        )
        ax.set_aspect("equal")
        ax.legend(fontsize=7)
    axes[-1].set_xlabel("x [m]")
    fig.tight_layout()
    fig.savefig(out_dir / "pivot_fig7.png")
    plt.close(fig)


# -------------------------------------------------------------------------------------------------- bench
def _cmd_bench(args: argparse.Namespace) -> int:
    if args.what == "distance":
        from depthguard.bench.distance import run_distance_benchmark

        out = run_distance_benchmark(quick=args.quick)
    elif args.what in EXTRA_BENCHES:
        out = _load_entry(EXTRA_BENCHES[args.what], f"the {args.what} benchmark")(quick=args.quick)
    else:
        try:
            from depthguard.bench.control import run_control_benchmark, run_selffilter_benchmark
        except ImportError as exc:
            raise _Exit(
                f"the {args.what} benchmark needs the robot extra: pip install 'depthguard[robot]' ({exc})"
            ) from None
        run = run_control_benchmark if args.what == "control" else run_selffilter_benchmark
        out = run(quick=args.quick)
    print(json.dumps(out, indent=None if args.json else 2, default=float))
    return 0


# --------------------------------------------------------------------------------------------------- demo
def _cmd_demo(args: argparse.Namespace) -> int:
    if args.out:
        from depthguard.io.files import prepare_out_dir

        prepare_out_dir(args.out, "--out folder")
    if not args.static:
        try:
            from depthguard.sim.demo import run_demo
        except ImportError:
            print("(the simulated cell is not available: running the static one-camera demo)", file=sys.stderr)
        else:
            return int(run_demo(out_dir=args.out) or 0)
    from depthguard.demo_static import run_static_demo

    run_static_demo(out_dir=args.out or "runs/demo-static")
    return 0


# ---------------------------------------------------------------------------------------------- calibrate
def _cmd_calibrate(args: argparse.Namespace) -> int:
    from depthguard.runner.calibrate import calibrate_cell

    out = calibrate_cell(args.cell, args.source, write=args.write, quick=args.quick)
    print(json.dumps(out, indent=None if args.json else 2, default=float))
    return 0


# --------------------------------------------------------------------------------------------------- cell
def _cmd_cell(args: argparse.Namespace) -> int:
    from depthguard.io.cellfile import describe_cell, read_cell
    from depthguard.runner.chain import check_camera_parents, load_cell_robot

    cell = read_cell(args.cell)
    check_camera_parents(cell, load_cell_robot(cell))  # the links named by attachments and cameras exist
    if args.json:
        print(json.dumps({"name": cell.name, "cameras": [c.name for c in cell.cameras], "ok": True}))
    else:
        print(describe_cell(cell))
    return 0


# ---------------------------------------------------------------------------------------------------- run
def _cmd_run(args: argparse.Namespace) -> int:
    from depthguard.runner import run_cell

    if args.out:
        _check_out_dir(args.out)
    out = run_cell(
        args.cell,
        args.source,
        quick=args.quick,
        realtime=args.realtime,
        out_dir=args.out,
        progress=not args.json,
        transport=args.transport,
        zenoh_domain=args.zenoh_domain,
        zenoh_connect=args.zenoh_connect,
        view=args.view,
    )
    print(json.dumps(out, indent=None if args.json else 2, default=float))
    return 0


# --------------------------------------------------------------------------------------------- node, view
def _cmd_node(args: argparse.Namespace) -> int:
    from depthguard.nodes import run_node

    out = run_node(
        args.name,
        args.cell,
        source=args.source,
        quick=args.quick,
        duration=args.duration,
        log=args.log,
        domain=args.zenoh_domain,
        connect=args.zenoh_connect,
        watchdog=args.watchdog,
    )
    print(json.dumps({"node": args.name, **out}, default=float))
    return 0


def _cmd_view(args: argparse.Namespace) -> int:
    from depthguard.viz.live import run_view_node

    run_view_node(
        args.cell, port=args.port, duration=args.duration, domain=args.zenoh_domain, connect=args.zenoh_connect
    )
    return 0


def _zenoh_flags(p: argparse.ArgumentParser) -> None:
    p.add_argument("--zenoh-domain", type=int, default=None, metavar="N", help="ROS domain id (default: cell file)")
    p.add_argument(
        "--zenoh-connect", action="append", default=None, metavar="ENDPOINT",
        help="Zenoh endpoint to connect to (repeatable; default: the cell file's, tcp/127.0.0.1:7447)",
    )  # fmt: skip


def _check_out_dir(path: str) -> None:
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise _Exit(f"--out {path}: exists and is not a directory")
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise _Exit(f"--out {path}: cannot create it ({exc.strerror})") from None


# ------------------------------------------------------------------------------------------------- parser
def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="depthguard", description="Depth-space human-robot collision avoidance")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("distance", help="distances from control points to the obstacles in depth image(s)")
    p.add_argument(
        "--camera",
        action="append",
        required=True,
        metavar="CAM.json",
        help="camera JSON; repeat for several cameras, the first is the principal one",
    )
    p.add_argument(
        "--depth",
        action="append",
        required=True,
        metavar="DEPTH.png|npy",
        help="depth image (16-bit PNG in mm or .npy float32 m), one per --camera",
    )
    p.add_argument("--points", required=True, metavar="POINTS.json", help="control points JSON")
    p.add_argument("--rho", type=_positive_float, default=0.4, help="radius of surveillance in m (default 0.4)")
    p.add_argument(
        "--mode",
        choices=["min", "all", "hybrid"],
        default="min",
        help="min: nearest obstacle; all: ICRA'12 eq. 9 direction; hybrid: RA-L'16 eq. 11",
    )
    p.add_argument(
        "--invalid",
        choices=["conservative", "ignore"],
        default="conservative",
        help="missing-depth policy (default conservative: unknown space is an obstacle)",
    )
    p.add_argument(
        "--mask",
        action="append",
        default=[],
        metavar="MASK.png",
        help="robot mask (nonzero = robot), once per camera in the same order",
    )
    p.add_argument(
        "--repeat", type=_positive_int, default=0, metavar="N", help="also time N repeated queries (I/O excluded)"
    )
    p.add_argument(
        "--model",
        choices=["frustum", "icra", "ral16"],
        default="frustum",
        help="point-to-pixel distance: frustum lower bound (default), ICRA'12 eq. 4 or literal RA-L'16 eqs. 5-7",
    )
    p.add_argument(
        "--fill-radius", type=int, default=4, help="hole-filling radius in pixels (default 4; 0: every hole is unknown)"
    )
    p.add_argument(
        "--grid-dd", type=_positive_float, default=0.01, help="depth-grid quantisation in m (several cameras)"
    )
    p.add_argument(
        "--workspace",
        type=_parse_workspace,
        default=None,
        metavar="xmin,xmax,ymin,ymax,zmin,zmax",
        help="workspace box in m (world frame) for the depth grid",
    )
    p.add_argument(
        "--grid-map",
        choices=["onthefly", "stored"],
        default="onthefly",
        help="depth-grid map: computed on the fly (default, 15 MB) or stored (cached on disk, ~0.9 GB)",
    )
    p.add_argument(
        "--backend",
        choices=["depthspace", "octree"],
        default="depthspace",
        help="depthspace (default: depth space for one camera, depth grid for several) or octree (SAPHARI §3, "
        "conservative: unseen space in the workspace is an obstacle)",
    )
    p.add_argument("--octree-res", type=_positive_float, default=0.05, help="octree node size in m (0.02-0.1)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=_cmd_distance)

    p = sub.add_parser("scenario", help="run a scenario (pivot, icra-exp1..4, ral-hexagon, ral-shadow, ral-hidden)")
    p.add_argument("name")
    p.add_argument("--quick", action="store_true", help="short, low-resolution form (for CI)")
    p.add_argument("--no-avoidance", action="store_true", help="run without collision avoidance")
    p.add_argument(
        "--cameras",
        type=int,
        choices=[1, 2, 3],
        default=None,
        help='number of cameras (3: the "ral" scenarios with a third camera behind the arm, docs/phantom-zero.md)',
    )
    p.add_argument(
        "--backend", choices=["depthspace", "octree"], default=None, help="distance backend (default depthspace)"
    )
    p.add_argument("--octree-res", type=_positive_float, default=None, help="octree node size in m (octree backend)")
    p.add_argument("--case", type=int, choices=[1, 2, 3, 4], default=None, help="case study (saphari-nsb)")
    p.add_argument(
        "--lambda",
        dest="lambda_",
        choices=["switch", "arctan", "linear"],
        default=None,
        help="NSB weighting (saphari-nsb)",
    )
    p.add_argument(
        "--contacts", type=int, choices=[1, 2], default=None, help="simultaneous contacts (saphari-contact-*)"
    )
    p.add_argument("--rate", type=_positive_float, default=None, help="control rate in Hz (saphari-contact-*)")
    p.add_argument("--ssm", action="store_true", help="speed and separation monitoring on top of the repulsion")
    p.add_argument("--view", action="store_true", help="live 3-D view in the browser")
    p.add_argument("--out", default=None, metavar="DIR", help="run folder (metrics, plots, recording)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=_cmd_scenario)

    p = sub.add_parser("bench", help="benchmarks (JSON with machine info, medians and p99s)")
    p.add_argument("what", choices=["distance", "control", "selffilter", *EXTRA_BENCHES])
    p.add_argument("--quick", action="store_true", help="fewer repetitions")
    p.add_argument("--json", action="store_true", help="compact JSON")
    p.set_defaults(func=_cmd_bench)

    p = sub.add_parser("run", help="run the whole chain on a source: bag:PATH, sim:SCENARIO or realsense")
    p.add_argument("--cell", required=True, metavar="CELL.toml", help="the cell file")
    p.add_argument(
        "--source", required=True, metavar="bag:PATH|sim:SCENARIO|realsense", help="where the data comes from"
    )
    pace = p.add_mutually_exclusive_group()
    pace.add_argument("--realtime", action="store_true", help="pace the run to the source's clock")
    pace.add_argument("--fast", action="store_true", help="as fast as possible on the source's clock (default)")
    p.add_argument("--quick", action="store_true", help="the scenario's short form (sim sources)")
    p.add_argument("--out", default=None, metavar="DIR", help="write DIR/recording.mcap (ROS 2 messages)")
    p.add_argument("--json", action="store_true", help="print one JSON summary")
    p.add_argument("--transport", choices=["none", "zenoh"], default="none", help="also publish the topics on Zenoh")
    _zenoh_flags(p)
    p.add_argument("--view", action="store_true", help="live 3-D view in the browser (viser)")
    p.set_defaults(func=_cmd_run)

    p = sub.add_parser("calibrate", help="camera extrinsics from the arm itself (SAPHARI §3.3)")
    p.add_argument("--cell", required=True, metavar="CELL.toml", help="the cell file (its extrinsics: the guess)")
    p.add_argument("--source", required=True, metavar="bag:PATH|sim:SCENARIO", help="frames at several arm poses")
    p.add_argument(
        "--write", default=None, metavar="FILE.toml", help="calibration file (default CELL.calibration.toml)"
    )
    p.add_argument("--quick", action="store_true", help="the scenario's low-resolution form (sim sources)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=_cmd_calibrate)

    p = sub.add_parser("node", help="run one node of a cell on Zenoh: sim, a camera, distance, controller, monitor")
    p.add_argument("name", help="node name: sim, a camera name of the cell, distance, controller or monitor")
    p.add_argument("--cell", required=True, metavar="CELL.toml", help="the cell file")
    p.add_argument("--source", default=None, metavar="sim:SCENARIO", help="the sim node's scenario")
    p.add_argument("--quick", action="store_true", help="the scenario's short form (sim node: 160x120 images)")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S seconds (default: never)")
    p.add_argument("--log", default=None, metavar="FILE", help="JSON-lines event log (timings)")
    p.add_argument("--watchdog", type=float, default=0.05, metavar="S", help="sim node: driver watchdog timeout")
    _zenoh_flags(p)
    p.set_defaults(func=_cmd_node)

    p = sub.add_parser("view", help="live 3-D view of a cell's nodes in the browser (viser)")
    p.add_argument("--cell", required=True, metavar="CELL.toml", help="the cell file")
    p.add_argument("--port", type=int, default=8080, help="HTTP port of the page (127.0.0.1)")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S seconds (default: never)")
    _zenoh_flags(p)
    p.set_defaults(func=_cmd_view)

    p = sub.add_parser("cell", help="cell files: 'cell check CELL.toml' prints what the file says")
    p.add_argument("action", choices=["check"])
    p.add_argument("cell", metavar="CELL.toml")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=_cmd_cell)

    p = sub.add_parser("demo", help="the main demo (the simulated cell; --static for the one-camera picture)")
    p.add_argument("--static", action="store_true", help="the static one-camera demo")
    p.add_argument("--out", default=None, metavar="DIR", help="output folder")
    p.set_defaults(func=_cmd_demo)
    return parser


def _join_negative_values(argv: list[str]) -> list[str]:
    """``--workspace -1.5,1.5,...`` would read as an option to argparse: glue such values to their flag."""
    out: list[str] = []
    it = iter(argv)
    for a in it:
        if a == "--workspace":
            nxt = next(it, None)
            out.append(a if nxt is None else f"{a}={nxt}")
        else:
            out.append(a)
    return out


def main(argv: list[str] | None = None) -> int:
    """Run the command line; return the exit code (0, 2 for any bad input with one line on stderr)."""
    parser = build_parser()
    try:
        args = parser.parse_args(_join_negative_values(sys.argv[1:] if argv is None else list(argv)))
    except SystemExit as exc:  # usage errors (already printed as one line) and --help
        return exc.code if isinstance(exc.code, int) else 2
    try:
        return int(args.func(args) or 0)
    except (_Exit, ValueError) as exc:  # InputError is a ValueError
        print(f"depthguard {args.command}: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
