"""The truth-free consistency monitor: a stream whose innovations match their covariance is
rarely flagged; one whose noise exceeds its statement is; the per-row flag is causal."""

from __future__ import annotations

import numpy as np
import pytest

from boomtip.fusion.consistency import Innovations, chi2_quantile, consistency_block, consistent_rows, stream_consistency


def _stream(rng, n=600, rate_hz=20.0, dof=1, scale=1.0):
    t = np.arange(n) / rate_hz
    nis = scale * rng.chisquare(dof, n)
    return t, nis, np.full(n, float(dof))


def test_chi2_quantile_matches_scipy_stats():
    from scipy.stats import chi2

    for dof in (1, 3, 250):
        assert chi2_quantile(0.999, dof) == pytest.approx(chi2.ppf(0.999, dof), rel=1e-9)


@pytest.mark.parametrize("dof", [1, 3])
def test_a_consistent_stream_is_flagged_in_well_under_one_percent_of_runs(dof):
    rng = np.random.default_rng(7)
    flagged = sum(stream_consistency(*_stream(rng, dof=dof))["flagged"] for _ in range(1000))
    assert flagged <= 5  # 0.1 % expected: 1 in 1000, at most 5 by chance (p < 0.01)


def test_a_stream_noisier_than_stated_is_flagged_and_a_quieter_one_is_underconfident():
    rng = np.random.default_rng(3)
    loud = stream_consistency(*_stream(rng, scale=2.0))
    assert loud["flagged"] and not loud["underconfident"] and loud["nis_per_dof"] == pytest.approx(2.0, rel=0.15)
    quiet = stream_consistency(*_stream(rng, scale=0.3))
    assert not quiet["flagged"] and quiet["underconfident"]
    assert stream_consistency(np.array([]), np.array([]), np.array([])) == {"updates": 0, "flagged": False,
                                                                             "underconfident": False}


def test_a_ten_second_burst_in_a_long_run_is_flagged_at_its_window():
    rng = np.random.default_rng(5)
    t, nis, dof = _stream(rng, n=20 * 120)  # 120 s
    burst = (t >= 60) & (t < 70)
    nis[burst] *= 3.0  # the run's mean stays within its bound; the window's does not
    res = stream_consistency(t, nis, dof)
    assert res["flagged"] and res["flagged_from_s"] == pytest.approx(60.0)
    assert res["beyond_99"] == pytest.approx(np.mean(nis > chi2_quantile(0.99, 1)), abs=1e-4)


def test_consistent_rows_are_causal_and_clear_a_window_after_the_burst():
    rng = np.random.default_rng(11)
    t, nis, dof = _stream(rng, n=20 * 60)
    nis[(t >= 20) & (t < 25)] *= 10.0
    inn = Innovations()
    for row in zip(t, nis, dof.astype(int)):
        inn.add("deck_radar", *row)
    inn.add("deck_radar", 30.0, float("nan"), 1)  # not a number: not kept
    t_out = np.arange(0, 60, 0.01)
    ok = consistent_rows(t_out, inn)
    assert ok[t_out < 20].all()  # nothing before the burst knows of it
    assert not ok[(t_out > 21) & (t_out < 30)].any()  # while the burst fills much of the window
    assert ok[t_out >= 35.1].all()  # the burst has left the trailing 10 s
    assert inn.count("deck_radar") == len(t) and inn.streams == ["deck_radar"]
    assert list(consistency_block(inn)) == ["deck_radar"]


def test_merged_innovations_keep_each_filters_rows_before_the_cut_and_no_stream_left_empty():
    a, b = Innovations(), Innovations()
    for t in (1.0, 2.0, 3.0):
        a.add("lidar_height", t, 1.5, 1)
    b.add("lidar_height", 2.5, 0.5, 1, 2.0)
    b.add("radar_height_rate", 9.0, 1.0, 1)  # only after the cut
    m = Innovations.merged([a, b], until_s=2.9)
    assert m.streams == ["lidar_height"] and m.count("lidar_height") == 3
    t, nis, dof, scale = m.arrays("lidar_height")
    assert t.tolist() == [1.0, 2.0, 2.5] and nis.tolist() == [1.5, 1.5, 0.5] and scale.tolist() == [1.0, 1.0, 2.0]
    assert list(consistency_block(m)) == ["lidar_height"]
    assert Innovations.merged([a, b]).streams == ["lidar_height", "radar_height_rate"]
    assert a.only({"radar"}).streams == [] and a.only({"lidar_height"}).count("lidar_height") == 3
