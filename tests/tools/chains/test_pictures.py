"""Which frames the detections picture shows: the first LiDAR frame from the middle of the run on,
and the worst by the chain's score, held where the frames are perceived."""

from __future__ import annotations

import math
from types import SimpleNamespace

from boomtip.tools.chains.pictures import FramePictures, Picked

SOURCE = SimpleNamespace(meta=SimpleNamespace(t_start_s=10.0), duration_s=20.0)  # the middle: t = 20 s


def output(t_s: float) -> SimpleNamespace:
    return SimpleNamespace(frame=SimpleNamespace(t_s=t_s))


def test_the_middle_frame_is_the_first_lidar_frame_from_the_middle_of_the_run_on():
    pictures = FramePictures(SOURCE)
    wanted = [pictures.wants(s, t) for s, t in [("lidar", 19.9), ("radar", 20.0), ("lidar", 20.1), ("lidar", 20.2)]]
    assert wanted == [False, False, True, False]
    for s, t in [("lidar", 19.9), ("radar", 20.05), ("lidar", 20.1), ("lidar", 20.2)]:
        pictures.offer(s, output(t))
    assert pictures.middle.frame.t_s == 20.1
    pictures.offer("lidar", None)  # a chain's nothing for a frame changes nothing
    assert pictures.middle.frame.t_s == 20.1


def test_the_worst_is_the_first_of_the_highest_score_and_frames_without_one_are_no_candidates():
    scores = {11.0: (2.0, "two"), 12.0: None, 13.0: (5.0, "five"), 14.0: (5.0, "five again"), 15.0: (1.0, "one")}
    pictures = FramePictures(SOURCE, lambda o: scores[o.frame.t_s])
    for t in scores:
        pictures.consider(output(t))
    pictures.consider(None)
    assert pictures.worst.output.frame.t_s == 13.0 and pictures.worst.why == "five"
    failed = FramePictures(SOURCE, lambda o: (math.inf, "failed") if o.frame.t_s > 12 else (0.1, "ok"))
    for t in (11.0, 12.0, 13.0, 14.0):
        failed.consider(output(t))
    assert failed.worst.output.frame.t_s == 13.0  # the first failure


def test_the_pictures_frames_are_the_middle_and_the_worst_unless_they_are_one():
    pictures = FramePictures(SOURCE)
    pictures.offer("lidar", output(20.1))
    pictures.adopt(Picked(output(30.0), "the worst"))
    assert [(p.output.frame.t_s, p.why) for p in pictures.frames()][1] == (30.0, "the worst")
    pictures.adopt(Picked(output(20.1), "the worst"))
    assert [p.output.frame.t_s for p in pictures.frames()] == [20.1]
    assert FramePictures(SOURCE).frames() == []
    converted = FramePictures(SOURCE)
    converted.adopt(Picked(SimpleNamespace(inner=output(25.0), t_s=25.0), "held by a worker"))
    assert converted.frames(lambda o: o.inner)[0].output.frame.t_s == 25.0


def test_without_truth_the_worst_heave_frame_is_a_failed_deck_stage_not_a_frame_it_never_saw():
    import numpy as np

    from boomtip.data.frames import Frame
    from boomtip.data.sim.sources import simulation_for
    from boomtip.perception.deck import DeckResult
    from boomtip.perception.pipeline import FrameResult, Measurement
    from boomtip.perception.timing import StageTimes
    from boomtip.tools.chains.runner import build_chain, processing_for
    from boomtip.tools.config.scenario import load_scenario

    sim = simulation_for(load_scenario("sts-loaded", ["duration_s=0.2"]))
    chain = build_chain(sim, processing_for(sim)).heave
    frame = Frame("lidar", 0, 0.0, np.zeros((5, 3)))

    def result(status: str, deck: DeckResult | None) -> FrameResult:
        value = 30.0 if status == "ok" else float("nan")
        return FrameResult(frame, [Measurement(0.0, "deck_lidar", "D", value, 0.002, 1.0, status)], StageTimes(), deck_lidar=deck)

    no_attitude = result("no MRU attitude at t=0.000 s (outside the log or in a gap)", None)
    no_plane = result("no deck plane", DeckResult(float("nan"), None, None, np.zeros((5, 3)), "no deck plane"))
    found = result("ok", DeckResult(30.0, np.array([0.0, 0.0, 1.0, 30.0]), None, np.zeros((5, 3)), "ok", 0.002))
    assert chain.frame_score(no_attitude, None) is None  # the deck stage never saw it
    assert chain.frame_score(no_plane, None)[0] == math.inf and "no deck plane" in chain.frame_score(no_plane, None)[1]
    assert chain.frame_score(found, None)[0] == 0.002  # else the least certain: its stated sigma
