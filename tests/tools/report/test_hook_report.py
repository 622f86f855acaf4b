"""hook_measurements.csv written a chunk of rows at a time: the same bytes as all at once."""

from __future__ import annotations

import numpy as np

from boomtip.tools.report import hook as hook_outputs
from boomtip.tools.report.hook_rows import ROW_DEFAULTS
from boomtip.tools.report.hook_rows import FrameRows


def test_rows_written_in_chunks_are_the_same_file(tmp_path, monkeypatch):
    rows = FrameRows()
    for k in range(11):
        row = {"t": 0.05 * k, **ROW_DEFAULTS, "status": "ok" if k % 3 else 'no "fix"', "x": 1.0 / (k + 1),
               "n_points": k, "tracker_accepted": k % 2 == 0, "time_ms": 3.25 * k}
        rows.append(row, np.eye(3) * 1e-4, None, None)
    hook_outputs.write_rows(tmp_path / "whole.csv", rows)
    monkeypatch.setattr(hook_outputs, "ROWS_CHUNK", 4)  # two full chunks and a short one
    hook_outputs.write_rows(tmp_path / "chunks.csv", rows)
    text = (tmp_path / "chunks.csv").read_text()
    assert text == (tmp_path / "whole.csv").read_text()
    lines = text.splitlines()
    assert len(lines) == 12 and lines[0].startswith("t,status,x,")
    assert lines[1].split(",")[:3] == ["0", "\"no 'fix'\"", "1"] and lines[11].split(",")[:2] == ["0.5", '"ok"']
    hook_outputs.write_rows(tmp_path / "empty.csv", FrameRows())
    assert (tmp_path / "empty.csv").read_text() == ",".join(hook_outputs.COLUMNS) + "\n"
