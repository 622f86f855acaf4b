import numpy as np

from boomtip.tools.report.plots import decimated


def test_a_short_series_is_drawn_whole():
    t = np.arange(100.0)
    y = np.sin(t)
    td, yd = decimated(t, y, bins=50)
    assert np.array_equal(td, t) and np.array_equal(yd, y)


def test_a_long_series_keeps_each_bins_extremes_its_gaps_and_its_order():
    rng = np.random.default_rng(3)
    t = np.arange(0, 600, 0.01)  # 60,000 samples
    y = np.sin(t) + 0.01 * rng.standard_normal(len(t))
    y[12345] = 9.0  # a spike: must survive
    y[30000:30050] = np.nan  # a gap: must stay one
    td, yd = decimated(t, y, bins=400)
    assert len(td) <= 3 * 400 and np.all(np.diff(td) > 0)
    assert 9.0 in yd and np.isnan(yd).any()
    # every bin's least and greatest finite value is drawn
    k = np.minimum((t / np.ptp(t) * 400).astype(int), 399)
    kd = np.minimum((td / np.ptp(t) * 400).astype(int), 399)
    for b in (0, 17, 150, 300, 399):
        v = y[k == b]
        assert np.nanmax(yd[kd == b]) == np.nanmax(v) and np.nanmin(yd[kd == b]) == np.nanmin(v)


def test_a_band_keeps_both_edges_extremes_on_common_times():
    t = np.linspace(0, 100, 20001)
    lo, hi = -1 - np.cos(t), 1 + np.sin(3 * t)
    td, lod, hid = decimated(t, lo, hi, bins=100)
    assert len(td) == len(lod) == len(hid) < len(t)
    assert lod.min() == lo.min() and hid.max() == hi.max()
    assert np.array_equal(lod, lo[np.searchsorted(t, td)]) and np.array_equal(hid, hi[np.searchsorted(t, td)])


def test_times_that_are_not_finite_are_dropped():
    t = np.arange(10000.0)
    t[5] = np.nan
    td, yd = decimated(t, np.ones(10000), bins=100)
    assert np.all(np.isfinite(td)) and len(td) == len(yd)
