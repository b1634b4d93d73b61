"""What ``depthguard cell check`` prints: a cell file as :func:`depthguard.io.cellfile.read_cell` understood it."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np

from depthguard.io.cellfile import CellFile, node_names, node_tls_files, per_node_certificates, ssm_range

__all__ = ["describe_cell"]


def _calibration_notes(cell: CellFile) -> dict[str, str]:
    """Per camera that the cell file's ``calibration`` file places: where its extrinsics come from, the
    calibration's date and residual (for :func:`describe_cell`; the file was validated by :func:`read_cell`)."""
    ref = cell.raw.get("calibration")
    if not isinstance(ref, str):
        return {}
    cal = tomllib.loads((Path(cell.path).parent / ref).read_text(encoding="utf-8"))
    notes = {}
    for e in cal.get("cameras", []):
        rmse = f", inlier RMSE {float(e['rmse']) * 1000:.1f} mm" if "rmse" in e else ""
        notes[e["name"]] = f" (calibration '{ref}' of {e.get('date', 'no date')}{rmse})"
    return notes


def _background_line(cell: CellFile) -> str:
    """Whether ``run`` applies a background (``[controller] background``) and what it holds."""
    ref = cell.controller.get("background")
    if ref is None:
        return "background: none" + (
            " (SSM takes every surface the cameras see, table and floor included, for a person:"
            " `depthguard commission` records the empty cell)" * bool(cell.controller["ssm"])
        )
    from depthguard.io.background import read_background

    bg = read_background(ref)
    sizes = ", ".join(f"{n} {bg.size(k)[0]}x{bg.size(k)[1]}" for k, n in enumerate(bg.names))
    valid = ", ".join(f"{v:.0%}" for v in bg.valid_fraction)
    what = f"'{cell.raw['controller']['background']}' ({sizes}; {bg.frames} frame sets of {bg.source} on {bg.date};"
    what += f" valid {valid})"
    if cell.controller["ssm"]:
        return f"background: {what}: applied to the depth images before the distances (SSM on)"
    return f"background: {what}: not applied (SSM off: the repulsion sees the whole scene, the table included)"


def _network_line(cell: CellFile) -> str:
    """The nodes' network (docs/nodes.md): ports, transport, the allow-list, and with one certificate per
    node the nodes whose certificate file is missing."""
    net = cell.network
    names = node_names(cell)
    crt = net.get("tls_certificate", "")
    if not crt:
        tls = "plain TCP (no TLS)"
    elif not per_node_certificates(net):
        tls = "mutual TLS, one certificate for all nodes (the allow-list trusts the nodes' names)"
    else:
        missing = [n for n in names if not Path(node_tls_files(net, n)[0]).is_file()]
        tls = "mutual TLS, one certificate per node, Zenoh's access control on" + (
            f" (no certificate yet for: {', '.join(missing)})" if missing else ""
        )
    return (
        f"network: ROS domain {net['domain']}; nodes listen on {net['host']} ports {net['base_port']}-"
        f"{net['base_port'] + len(names) - 1}; {tls}; connect {net['connect']}; distances and commands only from"
        f" {net['publishers']}"
    )


def describe_cell(cell: CellFile) -> str:
    """A human-readable summary of what the cell file says (``depthguard cell check``)."""
    r = cell.robot
    lines = [f"cell '{cell.name}' ({cell.path})"]
    if cell.description:
        lines.append(f"  {cell.description}")
    lines.append(
        f"robot: {r.model or r.urdf}; ee frame {r.ee_frame or '(last link)'}; control points {r.control_points!r}"
        f" (ee radius {r.ee_radius} m)" + (f" + {len(r.spheres)} explicit spheres" if r.spheres else "")
    )
    for a in r.attachments:
        lines.append(f"  attachment '{a.name}' on {a.link}: {a.shape} {list(a.size) or a.mesh} at xyz {list(a.xyz)}")
    calibrated = _calibration_notes(cell)
    for c in cell.cameras:
        intr = c.params
        what = (
            f"{intr['width']}x{intr['height']} fx {intr['fx']} fy {intr['fy']} cx {intr['cx']} cy {intr['cy']}"
            if c.intrinsics == "file"
            else f"intrinsics from {c.intrinsics}"
        )
        pose = "extrinsics from TF"
        if c.R is not None:
            centre = -c.R.T @ c.t
            pose = f"centre {np.round(centre, 3).tolist()} m in '{c.parent}'" + calibrated.get(c.name, "")
        if c.align == "color":
            what = (
                'depth aligned to the colour stream (align = "color", rs.align; live RealSense only): intrinsics'
                " from the device's colour stream at the aligned resolution"
            )
            pose += "; these extrinsics place the colour camera's optical frame"
        lines.append(
            f"camera '{c.name}': {what}; depth {intr['min_depth']}-{intr['max_depth']} m; {pose};"
            f" topic {c.topic} ({c.rate:g} Hz)"
            + (f"; depth noise {c.noise_coeff:g} z^2 (self-filter margin >= 5 sigma)" if c.noise_coeff > 0 else "")
        )
    d = cell.distance
    lines.append(
        f"distance: backend {d['backend']} ({'depth grid' if len(cell.cameras) > 1 else 'depth space'}"
        f" for {len(cell.cameras)} camera(s)"
        * (d["backend"] == "depthspace")
        + ")" * (d["backend"] == "depthspace")
        + f"; rho {d['rho']} m, mode {d['mode']}, missing depth {d['invalid']} (fill {d['fill_radius']} px)"
    )
    c = cell.controller
    lines.append(
        f"controller: {c['rate']:g} Hz; timeouts: distances {c['distance_timeout']} s, joints {c['joint_timeout']} s;"
        f" resume after {c['resume_time']} s valid; SSM "
        + (f"on (distances up to {ssm_range(cell):g} m)" if c["ssm"] else "off")
    )
    lines.append(_background_line(cell))
    lines.append("topics: " + ", ".join(f"{k} {v}" for k, v in cell.topics.items()))
    lines.append(_network_line(cell))
    return "\n".join(lines)
