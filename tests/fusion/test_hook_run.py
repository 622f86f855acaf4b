"""The hook run's reported covariance: the filter's own plus the levelling's stated bias."""

from __future__ import annotations

import numpy as np
import pytest

from boomtip.fusion.hook_run import with_levelling_bias


def test_a_levelling_bias_widens_the_covariance_across_the_rope_only():
    rng = np.random.default_rng(3)
    p = np.column_stack([rng.normal(0, 5, 50), rng.normal(0, 5, 50), -rng.uniform(20, 200, 50)])
    base = np.broadcast_to(np.eye(3) * 1e-4, (50, 3, 3)).copy()
    sigma = 1e-4
    cov = with_levelling_bias(p, base, sigma)
    u = p / np.linalg.norm(p, axis=1, keepdims=True)
    added = cov - base
    # nothing along the rope, l^2 sigma^2 in each direction across it
    np.testing.assert_allclose(np.einsum("ni,nij,nj->n", u, added, u), 0.0, atol=1e-15)
    e1 = np.cross(u, [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    np.testing.assert_allclose(np.einsum("ni,nij,nj->n", e1, added, e1), sigma**2 * np.sum(p**2, 1), rtol=1e-12)
    assert with_levelling_bias(p, base, 0.0) is base


def test_the_widened_covariance_is_consistent_with_a_drawn_tilt():
    """Hooks seen through a levelling tilted by draws of the stated sigma: NEES averages 2 on
    the two axes the tilt moves (3 with the filter's own noise on top of it)."""
    rng = np.random.default_rng(0)
    n, sigma, own = 4000, 1.2e-4, 0.004
    p = np.column_stack([rng.normal(0, 3, n), rng.normal(0, 3, n), -rng.uniform(50, 200, n)])
    tilt = rng.normal(0, sigma, (n, 2))
    err = np.cross(np.column_stack([tilt, np.zeros(n)]), p) + rng.normal(0, own, (n, 3))
    cov = with_levelling_bias(p, np.broadcast_to(np.eye(3) * own**2, (n, 3, 3)), sigma)
    nees = np.einsum("ni,ni->n", err, np.linalg.solve(cov, err[..., None])[..., 0])
    assert abs(np.mean(nees) - 3.0) < 0.15


def test_a_nan_encoder_or_mru_sample_updates_nothing_and_never_poisons_the_state():
    from boomtip.fusion.hook_kalman import HookFilter

    f = HookFilter("ekf", "flexible")
    f.initialize_from_measurements(np.array([0.5, -0.3, -60.0]), (0.3, 0.5, 60.0), (0.0, 0.0, 0.0, 0.0), 0.0)
    f.predict(0.005)
    x0, P0 = f.x.copy(), f.P.copy()
    f.update_encoders(float("nan"), float("nan"), float("nan"))
    f.update_mru(float("nan"), float("nan"), float("nan"), float("nan"))
    np.testing.assert_array_equal(f.x, x0)
    np.testing.assert_array_equal(f.P, P0)
    f.update_encoders(0.3, float("nan"), 60.0)  # the finite part is used
    assert np.all(np.isfinite(f.x)) and not np.array_equal(f.P, P0)


def test_the_run_reports_the_bias_and_the_chain_takes_it_from_the_installation():
    import math

    from boomtip.data.crane_model import CraneParams
    from boomtip.tools.config.scenario import load_scenario
    from boomtip.data.sim.crane_programmes import HOOK_SCENARIOS
    from boomtip.data.sim.crane_truth import simulate_crane
    from boomtip.data.sim.hook_measurements import measurements_from_truth
    from boomtip.data.sim.hook_world import HookSimulation
    from boomtip.tools.config.processing import Processing
    from boomtip.fusion.hook_config import HookFilterConfig
    from boomtip.fusion.hook_run import run_hook_filter
    from boomtip.tools.chains.hook import HookChain

    params = CraneParams()
    spec = HOOK_SCENARIOS["hook-2"](params)
    meas = measurements_from_truth(simulate_crane(params, spec.joints, spec.vessel, duration_s=6.0), seed=1)
    plain = run_hook_filter(meas, "ekf", "flexible", params, HookFilterConfig())
    biased = run_hook_filter(meas, "ekf", "flexible", params, HookFilterConfig(levelling_bias_sigma_rad=2e-4))
    np.testing.assert_allclose(biased.p_rel, plain.p_rel)  # the estimate itself is untouched
    np.testing.assert_allclose(biased.cov_p, with_levelling_bias(plain.p_rel, plain.cov_p, 2e-4), rtol=1e-9, atol=1e-15)
    sim = HookSimulation(load_scenario("hook-2", ["duration_s=0.3"]))
    inst = sim.meta.installation
    chain = HookChain(sim, Processing())
    expect = math.radians(math.hypot(inst.lidar.mount.accuracy_deg, inst.mru.bias_accuracy_deg))
    assert expect > 0 and chain.filter_cfg.levelling_bias_sigma_rad == pytest.approx(expect)
    assert HookChain(sim, Processing(hook={"filter": {"levelling_bias_sigma_rad": 0.0}})).filter_cfg.levelling_bias_sigma_rad == 0.0


def test_merged_events_are_compact_arrays_in_time_then_sensor_order():
    from boomtip.fusion.hook_run import merged_events

    t, s, i = merged_events(([0.0, 0.01, 0.02], [0.01, 0.03], [0.01]), 0.0, 0.025)
    assert t.tolist() == [0.01, 0.01, 0.01, 0.02]  # (0, 0.025]: the first MRU sample and the last encoder out
    assert s.tolist() == [0, 1, 2, 0]  # equal times: MRU, encoders, LiDAR
    assert i.tolist() == [1, 0, 0, 2]
    assert (t.dtype, s.dtype, i.dtype) == (np.float64, np.int8, np.int32)


def test_the_hoist_at_a_repeated_encoder_stamp_reads_a_row_not_an_empty_slice():
    """The tracker's hoist reading, from the two encoder rows about t (rosbag readers sort but
    keep repeated stamps)."""
    from boomtip.fusion.hook_tracker import HookTracker

    enc_t = np.array([0.0, 0.1, 0.2, 0.2, 0.3])
    table = np.zeros((5, 3))
    table[:, 2] = [10.0, 11.0, 12.0, 12.0, 13.0]
    tracker = HookTracker(enc_t, table, np.array([0.0, 0.3]), np.zeros((2, 4)))
    assert tracker.hoist_at(0.2) == 12.0
    assert tracker.hoist_at(0.15) == pytest.approx(11.5)
    assert tracker.hoist_at(0.3) == 13.0
