"""A run on two cores gives the serial run's outputs: a hook run's frames made in a child
process and its estimators split between two; a ship run's perception made in a child ahead of
its fusion. A child that dies stops the run with that reason."""

from __future__ import annotations

import csv
import os
import time
import json

import numpy as np
import pytest

from boomtip.data.frames import Frame, FrameSource
from boomtip.tools.config.scenario import load_scenario
from boomtip.data.sim.sources import simulation_for
from boomtip.tools.chains import workers
from boomtip.tools.chains.pictures import FramePictures
from boomtip.tools.chains.resources import RunResources
from boomtip.tools.chains.runner import run_into

TIMING_KEYS = {"runtime_fraction", "apt_ms", "time_ms"}


def _is_timing(key: str) -> bool:
    return key in TIMING_KEYS or "_ms" in key or key in ("worker_s", "wait_s")


def _without_timings(x):
    if isinstance(x, dict):
        return {k: _without_timings(v) for k, v in x.items() if not _is_timing(k)}
    if isinstance(x, list):
        return [_without_timings(v) for v in x]
    return x


def _rows(path):
    with open(path) as fh:
        return [{k: v for k, v in row.items() if k not in TIMING_KEYS} for row in csv.DictReader(fh)]


@pytest.mark.slow
@pytest.mark.skipif(not workers.parallel_enabled(), reason="one core, or no fork: nothing runs in parallel")
def test_a_run_on_two_cores_writes_what_the_serial_run_writes(tmp_path):
    outs = {}
    for label in ("serial", "parallel"):
        sim = simulation_for(load_scenario("hook-2", ["duration_s=1.5"]))
        out = tmp_path / label
        out.mkdir()
        if label == "serial":
            with workers.serial():
                assert not workers.parallel_enabled()
                run_into(sim, out, report=False)
        else:
            run_into(sim, out, report=False, resources=RunResources(lean=True, workers=2))
        outs[label] = out
    s, p = outs["serial"], outs["parallel"]
    assert (s / "hook_estimates.csv").read_bytes() == (p / "hook_estimates.csv").read_bytes()
    rows = _rows(s / "hook_measurements.csv")
    assert len(rows) == 30 and rows == _rows(p / "hook_measurements.csv")
    ks, kp = json.loads((s / "kpis.json").read_text()), json.loads((p / "kpis.json").read_text())
    assert _without_timings(ks) == _without_timings(kp)
    assert set(ks["hook"]) >= {"ekf_flexible", "ekf_rigid", "ukf_flexible", "ukf_rigid"}


@pytest.mark.slow
@pytest.mark.skipif(not workers.parallel_enabled(), reason="one core, or no fork: nothing runs in parallel")
# 7 s: past the static test's 4 s warm-up and the model's 50-frame merge ([0,3]: that merge in a
# thread, or in a forked process); 3 s: every frame still held back by the warm-up at the end
@pytest.mark.parametrize("duration, lags", [(7, "[0]"), (7, "[0,3]"), (3, "[0]")])
def test_a_ship_run_with_its_perception_in_a_worker_writes_what_one_process_writes(tmp_path, duration, lags):
    outs = {}
    for n in (1, 2):
        sim = simulation_for(load_scenario("sts-loaded", [f"duration_s={duration}",
                                                          f"processing.feeder.perception.registration.merge_lag_frames={lags}"]))
        outs[n] = tmp_path / f"workers{n}"
        outs[n].mkdir()
        run_into(sim, outs[n], report=False, resources=RunResources(lean=True, workers=n))
    one, two = outs[1], outs[2]
    for name in ("estimates.csv", "feeder_estimates.csv", "feeder_estimates_online.csv", "feeder_calibration.csv"):
        assert (one / name).read_bytes() == (two / name).read_bytes(), name
    assert _rows(one / "measurements.csv") == _rows(two / "measurements.csv")
    k1, k2 = json.loads((one / "kpis.json").read_text()), json.loads((two / "kpis.json").read_text())
    assert _without_timings(k1) == _without_timings(k2)
    assert len(_rows(one / "feeder_estimates.csv")) > 10 * duration  # the feeder was estimated, not skipped alike in both
    if duration == 7:
        assert k1["feeder"]["rmse_pos_m"][0] < 0.02
        merged = [(m["frames"], m["started_frame"], m["taken_frame"], m["status"]) for m in k1["feeder"]["model_merges"]]
        assert merged == ([(20, 20, 20, "ok"), (50, 50, 50, "ok")] if lags == "[0]" else [(20, 20, 20, "ok"), (50, 50, 53, "ok")])


class _Counting(FrameSource):
    """Frames 0..n-1; fails at ``fail_at``."""

    def __init__(self, n: int, fail_at: int | None = None) -> None:
        self.n, self.fail_at = n, fail_at

    def __iter__(self):
        for k in range(self.n):
            if k == self.fail_at:
                raise KeyError(f"frame {k} is broken")
            yield Frame("lidar", k, 0.05 * k, np.full((1000, 3), float(k)))

    def __len__(self) -> int:
        return self.n


def test_the_childs_frames_come_in_order_and_whole():
    frames = list(workers.frames_in_child(_Counting(12)))
    assert [f.index for f in frames] == list(range(12))
    assert all(f.points_sensor.shape == (1000, 3) and np.all(f.points_sensor == f.index) for f in frames)


def test_the_childs_failure_is_raised_here_after_the_frames_before_it():
    got = []
    with pytest.raises(KeyError, match="frame 5 is broken"):
        for f in workers.frames_in_child(_Counting(12, fail_at=5)):
            got.append(f.index)
    assert got == [0, 1, 2, 3, 4]


def test_stopping_early_ends_the_child():
    import multiprocessing as mp

    it = workers.frames_in_child(_Counting(1000))
    assert next(it).index == 0
    it.close()
    assert not [p for p in mp.active_children() if p.name == "boomtip-frames"]


def test_the_split_balances_the_costs_and_keeps_every_job():
    a, b = workers.split_by_cost({"ukf_flexible": 5.3, "ukf_rigid": 2.9, "ekf_flexible": 0.95, "ekf_rigid": 0.85})
    assert a == ["ukf_flexible"] and b == ["ukf_rigid", "ekf_flexible", "ekf_rigid"]
    a, b = workers.split_by_cost({"x": 1.0, "y": 1.0, "z": 1.0, "w": 1.0})
    assert sorted(a + b) == ["w", "x", "y", "z"] and len(a) == len(b) == 2


def test_run_split_returns_each_jobs_result_in_the_given_order():
    out = workers.run_split(["a", "bb", "ccc"], {"a": 3.0}, lambda name: (name, len(name), np.arange(len(name))))
    assert list(out) == ["a", "bb", "ccc"]
    assert [out[k][1] for k in out] == [1, 2, 3] and np.array_equal(out["ccc"][2], [0, 1, 2])

    def fails_on_bb(name):
        if name == "bb":
            raise ValueError("no job bb")
        return name

    for costs in ({"bb": 2.0}, {"a": 2.0}):  # the failing job in the first child, then in the second
        with pytest.raises(ValueError, match="no job bb"):
            workers.run_split(["a", "bb"], costs, fails_on_bb)


def test_stopping_early_ends_the_child_under_the_clis_sigterm_handler():
    """The CLI turns SIGTERM into KeyboardInterrupt; the child, blocked on a full queue, still ends."""
    import multiprocessing as mp
    import signal

    from boomtip.tools.cli.common import terminate_like_interrupt

    saved = signal.getsignal(signal.SIGTERM)
    try:
        terminate_like_interrupt()
        it = workers.frames_in_child(_Counting(1000))
        assert next(it).index == 0
        it.close()
    finally:
        signal.signal(signal.SIGTERM, saved)
    assert not [p for p in mp.active_children() if p.name == "boomtip-frames"]


class _Tally:
    """A stateful function: what it was given so far."""

    def __init__(self) -> None:
        self.seen = 0

    def __call__(self, frame: Frame) -> tuple[int, int]:
        self.seen += 1
        return frame.index, self.seen


def test_a_mapped_function_keeps_its_state_in_the_child_and_its_results_come_in_order():
    tally = _Tally()
    got = list(workers.mapped_in_child(_Counting(40), tally))
    assert got == [(k, k + 1) for k in range(40)]
    assert tally.seen == 0  # the state lives in the child


def _die_at(k: int):
    import os
    import signal

    def fn(frame: Frame) -> int:
        if frame.index == k:
            os.kill(os.getpid(), signal.SIGKILL)
        return frame.index

    return fn


def test_a_child_that_is_killed_stops_the_run_with_that_reason():
    got = []
    with pytest.raises(workers.WorkerDied, match="killed by signal 9"):
        for index in workers.mapped_in_child(_Counting(20), _die_at(6)):
            got.append(index)
    assert got == list(range(len(got))) and len(got) <= 6  # what reached this process before it died, then the reason


def _kill_self() -> None:
    import os
    import signal

    os.kill(os.getpid(), signal.SIGKILL)


def test_a_forked_call_returns_its_result_or_its_error_or_says_it_died():
    pool = workers.ForkExecutor("boomtip-test")
    big = np.arange(1_000_000.0)  # the child's copy: not pickled on the way in
    assert pool.submit(np.sum, big).result(timeout=30) == big.sum()
    with pytest.raises(KeyError, match="no such key"):
        pool.submit({}.__getitem__, "no such key").result(timeout=30)
    with pytest.raises(workers.WorkerDied, match="ended before its work was done"):
        pool.submit(_kill_self).result(timeout=30)
    pool.shutdown()


class _Noting(_Counting):
    """Frames whose reading adds a note to the source, as a loader does (a frame timed by the
    capture clock, a datagram dropped)."""

    def __init__(self, n: int) -> None:
        super().__init__(n)
        self.meta = type("Meta", (), {})()
        self.meta.notes, self.meta.t_start_s, self.meta.duration_s = ["known before the run"], 0.0, 0.4

    def __iter__(self):
        for frame in super().__iter__():
            if frame.index == 3:
                self.meta.notes.append("frame 3 was read with a note")
            yield frame


class _Chain:
    """perceive in the worker, fuse here; at the end what the worker's pipeline still held."""

    def __init__(self) -> None:
        self.fused, self.held = [], []

    def frames(self, source):
        return iter(source)

    def perceive(self, frame):
        return frame.index

    def without_clouds(self, index):
        return index

    def fuse(self, index):
        self.fused.append(index)
        return index

    def finish_perception(self):
        return ["held back"]

    def finish_fusion(self, held):
        self.held.extend(held)


@pytest.mark.skipif(not workers.parallel_enabled(), reason="one core, or no fork: nothing runs in parallel")
def test_what_the_worker_gathered_comes_back_at_the_end_the_sources_notes_and_the_held_frames():
    source, chain = _Noting(8), _Chain()
    pictures = FramePictures(source, lambda index: (float(index % 4), f"frame {index}"))
    out = list(RunResources(workers=2).processed(chain, source, pictures, keep_clouds=False))
    assert out == [("lidar", k) for k in range(8)] and chain.fused == list(range(8))
    assert chain.held == ["held back"]
    assert pictures.worst.why == "frame 3"  # the worst the worker saw (3 and 7 score alike: the first)
    assert source.meta.notes == ["known before the run", "frame 3 was read with a note"]


def _big(frame: Frame) -> np.ndarray:
    return np.full(300_000, float(frame.index))  # 2.4 MB: written to the pipe in many pieces


def test_a_child_killed_halfway_through_a_message_stops_the_run_instead_of_a_wait_forever():
    import multiprocessing as mp
    import os
    import signal
    import threading
    import time

    got, failure = [], []

    def consume():
        try:
            for item in workers.mapped_in_child(_Counting(200), _big, name="boomtip-test-big"):
                got.append(item[0])
                time.sleep(0.3)  # busy fusing: the child's next message waits in the pipe, half written
                if len(got) == 2:
                    (child,) = [p for p in mp.active_children() if p.name == "boomtip-test-big"]
                    os.kill(child.pid, signal.SIGKILL)
        except workers.WorkerDied as exc:
            failure.append(exc)

    reader = threading.Thread(target=consume, daemon=True)
    reader.start()
    reader.join(timeout=30)
    assert not reader.is_alive(), "the read waited for the dead child's message forever"
    assert failure and "killed by signal 9" in str(failure[0])


def test_shutting_a_fork_executor_down_stops_a_call_still_running():
    import multiprocessing as mp
    import time

    pool = workers.ForkExecutor("boomtip-test-sleep")
    pool.submit(time.sleep, 60)
    (child,) = [p for p in mp.active_children() if p.name == "boomtip-test-sleep"]
    t0 = time.perf_counter()
    pool.shutdown(cancel_futures=True)
    assert not child.is_alive() and time.perf_counter() - t0 < 10


@pytest.mark.skipif(not workers.parallel_enabled(), reason="one core, or no fork: nothing runs in parallel")
def test_a_worker_of_ours_runs_its_own_work_serially():
    pool = workers.ForkExecutor("boomtip-test-daemon")
    assert pool.submit(workers.parallel_enabled).result(timeout=30) is False  # a daemonic process may not fork
    pool.shutdown()


def _sleep_as_child():
    workers._as_child()
    time.sleep(2.0)


def test_a_child_signalled_as_it_starts_ends_by_the_signal_not_through_the_parents_handler():
    """Under the CLI's SIGTERM handler (KeyboardInterrupt), a child signalled before it set its
    own handlers would unwind through its copy of the parent's stack; SIGINT and SIGTERM are
    blocked across the fork, so it ends by the signal, and the parent's mask is as it was."""
    import multiprocessing as mp
    import signal

    from boomtip.tools.cli.common import terminate_like_interrupt

    saved, mask = signal.getsignal(signal.SIGTERM), signal.pthread_sigmask(signal.SIG_BLOCK, set())
    try:
        terminate_like_interrupt()
        for _ in range(10):
            proc = mp.get_context("fork").Process(target=_sleep_as_child, daemon=True)
            workers._started(proc)
            os.kill(proc.pid, signal.SIGTERM)  # at once: before the child's own handlers, as often as not
            proc.join(10)
            assert proc.exitcode == -signal.SIGTERM
    finally:
        signal.signal(signal.SIGTERM, saved)
    assert signal.pthread_sigmask(signal.SIG_BLOCK, set()) == mask
