"""Cameras carried by a robot link (a wrist camera): their world pose at a joint state, and the cell file's
``cameras[i].parent`` checked against the robot (``docs/real-cell.md``, §1)."""

from __future__ import annotations

import numpy as np

from depthguard.camera import Camera
from depthguard.io.cellfile import CellError, CellFile
from depthguard.robot.model import RobotModel

__all__ = ["carried_camera", "place_carried", "check_camera_parents", "refuse_carried_cameras"]


def carried_camera(local: Camera, model: RobotModel, q: np.ndarray, link: str) -> Camera:
    """The world-frame camera of ``local`` (its pose ``P_C = R P_L + t`` in ``link``'s frame) at joint
    positions ``q`` (n,): with the link's pose ``P_W = R_l P_L + p_l``, ``P_C = (R R_lᵀ) P_W + t - R R_lᵀ p_l``."""
    R_l, p_l = model.frame_pose(q, link)
    R = local.R @ R_l.T
    return local.with_pose(R, local.t - R @ p_l)


def place_carried(
    cameras: list[Camera], carried: list[tuple[int, str]], model: RobotModel, q: np.ndarray
) -> list[Camera]:
    """``cameras`` with each carried one (``carried``: ``(index, link)``, its pose in the link's frame) placed
    where its link is at joint positions ``q`` (:func:`carried_camera`); a new list."""
    out = list(cameras)
    for i, link in carried:
        out[i] = carried_camera(cameras[i], model, q, link)
    return out


def check_camera_parents(cell: CellFile, model: RobotModel, parents: list[str] | None = None) -> list[tuple[int, str]]:
    """``(index, link)`` of every camera carried by a robot link (``parents``: default the cell file's);
    a parent that is neither ``"world"`` nor a frame of ``model`` raises :class:`CellError` naming the key."""
    parents = list(parents) if parents is not None else [c.parent for c in cell.cameras]
    carried = []
    for i, link in enumerate(parents):
        if link == "world":
            continue
        if not model.model.existFrame(link):
            raise CellError(
                f"{cell.path}: cameras[{i}].parent = {link!r} is not a link of the robot; links:"
                f" {[f.name for f in model.model.frames]}"
            )
        carried.append((i, link))
    return carried


def refuse_carried_cameras(cell: CellFile, what: str, why: str) -> None:
    """Refuse a camera carried by a robot link where ``what`` takes world cameras only, saying ``why``."""
    carried = [f"cameras[{i}].parent = {c.parent!r}" for i, c in enumerate(cell.cameras) if c.parent != "world"]
    if carried:
        raise CellError(f"{cell.path}: {', '.join(carried)}: {what} takes cameras fixed in the world only ({why})")
