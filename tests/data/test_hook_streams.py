"""The hook's measurement streams cut at a time: each stream at its own time stamps."""

from __future__ import annotations

from dataclasses import fields

import numpy as np

from boomtip.data.hook_streams import TIMES_OF, HookMeasurements


def _streams() -> HookMeasurements:
    t_lidar, t_enc, t_mru = np.arange(0.0, 1.0, 0.05), np.arange(0.0, 1.0, 0.01), np.arange(0.0, 1.0, 0.005)
    k = len(t_lidar)
    return HookMeasurements(t_lidar, np.arange(3.0 * k).reshape(k, 3), t_enc, np.ones((len(t_enc), 3)), t_mru,
                            np.ones((len(t_mru), 4)), lidar_cov_m2=np.ones((k, 3, 3)), lidar_model_fit=np.ones(k, bool),
                            rope_direction=np.ones((k, 3)), rope_cov=np.ones((k, 3, 3)))


def test_every_stream_is_cut_at_its_own_times_inclusive():
    cut = _streams().until(0.5)
    assert cut.t_lidar[-1] == 0.5 and len(cut.t_lidar) == 11
    assert len(cut.t_encoders) == 51 and len(cut.t_mru) == 101
    for f in fields(cut):  # each field as long as its stream's times; a field left None stays None
        value = getattr(cut, f.name)
        if value is None:
            assert f.name == "lidar_sigma_m"
        else:
            assert len(value) == len(getattr(cut, TIMES_OF[f.name])), f.name
    np.testing.assert_array_equal(cut.lidar_p_rel_tip_world, _streams().lidar_p_rel_tip_world[:11])


def test_every_field_names_its_stream():
    assert set(TIMES_OF) == {f.name for f in fields(HookMeasurements)}


def test_a_time_before_every_sample_leaves_empty_streams_and_one_after_them_all():
    whole = _streams()
    assert len(whole.until(-1.0).t_lidar) == 0 and len(whole.until(-1.0).mru) == 0
    assert len(whole.until(5.0).t_mru) == len(whole.t_mru)


def test_stamps_out_of_order_are_cut_by_their_times_not_their_places():
    whole = _streams()
    order = np.random.default_rng(2).permutation(len(whole.t_lidar))
    shuffled = HookMeasurements(whole.t_lidar[order], whole.lidar_p_rel_tip_world[order], whole.t_encoders, whole.encoders,
                                whole.t_mru, whole.mru, rope_direction=whole.rope_direction[order])
    cut = shuffled.until(0.5)
    assert sorted(cut.t_lidar) == list(whole.t_lidar[:11])
    np.testing.assert_array_equal(cut.lidar_p_rel_tip_world, whole.lidar_p_rel_tip_world[order][whole.t_lidar[order] <= 0.5])
