"""Fusion solutions on real pipeline output, KPIs on known errors, and the run/process commands."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from typer.testing import CliRunner

from boomtip.data.io.recording import write_recording
from boomtip.tools.config.scenario import load_scenario
from boomtip.data.sim.simulator import Simulation
from boomtip.fusion.solutions import FusionConfig, jerk_psd, run_solution
from boomtip.fusion.tuning import default_jerk_psd, relative_heave_jerk_psd
from boomtip.perception.pipeline import HeavePipeline
from boomtip.tools.cli.commands import app
from boomtip.tools.chains.heave import to_fusion
from boomtip.tools.report.kpis import error_stats

NO_LATENCY = {"lidar": 0.0, "radar": 0.0}

runner = CliRunner()


@pytest.fixture(scope="module")
def loaded_rows():
    s = load_scenario("sts-loaded", ["duration_s=12"])
    sim = Simulation(s)
    pipe = HeavePipeline(sim.meta.installation, sim.mru)
    rows = [m for f in sim for m in pipe.process(f).measurements]
    return s, sim.truth, rows


def _fusion_inputs(rows, latency=NO_LATENCY):
    return [to_fusion(r, latency) for r in rows if r.ok]


def test_error_stats_on_a_known_series():
    st = error_stats(np.array([1.0, -2.0, 3.0, np.nan]))
    assert st["mae"] == pytest.approx(2.0) and st["max"] == 3.0
    assert st["rmse"] == pytest.approx(np.sqrt(14 / 3)) and st["n"] == 3


def test_process_noise_comes_from_a_sea_state_never_from_the_world():
    # grows with the wave height (as Hs^2) and falls with the period
    assert relative_heave_jerk_psd(4.0, 8.0) == pytest.approx(4 * relative_heave_jerk_psd(2.0, 8.0), rel=1e-9)
    assert relative_heave_jerk_psd(2.0, 7.0) > relative_heave_jerk_psd(2.0, 12.0)
    # the default holds for every sea up to the working limit (Hs 4 m, Tp >= 7 s)
    for hs in (0.5, 2.0, 4.0):
        for tp in (7.0, 9.0, 14.0):
            assert relative_heave_jerk_psd(hs, tp) <= default_jerk_psd() * (1 + 1e-12)
    cfg = FusionConfig()
    assert jerk_psd(cfg) == default_jerk_psd()
    assert jerk_psd(cfg, (1.0, 10.0)) == relative_heave_jerk_psd(1.0, 10.0)
    assert jerk_psd(FusionConfig(jerk_psd=0.5), (1.0, 10.0)) == 0.5
    with pytest.raises(ValueError):
        relative_heave_jerk_psd(0.0, 10.0)


def _mae(est, truth, col):
    keep = est.t_s >= 5.0
    return np.nanmean(np.abs(est.x[keep, col] - truth.at("D" if col == 0 else "D_dot", est.t_s[keep])))


@pytest.mark.slow
def test_fused_solution_meets_its_targets(loaded_rows):
    s, truth, rows = loaded_rows
    est = run_solution("fused", _fusion_inputs(rows), FusionConfig(), 12.0)
    assert _mae(est, truth, 0) < 0.005
    assert _mae(est, truth, 1) < 0.008


def test_known_latency_does_not_bias_the_fused_estimate(loaded_rows):
    s, truth, rows = loaded_rows
    late = _fusion_inputs(rows, {"lidar": 0.1, "radar": 0.1})
    assert all(m.t_arrival_s == pytest.approx(m.t_acq_s + 0.1) for m in late)
    est = run_solution("fused", late, FusionConfig(), 12.0)
    assert _mae(est, truth, 0) < 0.005


def test_outliers_are_gated_not_followed(loaded_rows):
    s, truth, rows = loaded_rows
    import copy

    bad = copy.deepcopy(rows)
    hit = [r for r in bad if r.method == "deck_lidar" and r.ok][20::10]
    assert len(hit) >= 5
    for r in hit:
        r.value += 5.0
    est = run_solution("deck_lidar", _fusion_inputs(bad), FusionConfig(), 12.0)
    assert est.statuses.get("gated", 0) >= len(hit) - 1
    assert _mae(est, truth, 0) < 0.005


def test_estimates_cover_every_tick_of_the_output_grid(loaded_rows):
    _, _, rows = loaded_rows
    est = run_solution("fused", _fusion_inputs(rows), FusionConfig(), 12.0)
    first = int(np.argmax(np.isfinite(est.x[:, 0])))
    assert np.all(np.isfinite(est.x[first:, 0])) and len(est.t_s) == 1201
    np.testing.assert_array_equal(est.t_s, np.arange(1201) / 100.0)


@pytest.mark.slow
def test_run_and_process_write_their_outputs(tmp_path):
    rec, out1, out2 = tmp_path / "rec", tmp_path / "run", tmp_path / "proc"
    r = runner.invoke(app, ["run", "-s", "sts-empty", "--duration", "6", "--out", str(out1), "--rerun"])
    assert r.exit_code == 0, r.output
    for name in ("measurements.csv", "estimates.csv", "kpis.json", "report.md", "plots/heave_D.png", "boomtip.rrd"):
        assert (out1 / name).is_file(), name
    kpis = json.loads((out1 / "kpis.json").read_text())
    assert set(kpis["measurements"]) == {"deck_lidar", "deck_radar", "reflectors_lidar", "doppler_radar", "doppler_radar_rot"}
    assert {"mae", "max", "apt_ms", "valid_fraction"} <= set(kpis["measurements"]["deck_lidar"])
    assert {"mae_D_m", "rmse_D_dot_mps", "apt_ms"} <= set(kpis["solutions"]["fused"])
    with open(out1 / "measurements.csv") as fh:
        header = next(csv.reader(fh))
    assert header[:6] == ["t", "method", "quantity", "value", "time_ms", "status"]
    # process a recording with a corrupt frame: the run goes on and says which file
    write_recording(Simulation(load_scenario("sts-empty", ["duration_s=3"])), rec)
    victim = sorted((rec / "lidar").iterdir())[5]
    victim.write_bytes(b"not a pcd at all")
    r = runner.invoke(app, ["process", str(rec), "--out", str(out2)])
    assert r.exit_code == 0, r.output
    rows = list(csv.DictReader(open(out2 / "measurements.csv")))
    bad = [x for x in rows if victim.name in x["status"]]
    assert len(bad) == 2 and all(x["value"] == "" for x in bad)
    assert sum(1 for x in rows if x["status"] == "ok") > 50
    # outputs are never written over inputs or existing results without --force
    assert runner.invoke(app, ["process", str(rec), "--out", str(rec / "out")]).exit_code == 2
    r = runner.invoke(app, ["process", str(rec), "--out", str(out2)])
    assert r.exit_code == 2 and "--force" in r.output
    assert runner.invoke(app, ["process", str(rec), "--out", str(out2), "--force"]).exit_code == 0


def test_the_wave_predictor_bridges_a_silence_of_every_sensor():
    """A minute of two-component waves measured (D at 10 Hz, D-dot at 20 Hz), then 10 s of
    nothing: the AR bridge follows the waves where the constant-acceleration extrapolation runs
    away, and its variance covers its error."""
    from boomtip.fusion.heave_filter import Measurement
    from boomtip.fusion.wave_predictor import fit_ar, forecast

    rng = np.random.default_rng(4)

    def D(t):
        return 45 + 2.0 * np.sin(2 * np.pi * t / 10.0) + 0.5 * np.sin(2 * np.pi * t / 7.0 + 1.0)

    def V(t):
        return 2.0 * 2 * np.pi / 10 * np.cos(2 * np.pi * t / 10.0) + 0.5 * 2 * np.pi / 7 * np.cos(2 * np.pi * t / 7.0 + 1.0)

    meas = [Measurement(t, t, "D", D(t) + rng.normal(0, 0.002), 0.002, "deck_lidar") for t in np.arange(0, 60, 0.1)]
    meas += [Measurement(t, t, "D_dot", V(t) + rng.normal(0, 0.003), 0.003, "doppler_radar_rot") for t in np.arange(0, 60, 0.05)]
    meas.sort(key=lambda m: m.t_arrival_s)
    bridged = run_solution("fused", meas, FusionConfig(), 70.0)
    runaway = run_solution("fused", meas, FusionConfig(wave_predictor=False), 70.0)
    gap = bridged.t_s >= 60.0
    err_b = np.abs(bridged.x[gap, 0] - D(bridged.t_s[gap]))
    err_r = np.abs(runaway.x[gap, 0] - D(runaway.t_s[gap]))
    assert err_b.max() < 0.1 < err_r.max()
    assert np.mean(err_b <= 3 * np.sqrt(bridged.var[gap, 0])) > 0.95
    # the AR model alone: a pure sinusoid sampled at 4 Hz is predicted to 1e-6 over 10 s
    t = np.arange(240) * 0.25
    y = 2.0 * np.sin(2 * np.pi * t / 10.0)
    fc, var = forecast(fit_ar(y, 4, 0.25), y, 40)
    np.testing.assert_allclose(fc, 2.0 * np.sin(2 * np.pi * (t[-1] + 0.25 * np.arange(1, 41)) / 10.0), atol=1e-6)
    assert np.all(np.diff(var) >= 0)


def test_an_estimate_no_measurement_holds_is_lost_with_its_reason():
    import numpy as np

    from boomtip.fusion.solutions import FusionConfig, lost_estimates

    cfg = FusionConfig()  # lost beyond 0.25 m of D sigma, 0.5 m/s of D-dot sigma
    x = np.array([[30.0, 0.1, 0.0], [30.0, 0.1, 0.0], [30.0, 0.1, 0.0], [-108.8, 0.0, 0.0], [130.0, 0.0, 0.0],
                  [np.nan, np.nan, np.nan]])
    var = np.array([[1e-4, 1e-4, 1.0], [0.26**2, 1e-4, 1.0], [1e-4, 0.6**2, 1.0], [133.0**2, 0.9**2, 1.0], [1e-4, 1e-4, 1.0],
                    [np.nan, np.nan, np.nan]])
    lost = lost_estimates(x, var, cfg, max_D_m=120.0)
    assert lost.why.tolist() == ["", "lost: D sigma beyond 0.25 m", "lost: D-dot sigma beyond 0.5 m/s",
                                 "lost: D sigma beyond 0.25 m; D-dot sigma beyond 0.5 m/s",
                                 "lost: D outside the sensors' 0 to 120 m", ""]
    assert lost.D.tolist() == [False, True, False, True, True, False]
    assert lost.D_dot.tolist() == [False, False, True, True, False, False]
    at_bound = lost_estimates(x[:1], np.array([[0.25**2, 0.5**2, 1.0]]), cfg)
    assert at_bound.why.tolist() == [""] and not at_bound.D.any()  # at the bound: not lost


def test_frames_closer_than_the_correlation_time_are_widened_per_source():
    from boomtip.fusion.heave_filter import Measurement
    from boomtip.fusion.solutions import shared_errors

    t = np.arange(0, 0.05, 0.005)  # a 200 Hz source
    fast = [Measurement(x, x, "D", 40.0, 0.002, "deck_lidar") for x in t]
    slow = [Measurement(x, x, "D", 40.0, 0.002, "deck_radar") for x in (0.0, 0.05, 0.1)]  # 20 Hz: untouched
    got = shared_errors(fast + slow, 0.05)
    sig = {m.source: [] for m in got}
    for m in got:
        sig[m.source].append(m.sigma)
    assert sig["deck_lidar"][0] == 0.002 and sig["deck_lidar"][1:] == pytest.approx([0.002 * np.sqrt(10)] * 9)
    assert sig["deck_radar"] == pytest.approx([0.002] * 3)
    assert shared_errors(fast, 0.0) is fast


def test_a_sensor_clock_s_offset_widens_d_by_d_dot_times_its_sigma():
    """A D stamped 1 ms off is off by D-dot x 1 ms: the estimate's variance carries it (a bias
    no averaging removes) where the deck moves fast, and not where it is still."""
    from boomtip.fusion.heave_filter import Measurement

    t = np.arange(0, 10, 0.1)
    D = 40.0 + 2.0 * np.sin(2 * np.pi * t / 10)
    meas = lambda clock: [Measurement(x, x, "D", d, 0.001, "deck_lidar", 0.0, clock) for x, d in zip(t, D)]
    cfg = FusionConfig(wave_predictor=False)
    plain, timed = (run_solution("deck_lidar", meas(c), cfg, 10.0) for c in (0.0, 0.01))
    added = timed.var[:, 0] - plain.var[:, 0]
    np.testing.assert_allclose(added[50:], (timed.x[50:, 1] * 0.01) ** 2, rtol=1e-6)
    fast, still = np.argmax(np.abs(timed.x[50:, 1])) + 50, np.argmin(np.abs(timed.x[50:, 1])) + 50
    assert added[fast] > 1e-4 and added[still] < 1e-6


def test_the_d_dot_floor_is_shared_by_the_frames_of_its_window():
    """20 Hz of D-dot frames share the floor's error over its 1 s window: each carries the
    floor times sqrt(20); 1 Hz frames carry it as it is; D's floor is per frame."""
    from boomtip.fusion.heave_filter import Measurement
    from boomtip.fusion.solutions import with_floors

    cfg = FusionConfig()  # floor 3 mm/s over 1 s, 0.5 mm on D
    fast = [Measurement(t, t, "D_dot", 0.0, 1e-6, "doppler_radar_rot") for t in np.arange(0, 1, 0.05)]
    slow = [Measurement(t, t, "D_dot", 0.0, 1e-6, "doppler_radar") for t in (0.0, 1.0, 2.0)]
    D = [Measurement(t, t, "D", 40.0, 1e-6, "deck_lidar") for t in np.arange(0, 1, 0.1)]
    got = with_floors(fast + slow + D, cfg)
    by = lambda s: [m.sigma for m in got if m.source == s]
    assert by("doppler_radar_rot")[1:] == pytest.approx([0.003 * np.sqrt(20)] * 19, rel=1e-6)
    assert by("doppler_radar") == pytest.approx([0.003] * 3, rel=1e-6)
    assert by("deck_lidar") == pytest.approx([0.0005] * 10, rel=1e-5)
    bad = Measurement(0.0, 0.0, "D", 40.0, float("nan"), "deck_lidar")
    assert with_floors([bad], cfg) == []
