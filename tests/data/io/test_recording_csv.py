"""read_csv a chunk of rows at a time: the same table, and errors at the right line and byte."""

import numpy as np
import pytest

from boomtip.data.io import recording
from boomtip.data.io.recording import RecordingError, read_csv


def _write(path, rows, header="t,a,b"):
    path.write_text(header + "\n" + "".join(f"{t!r},{a!r},{b!r}\n" for t, a, b in rows))


def test_a_long_csv_reads_in_chunks_to_the_same_table(tmp_path, monkeypatch):
    rng = np.random.default_rng(4)
    rows = np.column_stack([np.arange(1000) * 0.01, rng.normal(size=1000), rng.normal(size=1000)])
    _write(tmp_path / "x.csv", rows.tolist())
    whole = read_csv(tmp_path / "x.csv", ("t", "a", "b"))
    monkeypatch.setattr(recording, "CSV_CHUNK_ROWS", 7)
    chunked = read_csv(tmp_path / "x.csv", ("t", "a", "b"))
    assert all(np.array_equal(whole[k], chunked[k]) and np.array_equal(whole[k], rows[:, j]) for j, k in enumerate("tab"))


def test_windows_line_ends_and_blank_lines_read_alike(tmp_path):
    (tmp_path / "x.csv").write_bytes(b"t,a,b\r\n0,1,2\r\n\r\n0.1,3,4\r\n")
    got = read_csv(tmp_path / "x.csv", ("t", "a", "b"))
    assert got["a"].tolist() == [1.0, 3.0] and got["t"].tolist() == [0.0, 0.1]


def test_a_bad_row_deep_in_the_file_names_its_line(tmp_path, monkeypatch):
    monkeypatch.setattr(recording, "CSV_CHUNK_ROWS", 5)
    rows = [(0.01 * i, 1.0, 2.0) for i in range(30)]
    _write(tmp_path / "x.csv", rows)
    text = (tmp_path / "x.csv").read_text().splitlines()
    text[22] = "0.21,1.0,oops"  # line 23
    (tmp_path / "x.csv").write_text("\n".join(text) + "\n")
    with pytest.raises(RecordingError, match=r"x.csv: line 23: a value is not a number: '0.21,1.0,oops'"):
        read_csv(tmp_path / "x.csv", ("t", "a", "b"))


@pytest.mark.parametrize("block", [1 << 20, 3, 4])
def test_bytes_that_are_not_utf8_are_named_by_offset_wherever_the_blocks_cut(tmp_path, monkeypatch, block):
    monkeypatch.setattr(recording, "UTF8_BLOCK_BYTES", block)
    head = "t,a,b\n0,1,2\n0.1,é,3\n".encode()
    (tmp_path / "x.csv").write_bytes(head + b"\xff,1,2\n")
    with pytest.raises(RecordingError, match=f"x.csv: byte {len(head)}: not UTF-8"):
        read_csv(tmp_path / "x.csv", ("t", "a", "b"))
    (tmp_path / "y.csv").write_bytes(b"t,a,b\n0,1,2\xc3")  # a character cut at the end
    with pytest.raises(RecordingError, match="y.csv: byte 11: not UTF-8 text; expected a CSV of numbers"):
        read_csv(tmp_path / "y.csv", ("t", "a", "b"))


def test_a_bad_byte_after_a_character_cut_by_a_block_is_named_by_its_own_offset(tmp_path, monkeypatch):
    monkeypatch.setattr(recording, "UTF8_BLOCK_BYTES", 3)  # the first block ends inside the é
    (tmp_path / "x.csv").write_bytes(b"t,\xc3\xa9\xff")
    with pytest.raises(RecordingError, match="x.csv: byte 4: not UTF-8"):
        read_csv(tmp_path / "x.csv", ("t",))


@pytest.mark.parametrize("text, error", [
    ("t,a,b\r0,1,2\r0.1,3,4\r", None),  # classic Mac line ends
    ("t,a,b\r\r\n0,1,2\r\r\n0.1,x,4\r\r\n", "line 5: a value is not a number"),
    ("t,a,b\n0,1\r,2\n", "line 2: 2 values, expected 3"),
    ("t,a,b\n0,1,2\x0c\n0.1,x,4\n", "line 4: a value is not a number"),
    ("t,a,b\n0,1,2\u20280.1,3,4\n", None),
])
def test_lines_are_split_as_the_whole_texts_splitlines_splits_them(tmp_path, text, error):
    (tmp_path / "x.csv").write_bytes(text.encode())
    if error is None:
        assert read_csv(tmp_path / "x.csv", ("t", "a", "b"))["a"].tolist() == [1.0, 3.0]
    else:
        with pytest.raises(RecordingError, match=error):
            read_csv(tmp_path / "x.csv", ("t", "a", "b"))
