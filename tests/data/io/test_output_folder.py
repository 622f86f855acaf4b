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


HOLD = """
import sys, time
from boomtip.data.io.output_folder import output_folder
with output_folder(sys.argv[1], force=True) as staging:
    (staging / "mine").write_text("x")
    print("holding", flush=True)
    time.sleep(60)
"""


def _holder(out):
    proc = subprocess.Popen([sys.executable, "-c", HOLD, str(out)], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "holding"
    return proc


def test_an_out_another_process_writes_is_refused_with_its_pid_and_freed_when_it_dies(tmp_path):
    out = tmp_path / "out"
    holder = _holder(out)
    try:
        with pytest.raises(RecordingError, match=f"another run \\(PID {holder.pid}\\)"):
            with output_folder(out, force=True):
                pass
        assert (tmp_path / f".out.partial-{holder.pid}" / "mine").is_file()  # its staging folder is its own
    finally:
        holder.kill()  # SIGKILL: no cleanup of its own; the kernel frees its lock
        holder.wait()
    with output_folder(out, force=False) as staging:
        (staging / "x").write_text("x")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"] and sorted(p.name for p in out.iterdir()) == ["x"]


def test_a_lock_file_left_behind_holds_nothing(tmp_path):
    (tmp_path / ".out.lock").write_text(f"{os.getppid()}\n")  # a live PID in it: the file is not the lock
    with output_folder(tmp_path / "out", force=False):
        pass
    assert not (tmp_path / ".out.lock").exists()


def test_a_second_run_into_the_same_out_is_refused_while_the_first_writes(tmp_path):
    out = tmp_path / "out"
    with output_folder(out, force=False):
        with pytest.raises(OutputError, match=f"PID {os.getpid()}"):
            with output_folder(out, force=True):
                pass
    assert out.is_dir()


def test_a_non_empty_out_is_judged_under_the_lock(tmp_path):
    out = tmp_path / "out"
    with output_folder(out, force=False) as staging:
        (staging / "a").write_text("a")
        with pytest.raises(OutputError, match="PID"):  # the lock first: not "not empty"
            with output_folder(out, force=False):
                pass


def _staging(path, marker=True):
    path.mkdir()
    (path / "frame.pcd").write_text("x")
    if marker:
        (path / ".boomtip-staging").touch()
    return path


def _journal(parent, name, pid):
    (parent / f".{name}.swap-{pid}").write_text("boomtip swap\n")


def test_what_dead_runs_left_is_cleared_and_nothing_else(tmp_path):
    dead = _staging(tmp_path / ".rec.partial-12345")
    old = _staging(tmp_path / ".rec.old-12345", marker=False)
    _journal(tmp_path, "rec", 12345)
    (tmp_path / "rec").mkdir()  # rec exists: its old copy is a finished swap's leftover
    foreign = _staging(tmp_path / ".notes.partial-7", marker=False)  # a user's folder of that name: no marker
    huge = _staging(tmp_path / (".x.partial-" + "9" * 30))  # not a PID
    keep = _staging(tmp_path / "rec.partial-1")  # not a staging folder's name
    with output_folder(tmp_path / "out", force=False):
        pass
    assert not dead.exists() and not old.exists() and not (tmp_path / ".rec.swap-12345").exists()
    assert foreign.is_dir() and huge.is_dir() and keep.is_dir()
    assert not list(tmp_path.glob(".boomtip-trash-*"))
    assert clear_dead_staging(tmp_path / "missing") == []


def test_a_users_dot_old_files_are_never_taken_for_a_swap(tmp_path):
    """`.NAME.old-DIGITS` without boomtip's journal beside it is a user's backup: never renamed
    nor deleted, with or without NAME, and whatever --out is."""
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "todo.txt").write_text("x")
    backup = _staging(tmp_path / ".notes.old-20240101", marker=False)
    profile = tmp_path / ".profile.old-2"
    profile.write_text("bak")
    fake_journal = tmp_path / ".profile.swap-2"
    fake_journal.write_text("mine")
    with output_folder(tmp_path / "results", force=False):
        pass
    with pytest.raises(OutputError, match="not empty"):
        with output_folder(tmp_path / "notes", force=False):
            pass
    assert backup.is_dir() and profile.read_text() == "bak" and fake_journal.read_text() == "mine"
    assert not (tmp_path / "profile").exists()


def test_a_staging_folder_named_as_an_input_is_never_removed(tmp_path):
    rec = _staging(tmp_path / ".rec.partial-3")
    assert clear_dead_staging(tmp_path, inputs=(rec,)) == [] and rec.is_dir()


def test_a_swap_cut_short_gets_the_former_out_back(tmp_path):
    old = _staging(tmp_path / ".out.old-4242", marker=False)  # killed between the two renames
    _journal(tmp_path, "out", 4242)
    partial = _staging(tmp_path / ".out.partial-4242")
    with pytest.raises(OutputError, match="not empty"):
        with output_folder(tmp_path / "out", force=False):
            pass
    assert (tmp_path / "out" / "frame.pcd").is_file() and not old.exists() and not partial.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_ctrl_c_in_the_swap_takes_effect_after_it_with_the_results_in_place(tmp_path, monkeypatch):
    import signal as sig

    from boomtip.data.io.output_folder import InterruptedAfterCommit

    def interrupt():  # Ctrl-C lands between the two renames
        os.kill(os.getpid(), sig.SIGINT)

    before = sig.getsignal(sig.SIGINT)  # Python's default, or SIG_IGN in a shell's background job
    out = _swap_with(tmp_path, monkeypatch, interrupt, InterruptedAfterCommit)
    assert (out / "a").read_text() == "second" and sorted(p.name for p in tmp_path.iterdir()) == ["out"]
    assert sig.getsignal(sig.SIGINT) is before  # the handler the swap found, back in place


def test_a_live_runs_staging_beside_another_out_is_kept(tmp_path):
    holder = _holder(tmp_path / "a")
    try:
        with output_folder(tmp_path / "b", force=False):
            pass
        assert (tmp_path / f".a.partial-{holder.pid}" / "mine").is_file()
    finally:
        holder.kill()
        holder.wait()


def test_a_failed_swap_puts_the_former_out_back(tmp_path, monkeypatch):
    def disk_full():
        raise OSError(28, "No space left on device")

    out = _swap_with(tmp_path, monkeypatch, disk_full, OSError)
    assert (out / "a").read_text() == "first" and sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def _swap_with(tmp_path, monkeypatch, before_staging_moves, raises):
    """Replace OUT (holding a = first) by a run writing a = second, calling `before_staging_moves`
    just before the staging folder is renamed into place; the run raises `raises`."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "a").write_text("first")
    real = pathlib.Path.rename

    def rename(self, target):
        if ".partial-" in self.name:
            before_staging_moves()
        return real(self, target)

    monkeypatch.setattr(pathlib.Path, "rename", rename)
    with pytest.raises(raises):
        with output_folder(out, force=True) as staging:
            (staging / "a").write_text("second")
    monkeypatch.undo()
    return out


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
