"""Shared pieces of the command line (:mod:`depthguard.cli`, :mod:`depthguard.cli_cell`)."""

from __future__ import annotations

import argparse

import numpy as np


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


def _positive(text: str, cast, what: str):
    """``cast(text)`` if it is a finite number > 0, else an argparse error naming the expected form."""
    try:
        x = cast(text)
    except ValueError:
        x = None
    if x is None or not (np.isfinite(x) and x > 0):
        raise argparse.ArgumentTypeError(f"expected a positive {what}, got {text!r}") from None
    return x


def positive_float(text: str) -> float:
    return _positive(text, float, "number")


def positive_int(text: str) -> int:
    return _positive(text, int, "integer")


# ----------------------------------------------------------------------------------------------- distance
