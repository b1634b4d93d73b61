"""File formats (DESIGN.md §3): camera JSON, points JSON, depth images, masks."""

from depthguard.io.files import (
    ControlPoint,
    read_camera,
    read_depth,
    read_mask,
    read_points,
    write_camera,
    write_depth,
    write_mask,
    write_points,
)

__all__ = [
    "ControlPoint",
    "read_camera",
    "read_depth",
    "read_mask",
    "read_points",
    "write_camera",
    "write_depth",
    "write_mask",
    "write_points",
]
