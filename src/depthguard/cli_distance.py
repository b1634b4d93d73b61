"""Command line: the ``distance`` command (depth images + control points -> distances; :mod:`depthguard.cli`
registers it with :func:`add_distance_command`)."""

from __future__ import annotations

import argparse
import json

import numpy as np

from depthguard.cli_common import CliExit as _Exit
from depthguard.cli_common import octree_res as _octree_res
from depthguard.cli_common import parse_workspace as _parse_workspace
from depthguard.cli_common import pixel_radius as _pixel_radius
from depthguard.cli_common import pixel_stride as _pixel_stride
from depthguard.cli_common import positive_float as _positive_float
from depthguard.cli_common import repeat_count as _repeat_count

__all__ = ["add_distance_command"]

#: the most nodes an octree box of ``distance --backend octree`` may hold
_MAX_NODES = 50_000_000


def _direction_stride(text: str) -> int | str:
    """``--direction-stride``: ``auto`` or an integer >= 1."""
    return text if text == "auto" else _pixel_stride(text)


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
    depths = [read_depth(p, cam, c) for p, cam, c in zip(args.depth, cameras, args.camera, strict=True)]
    masks = (
        [read_mask(p, cam, c) for p, cam, c in zip(args.mask, cameras, args.camera, strict=True)]
        if args.mask
        else [None] * len(cameras)
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
            return query_distances(
                frame,
                centres,
                radii,
                rho=args.rho,
                mode=args.mode,
                model=args.model,
                direction_stride=args.direction_stride,
            )
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
            return fusion.query(centres, radii, rho=args.rho, mode=args.mode, direction_stride=args.direction_stride)

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
        if box.size > _MAX_NODES:
            raise _Exit(f"--workspace holds {box.size} nodes at --octree-res {res}: use a smaller box")
    else:  # (checked before it is built: a large --rho overflowed the box, or asked for terabytes)
        reach = args.rho + float(radii.max(initial=0.0)) + 2 * res
        with np.errstate(all="ignore"):
            nodes = float(np.prod((np.ptp(centres, axis=0) + 2 * reach) / res + 2))
        if not nodes <= _MAX_NODES:
            raise _Exit(
                f"--rho {args.rho} m: the octree box within rho of the points would hold {nodes:.3g} nodes at"
                f" --octree-res {res} (at most {_MAX_NODES}): use a smaller --rho or give --workspace"
            )
        box = box_around_points(centres, radii, args.rho, res)
    backend = OctreeBackend(box, mode="conservative", invalid=args.invalid, fill_radius=args.fill_radius)
    backend.update([CameraObservation(c, d, m) for c, d, m in zip(cameras, depths, masks, strict=True)])

    def query():
        return backend.query(centres, radii, rho=args.rho, mode=args.mode)

    return query


def add_distance_command(sub) -> None:
    """Add the ``distance`` command to the ``depthguard`` subparsers ``sub``."""
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
        "--direction-stride",
        type=_direction_stride,
        default="auto",
        metavar="auto|N",
        help="modes all/hybrid: the direction sum takes every N-th pixel in each direction (default auto: "
        "2 at 640 px wide, 1 below); the distance always uses every pixel",
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
        "--repeat", type=_repeat_count, default=0, metavar="N", help="also time N repeated queries (I/O excluded)"
    )
    p.add_argument(
        "--model",
        choices=["frustum", "icra", "ral16"],
        default="frustum",
        help="point-to-pixel distance: frustum lower bound (default), ICRA'12 eq. 4 or literal RA-L'16 eqs. 5-7",
    )
    p.add_argument(
        "--fill-radius",
        type=_pixel_radius,
        default=4,
        help="hole-filling radius in pixels (default 4; 0: every hole is unknown)",
    )
    _add_backend_options(p)
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=_cmd_distance)


def _add_backend_options(p) -> None:
    """The depth-grid (several cameras) and backend options of ``depthguard distance``."""
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
    p.add_argument("--octree-res", type=_octree_res, default=0.05, help="octree node size in m (0.02-0.1)")
