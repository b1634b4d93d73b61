"""OctoMap files of an obstacle octree (SAPHARI Fig. 6): ``occupied.bt`` and ``occluded.bt`` (binary
occupancy trees, one per node kind, since a ``.bt`` stores only occupancy) and ``octree.ot``, one
``ColorOcTree`` with occupied nodes red, occluded nodes orange and unseen nodes (conservative mode) grey.
Readable by OctoMap's tools (octovis) and by ``pyoctomap`` (``OcTree.readBinary``, ``ColorOcTree.read``).
Needs the ``octree`` extra (``pyoctomap``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["COLORS", "write_octomap"]

COLORS = {1: (255, 0, 0), 2: (255, 165, 0), 3: (128, 128, 128)}  # occupied, occluded, unseen


def _import():
    try:
        import pyoctomap
    except ImportError as exc:  # pragma: no cover - the extra is installed in CI
        raise ImportError("OctoMap export needs pyoctomap: pip install 'depthguard[octree]'") from exc
    return pyoctomap


def write_octomap(frame, out_dir: str | Path) -> dict[str, Path]:
    """Write ``occupied.bt``, ``occluded.bt`` (occluded and unseen nodes) and ``octree.ot`` for an
    :class:`~depthguard.octree.fusion.OctreeFrame`; returns their paths. Node centres are on the frame's
    lattice, which must be aligned with OctoMap's (box origin a multiple of the resolution, as
    :meth:`~depthguard.octree.grid.VoxelBox.around` makes it)."""
    pyoctomap = _import()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    box = frame.box
    if np.any(np.abs(box.origin / box.res - np.round(box.origin / box.res)) > 1e-6):
        raise ValueError(f"box origin {box.origin} is not on OctoMap's lattice of {box.res} m")
    paths = {}
    centres = {k: box.centres(np.argwhere(frame.kind == k)) for k in COLORS}
    for name, kinds in (("occupied.bt", (1,)), ("occluded.bt", (2, 3))):
        tree = pyoctomap.OcTree(box.res)
        for k in kinds:
            if len(centres[k]):
                tree.updateNodes(np.ascontiguousarray(centres[k]), True)
        tree.updateInnerOccupancy()
        paths[name] = out / name
        tree.writeBinary(str(paths[name]))
    color = pyoctomap.ColorOcTree(box.res)
    for k, rgb in COLORS.items():
        for c in centres[k]:
            color.updateNode(c, True)
            color.setNodeColor(c, *rgb)
    color.updateInnerOccupancy()
    paths["octree.ot"] = out / "octree.ot"
    color.write(str(paths["octree.ot"]))
    return paths
