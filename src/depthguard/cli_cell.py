"""Command line: the real-cell commands ``run``, ``calibrate``, ``commission``, ``node``, ``view`` and ``cell``
(:mod:`depthguard.cli` registers them with :func:`add_cell_commands`)."""

from __future__ import annotations

import argparse
import json
import sys

from depthguard.cli_common import (
    CliExit,
    background_margin,
    cert_days,
    check_out_dir,
    check_out_file,
    check_source,
    duration_s,
    frame_count,
    host_name,
    noise_coeff,
    path_text,
    ros_domain,
    rt_priority,
    tcp_port,
    watchdog_s,
    zenoh_endpoint,
)

__all__ = ["add_cell_commands"]


# ---------------------------------------------------------------------------------------------- calibrate
def _cmd_calibrate(args: argparse.Namespace) -> int:
    from depthguard.runner.calibrate import calibrate_cell

    check_source(args.source, ("bag", "sim"))  # before any work: a bad --source or --write must not cost the frames
    if args.write is not None:
        check_out_file(args.write, "--write")
    out = calibrate_cell(args.cell, args.source, write=args.write, quick=args.quick)
    print(json.dumps(out, indent=None if args.json else 2, default=float))
    return 0


# --------------------------------------------------------------------------------------------- commission
def _cmd_commission(args: argparse.Namespace) -> int:
    from depthguard.runner.commission import commission_cell

    check_source(args.source, ("bag", "sim", "realsense"))
    if args.out is not None:  # before any work: a bad --out must not cost the recording
        check_out_file(args.out, "--out")
    out = commission_cell(
        args.cell,
        args.source,
        frames=args.frames,
        out=args.out,
        quick=args.quick,
        progress=not args.json,
        noise_coeff=args.noise_coeff,
        margin=args.margin,
    )
    for w in out.get("warnings", ()):
        print(f"depthguard commission: warning: {w}", file=sys.stderr)
    print(json.dumps(out, indent=None if args.json else 2, default=float))
    return 0


# --------------------------------------------------------------------------------------------------- cell
def _cmd_cell(args: argparse.Namespace) -> int:
    from depthguard.io.cell_describe import describe_cell
    from depthguard.io.cellfile import CellError, read_cell
    from depthguard.runner.carried import check_camera_parents
    from depthguard.runner.chain import cell_control_points, load_cell_robot

    cell = read_cell(args.cell)
    try:
        model = load_cell_robot(cell)  # the URDF, its ee_frame, the links named by attachments
    except ValueError as exc:  # (the URDF reader names the URDF, or a frame only: add the cell file's key)
        msg = str(exc)
        raise CellError(msg if msg.startswith(str(cell.path)) else f"{cell.path}: robot: {msg}") from None
    check_camera_parents(cell, model)  # the links that carry cameras exist
    cell_control_points(cell, model)  # the links of [[robot.spheres]] exist
    if args.json:
        print(json.dumps({"name": cell.name, "cameras": [c.name for c in cell.cameras], "ok": True}))
    else:
        print(describe_cell(cell))
    return 0


# ---------------------------------------------------------------------------------------------------- run
def _cmd_run(args: argparse.Namespace) -> int:
    from depthguard.runner import run_cell

    check_source(args.source, ("bag", "sim", "realsense"))
    if args.out:
        check_out_dir(args.out)
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

    if args.source is not None:
        check_source(args.source, ("sim",))
    if args.log is not None:  # (opened once the node runs: a folder there was a traceback)
        check_out_file(args.log, "--log")
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
        rt_priority=args.rt_priority,
    )
    print(json.dumps({"node": args.name, **out}, default=float))
    return 0


def _cmd_view(args: argparse.Namespace) -> int:
    from depthguard.viz.live_node import run_view_node

    run_view_node(
        args.cell, port=args.port, duration=args.duration, domain=args.zenoh_domain, connect=args.zenoh_connect
    )
    return 0


def _cmd_certs(args: argparse.Namespace) -> int:
    import shutil

    from depthguard.nodes.certs import make_cell_certificates

    if shutil.which("openssl") is None:
        raise CliExit("depthguard certs needs the openssl command (Debian: apt install openssl)")
    try:
        out = make_cell_certificates(
            args.cell, args.out, days=args.days, hosts=args.host, nodes=args.node, overwrite=args.overwrite
        )
    except RuntimeError as exc:  # (openssl refused: its message, on one line)
        raise CliExit(str(exc)) from None
    if args.json:
        print(json.dumps(out))
        return 0
    print(f"certificates in {out['folder']}: made {out['made'] or 'none'}, kept {out['kept'] or 'none'}")
    print("add to the cell file's [network] table (one certificate per node: Zenoh's access control is on):")
    print("\n".join(out["network"]))
    return 0


def _cmd_ros2_msgs(args: argparse.Namespace) -> int:
    from depthguard.io.ros2_package import write_msgs_package

    out = write_msgs_package(args.out, overwrite=args.overwrite)
    if args.json:
        print(json.dumps(out))
        return 0
    print(f"ROS 2 interface package in {out['folder']} ({len(out['files'])} files); in the workspace:")
    print("  colcon build --packages-select depthguard_msgs && source install/setup.bash")
    print("then: ros2 topic echo /depthguard/distances")
    return 0


def _zenoh_flags(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--zenoh-domain", type=ros_domain, default=None, metavar="N", help="ROS domain id (default: cell file)"
    )
    p.add_argument(
        "--zenoh-connect", action="append", type=zenoh_endpoint, default=None, metavar="ENDPOINT",
        help="Zenoh endpoint to connect to (repeatable; default: the cell file's, tcp/127.0.0.1:7447)",
    )  # fmt: skip


def add_cell_commands(sub) -> None:
    """Add the real-cell subcommands to the ``depthguard`` subparsers ``sub``."""
    p = sub.add_parser("run", help="run the whole chain on a source: bag:PATH, sim:SCENARIO or realsense")
    p.add_argument("--cell", required=True, metavar="CELL.toml", help="the cell file")
    p.add_argument(
        "--source", required=True, metavar="bag:PATH|sim:SCENARIO|realsense", help="where the data comes from"
    )
    pace = p.add_mutually_exclusive_group()
    pace.add_argument("--realtime", action="store_true", help="pace the run to the source's clock")
    pace.add_argument("--fast", action="store_true", help="as fast as possible on the source's clock (default)")
    p.add_argument("--quick", action="store_true", help="the scenario's short form (sim sources)")
    p.add_argument(
        "--out", type=path_text, default=None, metavar="DIR", help="write DIR/recording.mcap (ROS 2 messages)"
    )
    p.add_argument("--json", action="store_true", help="print one JSON summary")
    p.add_argument("--transport", choices=["none", "zenoh"], default="none", help="also publish the topics on Zenoh")
    _zenoh_flags(p)
    p.add_argument("--view", action="store_true", help="live 3-D view in the browser (viser)")
    p.set_defaults(func=_cmd_run)
    _add_calibrate_command(sub)
    _add_commission_command(sub)
    _add_node_and_view_commands(sub)
    _add_certs_and_msgs_commands(sub)
    p = sub.add_parser("cell", help="cell files: 'cell check CELL.toml' prints what the file says")
    p.add_argument("action", choices=["check"])
    p.add_argument("cell", metavar="CELL.toml")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=_cmd_cell)


def _add_calibrate_command(sub) -> None:
    """``depthguard calibrate``: camera extrinsics from the arm itself."""
    p = sub.add_parser("calibrate", help="camera extrinsics from the arm itself (SAPHARI §3.3)")
    p.add_argument("--cell", required=True, metavar="CELL.toml", help="the cell file (its extrinsics: the guess)")
    p.add_argument("--source", required=True, metavar="bag:PATH|sim:SCENARIO", help="frames at several arm poses")
    p.add_argument(
        "--write",
        type=path_text,
        default=None,
        metavar="FILE.toml",
        help="calibration file (default CELL.calibration.toml)",
    )
    p.add_argument("--quick", action="store_true", help="the scenario's low-resolution form (sim sources)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=_cmd_calibrate)


def _add_node_and_view_commands(sub) -> None:
    """``depthguard node`` (one node of a cell on Zenoh) and ``depthguard view`` (the live view)."""
    p = sub.add_parser("node", help="run one node of a cell on Zenoh: sim, a camera, distance, controller, monitor")
    p.add_argument("name", help="node name: sim, a camera name of the cell, distance, controller or monitor")
    p.add_argument("--cell", required=True, metavar="CELL.toml", help="the cell file")
    p.add_argument("--source", default=None, metavar="sim:SCENARIO", help="the sim node's scenario")
    p.add_argument("--quick", action="store_true", help="the scenario's short form (sim node: 160x120 images)")
    p.add_argument(
        "--duration", type=duration_s, default=None, metavar="S", help="stop after S seconds (default: never)"
    )
    p.add_argument("--log", type=path_text, default=None, metavar="FILE", help="JSON-lines event log (timings)")
    p.add_argument(
        "--watchdog", type=watchdog_s, default=0.05, metavar="S", help="sim node: driver watchdog timeout (0-1 s)"
    )
    p.add_argument(
        "--rt-priority", type=rt_priority, default=None, metavar="N",
        help="run the node's threads with SCHED_FIFO priority N (1-99) where allowed (the controller: docs/nodes.md)",
    )  # fmt: skip
    _zenoh_flags(p)
    p.set_defaults(func=_cmd_node)

    p = sub.add_parser("view", help="live 3-D view of a cell's nodes in the browser (viser)")
    p.add_argument("--cell", required=True, metavar="CELL.toml", help="the cell file")
    p.add_argument("--port", type=tcp_port, default=8080, help="HTTP port of the page (127.0.0.1)")
    p.add_argument(
        "--duration", type=duration_s, default=None, metavar="S", help="stop after S seconds (default: never)"
    )
    _zenoh_flags(p)
    p.set_defaults(func=_cmd_view)


def _add_certs_and_msgs_commands(sub) -> None:
    """``depthguard certs`` (TLS certificates per node) and ``depthguard ros2-msgs`` (the interface package)."""
    p = sub.add_parser(
        "certs", help="a CA and one TLS certificate per node of a cell (Zenoh mutual TLS and access control)"
    )
    p.add_argument("--cell", required=True, metavar="CELL.toml", help="the cell file (its nodes and host)")
    p.add_argument(
        "--out", type=path_text, required=True, metavar="DIR", help="folder of the certificates (a CA there is reused)"
    )
    p.add_argument("--days", type=cert_days, default=365, metavar="N", help="validity of new certificates")
    p.add_argument(
        "--host", action="append", type=host_name, default=None, metavar="ADDR",
        help="an address the nodes listen on (repeatable; default 127.0.0.1, localhost and network.host)",
    )  # fmt: skip
    p.add_argument("--node", action="append", default=None, metavar="NAME", help="one more node (repeatable)")
    p.add_argument("--overwrite", action="store_true", help="replace existing node certificates")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=_cmd_certs)

    p = sub.add_parser(
        "ros2-msgs", help="write the depthguard_msgs ROS 2 interface package (to echo the nodes' own topics in ROS 2)"
    )
    p.add_argument(
        "--out", type=path_text, required=True, metavar="DIR", help="where the package folder goes (a workspace's src)"
    )
    p.add_argument("--overwrite", action="store_true", help="replace the files of an existing package folder")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=_cmd_ros2_msgs)


def _add_commission_command(sub) -> None:
    """``depthguard commission``: record the empty cell's background (docs/real-cell.md)."""
    p = sub.add_parser(
        "commission",
        help="record the empty cell's background for SSM ([controller] background); nobody may be in the cell",
        description="Record the background of the EMPTY cell for speed and separation monitoring: per camera the"
        " nearest non-robot depth over N frame sets (the robot self-filtered with its joint state; it may stand or"
        ' move), written as an .npz that the cell file references with [controller] background = "FILE".'
        " bag:PATH and realsense: record with NOBODY in the cell (whatever is there is hidden from the monitor"
        " afterwards); sim:SCENARIO: the scenario's cell without its people, the arm following its task.",
    )
    p.add_argument("--cell", required=True, metavar="CELL.toml", help="the cell file")
    p.add_argument(
        "--source", required=True, metavar="bag:PATH|sim:SCENARIO|realsense",
        help="the empty cell: a bag or live camera recorded with nobody in it, or a scenario (its people left out)",
    )  # fmt: skip
    p.add_argument(
        "--frames", type=frame_count, default=30, metavar="N",
        help="frame sets to read, spread over a bag or scenario (default 30)",
    )  # fmt: skip
    p.add_argument(
        "--out", type=path_text, default=None, metavar="FILE", help="the background file (default CELL.background.npz)"
    )  # fmt: skip
    p.add_argument("--quick", action="store_true", help="the scenario's low-resolution form (sim sources)")
    p.add_argument(
        "--noise-coeff", type=noise_coeff, default=None, metavar="C",
        help="depth noise sigma = C z^2 of the tolerance (default: the simulated camera's, or measured)",
    )  # fmt: skip
    p.add_argument(
        "--margin", type=background_margin, default=0.01, metavar="M", help="extra tolerance, m (0-1; default 0.01)"
    )
    p.add_argument("--json", action="store_true", help="print one JSON object (no progress line)")
    p.set_defaults(func=_cmd_commission)
