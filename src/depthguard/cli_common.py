"""Shared pieces of the command line (:mod:`depthguard.cli`, :mod:`depthguard.cli_cell`)."""

from __future__ import annotations

import argparse
import math
import os
from collections.abc import Callable
from pathlib import Path


class CliExit(Exception):
    """Raised by commands for a clean error exit (one line on stderr, exit code 2)."""


def check_out_dir(path: str) -> None:
    """Create the output folder ``path`` now, before any work, or raise :class:`CliExit` naming it
    (:func:`depthguard.io.files.prepare_out_dir`)."""
    from depthguard.errors import InputError
    from depthguard.io.files import prepare_out_dir

    try:
        prepare_out_dir(path, "--out")
    except InputError as exc:
        raise CliExit(str(exc)) from None


def parse_workspace(text: str) -> tuple[float, ...]:
    """``--workspace``: six finite numbers xmin,xmax,ymin,ymax,zmin,zmax with min < max."""
    try:
        vals = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--workspace must be xmin,xmax,ymin,ymax,zmin,zmax numbers, got {text!r}"
        ) from None
    if (
        len(vals) != 6
        or not all(math.isfinite(v) for v in vals)
        or any(vals[2 * i] >= vals[2 * i + 1] for i in range(3))
    ):
        raise argparse.ArgumentTypeError(
            f"--workspace must be xmin,xmax,ymin,ymax,zmin,zmax finite numbers with min < max, got {text!r}"
        ) from None
    return vals


def _number(text: str, cast, what: str, lo: float, hi: float, lo_open: bool = False):
    """``cast(text)`` if it is a finite number in [lo, hi] (``lo_open``: (lo, hi]), else an argparse error naming
    the expected form (argparse adds the option's name)."""
    try:
        x = cast(text)
        ok = math.isfinite(float(x))  # (an int beyond a float's range: OverflowError)
    except (ValueError, OverflowError):
        x, ok = None, False
    if not ok or not ((lo < x) if lo_open else (lo <= x)) or not x <= hi:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
    return x


def positive_float(text: str) -> float:
    return _number(text, float, "a positive number", 0.0, math.inf, lo_open=True)


def positive_int(text: str) -> int:
    return _number(text, int, "a positive integer", 0, math.inf, lo_open=True)


def bounded_int(lo: int, hi: int, what: str) -> Callable[[str], int]:
    """An argparse type: an integer in [lo, hi]; ``what`` names it in the error."""

    def parse(text: str) -> int:
        return _number(text, int, f"{what}, an integer in [{lo}, {hi}]", lo, hi)

    parse.__name__ = what.replace(" ", "_")
    return parse


def bounded_float(lo: float, hi: float, what: str, lo_open: bool = True) -> Callable[[str], float]:
    """An argparse type: a finite number in (lo, hi] (``lo_open=False``: [lo, hi])."""

    def parse(text: str) -> float:
        span = f"{'(' if lo_open else '['}{lo:g}, {hi:g}]"
        return _number(text, float, f"{what}, a number in {span}", lo, hi, lo_open=lo_open)

    parse.__name__ = what.replace(" ", "_")
    return parse


#: ``--repeat`` of ``depthguard distance``
repeat_count = bounded_int(1, 1_000_000, "a number of queries")
#: ``--direction-stride`` (pixels) of ``depthguard distance``
pixel_stride = bounded_int(1, 10_000, "a stride in pixels")
#: ``--frames`` of ``depthguard commission``
frame_count = bounded_int(1, 1_000_000, "a number of frame sets")
#: ``--fill-radius``: pixels (any radius beyond the image is the whole image)
pixel_radius = bounded_int(0, 10_000, "a radius in pixels")
#: ``--port``, ``--view-port``
tcp_port = bounded_int(1, 65535, "a TCP port")
#: ``--zenoh-domain`` (as the cell file's ``network.domain``)
ros_domain = bounded_int(0, 232, "a ROS domain id")
#: ``--rt-priority`` (``SCHED_FIFO``)
rt_priority = bounded_int(1, 99, "a SCHED_FIFO priority")
#: ``--days`` of ``depthguard certs`` (100 years at most: openssl's dates end in year 9999)
cert_days = bounded_int(1, 36_500, "a number of days")
#: ``--duration``: seconds (None: run until stopped)
duration_s = bounded_float(0.0, 1e9, "a number of seconds")
#: ``--watchdog`` of the sim node: a driver watchdog longer than a second no longer holds a runaway arm
watchdog_s = bounded_float(0.0, 1.0, "a watchdog timeout in seconds")
#: ``--margin`` of ``depthguard commission``: a background tolerance of metres would hide a person from the monitor
background_margin = bounded_float(0.0, 1.0, "a tolerance in m", lo_open=False)
#: ``--noise-coeff`` (sigma = C z^2; a Kinect's C is about 0.003: 0.1 is already 0.9 m at 3 m)
noise_coeff = bounded_float(0.0, 0.1, "a noise coefficient", lo_open=False)
#: ``--octree-res`` (:func:`depthguard.octree.grid.check_res`'s range)
octree_res = bounded_float(0.02, 0.1, "an octree node size in m", lo_open=False)


def zenoh_endpoint(text: str) -> str:
    """``--zenoh-connect``: a Zenoh endpoint ``PROTOCOL/HOST:PORT`` (as the cell file's ``network.connect``)."""
    from depthguard.io.cell_network import check_endpoint
    from depthguard.io.cellfile import CellError

    try:
        check_endpoint(Path("."), "endpoint", text)
    except CellError:
        raise argparse.ArgumentTypeError(
            f'expected a Zenoh endpoint such as "tcp/127.0.0.1:7447" (PROTOCOL/HOST:PORT), got {text!r}'
        ) from None
    return text


def host_name(text: str) -> str:
    """``--host`` of ``depthguard certs``: an IP address or a host name (a certificate's alternative name)."""
    from depthguard.validation import is_host

    if not is_host(text):
        raise argparse.ArgumentTypeError(f"expected an IP address or a host name, got {text!r}")
    return text


def path_text(text: str) -> str:
    """A path option's value: not empty (an empty path would silently mean the current folder, or nothing)."""
    if not text.strip():
        raise argparse.ArgumentTypeError(f"expected a path, got {text!r}")
    return text


def check_source(spec: str, kinds: tuple[str, ...], option: str = "--source") -> None:
    """``--source`` of the form ``bag:PATH``, ``sim:SCENARIO`` or ``realsense`` (those in ``kinds``), checked before
    any work; else :class:`CliExit` naming the option and the forms."""
    forms = {"bag": "bag:PATH", "sim": "sim:SCENARIO", "realsense": "realsense"}
    expected = " or ".join(forms[k] for k in kinds)
    kind, sep, arg = spec.partition(":")
    if kind not in kinds:
        raise CliExit(f"{option} must be {expected}, got {spec!r}")
    if kind == "realsense" and sep:
        raise CliExit(f"{option} realsense takes no ':' part (one camera, from the cell file), got {spec!r}")
    if kind != "realsense" and not arg.strip():
        raise CliExit(f"{option} must be {expected} with a non-empty {forms[kind].partition(':')[2]}, got {spec!r}")


def check_out_file(path: str, option: str) -> None:
    """``path`` as a file to write (not a folder, in a writable folder that exists), checked before any work;
    else :class:`CliExit` naming ``option``."""
    p = Path(path)
    parent = p.parent if str(p.parent) else Path(".")
    if p.is_dir():
        raise CliExit(f"{option} '{p}' is a folder, expected a file name")
    if not parent.is_dir():
        raise CliExit(f"{option} '{p}': the folder '{parent}' does not exist")
    if not os.access(parent, os.W_OK) or (p.exists() and not os.access(p, os.W_OK)):
        raise CliExit(f"{option} '{p}': not writable (permission denied)")
