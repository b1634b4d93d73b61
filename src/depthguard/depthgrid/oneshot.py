"""One-shot fused distances for the command line (``depthguard distance``): one camera through the depth
space, several through the depth grid (:class:`~depthguard.depthgrid.fusion.DepthGridFusion`)."""

from __future__ import annotations

import numpy as np

from depthguard.camera import Camera
from depthguard.depthgrid.fusion import DepthGridFusion
from depthguard.depthspace import PointDistances, prepare_frame, query_distances

__all__ = ["fused_distances"]


def fused_distances(
    cameras: list[Camera],
    depths: list[np.ndarray],
    masks: list[np.ndarray | None] | None,
    centres: np.ndarray,
    radii: np.ndarray | float,
    rho: float = 0.4,
    mode: str = "all",
    invalid: str = "conservative",
    dd: float = 0.01,
    workspace: tuple[float, float, float, float, float, float] | None = None,
    map_mode: str = "onthefly",
) -> PointDistances:
    """One-shot fused distances for the command line (``depthguard distance`` with several cameras).

    With one camera this is :func:`depthguard.depthspace.query_distances`; with two or more it builds a
    :class:`DepthGridFusion` (the first camera is the principal one), updates it once and queries it.
    """
    cameras = list(cameras)
    if len(cameras) == 1:
        frame = prepare_frame(cameras[0], depths[0], None if masks is None else masks[0], invalid=invalid)
        return query_distances(frame, centres, radii, rho=rho, mode=mode)
    fusion = DepthGridFusion(cameras, dd=dd, workspace=workspace, map_mode=map_mode)
    fusion.update(depths, masks, invalid=invalid)
    return fusion.query(centres, radii, rho=rho, mode=mode)
