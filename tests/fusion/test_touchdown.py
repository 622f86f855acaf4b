"""Has the load landed: the clearance at the deck, within its sigmas, for the hold time."""

from __future__ import annotations

from boomtip.fusion.touchdown import TouchdownDetector


def test_landed_from_the_first_frame_of_a_held_run_at_the_deck_and_latched():
    d = TouchdownDetector(hold_s=0.5)
    frames = [(0.0, 0.50), (0.05, 0.20), (0.10, 0.01), (0.15, -0.005), (0.20, 0.02)]
    frames += [(0.25 + 0.05 * k, 0.004) for k in range(10)]
    seen = [d.update(t, c, 0.008) for t, c in frames]
    assert not any(seen[:11]) and seen[-1]
    assert d.landed_s == 0.10
    assert d.update(2.0, 3.0, 0.008)  # latched: a later clearance does not lift it


def test_a_load_that_dips_close_and_rises_again_has_not_landed():
    d = TouchdownDetector(hold_s=0.5)
    for k in range(40):  # at the deck for 0.3 s in every second: a wave passing under it
        t = 0.05 * k
        c = 0.01 if (t % 1.0) < 0.3 else 0.4
        assert not d.update(t, c, 0.008)
    assert d.landed_s is None


def test_a_frame_without_a_clearance_breaks_the_run():
    d = TouchdownDetector(hold_s=0.2)
    assert not d.update(0.0, 0.0, 0.01)
    assert not d.update(0.1, float("nan"), 0.01)
    assert not d.update(0.2, 0.0, 0.01)
    assert d.update(0.45, 0.0, 0.01) and d.landed_s == 0.2
