"""Running a study: the executor (local processes or Dask), `runs.csv` kept up to date after
every finished task (so `--resume` picks up after a crash), then `summary.csv`, the plots and
`sweep.json`."""

from __future__ import annotations

import csv
import io
import shutil
from concurrent.futures import Executor, ProcessPoolExecutor, as_completed
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator

from boomtip.data.io.atomic import atomic_write_bytes
import json

from boomtip.data.io.recording import RecordingError, check_output_folder, write_json
from boomtip.tools.study.tasks import TIMING_KEYS, Task, run_task, summarise
from boomtip.tools.study.worker_env import study_worker
from boomtip.tools.report.plots import legend

FIRST_COLUMNS = ("task", "seed", "status", "error", "wall_s")
# A local cluster's own upkeep, kept off the tasks' cores: no statistical profiler (its stack
# sampling every 10 ms takes the GIL from the task: a third longer per task with two workers on
# two cores), and the memory and system monitors every few seconds instead of 10 times a second
QUIET_DASK = {"distributed.worker.profile.enabled": False, "distributed.worker.memory.monitor-interval": "2s",
              "distributed.admin.system-monitor.interval": "5s"}


def check_executor(kind: str) -> None:
    if kind not in ("local", "dask"):
        raise RecordingError(f"--executor '{kind}': expected local or dask")


@contextmanager
def make_executor(kind: str = "local", workers: int | None = None, scheduler: str | None = None) -> Iterator[Executor]:
    """`local`: a pool of worker processes (spawned: Open3D's and OpenMP's threads do not survive
    a fork). `dask`: the cluster at `scheduler`, or a LocalCluster of `workers` processes with
    one thread each. The task code is the same: both are concurrent.futures executors. Each
    worker runs one task at a time on one core: its OpenMP and BLAS threads are pinned to one
    (Dask's nanny does it by default), or the workers of a pool with a worker per core would
    fight for the cores. A local worker ends with its parent, even one that is killed."""
    import os

    n = max(1, workers or os.cpu_count() or 1)
    check_executor(kind)
    if kind == "local":
        import multiprocessing

        with ProcessPoolExecutor(max_workers=n, mp_context=multiprocessing.get_context("spawn"),
                                 initializer=study_worker) as pool:
            yield pool
    elif kind == "dask":
        import dask
        from distributed import Client, LocalCluster

        # pure=False: every task runs. Dask's default takes equal calls for one and hands back a
        # result still held (a re-run task, a warm-up's) without running it, with its old timings
        if scheduler:
            with Client(scheduler) as client:
                yield client.get_executor(pure=False)
        else:
            with dask.config.set(QUIET_DASK), \
                    LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
                    Client(cluster) as client:
                yield client.get_executor(pure=False)
    else:
        raise ValueError(f"--executor '{kind}': expected local or dask")


def prepare_study_dir(out: Path, force: bool, resume: bool, study: dict, inputs: tuple[Path, ...] = ()) -> list[dict]:
    """The rows already finished (with --resume, of the same study only); refuses to touch a
    non-empty folder otherwise, unless --force, and never a folder that holds the current one,
    the home folder or an input."""
    check_output_folder(out, inputs)
    if out.exists() and any(out.iterdir()):
        if resume:
            try:
                before = json.loads((out / "study.json").read_text())
            except (OSError, ValueError):
                raise RecordingError(f"{out}: not a study folder (no readable study.json); nothing to resume") from None
            if before != study:
                changed = sorted(k for k in set(before) | set(study) if before.get(k) != study.get(k))
                raise RecordingError(f"{out}: --resume with a different study ({', '.join(changed)} changed); "
                                     "use another --out or --force")
            return [r for r in read_rows(out / "runs.csv") if r.get("status") == "ok"]
        if not force:
            raise RecordingError(f"{out} is not empty; pass --resume to finish its study or --force to replace it")
        (out / "study.json").unlink(missing_ok=True)  # first: a folder half deleted is no study to resume
        shutil.rmtree(out)
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "study.json", study)
    return []


def read_rows(path: Path) -> list[dict]:
    if not path.is_file():
        return []
    with open(path, newline="") as fh:
        return [{k: _parse(v) for k, v in r.items()} for r in csv.DictReader(fh)]


def _parse(v: str):
    if v in ("", None):
        return v
    if v in ("True", "False"):  # a grid over a boolean key: written by repr, read back as a bool
        return v == "True"
    try:
        return int(v) if v.lstrip("-").isdigit() else float(v)
    except ValueError:
        return v


def write_rows(path: Path, rows: list[dict], grid_keys: list[str]) -> None:
    """Rows in task order, every column any row has; floats as repr (exact round trip)."""
    cols = [c for c in ("task", *grid_keys, "seed", "status", "error", "wall_s")]
    extra = sorted({k for r in rows for k in r} - set(cols))
    cols += extra
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cols)
    for r in rows:
        w.writerow(["" if r.get(c) is None else repr(r[c]) if isinstance(r.get(c), float) else r.get(c, "") for c in cols])
    atomic_write_bytes(path, buf.getvalue().encode())


def run_study(tasks: list[Task], out: Path, grid_keys: list[str], executor: Executor, done: list[dict],
              progress: Callable[[int], None] | None = None) -> list[dict]:
    """Submit every task not done yet; rewrite runs.csv as each finishes."""
    order = {t.id: i for i, t in enumerate(tasks)}
    rows = {r["task"]: r for r in done if r.get("task") in order}
    todo = [t for t in tasks if t.id not in rows]
    if progress and rows:
        progress(len(rows))
    futures = [executor.submit(run_task, t) for t in todo]
    for fut in as_completed(futures):
        row = fut.result()
        rows[row["task"]] = row
        write_rows(out / "runs.csv", sorted(rows.values(), key=lambda r: order[r["task"]]), grid_keys)
        if progress:
            progress(1)
    ordered = sorted(rows.values(), key=lambda r: order[r["task"]])
    write_rows(out / "runs.csv", ordered, grid_keys)
    return ordered


def write_summary(out: Path, rows: list[dict], grid_keys: list[str]) -> list[dict]:
    summary = summarise(rows, grid_keys)
    buf = io.StringIO()
    cols = [*grid_keys, "kpi", "n", "mean", "std", "ci95_lo", "ci95_hi", "median", "median_ci95_lo", "median_ci95_hi",
            "p2_5", "p97_5"]
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cols)
    for r in summary:
        w.writerow([repr(r[c]) if isinstance(r[c], float) else r[c] for c in cols])
    atomic_write_bytes(out / "summary.csv", buf.getvalue().encode())
    return summary


def write_sweep_json(out: Path, command: list[str], scenario: dict | None, tasks: list[Task], rows: list[dict]) -> None:
    write_json(out / "sweep.json", {
        "command": command, "scenario": scenario, "tasks": len(tasks),
        "ok": sum(r.get("status") == "ok" for r in rows), "failed": [r["task"] for r in rows if r.get("status") != "ok"],
        "timing_columns": list(TIMING_KEYS),
    })


def plot_kpis(out: Path, summary: list[dict], grid_keys: list[str], kpis: list[str], labels: dict[str, str]) -> list[Path]:
    """Each chosen KPI against each grid key, the mean with its 95 % band (other keys pooled)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from boomtip.tools.study.tasks import is_number

    paths = []
    for key in grid_keys:
        xs = sorted({r[key] for r in summary if is_number(r[key])})
        if len(xs) < 2:
            continue
        fig, ax = plt.subplots(figsize=(7, 4.5))
        drawn = 0
        for kpi in kpis:
            sel = [r for r in summary if r["kpi"] == kpi]
            if not sel:
                continue
            m = np.array([np.mean([r["mean"] for r in sel if r[key] == x]) for x in xs])
            lo = np.array([np.mean([r["ci95_lo"] for r in sel if r[key] == x]) for x in xs])
            hi = np.array([np.mean([r["ci95_hi"] for r in sel if r[key] == x]) for x in xs])
            line, = ax.plot(xs, m, "o-", label=kpi)
            drawn += 1
            if np.all(np.isfinite(lo)):
                ax.fill_between(xs, lo, hi, color=line.get_color(), alpha=0.2)
        ax.set_xlabel(labels.get(key, key))
        ax.set_ylabel("KPI (SI units)")
        ax.grid(alpha=0.3)
        if drawn:
            legend(ax, fontsize=8)
        ax.set_title("mean and 95 % confidence interval over seeds")
        fig.tight_layout()
        path = out / f"sweep_{key.replace('.', '_')}.png"
        fig.savefig(path, dpi=90)
        plt.close(fig)
        paths.append(path)
    return paths

