"""Command line: a thin layer over the library (``depthguard --help``).

Errors (bad files, bad options) go to stderr with exit code 2.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import NoReturn

from depthguard.cli_cell import add_cell_commands
from depthguard.cli_common import CliExit as _Exit
from depthguard.cli_common import octree_res as _octree_res
from depthguard.cli_common import path_text as _path_text
from depthguard.cli_common import positive_float as _positive_float
from depthguard.cli_common import tcp_port as _tcp_port
from depthguard.cli_distance import add_distance_command


class _Parser(argparse.ArgumentParser):
    """Usage errors as one line on stderr (exit code 2), like every other error of the command line."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())} (see {self.prog} --help)\n")


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


def _scenario_options(args: argparse.Namespace, view: int | None) -> dict:
    keys = ("cameras", "backend", "octree_res", "case", "lambda_", "contacts", "rate", "ssm")
    return {**{k: getattr(args, k, None) for k in keys}, "view": view}


# the scenarios that can feed the live view (they simulate depth cameras in a cell)
VIEW_SCENARIOS = ("ssm-approach", "saphari-octree")


def _view_port(args: argparse.Namespace) -> int | None:
    """``--view``: the live view's port (``--view-port``), after checking that the scenario has one and that
    viser imports; None without ``--view``."""
    if not getattr(args, "view", False):
        return None
    if args.name == "pivot" or (args.name in EXTRA_SCENARIOS and args.name not in VIEW_SCENARIOS):
        from depthguard.sim.scenarios import list_scenarios  # (no simulator import)

        raise _Exit(
            f"--view: scenario {args.name!r} has no simulated depth cameras to show; the live view runs with the"
            f" cell scenarios ({', '.join(list_scenarios())}) and {', '.join(VIEW_SCENARIOS)}"
        )
    try:
        import viser  # noqa: F401
    except ImportError as exc:
        raise _Exit(f"--view needs viser: pip install 'depthguard[all]' ({exc})") from None
    if not 1 <= args.view_port <= 65535:
        raise _Exit(f"--view-port must be a TCP port (1-65535), got {args.view_port}")
    return int(args.view_port)


def _cmd_scenario(args: argparse.Namespace) -> int:
    if args.out:  # before any work: a bad --out must not cost a whole run
        from depthguard.io.files import prepare_out_dir

        prepare_out_dir(args.out, "--out folder")
    view = _view_port(args)  # (a scenario without a view, or no viser: refused before any work)
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
            options=_scenario_options(args, view),
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
            placement=getattr(args, "placement", None),
            view=view,
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


# ------------------------------------------------------------------------------------------------- parser
def _add_scenario(sub) -> None:
    """The ``scenario`` command's options."""
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
        "--placement",
        choices=["icra", "icra-ssm", "ral", "ral3", "ral-rolled", "ral-rolled-far"],
        default=None,
        help="camera placement instead of the scenario file's (ral-rolled: the second camera on its side, "
        "ral-shadow's and ral-hidden's; ral-rolled-far: and the principal farther back, ral-hexagon's; ral: the "
        "upright pair of before; docs/phantom-zero.md)",
    )
    p.add_argument(
        "--backend", choices=["depthspace", "octree"], default=None, help="distance backend (default depthspace)"
    )
    p.add_argument("--octree-res", type=_octree_res, default=None, help="octree node size in m (0.02-0.1; octree)")
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
    p.add_argument("--view", action="store_true", help="live 3-D view in the browser while the run goes on")
    p.add_argument(
        "--view-port",
        type=_tcp_port,
        default=8080,
        metavar="PORT",
        help="port of the live view (127.0.0.1; default 8080)",
    )
    p.add_argument("--out", type=_path_text, default=None, metavar="DIR", help="run folder (metrics, plots, recording)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=_cmd_scenario)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="depthguard", description="Depth-space human-robot collision avoidance")
    sub = parser.add_subparsers(dest="command", required=True)

    add_distance_command(sub)  # depthguard.cli_distance
    _add_scenario(sub)
    p = sub.add_parser("bench", help="benchmarks (JSON with machine info, medians and p99s)")
    p.add_argument("what", choices=["distance", "control", "selffilter", *EXTRA_BENCHES])
    p.add_argument("--quick", action="store_true", help="fewer repetitions")
    p.add_argument("--json", action="store_true", help="compact JSON")
    p.set_defaults(func=_cmd_bench)

    add_cell_commands(sub)  # run, calibrate, node, view, cell (depthguard.cli_cell)

    p = sub.add_parser("demo", help="the main demo (the simulated cell; --static for the one-camera picture)")
    p.add_argument("--static", action="store_true", help="the static one-camera demo")
    p.add_argument("--out", type=_path_text, default=None, metavar="DIR", help="output folder")
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
    except ImportError as exc:  # a missing extra (Zenoh, viser, the simulator) imported once the command runs
        msg = " ".join(str(exc).split())
        print(f"depthguard {args.command}: error: {msg} (pip install 'depthguard[all]')", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
