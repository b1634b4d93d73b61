"""The per-frame update of :class:`~depthguard.depthgrid.fusion.DepthGridFusion` (its frame stage).

:meth:`DepthGridFusion.update <depthguard.depthgrid.fusion.DepthGridFusion.update>` runs two parts, on two
threads when it is given a ``side`` executor; they write disjoint arrays of the fusion object:

* :func:`update_principal`: the principal camera's segment starts and kinds and their tile bounds
  (``_start``, ``_kind``, ``_tmin``, ``_tmax``);
* :func:`update_secondary`: the secondary cameras' robot windows, votes and vote pyramid (``_votes``,
  ``_has_windows``, ``_pyr``).

The per-pixel kernels they call are in :mod:`~depthguard.depthgrid.frames`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from depthguard.depthgrid.chunks import tile_bounds
from depthguard.depthgrid.frames import limit_robot_votes, prepare_principal, prepare_secondary, write_windows
from depthguard.depthgrid.pyramid import build_pyramid, window_aware_votes
from depthguard.depthspace import TILE

if TYPE_CHECKING:
    from depthguard.depthgrid.fusion import DepthGridFusion

__all__ = ["update_principal", "update_secondary"]


def _image(cam, image, name: str, dtype):
    return np.ascontiguousarray(cam.check_image(image, name), dtype=dtype)


def update_principal(fusion: DepthGridFusion, depth, mask, conservative: bool) -> None:
    """The principal camera's part of :meth:`DepthGridFusion.update`: segment starts and kinds, and their tile
    bounds."""
    cam = fusion.cameras[0]
    d = _image(cam, depth, "depth", np.float32)
    has_mask = mask is not None
    robot = _image(cam, mask, "mask", np.bool_) if has_mask else np.zeros((1, 1), dtype=np.bool_)
    prepare_principal(
        d,
        robot,
        has_mask,
        fusion.fill_radius,
        np.float32(cam.min_depth),
        conservative,
        fusion._start,
        fusion._kind,
        fusion._fill_scratch,
        fusion._hole_at,
    )
    fusion._tmin, fusion._tmax = tile_bounds(fusion._start, fusion._kind, TILE)


def update_secondary(fusion: DepthGridFusion, depths, masks, conservative: bool, windows) -> None:
    """The secondary cameras' part of :meth:`DepthGridFusion.update`: robot windows, votes and the vote pyramid
    (it touches nothing that :func:`update_principal` writes)."""
    if callable(windows):
        windows = windows()
        if windows is not None and len(windows) != len(fusion.cameras):
            raise ValueError(f"windows: got {len(windows)} entries for {len(fusion.cameras)} cameras")
    hm = fusion._hm
    fusion._has_windows = write_windows(fusion._votes, hm, fusion.cameras, windows)
    for k in range(1, len(fusion.cameras)):
        cam, mask = fusion.cameras[k], masks[k]
        d = _image(cam, depths[k], "depth", np.float32)
        has_mask = mask is not None
        robot = _image(cam, mask, "mask", np.bool_) if has_mask else np.zeros((1, 1), dtype=np.bool_)
        prepare_secondary(
            d,
            robot,
            has_mask,
            conservative,
            fusion.robot_occludes,
            np.float32(fusion.vote_margin),
            fusion._votes[k - 1, : cam.height, : cam.width],
        )
    if not fusion.robot_occludes:  # several secondary cameras: see limit_robot_votes
        limit_robot_votes(
            fusion.cameras[1:],
            depths[1:],
            masks[1:],
            [fusion._votes[k - 1, : c.height, : c.width] for k, c in enumerate(fusion.cameras[1:], start=1)],
            fusion.vote_margin,
        )
    base = window_aware_votes(fusion._votes, hm) if fusion._has_windows else fusion._votes[:, :hm]
    build_pyramid(np.ascontiguousarray(base), fusion._pyr_meta, fusion._pyr)
