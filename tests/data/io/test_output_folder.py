"""Output folders lose nothing: --force never deletes an input of the command, a folder being
written is locked against a second run, staging folders of dead runs are cleared, and a failed
run leaves OUT as it was."""

from __future__ import annotations

import os
import pathlib
import shutil
import subprocess
import sys

import pytest
from typer.testing import CliRunner

from boomtip.data.io.output_folder import OutputError, clear_dead_staging, output_folder
from boomtip.data.io.recording import RecordingError
from boomtip.tools.cli import app

runner = CliRunner()


def _dead_pid() -> int:
    """A PID that was a process and is no longer one."""
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_a_block_that_completes_becomes_out_and_one_that_fails_leaves_out_as_it_was(tmp_path):
    out = tmp_path / "out"
    with output_folder(out, force=False) as staging:
        (staging / "a.txt").write_text("first")
    assert (out / "a.txt").read_text() == "first" and not list(tmp_path.glob(".out.*"))
    with pytest.raises(RuntimeError):
        with output_folder(out, force=True) as staging:
            (staging / "a.txt").write_text("second")
            raise RuntimeError("the run failed")
    assert (out / "a.txt").read_text() == "first" and not list(tmp_path.glob(".out.*"))  # nor the lock
    with pytest.raises(OutputError, match="not empty; pass --force"):
        with output_folder(out, force=False):
            pass


def test_an_out_being_written_is_refused_with_the_holders_pid(tmp_path):
    out = tmp_path / "out"
    holder = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        (tmp_path / ".out.lock").write_text(f"{holder.pid}\n")
        with pytest.raises(RecordingError, match=f"another run \\(PID {holder.pid}\\)"):
            with output_folder(out, force=True):
                pass
    finally:
        holder.kill()
        holder.wait()
    assert (tmp_path / ".out.lock").read_text().strip() == str(holder.pid)  # not ours to remove while it lived
    with output_folder(out, force=True) as staging:  # its PID gone: a stale lock, taken over
        (staging / "x").write_text("x")
    assert (out / "x").exists() and not (tmp_path / ".out.lock").exists()


def test_a_second_run_into_the_same_out_is_refused_while_the_first_writes(tmp_path):
    out = tmp_path / "out"
    with output_folder(out, force=False):
        with pytest.raises(OutputError, match=f"PID {os.getpid()}"):
            with output_folder(out, force=True):
                pass
    assert out.is_dir()


def test_staging_folders_of_dead_runs_are_cleared_and_a_live_runs_kept(tmp_path):
    dead, live = tmp_path / f".rec.partial-{_dead_pid()}", tmp_path / f".other.partial-{os.getppid()}"
    old = tmp_path / f".rec.old-{_dead_pid()}"
    for p in (dead, live, old):
        p.mkdir()
        (p / "frame.pcd").write_text("x")
    keep = tmp_path / "rec.partial-1"  # not a staging folder's name: never touched
    keep.mkdir()
    with output_folder(tmp_path / "out", force=False):
        pass
    assert not dead.exists() and not old.exists() and live.is_dir() and keep.is_dir()
    assert clear_dead_staging(tmp_path / "missing") == []


REAL = pathlib.Path(__file__).resolve().parents[1] / "real" / "ouster"
PCAP = REAL / "OS-1-32-G_v2.1.1_1024x10.pcap"
LEVEL = "attitude: level\nradar: {enabled: false}\nmarkers: {enabled: false}\nlidar: {pattern: spinning}\n"


@pytest.mark.parametrize("where", ["installation", "meta"])
def test_force_never_deletes_an_input_of_process(tmp_path, where):
    out = tmp_path / "X"
    out.mkdir()
    rig = (out if where == "installation" else tmp_path) / "rig.yaml"
    rig.write_text(LEVEL)
    meta = (out if where == "meta" else tmp_path) / "capture.json"
    shutil.copy(PCAP.with_suffix(".json"), meta)
    r = runner.invoke(app, ["process", str(PCAP), "--meta", str(meta), "--installation", str(rig), "--out", str(out), "--force"])
    assert r.exit_code == 2 and "overlaps the input" in r.output, r.output
    assert rig.read_text() == LEVEL and meta.read_bytes() == PCAP.with_suffix(".json").read_bytes()


def test_force_never_deletes_the_scenario_file_of_simulate_or_run(tmp_path):
    out = tmp_path / "X"
    out.mkdir()
    scenario = out / "my.yaml"
    scenario.write_text("duration_s: 0.2\n")
    for cmd in ("simulate", "run"):
        r = runner.invoke(app, [cmd, "--scenario", str(scenario), "--out", str(out), "--force"])
        assert r.exit_code == 2 and "overlaps the input" in r.output, r.output
        assert scenario.read_text() == "duration_s: 0.2\n"
