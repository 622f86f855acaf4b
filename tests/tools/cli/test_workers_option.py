"""--workers: the cores by default, refused outside 1 to 4 x the cores with a message that says so."""

from __future__ import annotations

import os

import pytest
from typer.testing import CliRunner

from boomtip.tools.chains.chain import ChainError
from boomtip.tools.cli import app
from boomtip.tools.cli.commands import run_workers

CORES = len(os.sched_getaffinity(0))


def test_the_default_is_the_cores_and_a_valid_count_stands():
    assert run_workers(None) == CORES
    assert run_workers(1) == 1 and run_workers(4 * CORES) == 4 * CORES


@pytest.mark.parametrize("n", [0, -1, 4 * CORES + 1])
def test_a_count_outside_the_range_is_refused_naming_it(n):
    with pytest.raises(ChainError, match=rf"--workers {n}: expected 1 to {4 * CORES}"):
        run_workers(n)


def test_the_command_line_refuses_it_before_reading_anything(tmp_path):
    missing = tmp_path / "no such recording"
    res = CliRunner().invoke(app, ["process", str(missing), "-o", str(tmp_path / "out"), "--workers", "0"])
    assert res.exit_code == 2
    assert "--workers 0: expected 1 to" in res.output
    assert not (tmp_path / "out").exists()
