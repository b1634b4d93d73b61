"""OctoMap files of an obstacle octree (SAPHARI Fig. 6): ``occupied.bt`` and ``occluded.bt`` (binary
occupancy trees, one per node kind, since a ``.bt`` stores only occupancy) and ``octree.ot``, one
``ColorOcTree`` with occupied nodes red, occluded nodes orange and unseen nodes (conservative mode) grey.
Readable by OctoMap's tools (octovis) and by ``pyoctomap`` (``OcTree.readBinary``, ``ColorOcTree.read``).
Needs the ``octree`` extra (``pyoctomap``).

The ``.bt`` files are pruned (eight occupied siblings become one larger leaf, as OctoMap writes them); the
``.ot`` file keeps every node at the finest depth, since OctoMap prunes a ``ColorOcTree`` by occupancy
alone and would give eight siblings of different kinds one averaged colour.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["COLORS", "KEY_RANGE", "write_octomap"]

COLORS = {1: (255, 0, 0), 2: (255, 165, 0), 3: (128, 128, 128)}  # occupied, occluded, unseen
#: OctoMap's 16-bit keys: node index ``floor(x / res)`` along each axis within ``[-32768, 32767]``, so
#: coordinates within about ``±32768 res`` (±655 m at 0.02 m, ±3277 m at 0.1 m).
KEY_RANGE = (-32768, 32767)


def _import():
    try:
        import pyoctomap
    except ImportError as exc:  # pragma: no cover - the extra is installed in CI
        raise ImportError("OctoMap export needs pyoctomap: pip install 'depthguard[octree]'") from exc
    return pyoctomap


def _node_indices(frame) -> tuple[np.ndarray, np.ndarray]:
    """``(keys (M, 3) int64, kinds (M,))``: the nodes of ``frame`` on OctoMap's lattice (index ``k`` is the
    node ``[k res, (k + 1) res)`` per axis). ``ValueError`` for a box off that lattice, a ``kind`` array of
    another shape than the box or with other values than 0-3, and nodes outside OctoMap's key range."""
    box = frame.box
    res = float(box.res)
    if not (np.isfinite(res) and res > 0):
        raise ValueError(f"OctoMap export: resolution must be a positive number of metres, got {box.res}")
    if float(f"{res:.6g}") != res:  # (OctoMap writes the resolution as text, to 6 significant digits)
        raise ValueError(
            f"OctoMap export: resolution {res!r} m does not survive OctoMap's file header, which keeps 6"
            f" significant digits ({res:.6g}): the file's lattice would not be the frame's"
        )
    cells = np.asarray(box.origin, float) / res
    if not np.all(np.isfinite(cells)) or np.any(np.abs(cells - np.round(cells)) > 1e-6):
        raise ValueError(
            f"OctoMap export: box origin {box.origin} is not on OctoMap's lattice of {res} m "
            "(it must be a multiple of the resolution, as VoxelBox.around makes it)"
        )
    kind = np.asarray(frame.kind)
    if kind.shape != tuple(box.shape):
        raise ValueError(f"OctoMap export: node kinds of shape {kind.shape} for a box of shape {tuple(box.shape)}")
    bad = ~np.isin(kind, (0, *COLORS))
    if bad.any():
        raise ValueError(f"OctoMap export: node kind {int(kind[bad][0])} is none of 0 (free) and {sorted(COLORS)}")
    idx = np.argwhere(kind != 0)
    keys = idx.astype(np.int64) + np.round(cells).astype(np.int64)
    if len(keys) and (keys.min() < KEY_RANGE[0] or keys.max() > KEY_RANGE[1]):
        lo, hi = KEY_RANGE[0] * res, (KEY_RANGE[1] + 1) * res
        raise ValueError(
            f"OctoMap export: nodes beyond OctoMap's key range at {res} m (coordinates within [{lo:g}, {hi:g}) m "
            f"per axis); the box spans {box.origin} to {box.hi}"
        )
    return keys, kind[kind != 0]


def _written(ok: object, path: Path) -> Path:
    """``path``, or ``OSError`` naming it when OctoMap reports that it could not write it."""
    if ok is False or not path.is_file():
        raise OSError(f"OctoMap export: could not write {path}")
    return path


def write_octomap(frame, out_dir: str | Path) -> dict[str, Path]:
    """Write ``occupied.bt``, ``occluded.bt`` (occluded and unseen nodes) and ``octree.ot`` (colours
    :data:`COLORS`) for an :class:`~depthguard.octree.fusion.OctreeFrame` into ``out_dir`` (created if
    missing; files of these names are replaced); returns their paths.

    Node centres are on the frame's lattice, which must be aligned with OctoMap's (box origin a multiple of
    the resolution, as :meth:`~depthguard.octree.grid.VoxelBox.around` makes it): every node of the frame is
    the OctoMap leaf of the same cube at the finest depth.

    Raises:
        ValueError: a box off OctoMap's lattice, a resolution of more than 6 significant digits (OctoMap's
            file header keeps 6), nodes beyond OctoMap's key range (:data:`KEY_RANGE`), node
            kinds of another shape than the box or other than 0-3; nothing is written then.
        OSError: ``out_dir`` is not a writable folder (naming the path).
    """
    pyoctomap = _import()
    keys, kinds = _node_indices(frame)
    res = float(frame.box.res)
    centres = {k: np.ascontiguousarray((keys[kinds == k] + 0.5) * res) for k in COLORS}
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {}
    for name, kinds_in in (("occupied.bt", (1,)), ("occluded.bt", (2, 3))):
        tree = pyoctomap.OcTree(res)
        for k in kinds_in:
            if len(centres[k]):
                tree.updateNodes(centres[k], True)
        tree.updateInnerOccupancy()
        paths[name] = _written(tree.writeBinary(str(out / name)), out / name)
    color = pyoctomap.ColorOcTree(res)
    for k, rgb in COLORS.items():
        for c in centres[k]:
            color.updateNode(c, True, True)  # (lazy: no pruning, which would merge nodes of other colours)
            color.setNodeColor(c, *rgb)
    if len(keys):  # (pyoctomap's ColorOcTree.updateInnerOccupancy crashes the process on an empty tree)
        color.updateInnerOccupancy()
    paths["octree.ot"] = _written(color.write(str(out / "octree.ot")), out / "octree.ot")
    return paths
