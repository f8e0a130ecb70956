"""The brick table of a sparse snapshot a client sends: every stored brick named exactly once,
inside the world, no solid brick of colour 0, no block twice (each file here has a consistent
field, so only these rules can refuse it)."""

import struct

import numpy as np
import pytest

from sdfserver.errors import InvalidInput
from sdfserver.storage.sparse_snapshot import SparseContent, check_upload, parse_sparse

SIZE, BRICK, CAP = (32, 16, 16), 16, 4  # bricks 2 x 1 x 1, one table block


def content(codes_at: dict[tuple[int, int, int], int], bricks: int) -> SparseContent:
    """Stored bricks of air at the cap (a valid field), named at (bx, by, bz)."""
    codes = np.full((16, 16, 16), -1, dtype=np.int32)
    for (x, y, z), code in codes_at.items():
        codes[z, y, x] = code
    voxels = np.zeros((bricks, BRICK, BRICK, BRICK), np.uint8)
    field = np.full((bricks, BRICK, BRICK, BRICK), CAP << 8, np.uint16)
    return SparseContent(BRICK, {(0, 0, 0): codes}, voxels, field)


def refuse(reason: str) -> InvalidInput:
    return InvalidInput(reason)


def test_a_table_naming_each_stored_brick_once_passes():
    check_upload(content({(0, 0, 0): 0, (1, 0, 0): 1}, 2), SIZE, CAP, refuse)


@pytest.mark.parametrize("codes_at, bricks, why", [
    ({(0, 0, 0): 0, (1, 0, 0): 0}, 1, "named 2 times"),  # two bricks, one slot: they would change together
    ({(0, 0, 0): 0}, 2, "named 0 times"),  # a stored brick nothing names
    ({(0, 0, 0): -2}, 0, "colour 0"),
    ({(0, 0, 0): 0, (5, 0, 0): 1}, 2, "beyond the world"),  # stored brick x 5 of a world 2 bricks wide
])
def test_a_table_that_breaks_a_rule_is_refused(codes_at, bricks, why):
    with pytest.raises(InvalidInput) as info:
        check_upload(content(codes_at, bricks), SIZE, CAP, refuse)
    assert why in str(info.value)


def test_a_block_listed_twice_is_refused():
    record = np.array([0, 0, 0, 1, -1], dtype="<i4").tobytes()
    with pytest.raises(InvalidInput, match="twice"):
        parse_sparse(record + record, 2 * len(record), 0, BRICK, lambda at, why: InvalidInput(why))
    assert struct.calcsize("<5i") == len(record)


def test_uniform_codes_beyond_the_worlds_side_are_allowed():
    """A uniform solid block split by an edit keeps its code for bricks past the side: harmless."""
    check_upload(content({(0, 0, 0): 0, (1, 0, 0): 1, (5, 0, 0): -9}, 2), SIZE, CAP, refuse)
