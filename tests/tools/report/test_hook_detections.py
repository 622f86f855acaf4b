"""plots/detections.png of a hook run: a frame's block points, the block model at the fit, the
rope and the tracker's prior, in the recording's class colours; the fits' status per frame; a run
without a frame says so in its title."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from boomtip.data.sim.hook_world import HookSimulation
from boomtip.tools.chains.runner import build_chain, processing_for
from boomtip.tools.config.scenario import load_scenario
from boomtip.tools.report.classes import by_name
from boomtip.tools.report.hook_detections import (
    FrameStatus,
    hook_detections_figure,
    hook_frame_title,
    statuses,
    write_hook_detections,
)


@pytest.fixture(scope="module")
def hook_frame():
    sim = HookSimulation(load_scenario("hook-2", ["duration_s=0.5"]))
    chain = build_chain(sim, processing_for(sim))
    for frame in sim:
        res = chain.process(frame)
        if res is not None and res.detection is not None and res.detection.ok:
            return res, chain.pipeline.cfg.block_height_m
    raise AssertionError("no LiDAR frame with a block fit")


def test_the_picture_draws_the_block_its_model_and_the_prior(hook_frame, tmp_path):
    res, height = hook_frame
    rows = statuses(np.array([0.0, 0.05]), np.array(["ok", "sparse"], object), np.array(["ok", ""], object))
    assert [(r.method, r.ok) for r in rows] == [("hook block", True), ("hook block", False), ("rope", True)]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        fig = hook_detections_figure([(res, "the worst")], rows, height)
        labels = {t.get_text() for ax in fig.axes if ax.get_legend() for t in ax.get_legend().get_texts()}
        assert {by_name("hook_segment").label, by_name("hook_block").label, "predicted (the tracker's prior)"} <= labels
        assert {"ok", "sparse"} <= labels
        path = write_hook_detections(tmp_path, [(res, "the worst")], rows, height)
    import matplotlib.image as mpimg

    assert mpimg.imread(path)[..., :3].std() > 0.05  # drawn, not blank
    assert hook_frame_title(res).endswith("the block found") and f"{res.detection.n_points} block points" in hook_frame_title(res)


def test_without_a_frame_the_title_says_so(tmp_path):
    assert hook_frame_title(None) == "No LiDAR frame in this run: nothing to draw"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert write_hook_detections(tmp_path, [], [FrameStatus(0.0, "hook block", "no MRU attitude")], 4.0).is_file()
