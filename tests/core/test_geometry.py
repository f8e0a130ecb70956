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


def test_touch_and_union_agree_with_growing_and_intersecting_boxes():
    import random

    from sdfserver.geometry import touch

    rng = random.Random()
    for _ in range(20000):
        a, b = (_random_box(rng) for _ in range(2))
        assert touch(a, b) == a.grow(1).overlaps(b), (a, b)
        union = a.union(b)
        assert union.contains(a) and union.contains(b)
        assert union.lo == tuple(map(min, a.lo, b.lo)) and union.hi == tuple(map(max, a.hi, b.hi))


def test_a_step_of_many_boxes_grows_to_the_regions_one_box_at_a_time_would():
    """The dirty set grows many boxes on arrays; the regions are those of the plain loop."""
    import random

    import sdfserver.dirty as dirty
    from sdfserver.world import WorldConfig

    rng = random.Random()
    for _ in range(60):
        size = tuple(rng.choice((16, 48, 64, 100)) for _ in range(3))
        config = WorldConfig(size=size, chunk_size=rng.choice((8, 16)), max_distance=rng.choice((0, 3, 16, 255)),
                             borders=rng.choice(("exact", "padded")), algorithm="brute")
        boxes = dirty.DirtySet()
        boxes.add([Box(b.lo, tuple(min(h, s) for h, s in zip(b.hi, size))) for b in
                   (_random_box(rng, size) for _ in range(rng.randrange(dirty.VECTOR_BOXES, 40)))])
        on_arrays = boxes.regions(config)
        vector_boxes, dirty.VECTOR_BOXES = dirty.VECTOR_BOXES, 10**9
        try:
            one_at_a_time = boxes.regions(config)
        finally:
            dirty.VECTOR_BOXES = vector_boxes
        assert sorted(on_arrays, key=str) == sorted(one_at_a_time, key=str)


def _random_box(rng, size=(20, 20, 20)) -> Box:
    lo = tuple(rng.randrange(0, s - 1) for s in size)
    return Box(lo, tuple(min(s, v + rng.randrange(1, 9)) for v, s in zip(lo, size)))
