"""Studies at scale: sweeps and Monte Carlo over any scenario keys, and batches of recordings,
one task per run, on local processes or a Dask cluster.

A study varies the world (and what the installation says), never what processing is told
beyond that. Each task runs a whole chain in a temporary folder and returns one row: the grid
values, the seed, every KPI of kpis.json flattened, the wall time and a status (a failed run
is a row with its error; the study goes on). The same task function runs on every executor
(Dask's `Client.get_executor()` is a `concurrent.futures.Executor`), so the rows are the
same whichever ran them, timings aside.
"""

from __future__ import annotations

import itertools
import math
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

# Presets: document 000's sensitivity study (5.3.2) and what it left out. Each value is a set of
# overrides (a delay applies to both sensors; a rate to the LiDAR, the radar twice it).
PRESETS: dict[str, tuple[str, list[float], Any]] = {
    "delay": ("measurement delay [s]", [0.0, 0.05, 0.1, 0.2, 0.3],
              lambda v: [f"lidar.latency_s={v}", f"radar.latency_s={v}"]),
    "mru_noise": ("MRU angle noise [deg]", [0.0, 0.02, 0.05, 0.1, 0.2],
                  lambda v: [f"mru.angle_noise_deg={v}", f"mru.rate_noise_degps={1.25 * v}"]),
    "mru_bias": ("MRU roll/pitch bias [deg]", [0.0, 0.02, 0.05, 0.1, 0.2],
                 lambda v: [f"mismatch.mru_bias_deg=[{v},{-v},0]"]),
    "rate": ("LiDAR rate [Hz] (radar twice)", [1.0, 2.0, 5.0, 10.0, 20.0],
             lambda v: [f"lidar.rate_hz={v}", f"radar.rate_hz={2 * v}"]),
    "density": ("LiDAR angular resolution [deg] (radar 2x/3x)", [0.25, 0.5, 1.0, 2.0],
                lambda v: [f"lidar.res_h_deg={v}", f"lidar.res_v_deg={v}", f"radar.res_az_deg={2 * v}",
                           f"radar.res_el_deg={3 * v}"]),
    "fov": ("LiDAR field of view [deg] (horizontal, vertical a quarter)", [30.0, 60.0, 90.0, 120.0],
            lambda v: [f"lidar.fov_h_deg={v}", f"lidar.fov_v_deg={v / 4}"]),
    "false_reflectors": ("false bright patches", [0, 5, 10, 20, 40],
                         lambda v: [f"feeder.reflectors.false_bright_points={int(v)}"]),
    "clock_offset": ("unknown LiDAR clock offset [s]", [0.0, 0.005, 0.01, 0.02, 0.05],
                     lambda v: [f"mismatch.lidar_clock_offset_s={v}"]),
    # every seed a different world: its mismatch drawn (data.sim.randomize), widths x the value
    "worlds": ("randomized worlds (width of every deviation's distribution)", [1.0],
               lambda v: ["world.randomize.enabled=true", f"world.randomize.scale={v}"]),
}
TIMING_KEYS = ("apt_ms", "runtime_fraction", "wall_s", "time_ms", "filter_ms")


@dataclass(frozen=True)
class Axis:
    """One grid axis: its name and, per value, the overrides that set it."""

    name: str
    values: tuple
    overrides: tuple[tuple[str, ...], ...]
    label: str = ""


def axis_from_grid(text: str) -> Axis:
    """`KEY=V1,V2,...` (values are YAML scalars, as for --set)."""
    import yaml

    if "=" not in text:
        raise ValueError(f"--grid '{text}': expected KEY=V1,V2,...")
    key, raw = (p.strip() for p in text.split("=", 1))
    parts = [p.strip() for p in raw.split(",") if p.strip()]
    if not key or not parts:
        raise ValueError(f"--grid '{text}': expected KEY=V1,V2,... with at least one value")
    values = tuple(_number_or_yaml(p, yaml) for p in parts)
    return Axis(key, values, tuple((f"{key}={p}",) for p in parts), key)


def _number_or_yaml(text: str, yaml):
    """`1e-3` is a string to YAML 1.1 but a number to anyone writing a grid."""
    try:
        return float(text) if not text.lstrip("+-").isdigit() else int(text)
    except ValueError:
        return yaml.safe_load(text)


def axis_from_preset(name: str, values: list[float] | None = None) -> Axis:
    if name not in PRESETS:
        raise ValueError(f"unknown preset '{name}'; expected one of {', '.join(PRESETS)}")
    label, default, to_overrides = PRESETS[name]
    vals = tuple(values or default)
    return Axis(name, vals, tuple(tuple(to_overrides(v)) for v in vals), label)


def derived_seeds(base_seed: int, n: int) -> list[int]:
    """n seeds from the scenario's: the first is the scenario's own, the others drawn from a
    SeedSequence of it (deterministic, independent streams)."""
    rest = np.random.SeedSequence(base_seed).generate_state(max(n - 1, 0)) if n > 1 else []
    return [int(base_seed)] + [int(s) & 0x7FFFFFFF for s in rest]


@dataclass
class Task:
    id: str
    scenario: str
    overrides: tuple[str, ...]
    duration_s: float | None
    seed: int
    grid: dict = field(default_factory=dict)
    recording: str | None = None  # batch: process this recording instead of simulating
    processing: dict | None = None  # batch: the settings (a Processing's dump) instead of the recording's own


def sweep_tasks(scenario: str, axes: list[Axis], seeds: int, base_overrides: list[str], duration_s: float | None,
                base_seed: int) -> list[Task]:
    tasks = []
    points = list(itertools.product(*[range(len(a.values)) for a in axes])) if axes else [()]
    for point in points:
        grid = {a.name: a.values[i] for a, i in zip(axes, point)}
        over = tuple(base_overrides) + tuple(o for a, i in zip(axes, point) for o in a.overrides[i])
        for seed in derived_seeds(base_seed, seeds):
            gid = ",".join(f"{k}={v}" for k, v in grid.items())
            tasks.append(Task(f"{gid}|seed={seed}", scenario, over, duration_s, seed, grid))
    return tasks


def flatten(obj: Any, prefix: str = "") -> dict[str, Any]:
    """kpis.json as one level: `solutions.fused.mae_D_m`, lists by index (`rmse_pos_m.0`)."""
    out: dict[str, Any] = {}
    if isinstance(obj, dict):
        for k, v in obj.items():
            out.update(flatten(v, f"{prefix}.{k}" if prefix else str(k)))
    elif isinstance(obj, (list, tuple)):
        for i, v in enumerate(obj):
            out.update(flatten(v, f"{prefix}.{i}"))
    else:
        out[prefix] = obj
    return out


def run_task(task: Task) -> dict:
    """One run, in a temporary folder: simulate the scenario (or read the recording), run its
    chain, return the row. Never raises: a failure is the row's status."""
    import os

    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # workers: one BLAS thread, as the CLI
    row: dict = {"task": task.id, **task.grid, "seed": task.seed, "status": "ok", "error": ""}
    t0 = time.perf_counter()
    try:
        from boomtip.tools.chains.resources import RunResources
        from boomtip.tools.chains.runner import run_into

        if task.recording is not None:
            from boomtip.data.io.recording import Recording

            source = Recording(task.recording)
        else:
            from boomtip.tools.config.scenario import load_scenario
            from boomtip.data.sim.sources import simulation_for

            # the seed and duration first, so a grid over either (an override) wins
            extra = [f"seed={task.seed}"] + ([f"duration_s={task.duration_s}"] if task.duration_s is not None else [])
            extra += list(task.overrides)
            source = simulation_for(load_scenario(task.scenario, extra))
        processing = None
        if task.processing is not None:
            from boomtip.tools.config.processing import Processing

            processing = Processing.model_validate(task.processing)
        with tempfile.TemporaryDirectory() as tmp:
            res = run_into(source, Path(tmp), processing, report=False, resources=RunResources(lean=True))
        row.update({k: v for k, v in flatten(res.kpis).items() if k not in row})
    except Exception as exc:  # a failed run is a row; the study goes on
        row["status"] = "failed"
        row["error"] = f"{type(exc).__name__}: {exc}"
    row["wall_s"] = time.perf_counter() - t0
    return row


def is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and v is not None


def median_interval(vals: np.ndarray) -> tuple[float, float]:
    """The distribution-free 95 % confidence interval of the median: the order statistics the
    binomial(n, 1/2) puts 2.5 % beyond on each side (NaN for fewer than 6 values, where none is)."""
    from scipy.stats import binom

    n = len(vals)
    k = int(binom.ppf(0.025, n, 0.5))  # P(X < k) <= 2.5 %: x_(k) and x_(n+1-k), 1-based
    if n < 6 or k < 1:
        return float("nan"), float("nan")
    v = np.sort(vals)
    return float(v[k - 1]), float(v[n - k])


def summarise(rows: list[dict], grid_keys: list[str]) -> list[dict]:
    """Per grid point and numeric KPI: n, mean, standard deviation and the 95 % confidence
    interval of the mean (Student t); the median with its 95 % confidence interval (order
    statistics) and the runs' own spread (2.5th and 97.5th percentiles)."""
    from scipy.stats import t as student_t

    ok = [r for r in rows if r.get("status") == "ok"]
    groups: dict[tuple, list[dict]] = {}
    for r in ok:
        groups.setdefault(tuple(r.get(k) for k in grid_keys), []).append(r)
    skip = set(grid_keys) | {"task", "seed", "status", "error"}
    out = []
    for point, members in groups.items():
        keys = list(dict.fromkeys(k for m in members for k, v in m.items() if k not in skip and is_number(v)))
        for key in keys:
            vals = np.array([m[key] for m in members if is_number(m.get(key))], dtype=float)
            vals = vals[np.isfinite(vals)]
            n = len(vals)
            if n == 0:
                continue
            mean = float(vals.mean())
            std = float(vals.std(ddof=1)) if n > 1 else float("nan")
            half = float(student_t.ppf(0.975, n - 1) * std / math.sqrt(n)) if n > 1 else float("nan")
            m_lo, m_hi = median_interval(vals)
            out.append({**dict(zip(grid_keys, point)), "kpi": key, "n": n, "mean": mean, "std": std,
                        "ci95_lo": mean - half, "ci95_hi": mean + half, "median": float(np.median(vals)),
                        "median_ci95_lo": m_lo, "median_ci95_hi": m_hi,
                        "p2_5": float(np.percentile(vals, 2.5)), "p97_5": float(np.percentile(vals, 97.5))})
    return out
