"""The `boomtip` command line: a thin layer over data/, perception/, fusion/ and tools/."""

from __future__ import annotations

import sys
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator, Optional

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

from boomtip.data.io.pcd import PcdError
from boomtip.data.io.recording import RecordingError
from boomtip.tools.runner import ChainError
from boomtip.data.scenario import ScenarioError, available_scenarios, load_scenario, scenario_to_yaml, valid_keys

app = typer.Typer(add_completion=False, no_args_is_help=True, help="Point-cloud perception for offshore cranes.")
bench_app = typer.Typer(no_args_is_help=True, help="Benchmarks: each prints a ratio against a baseline measured in the same run.")
app.add_typer(bench_app, name="bench")
console = Console(stderr=True, soft_wrap=True)

ScenarioOpt = typer.Option(..., "--scenario", "-s", help="Built-in scenario name or a YAML file.")
SetOpt = typer.Option(None, "--set", help="Override a scenario key: dotted.key=value (repeatable).")


@contextmanager
def user_errors() -> Iterator[None]:
    """Turn expected user-input errors into one clear message and exit code 2."""
    try:
        yield
    except (ScenarioError, RecordingError, PcdError, ChainError, FileNotFoundError) as exc:
        console.print(f"[bold red]error:[/] {exc}", highlight=False)
        raise typer.Exit(2) from None


@contextmanager
def progress_bar(total: int, label: str) -> Iterator:
    quiet = not sys.stderr.isatty()
    with Progress(
        TextColumn(label), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(), console=console, disable=quiet
    ) as prog:
        task = prog.add_task(label, total=total)
        yield lambda n=1: prog.advance(task, n)


def resolve_scenario(scenario: str, overrides: list[str] | None, duration: float | None = None, seed: int | None = None):
    extra = list(overrides or [])
    if duration is not None:
        extra.append(f"duration_s={duration}")
    if seed is not None:
        extra.append(f"seed={seed}")
    return load_scenario(scenario, extra)


@app.command()
def scenarios(
    show: Optional[str] = typer.Option(None, "--show", help="Print one scenario, fully resolved, as YAML."),
    keys: bool = typer.Option(False, "--keys", help="List every valid dotted scenario key."),
) -> None:
    """List the built-in scenarios (or show one)."""
    with user_errors():
        if keys:
            print("\n".join(valid_keys()))
            return
        if show:
            print(scenario_to_yaml(load_scenario(show)), end="")
            return
        for name, path in available_scenarios().items():
            s = load_scenario(path)
            print(f"{name:16s} {s.duration_s:6.0f} s  {s.description}")


@app.command()
def simulate(
    scenario: str = ScenarioOpt,
    out: Path = typer.Option(..., "--out", "-o", help="Recording folder to write."),
    duration: Optional[float] = typer.Option(None, "--duration", help="Seconds to simulate (overrides duration_s)."),
    seed: Optional[int] = typer.Option(None, "--seed", help="Random seed (overrides seed)."),
    set_: Optional[list[str]] = SetOpt,
    force: bool = typer.Option(False, "--force", help="Replace a non-empty --out."),
) -> None:
    """Simulate a scenario and write a recording (PCD frames, MRU log, ground truth)."""
    from boomtip.data.io.recording import write_recording
    from boomtip.data.sources import simulation_for

    with user_errors():
        s = resolve_scenario(scenario, set_, duration, seed)
        t0 = time.perf_counter()
        sim = simulation_for(s)
        with progress_bar(len(sim), "simulating") as advance:
            meta = write_recording(sim, out, force=force, progress=advance)
        wall = time.perf_counter() - t0
    frames = meta["frames"]
    console.print(
        f"wrote {out}: {frames['lidar']} LiDAR + {frames['radar']} radar frames, {s.duration_s:g} s simulated "
        f"in {wall:.1f} s ({s.duration_s / wall:.1f}x real time)"
    )


def _print_kpis(kpis: dict) -> None:
    from boomtip.tools.report import kpi_table, measurement_table

    print(f"\n{kpis['scenario']} (seed {kpis['seed']}, {kpis['duration_s']:.0f} s)\n")
    if "hook" in kpis:
        h = kpis["hook"]
        seg = h["segmentation"]
        print(f"hook segmentation: model fit in {100 * seg['found_fraction']:.1f} % and sparse fix in "
              f"{100 * seg.get('sparse_fraction', 0.0):.1f} % of {seg['frames']} frames, "
              f"precision {seg.get('precision', float('nan')):.4f}, recall {seg.get('recall', float('nan')):.4f}, "
              f"{seg['apt_ms']:.1f} ms/frame")
        if "rope" in h:
            from boomtip.tools.hook_outputs import rope_summary

            print(rope_summary(h["rope"]))
        print(f"{'estimator':14s} {'RMSE pos x/y/z [cm]':>24s} {'RMSE vel x/y/z [cm/s]':>24s} {'runtime':>9s} {'NEES (3)':>9s}"
              f" {'rel. tip pos [cm]':>20s}")
        for name, k in h.items():
            if isinstance(k, dict) and "rmse_pos_m" in k:
                f = lambda v: "/".join(f"{100 * x:.2f}" for x in v)  # noqa: E731
                print(f"{name:14s} {f(k['rmse_pos_m']):>24s} {f(k['rmse_vel_mps']):>24s} {100 * k['runtime_fraction']:8.2f}% "
                      f"{k.get('nees_pos_mean', float('nan')):9.2f} {f(k.get('rmse_rel_pos_m', [float('nan')] * 3)):>20s}")
        return
    print("Raw measurements (before any filter):")
    print(measurement_table(kpis))
    if "solutions" in kpis:
        print("\nSolutions after the Kalman filter (" + kpis["solutions_note"] + "), document 000's Table 5.4 beside ours:")
        print(kpi_table(kpis))


def _run_and_report(source, out: Path, force: bool, rerun: bool, inputs=()) -> None:
    from boomtip.tools.runner import run

    with progress_bar(len(source), "processing") as advance:
        result = run(source, out, force=force, rerun=rerun, inputs=inputs, progress=advance)
    _print_kpis(result.kpis)
    console.print(f"\nwrote {out}: " + ", ".join(result.written))


@app.command()
def run(
    scenario: str = ScenarioOpt,
    out: Path = typer.Option(..., "--out", "-o", help="Output folder."),
    duration: Optional[float] = typer.Option(None, "--duration", help="Seconds to simulate (overrides duration_s)."),
    seed: Optional[int] = typer.Option(None, "--seed", help="Random seed (overrides seed)."),
    set_: Optional[list[str]] = SetOpt,
    rerun: bool = typer.Option(False, "--rerun", help="Also write a rerun-sdk recording OUT/boomtip.rrd."),
    force: bool = typer.Option(False, "--force", help="Replace a non-empty --out."),
) -> None:
    """Simulate a scenario in memory and run perception + fusion on it (no recording on disk)."""
    from boomtip.data.sources import simulation_for

    with user_errors():
        s = resolve_scenario(scenario, set_, duration, seed)
        _run_and_report(simulation_for(s), out, force, rerun)


@app.command()
def process(
    recording: Path = typer.Argument(..., help="Recording folder written by `boomtip simulate` (or the same layout)."),
    out: Path = typer.Option(..., "--out", "-o", help="Output folder."),
    rerun: bool = typer.Option(False, "--rerun", help="Also write a rerun-sdk recording OUT/boomtip.rrd."),
    force: bool = typer.Option(False, "--force", help="Replace a non-empty --out."),
) -> None:
    """Run perception + fusion on a recording."""
    from boomtip.data.io.recording import Recording

    with user_errors():
        _run_and_report(Recording(recording), out, force, rerun, inputs=(recording,))


@app.command()
def view(
    out: Path = typer.Argument(..., help="An output folder of `boomtip run --rerun` or `boomtip process --rerun`."),
    spawn: bool = typer.Option(False, "--spawn", help="Open the rerun viewer on it (needs a display)."),
) -> None:
    """Show where a run's rerun recording is, or open it in the rerun viewer."""
    rrd = out / "boomtip.rrd"
    if not rrd.is_file():
        console.print(f"[bold red]error:[/] {rrd} not found; run `boomtip run ... --rerun` or `boomtip process ... --rerun` first")
        raise typer.Exit(2)
    if spawn:
        import subprocess

        raise typer.Exit(subprocess.call([sys.executable, "-m", "rerun", str(rrd)]))
    print(f"{rrd} ({rrd.stat().st_size / 1e6:.1f} MB): open it with `rerun {rrd}` or `boomtip view {out} --spawn`")


@app.command()
def sweep(
    param: str = typer.Argument(..., help="delay | mru_noise | rate | density | false_reflectors"),
    scenario: str = typer.Option("sts-loaded", "--scenario", "-s"),
    values: Optional[str] = typer.Option(None, "--values", help="Comma-separated grid (default: the parameter's own grid)."),
    duration: float = typer.Option(30.0, "--duration", help="Seconds per run."),
    jobs: int = typer.Option(2, "--jobs", "-j", help="Parallel processes."),
    set_: Optional[list[str]] = SetOpt,
    out: Path = typer.Option(..., "--out", "-o"),
    force: bool = typer.Option(False, "--force"),
) -> None:
    """Sensitivity study: KPIs over a grid of one parameter (document 000, 5.3.2)."""
    from boomtip.tools.sweep import PARAMS, run_sweep

    with user_errors():
        if param not in PARAMS:
            raise ScenarioError(f"unknown sweep parameter '{param}'; expected one of {', '.join(PARAMS)}")
        try:
            grid = [float(v) for v in values.split(",")] if values else None
        except ValueError:
            raise ScenarioError(f"--values '{values}': expected comma-separated numbers") from None
        load_scenario(scenario, list(set_ or []))  # refuse a bad scenario or key before spawning
        n = len(grid or PARAMS[param][1])
        with progress_bar(n, f"sweep {param}") as advance:
            summary = run_sweep(scenario, param, grid, duration, out, jobs, force, list(set_ or []), advance)
    print(f"{'value':>8s} " + " ".join(f"{n + ' D/Ddot':>26s}" for n in summary["runs"][0]["kpis"]["solutions"]))
    for r in summary["runs"]:
        cells = [f"{1e3 * k['mae_D_m']:9.2f} mm {1e3 * k['mae_D_dot_mps']:7.2f} mm/s" for k in r["kpis"]["solutions"].values()]
        print(f"{r['value']:8g} " + " ".join(f"{c:>26s}" for c in cells))
    console.print(f"wrote {out}/sweep.json and {out}/sweep_{param}.png")


def write_bench_json(path: Optional[Path], result: dict, force: bool) -> None:
    if path is None:
        return
    from boomtip.data.io.recording import RecordingError, write_json

    if path.exists() and not force:
        raise RecordingError(f"--json {path} exists; pass --force to replace it")
    path.parent.mkdir(parents=True, exist_ok=True)
    write_json(path, result)


JsonOpt = typer.Option(None, "--json", help="Also write the figures (ratio, times, accuracies) to this JSON file.")
ForceOpt = typer.Option(False, "--force", help="Replace an existing --json file.")


@bench_app.command("raycast")
def bench_raycast_cmd(
    scenario: str = typer.Option("sts-loaded", "--scenario", "-s"),
    frames: int = typer.Option(20, "--frames", min=1),
    simulate_s: float = typer.Option(60.0, "--simulate-s", help="Also time `simulate` over this many seconds (0: skip)."),
    set_: Optional[list[str]] = SetOpt,
    json_path: Optional[Path] = JsonOpt,
    force: bool = ForceOpt,
) -> None:
    """LiDAR frames/s vs the trimesh route on the same frames; simulate vs real time."""
    from boomtip.tools.bench import bench_raycast

    with user_errors():
        s = resolve_scenario(scenario, set_)
        r = bench_raycast(s, frames=frames, simulate_s=simulate_s)
        write_bench_json(json_path, r, force)
    print(f"raycast  {r['triangles']} triangles, {r['rays_per_frame']} rays/frame, {r['points_per_frame']:.0f} points/frame, {frames} frames")
    print(f"  boomtip (Open3D scenes, rays moved per body): {r['boomtip_fps']:8.1f} frames/s")
    print(f"  baseline (posed trimesh + embreex per frame): {r['baseline_fps']:8.1f} frames/s")
    print(f"  ratio {r['ratio']:.1f}x   hit agreement {100 * r['hit_agreement']:.2f} %")
    if "simulate_realtime_factor" in r:
        print(f"simulate {r['simulate_duration_s']:g} s of {s.name} in {r['simulate_wall_s']:.1f} s: "
              f"{r['simulate_realtime_factor']:.1f}x real time")


@bench_app.command("perception")
def bench_perception_cmd(
    scenario: str = typer.Option("sts-loaded", "--scenario", "-s"),
    frames: int = typer.Option(30, "--frames", min=1),
    set_: Optional[list[str]] = SetOpt,
    json_path: Optional[Path] = JsonOpt,
    force: bool = ForceOpt,
) -> None:
    """Deck detection and its stages vs Open3D's own calls on the same frames; every method's APT and MAE."""
    from boomtip.tools.bench import bench_perception

    with user_errors():
        s = resolve_scenario(scenario, set_)
        r = bench_perception(s, frames=frames)
        write_bench_json(json_path, r, force)
    print(f"perception  {s.name}, {frames} LiDAR frames, {r['points_per_frame']:.0f} points/frame")
    print(f"  baseline: {r['baseline']}")
    print(f"  {'stage':28s} {'boomtip ms':>11s} {'Open3D ms':>10s} {'ratio':>7s}")
    for label, key in (("preprocess (same operations)", "preprocess"), ("plane search (same points)", "plane_search"),
                       ("deck detection end to end", "deck_detection")):
        ms = r[f"{key}_ms"]
        print(f"  {label:28s} {ms['boomtip']:11.2f} {ms['open3d']:10.2f} {ms['open3d'] / ms['boomtip']:6.1f}x")
    print(f"  deck D MAE: boomtip {1e3 * r['deck_mae_m']['boomtip']:.2f} mm (max {1e3 * r['deck_max_m']['boomtip']:.2f}), "
          f"Open3D {1e3 * r['deck_mae_m']['open3d']:.2f} mm (max {1e3 * r['deck_max_m']['open3d']:.2f})")
    print(f"  ratio {r['ratio']:.1f}x")
    print("  every method, as the pipeline times it:")
    for m, k in r["methods"].items():
        unit = "mm/s" if m.startswith("doppler") else "mm"
        print(f"    {m:20s} APT {k['apt_ms']:6.2f} ms   MAE {1e3 * k['mae']:6.2f} {unit}   valid {100 * k['valid_fraction']:.0f} %")


@bench_app.command("fusion")
def bench_fusion_cmd(
    program: str = typer.Option("hook-2", "--program", help="hook-1 .. hook-4 (document 002, 5.2)"),
    duration: float = typer.Option(60.0, "--duration"),
    json_path: Optional[Path] = JsonOpt,
    force: bool = ForceOpt,
) -> None:
    """Hook EKF (flexible) runtime vs the same filter with numerically differenced Jacobians."""
    from boomtip.tools.bench import bench_fusion

    with user_errors():
        if program not in ("hook-1", "hook-2", "hook-3", "hook-4"):
            raise ScenarioError(f"--program '{program}': expected hook-1, hook-2, hook-3 or hook-4")
        r = bench_fusion(program, duration)
        write_bench_json(json_path, r, force)
    print(f"fusion  EKF flexible on {program}, {duration:g} s, LiDAR = truth + 1.5 cm noise (document 002's measurement)")
    names = {"analytic": "exact Jacobian", "numeric": "numeric Jacobian", "analytic_rope": "exact, + rope 0.1 mrad"}
    for label, name in names.items():
        k = r[label]
        f = lambda v: "/".join(f"{100 * x:.2f}" for x in v)  # noqa: E731
        print(f"  {name:22s}: {k['runtime_s']:6.2f} s = {100 * k['runtime_fraction']:5.2f} % of real time, "
              f"RMSE pos {f(k['rmse_pos_m'])} cm, vel {f(k['rmse_vel_mps'])} cm/s")
    print(f"  ratio numeric / exact {r['ratio']:.2f}x")


def main() -> None:  # pragma: no cover - console entry point
    app()


if __name__ == "__main__":  # pragma: no cover
    app()
