"""OctoMap export (read back with pyoctomap) and octree pruning."""

from __future__ import annotations

import numpy as np
import pytest

from depthguard.octree.fusion import OctreeFrame
from depthguard.octree.grid import VoxelBox
from depthguard.octree.tree import prune

pyoctomap = pytest.importorskip("pyoctomap")

BOX = VoxelBox.around([-0.4, -0.4, 0.0], [0.4, 0.4, 0.6], 0.05)


def frame_with(kind):
    return OctreeFrame(BOX, kind != 0, kind, np.ones(BOX.shape, bool), np.zeros((1, *BOX.shape), np.uint8), "saphari")


def test_written_trees_read_back_with_occupied_and_occluded_apart(tmp_path):
    from depthguard.io.octomap import COLORS, write_octomap

    kind = np.zeros(BOX.shape, np.uint8)
    kind[2:4, 2:4, 2:4] = 1
    kind[6:10, 6:8, 1:3] = 2
    kind[0, 0, 0] = 3
    paths = write_octomap(frame_with(kind), tmp_path)
    occ = pyoctomap.OcTree(0.05)
    assert occ.readBinary(str(paths["occupied.bt"]))
    hid = pyoctomap.OcTree(0.05)
    assert hid.readBinary(str(paths["occluded.bt"]))
    for k, tree, other in ((1, occ, hid), (2, hid, occ), (3, hid, occ)):
        for c in BOX.centres(np.argwhere(kind == k)):
            node = tree.search(c)
            assert node is not None and tree.isNodeOccupied(node)
            assert other.search(c) is None
    # free nodes are not in either tree
    free_c = BOX.centres(np.array([[5, 5, 8]]))[0]
    assert occ.search(free_c) is None and hid.search(free_c) is None
    col = pyoctomap.ColorOcTree(0.05).read(str(paths["octree.ot"]))
    for ijk, k in (([2, 2, 2], 1), ([6, 6, 1], 2), ([0, 0, 0], 3)):
        node = col.search(BOX.centres(np.array([ijk]))[0])
        assert tuple(node.getColor()) == COLORS[k]
    assert len({COLORS[1], COLORS[2], COLORS[3]}) == 3


def test_prune_merges_solid_blocks_and_keeps_the_volume():
    occ = np.zeros(BOX.shape, bool)
    occ[0:8, 0:8, 0:8] = True  # one 8^3 block aligned with the lattice: prunes to a single leaf
    occ[10, 10, 10] = True
    leaves = prune(occ, BOX)
    n = sum(len(c) for _, c in leaves)
    vol = sum(len(c) * s**3 for s, c in leaves)
    assert vol == pytest.approx(occ.sum() * 0.05**3)
    assert n == 2
    # every original node lies in exactly one leaf
    centres = BOX.centres(np.argwhere(occ))
    hits = np.zeros(len(centres), int)
    for s, corners in leaves:
        for lo in corners:
            hits += np.all((centres >= lo) & (centres < lo + s), axis=1)
    assert (hits == 1).all()
