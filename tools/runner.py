"""Run the relative-heave pipeline and fusion over a frame source and write the outputs.

OUT/measurements.csv   t, method, quantity, value, time_ms, status, sigma
OUT/estimates.csv      t, solution, D, D_dot, D_ddot, var_D, var_D_dot
OUT/kpis.json          measurements.<method> and solutions.<solution>, when there is truth
OUT/report.md + plots  Table 5.4 layout beside document 000 (tools/report.py)
OUT/boomtip.rrd        with --rerun (tools/visualise.py)
Everything is written into a staging folder and moved into place at the end.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from boomtip.data.frames import FrameSource
from boomtip.data.io.pcd import atomic_write_bytes
from boomtip.data.io.recording import commit_output, prepare_output, write_json
from boomtip.fusion.solutions import SOLUTIONS, Estimates, FusionConfig, run_solution
from boomtip.perception.pipeline import HeavePipeline, Measurement, PipelineConfig
from boomtip.tools.kpis import WARMUP_S, measurement_kpis, solution_kpis, truth_amplitudes

MEASUREMENT_COLUMNS = ("t", "method", "quantity", "value", "time_ms", "status", "sigma")


@dataclass
class RunResult:
    rows: list[Measurement]
    estimates: dict[str, Estimates]
    kpis: dict


def write_measurements(path: Path, rows: list[Measurement]) -> None:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(MEASUREMENT_COLUMNS)
    for r in rows:
        w.writerow([f"{r.t_s:.6f}", r.method, r.quantity, "" if not np.isfinite(r.value) else f"{r.value:.6f}",
                    f"{r.time_ms:.4f}", r.status, "" if not np.isfinite(r.sigma) else f"{r.sigma:.6g}"])
    atomic_write_bytes(path, buf.getvalue().encode())


def write_estimates(path: Path, estimates: dict[str, Estimates]) -> None:
    buf = io.StringIO()
    buf.write("t,solution,D,D_dot,D_ddot,var_D,var_D_dot\n")
    for name, e in estimates.items():
        ok = np.isfinite(e.x[:, 0])
        for t, x, v in zip(e.t_s[ok], e.x[ok], e.var[ok]):
            buf.write(f"{t:.4f},{name},{x[0]:.6f},{x[1]:.6f},{x[2]:.6f},{v[0]:.6g},{v[1]:.6g}\n")
    atomic_write_bytes(path, buf.getvalue().encode())


def run_heave(
    source: FrameSource,
    out: Path,
    force: bool = False,
    pipeline_cfg: PipelineConfig | None = None,
    fusion_cfg: FusionConfig | None = None,
    rerun: bool = False,
    report: bool = True,
    inputs: tuple[Path, ...] = (),
    progress: Callable[[int], None] | None = None,
) -> RunResult:
    staging = prepare_output(out, force, inputs)
    try:
        result = run_into(source, staging, pipeline_cfg, fusion_cfg or FusionConfig(), rerun, report, progress)
    except BaseException:
        import shutil

        shutil.rmtree(staging, ignore_errors=True)
        raise
    commit_output(staging, out)
    return result


def run_into(source, staging: Path, pipeline_cfg, fusion_cfg: FusionConfig, rerun: bool, report: bool, progress) -> RunResult:
    s = source.meta.scenario
    if s.hook.enabled:
        from boomtip.tools.hook_runner import run_hook_into

        hook = run_hook_into(source, staging, progress=progress, rerun=rerun)
        kpis = {"scenario": s.name, "seed": s.seed, "duration_s": s.duration_s, "hook": hook}
        write_json(staging / "kpis.json", kpis)
        return RunResult([], {}, kpis)
    pipeline = HeavePipeline(source.meta, source.mru, pipeline_cfg)
    logger = None
    if rerun:
        from boomtip.tools.visualise import RerunLogger

        logger = RerunLogger(staging / "boomtip.rrd", source)
    rows: list[Measurement] = []
    for frame in source:
        res = pipeline.process(frame)
        rows.extend(res.measurements)
        if logger:
            logger.log_frame(res)
        if progress:
            progress(1)
    write_measurements(staging / "measurements.csv", rows)
    duration = max((r.t_s for r in rows), default=0.0)
    estimates = {name: run_solution(name, rows, s, fusion_cfg, duration) for name in fusion_cfg.solutions}
    write_estimates(staging / "estimates.csv", estimates)
    kpis: dict = {"scenario": s.name, "seed": s.seed, "duration_s": duration, "measurements": measurement_kpis(rows, source.truth)}
    if source.truth is not None:
        kpis["solutions"] = {n: solution_kpis(e, source.truth, rows, SOLUTIONS[n]) for n, e in estimates.items()}
        kpis["solutions_note"] = f"solution errors exclude the first {WARMUP_S:g} s (filter convergence)"
        kpis["truth_max_amplitude"] = truth_amplitudes(source.truth)
    write_json(staging / "kpis.json", kpis)
    if source.truth is not None:
        if report:
            from boomtip.tools.report import write_report

            write_report(staging, kpis, estimates, source.truth, rows)
    if logger:
        logger.log_estimates(estimates, source.truth)
        logger.close()
    return RunResult(rows, estimates, kpis)
