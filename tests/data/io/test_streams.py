"""Streams as real logs come: a NaN stretch, a glitch no vessel makes, a time that goes back.
A bad sample is dropped with a warning that counts it and names its first lines (`--strict`
refuses instead); a log of mostly bad samples is refused."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from boomtip.data.frames import MRU_COLUMNS, MruLog
from boomtip.data.io.recording import MRU_BOUNDS, MRU_STEPS, RecordingError, read_csv
from boomtip.tools.cli import app

RATE_HZ = 200.0


def _mru_csv(path, t, roll):
    cols = {"t": t, "roll": roll, "pitch": 0.01 * np.cos(t), "yaw": np.full_like(t, 3.1), "roll_rate": 0.02 * np.cos(t),
            "pitch_rate": -0.01 * np.sin(t), "yaw_rate": np.zeros_like(t)}
    lines = [",".join(MRU_COLUMNS)] + [",".join(repr(float(cols[c][k])) for c in MRU_COLUMNS) for k in range(len(t))]
    path.write_text("\n".join(lines) + "\n")


def _read(path, strict=False):
    notes: list[str] = []
    return read_csv(path, MRU_COLUMNS, bounds=MRU_BOUNDS, steps=MRU_STEPS, strict=strict, notes=notes), notes


def test_a_50_ms_glitch_is_dropped_whole_and_the_attitude_bridges_it(tmp_path):
    t = np.arange(0, 10, 1 / RATE_HZ)
    roll = 0.02 * np.sin(t)
    glitched = roll.copy()
    glitched[1000:1010] = 1.57  # 10 samples: 90 deg in 5 ms, held, and back
    path = tmp_path / "mru.csv"
    _mru_csv(path, t, glitched)
    cols, notes = _read(path)
    assert len(cols["t"]) == len(t) - 10 and not np.any(np.isin(cols["t"], t[1000:1010]))
    assert notes and "dropped 10 of 2000 samples (lines 1002, 1003, 1004, 1005, 1006, ...)" in notes[0]
    assert "column 'roll' steps" in notes[0] and "a glitch" in notes[0]
    log = MruLog.from_columns(cols)  # 55 ms without a sample: within the log's gap, interpolated
    rpy, _ = log.attitude(t[1005])
    gap_s = t[1010] - t[999]
    chord_error = 0.02 * gap_s ** 2 / 8  # a linear interpolation's sag on 0.02 sin(t) over the gap
    assert abs(rpy[0] - roll[1005]) <= chord_error
    with pytest.raises(RecordingError, match=f"{path}: line 1002: column 'roll' steps"):
        _read(path, strict=True)


def test_nan_values_and_a_time_that_goes_back_are_dropped_and_counted(tmp_path):
    t = np.arange(0, 2, 1 / RATE_HZ)
    roll = 0.01 * np.sin(t)
    roll[100:120] = np.nan
    t_bad = t.copy()
    t_bad[300] = t_bad[298]  # a repeated stamp
    path = tmp_path / "mru.csv"
    _mru_csv(path, t_bad, roll)
    cols, notes = _read(path)
    assert len(cols["t"]) == len(t) - 21 and np.all(np.diff(cols["t"]) > 0) and np.all(np.isfinite(cols["roll"]))
    assert "dropped 21 of 400 samples (lines 102, 103, 104, 105, 106, ...): first column 'roll' is nan" in notes[0]
    with pytest.raises(RecordingError, match="line 102: column 'roll' is nan \\(expected a finite number\\)"):
        _read(path, strict=True)


def test_a_log_of_mostly_bad_samples_is_refused(tmp_path):
    t = np.arange(0, 1, 1 / RATE_HZ)
    roll = np.full_like(t, np.nan)
    roll[:50] = 0.0
    path = tmp_path / "mru.csv"
    _mru_csv(path, t, roll)
    with pytest.raises(RecordingError, match="150 of 200 samples are bad"):
        _read(path)


def test_a_good_log_reads_as_it_is(tmp_path):
    t = np.arange(0, 5, 1 / RATE_HZ)
    path = tmp_path / "mru.csv"
    _mru_csv(path, t, 0.3 * np.sin(2 * t))  # rolling at up to 0.6 rad/s: within the bound
    cols, notes = _read(path)
    assert notes == [] and len(cols["t"]) == len(t) and np.array_equal(cols["t"], t)


@pytest.mark.slow
def test_a_hook_recording_with_a_nan_stretch_of_slew_runs_to_the_end(tmp_path):
    """0.6 s of NaN slew samples in a 10 s hook recording: processed, the dropped samples said,
    and from 0.4 s after the gap every hook estimate present and finite."""
    runner = CliRunner()
    rec = tmp_path / "rec"
    assert runner.invoke(app, ["simulate", "-s", "hook-2", "--duration", "10", "--out", str(rec)]).exit_code == 0
    enc = rec / "encoders.csv"
    lines = enc.read_text().splitlines()
    head = lines[0].split(",")
    i_t, i_slew = head.index("t"), head.index("slew")
    out = [lines[0]]
    for line in lines[1:]:
        v = line.split(",")
        if 4.0 <= float(v[i_t]) < 4.6:
            v[i_slew] = "nan"
        out.append(",".join(v))
    enc.write_text("\n".join(out) + "\n")
    res = runner.invoke(app, ["process", str(rec), "--out", str(tmp_path / "o")])
    assert res.exit_code == 0, res.output
    assert "dropped 60 of" in res.output
    kpis = json.loads((tmp_path / "o" / "kpis.json").read_text())
    assert any("encoders.csv: dropped 60 of" in w for w in kpis["warnings"])
    est = np.genfromtxt(tmp_path / "o" / "hook_estimates.csv", delimiter=",", names=True, dtype=None, encoding="utf-8")
    after = est[est["t"] >= 5.0]
    assert len(after) > 0 and set(after["estimator"]) == {"ekf_flexible", "ekf_rigid", "ukf_flexible", "ukf_rigid"}
    for col in ("x", "y", "z", "vx", "vy", "vz"):
        assert np.all(np.isfinite(after[col]))
    strict = runner.invoke(app, ["process", str(rec), "--out", str(tmp_path / "s"), "--strict"])
    assert strict.exit_code == 2 and "encoders.csv: line" in strict.output and "column 'slew' is nan" in strict.output


def test_a_clean_log_with_its_noise_loses_no_sample(tmp_path):
    t = np.arange(0, 60, 1 / RATE_HZ)
    noisy = 0.05 * np.sin(0.6 * t) + np.random.default_rng(3).normal(0.0, np.radians(0.2), len(t))  # 0.2 deg noise
    path = tmp_path / "mru.csv"
    _mru_csv(path, t, noisy)
    cols, notes = _read(path)
    assert notes == [] and len(cols["t"]) == len(t)


@pytest.mark.parametrize("where", [0, 1000, 1990])
def test_a_glitch_at_the_start_the_middle_or_the_end_takes_only_itself(tmp_path, where):
    t = np.arange(0, 10, 1 / RATE_HZ)
    roll = 0.02 * np.sin(t)
    roll[where:where + 10] = 1.2
    path = tmp_path / "mru.csv"
    _mru_csv(path, t, roll)
    cols, notes = _read(path)
    assert len(cols["t"]) == len(t) - 10 and not np.any(np.isin(cols["t"], t[where:where + 10]))
    assert "dropped 10 of 2000" in notes[0] and "np.float64" not in notes[0]


def test_a_stamp_far_in_the_future_takes_only_itself(tmp_path):
    t = np.arange(0, 2, 1 / RATE_HZ)
    t_bad = t.copy()
    t_bad[50] = 1e9
    path = tmp_path / "mru.csv"
    _mru_csv(path, t_bad, 0.01 * np.sin(t))
    cols, notes = _read(path)
    assert len(cols["t"]) == len(t) - 1 and 1e9 not in cols["t"]
    assert "dropped 1 of 400 samples (lines 52): first time 1000000000.0 is after the samples that follow it" in notes[0]
    assert "np.float64" not in notes[0]


def test_a_frozen_sensor_is_dropped_after_its_first_sample_and_a_still_log_is_not(tmp_path):
    t = np.arange(0, 10, 1 / RATE_HZ)
    roll = 0.02 * np.sin(t) + np.random.default_rng(5).normal(0.0, 1e-4, len(t))
    path = tmp_path / "mru.csv"
    frozen = roll.copy()
    _mru_csv(path, t, frozen)
    lines = path.read_text().splitlines()
    for k in range(602, 1001):  # 2 s stuck: the sensor repeats its whole sample of t = 3.000 s (line 602)
        lines[k] = ",".join(lines[k].split(",")[:1] + lines[601].split(",")[1:])
    path.write_text("\n".join(lines) + "\n")
    cols, notes = _read(path)
    assert len(cols["t"]) == len(t) - 399 and "frozen sensor" in notes[0] and "unchanged for 2 s from t = 3.000 s" in notes[0]
    still = tmp_path / "still.csv"
    _mru_csv(still, t, np.zeros_like(t))  # roll never moves, pitch does: not every value is frozen
    assert _read(still)[1] == []
    level = tmp_path / "level.csv"  # a level rig's log of zeros with one flicker: still, not frozen
    lines = [",".join(MRU_COLUMNS)] + [f"{k / RATE_HZ!r},0.0,0.0,0.0,0.0,0.0,0.0" for k in range(2000)]
    lines[1001] = "5.0,0.0001,0.0,0.0,0.0,0.0,0.0"
    level.write_text("\n".join(lines) + "\n")
    assert _read(level)[1] == []


def test_a_step_between_two_long_stretches_drops_neither(tmp_path):
    """A sensor restarting with another offset: both sides are the log (the filters see the
    step); only a stretch shorter than a second that does not continue its neighbours is a glitch."""
    t = np.arange(0, 10, 1 / RATE_HZ)
    roll = 0.02 * np.sin(t)
    roll[700:] += 0.3
    path = tmp_path / "mru.csv"
    _mru_csv(path, t, roll)
    cols, notes = _read(path)
    assert notes == [] and len(cols["t"]) == len(t)


def test_a_simulated_mrus_glitch_and_freeze_are_screened_as_a_files_are():
    """The world's MRU faults (world.mru.glitches_s, frozen_s) reach processing through the
    same screen as a file's log: the runner screens every source's attitude."""
    from boomtip.data.sim.simulator import Simulation
    from boomtip.tools.chains.runner import screen_attitude
    from boomtip.tools.config.scenario import load_scenario

    sim = Simulation(load_scenario("sts-empty", ["duration_s=8", "world.mru.glitches_s=[[2,2.05]]",
                                                 "world.mru.frozen_s=[[4,5.5]]"]))
    n = len(sim.mru.t_s)
    assert np.all(np.abs(sim.mru.rpy_rad[(sim.mru.t_s >= 2) & (sim.mru.t_s < 2.05), 0] - np.radians(89.9)) < 1e-12)
    screen_attitude(sim)
    assert n - len(sim.mru.t_s) == 10 + 300  # the glitch's 10 samples; the freeze repeats the sample before it 300 times
    assert len(sim.meta.notes) == 1 and "dropped 310 of" in sim.meta.notes[0]
    assert not np.any((sim.mru.t_s >= 2) & (sim.mru.t_s < 2.05))
