"""`boomtip bench sweep`: what a study's executor costs. Per-task overhead (the sweep's wall time
beyond its tasks' own, per task, one worker) on local processes and on Dask, and the speed-up
of two workers over one on the same 16 tasks, all measured in one run."""

from __future__ import annotations

import time

from boomtip.tools.study.tasks import axis_from_grid, sweep_tasks, run_task
from boomtip.tools.study.executor import make_executor


def timed_map(tasks, kind: str, workers: int) -> tuple[float, float]:
    """Wall time of the tasks on a warm executor (workers started and modules imported by one
    warm-up task each) and the sum of the tasks' own times."""
    with make_executor(kind, workers) as pool:
        list(pool.map(run_task, tasks[:workers]))  # warm-up: start and import in every worker
        t0 = time.perf_counter()
        rows = list(pool.map(run_task, tasks))
        wall = time.perf_counter() - t0
    if any(r["status"] != "ok" for r in rows):
        raise RuntimeError(f"bench tasks failed: {[r['error'] for r in rows if r['status'] != 'ok'][:2]}")
    return wall, sum(r["wall_s"] for r in rows)


def bench_sweep(scenario: str = "sts-empty", tasks: int = 16, duration_s: float = 1.0) -> dict:
    grid = axis_from_grid("lidar.rate_hz=" + ",".join(str(5 + i % 4) for i in range(4)))
    todo = sweep_tasks(scenario, [grid], max(1, -(-tasks // 4)), [], duration_s, 1)[:tasks]  # seeds per rate, rounded up
    out: dict = {"scenario": scenario, "tasks": len(todo), "task_duration_s": duration_s}
    baseline_own = None
    for kind in ("local", "dask"):
        wall, own = timed_map(todo, kind, 1)
        # the same tasks' own time in a plain local worker is the baseline for both: a Dask
        # worker's threads also slow the task itself, which is part of what Dask costs
        baseline_own = own if baseline_own is None else baseline_own
        out[kind] = {"wall_s": wall, "tasks_own_s": own, "overhead_per_task_s": max(wall - baseline_own, 0.0) / len(todo)}
    wall2, _ = timed_map(todo, "local", 2)
    out["two_workers_wall_s"] = wall2
    out["ratio"] = wall2 / out["local"]["wall_s"]  # two workers' time over one worker's
    return out
