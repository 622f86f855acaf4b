"""plots/detections.png: one LiDAR frame's detections over its cloud, and every method's status;
a run without a LiDAR frame or a deck says so in its title instead of failing."""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import pytest

from boomtip.data.sim.sources import simulation_for
from boomtip.perception.pipeline import Measurement
from boomtip.tools.chains.runner import build_chain, processing_for
from boomtip.tools.config.scenario import load_scenario
from boomtip.tools.report.classes import by_name
from boomtip.tools.report.detections import deck_axes, detections_figure, detections_title, write_detections


@pytest.fixture(scope="module")
def lidar_frame():
    sim = simulation_for(load_scenario("sts-loaded", ["duration_s=0.5"]))
    chain = build_chain(sim, processing_for(sim)).heave
    for frame in sim:
        res = chain.process(frame)
        if frame.sensor == "lidar" and res.deck_lidar is not None and res.deck_lidar.ok:
            return res, chain.rows, chain.pipeline.p_tip["lidar"]
    raise AssertionError("no LiDAR frame with a deck")


def test_the_deck_axes_put_the_plane_at_height_zero_and_the_sensor_above():
    plane = np.array([0.1, -0.2, 0.97, 40.0])
    plane[:3] /= np.linalg.norm(plane[:3])
    R, origin = deck_axes(plane)
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-12)
    on_plane = origin + 5.0 * R[0] - 3.0 * R[1]
    assert abs(plane[:3] @ on_plane + plane[3]) < 1e-9
    assert (R @ (np.zeros(3) - origin))[2] == pytest.approx(40.0)  # the sensor 40 m above the deck


def test_the_picture_draws_every_class_it_found_and_the_status_of_every_method(lidar_frame, tmp_path):
    res, rows, tip = lidar_frame
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        fig = detections_figure([(res, "a representative frame"), (res, "the worst")], rows, tip)
        labels = {t.get_text() for ax in fig.axes if ax.get_legend() for t in ax.get_legend().get_texts()}
        assert {by_name(c).label for c in ("cloud", "deck", "markers", "tip")} <= labels
        assert "ok" in labels
        path = write_detections(tmp_path, [(res, "a representative frame")], rows, tip)
    import matplotlib.image as mpimg

    img = mpimg.imread(path)
    assert path == tmp_path / "plots" / "detections.png"
    assert img.shape[0] > 500 and img[..., :3].std() > 0.05  # drawn, not blank


def test_without_a_frame_or_a_deck_the_title_says_so_and_the_picture_is_still_written(lidar_frame, tmp_path):
    res, rows, tip = lidar_frame
    assert detections_title(None) == "No LiDAR frame in this run: nothing to draw"
    no_deck = replace(res, deck_lidar=replace(res.deck_lidar, plane_sensor=None, fit=None, status="no plane found"))
    assert detections_title(no_deck).endswith("no deck found (no plane found)")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert write_detections(tmp_path, [], [], tip).is_file()
        bad = [Measurement(0.1 * k, "deck_lidar", "D", float("nan"), float("nan"), 1.0, "no plane found") for k in range(5)]
        assert write_detections(tmp_path, [(no_deck, "the worst")], bad, tip).is_file()
