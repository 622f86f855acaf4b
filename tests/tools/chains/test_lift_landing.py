"""The lift's landing wiring: a carried deck's shared error widened for the filters alone."""

from __future__ import annotations

import math

import pytest

from boomtip.perception.lift import LoadClearance
from boomtip.tools.chains.lift_landing import LiftLanding
from boomtip.tools.config.processing import LiftProcessing


def test_a_carried_decks_error_is_widened_for_the_filters_by_the_frames_that_share_it():
    cfg = LiftProcessing()
    landing = LiftLanding(cfg, (6.058, 2.438, 2.591), 70.0, lidar_rate_hz=20.0)
    frames = cfg.deck_frame.fallback_error_correlation_s * 20.0  # 20 frames share one carried deck's error
    seen = LoadClearance("ok", 1.0, 0.004, centre_height_sigma_m=0.003, deck_sigma_m=0.002)
    assert landing.filter_sigmas(seen) == (0.004, 0.003)  # a deck seen: each frame's own
    hidden = LoadClearance("ok", 1.0, 0.010, centre_height_sigma_m=0.009, deck_sigma_m=0.008, deck_hidden="too few deck points")
    sigma_m, centre_sigma_m = landing.filter_sigmas(hidden)
    assert sigma_m == pytest.approx(math.sqrt(0.010**2 + (frames - 1) * 0.008**2))
    assert centre_sigma_m == pytest.approx(math.sqrt(0.009**2 + (frames - 1) * 0.008**2))
    assert hidden.sigma_m == 0.010  # the frame's own sigma (rows, touchdown) stays as measured
