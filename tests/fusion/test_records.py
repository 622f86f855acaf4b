import numpy as np
import pytest

from boomtip.data.io.blocks import DiskBlocks
from boomtip.fusion.records import MemoryBlocks, Records


@pytest.mark.parametrize("store", [None, "memory", "disk"])
def test_rows_read_back_as_appended_across_blocks(store):
    s = {None: None, "memory": MemoryBlocks(), "disk": DiskBlocks()}[store]
    rec = Records(5, s, block_rows=4)
    rows = np.arange(11 * 5, dtype=float).reshape(11, 5) + 0.25
    for r in rows:
        rec.append(r)
    assert len(rec) == 11
    assert np.array_equal(rec.read(), rows)
    for a, b in ((0, 4), (3, 9), (8, 11), (10, 30), (5, 5), (-2, 2)):
        assert np.array_equal(rec.read(a, b), rows[max(a, 0):b]), (a, b)
    assert np.array_equal(rec.column(2), rows[:, 2]) and np.array_equal(rec.column(slice(1, 3)), rows[:, 1:3])


def test_the_last_row_stays_in_memory_and_can_be_amended_even_when_its_block_is_full():
    rec = Records(3, DiskBlocks(), block_rows=2)
    rec.append(np.zeros(3))
    rec.append(np.ones(3))  # the block is full, and not yet written
    rec.last[1] += 5.0
    rec.append(np.full(3, 2.0))  # now it is, with the amendment
    assert rec.read().tolist() == [[0, 0, 0], [1, 6, 1], [2, 2, 2]]


def test_nothing_recorded():
    rec = Records(4)
    assert len(rec) == 0 and rec.read().shape == (0, 4) and rec.column(1).shape == (0,)
    with pytest.raises(IndexError):
        rec.last
