"""The lift's rows: a clearance too uncertain is lost, not printed."""

from __future__ import annotations

import math

import numpy as np

from boomtip.tools.report.lift import COLUMNS, as_columns, estimate_row


def _state(value, sigma):
    return np.array([value, 0.1, 0.0]), np.diag([sigma**2, 0.01, 1.0])


def test_a_clearance_within_its_bound_is_given_less_the_rope_paid_out():
    row = estimate_row(_state(12.0, 0.01), _state(12.2, 0.01), (2.0, 0.3), 2.0, 0.1)
    assert row["estimate"] == "ok"
    assert row["clearance_m"] == 10.0 and math.isclose(row["clearance_rate_mps"], -0.2)
    assert row["height_m"] == 10.2 and row["sigma_m"] == 0.01


def test_a_clearance_beyond_its_bound_or_not_yet_measured_is_left_empty_with_the_reason():
    lost = estimate_row(_state(12.0, 0.5), _state(12.2, 0.5), (2.0, 0.3), 2.0, 0.1)
    none = estimate_row(_state(np.nan, np.inf), _state(np.nan, np.inf), (2.0, 0.3), 2.0, 0.1)
    assert lost["estimate"] == "lost" and none["estimate"] == "no clearance yet"
    cols = as_columns([lost, none])
    assert set(COLUMNS) <= set(cols) and np.all(np.isnan(cols["clearance_m"])) and list(cols["estimate"]) == ["lost", "no clearance yet"]
