"""Shared pieces of the command line (:mod:`depthguard.cli`, :mod:`depthguard.cli_cell`)."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


class CliExit(Exception):
    """Raised by commands for a clean error exit (one line on stderr, exit code 2)."""


def check_out_dir(path: str) -> None:
    """Create the output folder ``path`` now, before any work, or raise :class:`CliExit` naming it."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise CliExit(f"--out {path}: exists and is not a directory")
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CliExit(f"--out {path}: cannot create it ({exc.strerror})") from None


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


def positive_float(text: str) -> float:
    try:
        x = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
    if not (np.isfinite(x) and x > 0):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
    return x


def positive_int(text: str) -> int:
    try:
        x = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if x < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    return x


# ----------------------------------------------------------------------------------------------- distance
