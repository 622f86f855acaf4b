"""The feeder model's merges beside the frames (FeederChain's LiDAR path).

A merge aligns every collected frame to the others (perception/feeder_registration.py,
`merged_model`): seconds for 200 frames, while a frame has tens of milliseconds. By default
(`merge_lag_frames` (0,)) it runs inline, in the frame it is due at, and its time is that
frame's. With a lag it runs on a snapshot of the frames and poses collected when it was due, in a worker
thread or, given an executor, wherever that runs it (the ship chain forks a process per merge
when the run has two: a thread shares the interpreter with the chain, and the merge's many small
numpy steps hold it); the chain keeps registering to the current model and collecting.

Its model is taken at a fixed LiDAR frame (`merge_lag_frames` after the one that started
it), waiting there if it is not done: when it is taken never depends on the machine's
speed, so runs repeat bit for bit. A merge that fails leaves the old model, with a note; a new
keyframe (a new model) drops a merge of the old one. A merge still running when the run ends
is waited for (its result dropped): the thread would otherwise hold a core past the run.
"""

from __future__ import annotations

import time
from concurrent.futures import Executor, Future, ThreadPoolExecutor
from dataclasses import dataclass

from boomtip.perception.feeder_registration import FeederModel, MergedModel, merged_model


@dataclass
class MergeRecord:
    frames: int  # frames merged
    started_frame: int  # the LiDAR frame (count) it was started at
    taken_frame: int  # and the one its model was taken at (-1: never)
    worker_s: float  # its time in the worker
    wait_s: float  # how long the chain's thread waited for it at the taking
    status: str  # "ok", or why its model was not taken


class BackgroundMerges:
    """Merges of a FeederModel run beside the frames and taken at fixed frames. `executor`: where
    a lagged merge runs (anything with concurrent.futures' `submit`, e.g. another process: a merge
    is a pure function and its result pickles); None: a worker thread."""

    def __init__(self, model: FeederModel, executor: Executor | None = None) -> None:
        self.model = model
        self._executor = executor
        lags = model.cfg.merge_lag_frames
        # merge's frames -> its lag (past the end of the lags, the last; none: inline)
        self.lags = {n: lags[min(i, len(lags) - 1)] if lags else 0 for i, n in enumerate(model.cfg.model_merges)}
        self.records: list[MergeRecord] = []
        self.frame = 0  # LiDAR frames seen
        self._pool: ThreadPoolExecutor | None = None
        self._pending: tuple[Future, MergeRecord, int] | None = None  # (its result, record, the model's keyframes then)

    def next_frame(self) -> None:
        """At the start of each LiDAR frame: count it, and take a merge due at it."""
        self.frame += 1
        if self._pending is not None and self.frame >= self._pending[1].taken_frame:
            self._take()

    def start(self) -> None:
        """A merge is due (FeederModel.collect said so): run it beside the frames, or inline at a lag of 0."""
        if self._pending is not None:  # the next merge is due before the last was taken: take it first
            self._take()
        frames, poses, samples = self.model.merge_inputs()
        n = len(frames)
        lag = self.lags.get(n, 0)
        rec = MergeRecord(n, self.frame, self.frame + lag, 0.0, 0.0, "running")
        self.records.append(rec)
        if lag == 0:
            future: Future = Future()
            try:
                future.set_result(_timed(merged_model, frames, poses, self.model.cfg, samples))
            except Exception as e:  # noqa: BLE001 - a failed merge leaves the old model (see _take)
                future.set_exception(e)
        else:
            if self._pool is None:
                self._pool = self._executor or ThreadPoolExecutor(max_workers=1, thread_name_prefix="feeder-merge")
            future = self._pool.submit(_timed, merged_model, frames, poses, self.model.cfg, samples)
        self._pending = (future, rec, self.model.keyframes)
        if lag == 0:
            self._take()

    def _take(self) -> None:
        future, rec, keyframes = self._pending
        self._pending = None
        t0 = time.perf_counter()
        try:
            merged, rec.worker_s = future.result()
            failure = None
        except Exception as e:  # noqa: BLE001 - a failure of the merge: the chain goes on with the old model
            if isinstance(e, getattr(self._executor, "fatal", ())):  # the executor's own failure (a worker lost) stops the run
                raise
            failure = f"failed: {type(e).__name__}: {e}"
        rec.wait_s = time.perf_counter() - t0
        rec.taken_frame = self.frame
        if self.model.keyframes != keyframes:  # a new keyframe since: this merge was of the old model, whose fate is moot
            rec.status, rec.taken_frame = "dropped: a new keyframe was taken while it ran", -1
            return
        if failure is not None:
            rec.status, rec.taken_frame = failure, -1
            if rec.frames >= max(self.model.cfg.model_merges):
                self.model.collected.clear()  # the last merge: the old model stays final
                self.model.merged = True
            return
        self.model.apply_merge(merged)
        rec.status = "ok"

    def close(self) -> None:
        """At the end of the run: a merge not yet due is dropped, and waited for if it is still
        running, so no worker outlives the run (outputs, the next run of a sweep, a bench)."""
        if self._pending is not None:
            self._pending[1].status, self._pending[1].taken_frame = "dropped: the run ended first", -1
            self._pending = None
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None


def _timed(fn, *args) -> tuple[MergedModel, float]:
    t0 = time.perf_counter()
    return fn(*args), time.perf_counter() - t0
