"""File formats (``docs/conventions.md``, "File formats"): camera JSON, points JSON, depth images, masks."""

from depthguard.errors import InputError
from depthguard.io.files import (
    ControlPoint,
    check_input_file,
    prepare_out_dir,
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
    "InputError",
    "check_input_file",
    "prepare_out_dir",
    "read_camera",
    "read_depth",
    "read_mask",
    "read_points",
    "write_camera",
    "write_depth",
    "write_mask",
    "write_points",
]
