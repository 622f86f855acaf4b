"""`boomtip bench batch`: how `boomtip batch` scales with its workers. The same recordings (made
once, not timed) processed as batch tasks on one worker and on two, on Dask's LocalCluster and on
the local process pool, each on a warm executor (workers started and modules imported by a
warm-up task each), all in one run. Speed-up = one worker's wall time over two workers'."""

from __future__ import annotations

import tempfile
from pathlib import Path

from boomtip.tools.bench.sweep import timed_map

__all__ = ["bench_batch"]


def _recordings(scenario: str, n: int, duration_s: float, folder: Path) -> list[Path]:
    from boomtip.data.io.recording import write_recording
    from boomtip.data.sim.sources import simulation_for
    from boomtip.tools.config.scenario import load_scenario

    paths = []
    for k in range(n):  # a different world each: seeds differ
        sim = simulation_for(load_scenario(scenario, [f"duration_s={duration_s}", f"seed={k + 1}"]))
        paths.append(folder / f"rec{k}")
        write_recording(sim, paths[-1])
    return paths


def bench_batch(scenario: str = "sts-loaded", recordings: int = 6, duration_s: float = 6.0) -> dict:
    from boomtip.tools.study.tasks import Task

    out: dict = {"scenario": scenario, "recordings": recordings, "recording_s": duration_s}
    with tempfile.TemporaryDirectory(prefix="boomtip-bench-batch-") as tmp:
        paths = _recordings(scenario, recordings, duration_s, Path(tmp))
        tasks = [Task(f"{i}:{p}", "", (), None, 0, {"recording": str(p)}, recording=str(p)) for i, p in enumerate(paths)]
        for kind in ("dask", "local"):
            one, own_one = timed_map(tasks, kind, 1)
            two, own_two = timed_map(tasks, kind, 2)
            # the tasks' own times: longer on two workers when they share what a core does not own (memory, cache)
            out[kind] = {"one_worker_wall_s": round(one, 3), "two_workers_wall_s": round(two, 3),
                         "tasks_own_s": {"one_worker": round(own_one, 3), "two_workers": round(own_two, 3)},
                         "speedup": round(one / two, 3)}
    out["ratio"] = out["dask"]["speedup"]
    out["ratio_note"] = "Dask, two workers' speed-up over one (2 is every core used to the full)"
    return out
