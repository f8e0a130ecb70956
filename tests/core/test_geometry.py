from sdfserver.geometry import Box, merge_regions


def test_snap_and_chunk_range():
    box = Box((3, 17, 0), (9, 33, 1))
    assert box.snap(16) == Box((0, 16, 0), (16, 48, 16))
    assert box.chunk_range(16) == Box((0, 1, 0), (1, 3, 1))


def test_merge_keeps_apart_and_joins_touching():
    a, b, c = Box((0, 0, 0), (8, 8, 8)), Box((8, 0, 0), (16, 8, 8)), Box((32, 32, 32), (40, 40, 40))
    merged = merge_regions([a, c, b])
    assert sorted(merged, key=lambda r: r.lo) == [Box((0, 0, 0), (16, 8, 8)), c]
    # After merging, no region's one-voxel shell may touch another region.
    assert not merged[0].grow(1).overlaps(merged[1])


def test_merge_chains_until_stable():
    boxes = [Box((i * 10, 0, 0), (i * 10 + 10, 1, 1)) for i in range(5)]
    assert merge_regions(boxes[::-1]) == [Box((0, 0, 0), (50, 1, 1))]
