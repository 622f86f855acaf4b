import numpy as np
import pytest

from boomtip.data.io.blocks import DiskBlocks


def test_blocks_read_back_by_row_ranges():
    d = DiskBlocks()
    a, b = np.arange(6.0).reshape(2, 3), np.arange(6.0, 15.0).reshape(3, 3)
    d.write(a)
    d.write(b)
    whole = np.concatenate([a, b])
    assert len(d) == 5 and np.array_equal(d.read(0, 5), whole) and np.array_equal(d.read(1, 4), whole[1:4])
    assert d.read(4, 9).shape == (1, 3) and d.read(3, 3).shape == (0, 3)
    d.close()


def test_a_disk_store_refuses_rows_of_another_width():
    d = DiskBlocks()
    d.write(np.zeros((2, 3)))
    with pytest.raises(ValueError, match="rows of 4 values written to a store of rows of 3"):
        d.write(np.zeros((1, 4)))
    assert len(d) == 2 and d.read(0, 5).shape == (2, 3)
