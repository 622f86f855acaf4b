"""What `boomtip bench sweep` computes (tools/bench/sweep.py), with the executors, the tasks and the
clock replaced by stand-ins whose times are given: 16 tasks over four LiDAR rates, one warm-up task
per worker outside the timing, the per-task overhead against the tasks' own time in a plain local
worker (for Dask too), never negative, and the two-worker ratio; a failed task fails the bench."""

from __future__ import annotations

import types
from contextlib import contextmanager

import pytest

from boomtip.tools.bench import sweep
from boomtip.tools.study.tasks import derived_seeds

OWN_S = {"local": 0.5, "dask": 0.75}  # a task's own time: a Dask worker's threads slow it too


class FakePool:
    def __init__(self, kind: str, workers: int, log: list) -> None:
        self.kind, self.workers, self.log = kind, workers, log

    def map(self, fn, tasks):
        tasks = list(tasks)
        self.log.append((self.kind, self.workers, [t.id for t in tasks]))
        return [{**fn(t), "wall_s": OWN_S[self.kind]} for t in tasks]


def fake_run_task(task):
    return {"task": task.id, "status": "ok", "error": "", "wall_s": 0.0}


def install(monkeypatch, walls: list[float], run_task=fake_run_task) -> list:
    """The three timed runs (local x1, dask x1, local x2) take `walls` seconds."""
    log: list = []

    @contextmanager
    def make_executor(kind, workers):
        yield FakePool(kind, workers, log)

    ticks = []
    for i, w in enumerate(walls):
        ticks += [100.0 * i, 100.0 * i + w]
    monkeypatch.setattr(sweep, "make_executor", make_executor)
    monkeypatch.setattr(sweep, "run_task", run_task)
    monkeypatch.setattr(sweep, "time", types.SimpleNamespace(perf_counter=iter(ticks).__next__))
    return log


def test_the_bench_times_sixteen_tasks_after_a_warm_up(monkeypatch):
    log = install(monkeypatch, [10.0, 13.0, 6.0])
    out = sweep.bench_sweep()
    ids = [f"lidar.rate_hz={r}|seed={s}" for r in (5, 6, 7, 8) for s in derived_seeds(1, 4)]
    assert [(k, w, len(t)) for k, w, t in log] == [("local", 1, 1), ("local", 1, 16), ("dask", 1, 1), ("dask", 1, 16),
                                                   ("local", 2, 2), ("local", 2, 16)]
    assert log[1][2] == ids and log[0][2] == ids[:1] and log[4][2] == ids[:2]  # warm-up: the first task per worker
    assert (out["scenario"], out["tasks"], out["task_duration_s"]) == ("sts-empty", 16, 1.0)
    # own time 16 x 0.5 s = 8 s in a local worker; Dask's overhead is counted against that too
    assert out["local"] == {"wall_s": 10.0, "tasks_own_s": 8.0, "overhead_per_task_s": 2.0 / 16}
    assert out["dask"] == {"wall_s": 13.0, "tasks_own_s": 12.0, "overhead_per_task_s": 5.0 / 16}
    assert out["two_workers_wall_s"] == 6.0 and out["ratio"] == 0.6


def test_an_overhead_is_never_negative(monkeypatch):
    install(monkeypatch, [7.0, 13.0, 6.0])  # faster than its tasks' own time: no overhead, not a gain
    assert sweep.bench_sweep()["local"]["overhead_per_task_s"] == 0.0


def test_two_tasks_are_the_first_two_rates(monkeypatch):
    log = install(monkeypatch, [1.0, 1.0, 1.0])
    out = sweep.bench_sweep(tasks=2, duration_s=0.5)
    assert out["tasks"] == 2 and out["task_duration_s"] == 0.5
    assert log[1][2] == [f"lidar.rate_hz={r}|seed=1" for r in (5, 6)]


def test_the_bench_runs_as_many_tasks_as_asked(monkeypatch):
    install(monkeypatch, [1.0, 1.0, 1.0])
    assert sweep.bench_sweep(tasks=6)["tasks"] == 6


def test_a_failed_task_fails_the_bench(monkeypatch):
    def failing(task):
        bad = task.id.startswith("lidar.rate_hz=7")
        return {"task": task.id, "status": "failed" if bad else "ok", "error": "ValueError: no deck" if bad else ""}

    install(monkeypatch, [1.0, 1.0, 1.0], failing)
    with pytest.raises(RuntimeError, match=r"bench tasks failed: \['ValueError: no deck', 'ValueError: no deck'\]"):
        sweep.bench_sweep()
