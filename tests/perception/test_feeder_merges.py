"""The feeder model's merges beside the frames (perception/feeder_merges.py): taken at fixed
frames whatever the machine's speed, a failed merge keeps the old model, a new keyframe drops a
merge of the old one."""

from __future__ import annotations

import numpy as np
import pytest


def _structure(seed: int) -> np.ndarray:
    """A deck with a bulwark along x and a container end wall across it: x, y and yaw pinned."""
    r = np.random.default_rng(seed)
    deck = np.column_stack([r.uniform(-20, 20, 1500), r.uniform(-8, 8, 1500), np.zeros(1500)])
    wall = np.column_stack([r.uniform(-20, 20, 600), np.full(600, 8.0), r.uniform(0, 1.5, 600)])
    end = np.column_stack([np.full(400, 5.0), r.uniform(-2, 2, 400), r.uniform(0, 2.6, 400)])
    return np.vstack([deck, wall, end]) + r.normal(0, 0.005, (2500, 3))


def _model_with(n_frames: int, merges=(4, 8), lags=(2, 4)):
    from boomtip.perception.feeder_registration import FeederModel, RegistrationConfig

    with pytest.raises(ValueError, match="at least 0"):
        RegistrationConfig(model_merges=merges, merge_lag_frames=(2, -1))
    model = FeederModel(RegistrationConfig(model_merges=merges, merge_lag_frames=lags))
    model.set_keyframe(_structure(0), np.eye(4))
    due = [model.collect(_structure(k), np.eye(4)) for k in range(1, n_frames)]
    return model, due


def test_a_merge_runs_beside_the_frames_and_is_taken_at_its_frame_waiting_for_it(monkeypatch):
    """A merge of 4 frames at a lag of 2 is taken two LiDAR frames later, not before even when it
    is done, and the chain waits there when it is not; a frame collected meanwhile follows the
    merged ones with its own pose."""
    import time

    from boomtip.perception import feeder_merges as feeder_merge

    model, due = _model_with(4)
    assert due == [False, False, True]
    real = feeder_merge.merged_model
    monkeypatch.setattr(feeder_merge, "merged_model", lambda *a: (time.sleep(0.4), real(*a))[1])
    merges = feeder_merge.BackgroundMerges(model)
    merges.next_frame()
    surface_before = model.surface
    snapshot = model.merge_inputs()
    merges.start()
    T_meanwhile = np.eye(4)
    T_meanwhile[0, 3] = 0.123
    assert not model.collect(_structure(9), T_meanwhile)
    merges.next_frame()  # one frame later: not yet, whether done or not
    assert model.surface is surface_before and model.model_frames == 1 and merges.records[0].status == "running"
    merges.next_frame()  # two frames later: taken, after waiting for the worker
    rec = merges.records[0]
    assert rec.status == "ok" and (rec.started_frame, rec.taken_frame) == (1, 3)
    assert rec.wait_s > 0.2 and rec.worker_s > 0.4
    assert model.surface is not surface_before and model.model_frames == 4 and not model.merged
    assert len(model.collected) == 5 and model.collected[4][1][0, 3] == 0.123  # the frame collected meanwhile
    # the poses are those the same merge gives inline, to the bit, and within 2 mm of where they were
    frames, poses, samples = snapshot
    inline = real(frames, poses, model.cfg, samples).poses
    assert all(np.array_equal(T, A) for (_, T, _), A in zip(model.collected[:4], inline))
    assert max(np.abs(T - np.eye(4)).max() for _, T, _ in model.collected[:4]) < 2e-3
    merges.close()


def test_a_failed_merge_keeps_the_old_model_and_says_why(monkeypatch):
    from boomtip.perception import feeder_merges as feeder_merge

    def broken(*_):
        raise RuntimeError("no overlap at all")

    monkeypatch.setattr(feeder_merge, "merged_model", broken)
    model, _ = _model_with(4)
    merges = feeder_merge.BackgroundMerges(model)
    surface_before = model.surface
    merges.start()
    merges.next_frame()
    merges.next_frame()
    rec = merges.records[0]
    assert rec.status == "failed: RuntimeError: no overlap at all" and rec.taken_frame == -1
    assert model.surface is surface_before and model.model_frames == 1 and not model.merged
    # the chain goes on: the next merge is due at 8 frames and runs
    monkeypatch.undo()
    assert [model.collect(_structure(k), np.eye(4)) for k in range(4, 8)] == [False, False, False, True]
    merges.start()
    for _ in range(4):
        merges.next_frame()
    assert merges.records[1].status == "ok" and model.model_frames == 8 and model.merged


def test_a_new_keyframe_drops_the_merge_of_the_old_model():
    from boomtip.perception.feeder_merges import BackgroundMerges

    model, _ = _model_with(4)
    merges = BackgroundMerges(model)
    merges.start()
    model.set_keyframe(_structure(5), np.eye(4))
    surface = model.surface
    merges.next_frame()
    merges.next_frame()
    assert merges.records[0].status.startswith("dropped: a new keyframe") and model.surface is surface
    assert model.model_frames == 1 and len(model.collected) == 1



def test_a_merge_done_early_is_still_taken_only_at_its_frame():
    from boomtip.perception import feeder_merges as feeder_merge

    model, _ = _model_with(4)
    merges = feeder_merge.BackgroundMerges(model)
    merges.next_frame()
    surface_before = model.surface
    merges.start()
    merges._pending[0].result()  # the worker is done
    merges.next_frame()
    assert model.surface is surface_before and merges.records[0].status == "running"
    merges.next_frame()
    assert model.surface is not surface_before and merges.records[0].status == "ok"
    merges.close()


def test_a_failed_merge_of_an_old_keyframe_leaves_the_new_model_alone(monkeypatch):
    """The last merge fails after a new keyframe was taken: the new model is not frozen."""
    from boomtip.perception import feeder_merges as feeder_merge

    model, _ = _model_with(8)  # the 8-frame merge, the last one, is due
    monkeypatch.setattr(feeder_merge, "merged_model", lambda *a: (_ for _ in ()).throw(MemoryError("merge")))
    merges = feeder_merge.BackgroundMerges(model)
    merges.start()
    model.set_keyframe(_structure(20), np.eye(4))
    merges.next_frame()
    merges.next_frame()
    merges.next_frame()
    merges.next_frame()
    assert merges.records[-1].status.startswith("dropped: a new keyframe")
    assert not model.merged and model.collected  # the new model still grows and merges
    merges.close()


def test_a_merge_pickles_as_arrays_and_comes_back_the_same_model():
    """A merge made in another process comes back pickled: its cloud and search index rebuilt
    from the same points and normals."""
    import pickle

    from boomtip.perception.feeder_registration import RegistrationConfig, merged_model

    frames = [_structure(k) for k in range(4)]
    merged = merged_model(frames, [np.eye(4)] * 4, RegistrationConfig())
    back = pickle.loads(pickle.dumps(merged))
    assert back.frames == merged.frames and all(np.array_equal(a, b) for a, b in zip(back.poses, merged.poses))
    assert np.array_equal(np.asarray(back.cloud.points), np.asarray(merged.cloud.points))
    assert np.array_equal(np.asarray(back.cloud.normals), np.asarray(merged.cloud.normals))
    query = frames[1][:200] + 0.01
    for a, b in zip(back.surface.nearest(query, 0.5), merged.surface.nearest(query, 0.5)):
        assert np.array_equal(a, b)


def test_an_executors_own_failure_stops_the_run_where_a_failed_merge_would_not():
    """A merge that fails leaves the old model; the executor losing its worker (its `fatal`
    errors) is no merge's failure and is raised."""
    from concurrent.futures import Future

    from boomtip.perception.feeder_merges import BackgroundMerges

    class Lost(RuntimeError):
        pass

    class Failing:
        fatal = (Lost,)

        def __init__(self, error):
            self.error = error

        def submit(self, fn, *args):
            f = Future()
            f.set_exception(self.error)
            return f

        def shutdown(self, wait=True, *, cancel_futures=False):
            pass

    for error, raised in ((ValueError("no overlap"), False), (Lost("the worker was killed"), True)):
        model, due = _model_with(4)
        merges = BackgroundMerges(model, Failing(error))
        merges.start()
        merges.next_frame()
        if raised:
            with pytest.raises(Lost):
                merges.next_frame()
        else:
            merges.next_frame()
            assert merges.records[-1].status.startswith("failed: ValueError: no overlap")
