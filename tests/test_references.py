"""The references themselves: a later voxel row wins; the oracle caps and counts steps."""

import numpy as np

from references import apply_edits, oracle_distance


def test_a_later_voxel_row_wins():
    voxels = np.zeros((2, 2, 2), np.uint8)
    apply_edits(voxels, [{"op": "voxels", "voxels": [[1, 0, 0, 5], [0, 1, 1, 6], [1, 0, 0, 7]]}])
    assert voxels[0, 0, 1] == 7 and voxels[1, 1, 0] == 6 and voxels.sum() == 13


def test_the_oracle_caps_and_counts_steps():
    voxels = np.zeros((1, 1, 6), np.uint8)
    voxels[0, 0, 0] = 1
    assert oracle_distance(voxels, 3).tolist() == [[[0, 1, 2, 3, 3, 3]]]
    assert oracle_distance(np.zeros((2, 2, 2), np.uint8), 4).max() == 4
