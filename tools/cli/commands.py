"""The `boomtip` command line: a thin layer over data/, perception/, fusion/ and tools/.

The heavy libraries (numpy, scipy, Open3D, the scenario models) load inside the commands that
use them: `boomtip --help` and `boomtip scenarios` start at once."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Optional

import typer
from rich.markup import escape

from boomtip.tools.cli.bench import bench_app
from boomtip.tools.cli.summary import print_kpis
from boomtip.tools.cli.common import (INTERRUPTED_STUDY, INTERRUPTED_STUDY_UNSTARTED, ScenarioOpt, SetOpt, console,
                                       progress_bar, resolve_scenario, scenario_inputs, terminate_like_interrupt,
                                       user_errors)

app = typer.Typer(add_completion=False, no_args_is_help=True, help="Point-cloud perception for offshore cranes.")
app.add_typer(bench_app, name="bench")


ProcessingSetOpt = typer.Option(None, "--set", help="A processing setting: processing.KEY=VALUE (repeatable; the "
                                 "section may be left out where the key is only processing's).")
ProcessingFileOpt = typer.Option(None, "--processing", help="Processing settings from a YAML file (or a run's "
                                 "settings.json); --set comes on top.")
LeanOpt = typer.Option(True, "--lean/--plain", help="lean (default): a long run's memory flat in its length (per-run "
                       "tables on disk, freed heap returned to the system); plain: everything in this process's memory. "
                       "The outputs are the same.")
RunWorkersOpt = typer.Option(None, "--workers", "-j", help="Processes the run uses (default: the cores): with 2 or more, "
                             "each frame's perception (or a hook run's simulation and estimators) goes ahead in a second "
                             "process while this one fuses; the chains have no third share yet. 1: everything in this "
                             "process. The outputs are the same.")


def _version(value: bool) -> None:
    if value:
        from boomtip.tools.config.settings import boomtip_commit, boomtip_version

        commit = boomtip_commit()
        print(f"boomtip {boomtip_version()}" + (f" ({commit})" if commit else ""))
        raise typer.Exit()


@app.callback()
def _main(
    _show_version: bool = typer.Option(False, "--version", callback=_version, is_eager=True, help="Print the version and exit."),
    no_thread_tuning: bool = typer.Option(False, "--no-thread-tuning", help="Keep the environment's BLAS and OpenMP "
                                          "threading (by default the command sets OPENBLAS_NUM_THREADS=1, "
                                          "MKL_NUM_THREADS=1 and OMP_WAIT_POLICY=PASSIVE where unset)"),
) -> None:
    """Point-cloud perception for offshore cranes."""
    terminate_like_interrupt()


@app.command()
def scenarios(
    show: Optional[str] = typer.Option(None, "--show", help="Print one scenario, fully resolved, as YAML."),
    keys: bool = typer.Option(False, "--keys", help="List every valid dotted scenario key."),
) -> None:
    """List the built-in scenarios (or show one)."""
    from boomtip.tools.config.catalog import available_scenarios, scenario_headline

    with user_errors():
        if keys or show:
            from boomtip.tools.config.scenario import load_scenario, scenario_to_yaml, valid_keys

            print("\n".join(valid_keys()) if keys else scenario_to_yaml(load_scenario(show)), end="\n" if keys else "")
            return
        for name, path in available_scenarios().items():
            headline = scenario_headline(path)
            if headline is None:  # left to the defaults: the full model says
                from boomtip.tools.config.scenario import load_scenario

                s = load_scenario(path)
                headline = (s.duration_s, s.description)
            print(f"{name:16s} {headline[0]:6.0f} s  {headline[1]}")


@app.command()
def simulate(
    scenario: str = ScenarioOpt,
    out: Path = typer.Option(..., "--out", "-o", help="Recording folder to write."),
    duration: Optional[float] = typer.Option(None, "--duration", help="Seconds to simulate (overrides duration_s)."),
    seed: Optional[int] = typer.Option(None, "--seed", help="Random seed (overrides seed)."),
    set_: Optional[list[str]] = SetOpt,
    format: str = typer.Option("boomtip", "--format", help="boomtip (PCD folder), mcap, ros2 (sqlite3) or ros1 (.bag)."),
    force: bool = typer.Option(False, "--force", help="Replace a non-empty --out."),
) -> None:
    """Simulate a scenario and write a recording (frames, MRU log, encoders, ground truth)."""
    from boomtip.data.io.recording import write_recording
    from boomtip.data.io.ros_writer import KINDS, write_bag
    from boomtip.data.sim.sources import simulation_for
    from boomtip.tools.config.scenario import ScenarioError

    with user_errors():
        if format not in ("boomtip", *KINDS):
            raise ScenarioError(f"--format {format!r}: expected boomtip, {', '.join(KINDS)}")
        s = resolve_scenario(scenario, set_, duration, seed)
        t0 = time.perf_counter()
        sim = simulation_for(s)
        with progress_bar(len(sim), "simulating") as advance:
            inputs = scenario_inputs(scenario)
            if format == "boomtip":
                meta = write_recording(sim, out, force=force, progress=advance, inputs=inputs)
            else:
                meta = write_bag(sim, out, format, force=force, progress=advance, inputs=inputs)
        wall = time.perf_counter() - t0
    frames = meta["frames"]
    console.print(
        f"wrote {out}: {frames['lidar']} LiDAR + {frames['radar']} radar frames, {s.duration_s:g} s simulated "
        f"in {wall:.1f} s ({s.duration_s / wall:.1f}x real time)"
    )


def _command_record(ctx: typer.Context) -> dict:
    """The command as settings.json records it: its name and its parsed options (paths as text)."""
    plain = lambda v: [plain(x) for x in v] if isinstance(v, (list, tuple)) else (str(v) if isinstance(v, Path) else v)  # noqa: E731
    return {"name": ctx.info_name, "params": {k.rstrip("_"): plain(v) for k, v in ctx.params.items()}}


def run_workers(workers: int | None) -> int:
    """--workers checked against the machine: 1 to 4 x its cores (default: its cores)."""
    import os

    from boomtip.tools.chains.chain import ChainError

    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    if workers is None:
        return cores
    if not 1 <= workers <= 4 * cores:
        raise ChainError(f"--workers {workers}: expected 1 to {4 * cores} (4 x the {cores} cores this process may use)")
    return workers


def _run_and_report(ctx: typer.Context, source, out: Path, force: bool, rerun: bool, inputs=(), lean: bool = True,
                    processing=None, workers: int | None = None) -> None:
    from boomtip.tools.chains.resources import RunResources
    from boomtip.tools.chains.runner import run

    resources = RunResources(lean=lean, workers=run_workers(workers))
    with progress_bar(len(source), "processing") as advance:
        result = run(source, out, force=force, processing=processing, rerun=rerun, inputs=inputs, progress=advance,
                     resources=resources, command=_command_record(ctx))
    print_kpis(result.kpis)
    console.print(f"\nwrote {out}: " + ", ".join(result.written))


@app.command()
def run(
    ctx: typer.Context,
    scenario: str = ScenarioOpt,
    out: Path = typer.Option(..., "--out", "-o", help="Output folder."),
    duration: Optional[float] = typer.Option(None, "--duration", help="Seconds to simulate (overrides duration_s)."),
    seed: Optional[int] = typer.Option(None, "--seed", help="Random seed (overrides seed)."),
    set_: Optional[list[str]] = SetOpt,
    rerun: bool = typer.Option(False, "--rerun", help="Also write a rerun-sdk recording OUT/boomtip.rrd."),
    force: bool = typer.Option(False, "--force", help="Replace a non-empty --out."),
    lean: bool = LeanOpt,
    workers: Optional[int] = RunWorkersOpt,
) -> None:
    """Simulate a scenario in memory and run perception + fusion on it (no recording on disk)."""
    from boomtip.data.sim.sources import simulation_for

    with user_errors():
        run_workers(workers)  # before anything is simulated
        s = resolve_scenario(scenario, set_, duration, seed)
        _run_and_report(ctx, simulation_for(s), out, force, rerun, inputs=scenario_inputs(scenario), lean=lean,
                        workers=workers)


@app.command()
def process(
    ctx: typer.Context,
    recording: Path = typer.Argument(..., help="A boomtip recording, a folder of .pcd/.ply/.bin clouds, an Ouster "
                                     ".pcap, a ROS 1 .bag, a ROS 2 bag folder or an .mcap."),
    out: Path = typer.Option(..., "--out", "-o", help="Output folder."),
    format: Optional[str] = typer.Option(None, "--format", help="Force a loader: boomtip, folder, ouster, ros1, ros2, "
                                         "mcap (default: guessed from the path)."),
    installation: Optional[Path] = typer.Option(None, "--installation", help="Installation YAML (sensors, mounts, crane)."),
    topic: Optional[list[str]] = typer.Option(None, "--topic", help="Bags: ROLE=NAME for lidar, radar, mru, "
                                              "feeder_mru, encoders (default: guessed by message type); ROLE=none "
                                              "reads no topic for that role."),
    meta: Optional[Path] = typer.Option(None, "--meta", help="Ouster: the sensor-metadata JSON (default: beside the pcap)."),
    start: Optional[float] = typer.Option(None, "--start", help="Skip the frames before this time (s)."),
    duration: Optional[float] = typer.Option(None, "--duration", help="Process this many seconds from --start."),
    every: int = typer.Option(1, "--every", help="Every N-th frame of each sensor."),
    rerun: bool = typer.Option(False, "--rerun", help="Also write a rerun-sdk recording OUT/boomtip.rrd."),
    force: bool = typer.Option(False, "--force", help="Replace a non-empty --out."),
    lean: bool = LeanOpt,
    workers: Optional[int] = RunWorkersOpt,
    set_: Optional[list[str]] = ProcessingSetOpt,
    processing: Optional[Path] = ProcessingFileOpt,
    strict: bool = typer.Option(False, "--strict", help="Refuse a recording with a bad sample in a stream (NaN, beyond "
                                "physical bounds, an impossible step, a time not after the last) instead of dropping it "
                                "with a warning that counts it."),
) -> None:
    """Run perception + fusion on a recording (any format the loaders read)."""
    from boomtip.data.io.installation_file import load_installation
    from boomtip.data.io.loaders import open_source, parse_topics
    from boomtip.tools.config.settings import processing_settings

    with user_errors():
        run_workers(workers)  # before anything is read
        inst = load_installation(installation) if installation else None
        source = open_source(recording, format, inst, start, duration, every, topics=parse_topics(topic), meta=meta,
                             strict=strict)
        settings = processing_settings(source.meta.processing, processing, set_) if (processing or set_) else None
        _run_and_report(ctx, source, out, force, rerun, inputs=(recording, installation, meta, processing), lean=lean,
                        processing=settings, workers=workers)


@app.command("installation")
def installation_cmd(
    template: bool = typer.Option(False, "--template", help="Print a commented template of every installation key."),
    check: Optional[Path] = typer.Option(None, "--check", help="Validate an installation file and print it resolved."),
) -> None:
    """Installation files: a template to fill in, or a check of one."""
    import yaml

    from boomtip.data.io.installation_file import installation_template, load_installation
    from boomtip.tools.config.scenario import ScenarioError

    with user_errors():
        if check is not None:
            print(yaml.safe_dump(load_installation(check).model_dump(mode="json"), sort_keys=False), end="")
        elif template:
            print(installation_template(), end="")
        else:
            raise ScenarioError("boomtip installation: pass --template or --check FILE")


@app.command()
def view(
    out: Path = typer.Argument(..., help="An output folder of `boomtip run --rerun` or `boomtip process --rerun`."),
    spawn: bool = typer.Option(False, "--spawn", help="Open the rerun viewer on it (needs a display)."),
    web: bool = typer.Option(False, "--web", help="Serve rerun's web viewer on this machine (127.0.0.1) and print its "
                             "page's URL; stops on Ctrl-C or SIGTERM. Works without a display."),
    port: int = typer.Option(9090, "--port", min=0, max=65535, help="--web: the viewer page's port (0: a free one)."),
    grpc_port: Optional[int] = typer.Option(None, "--grpc-port", min=0, max=65535, help="--web: the port the recording "
                                            "is served from (default: 9876, or a free one if it is taken)."),
) -> None:
    """Show where a run's rerun recording is, open it in the rerun viewer, or serve it to a browser."""
    from boomtip.tools.cli.view import ViewerError, has_display, no_display_message, serve_web

    rrd = out / "boomtip.rrd"
    if not rrd.is_file():
        console.print(f"[bold red]error:[/] {escape(str(rrd))} not found; run `boomtip run ... --rerun` or "
                      "`boomtip process ... --rerun` first", highlight=False)
        raise typer.Exit(2)
    if web:
        with user_errors(f"the web viewer on {rrd} was stopped"):
            try:
                code = serve_web(rrd, port, grpc_port, lambda url: print(f"rerun web viewer on {rrd}: {url}", flush=True))
            except ViewerError as exc:
                console.print("[bold red]error:[/] " + escape(str(exc)), highlight=False)
                raise typer.Exit(2) from None
        raise typer.Exit(code)
    if spawn:
        if not has_display():
            console.print(no_display_message(out), highlight=False)
            raise typer.Exit(2)
        import subprocess

        raise typer.Exit(subprocess.call([sys.executable, "-m", "rerun", str(rrd)]))
    print(f"{rrd} ({rrd.stat().st_size / 1e6:.1f} MB): open it with `rerun {rrd}`, `boomtip view {out} --spawn` (a display) "
          f"or `boomtip view {out} --web` (a browser)")


DEFAULT_KPIS = ("solutions.fused.mae_D_m", "solutions.fused.mae_D_dot_mps", "solutions.deck_lidar.mae_D_m",
                "solutions.reflectors_lidar.mae_D_m", "hook.ekf_flexible.rmse_pos_m.0", "hook.ekf_flexible.rmse_pos_m.1",
                "hook.ekf_flexible.rmse_pos_m.2")
WorkersOpt = typer.Option(None, "--workers", "-j", min=1, help="Worker processes (default: the number of cores).")
ExecutorOpt = typer.Option("local", "--executor", help="local (processes) or dask.")
SchedulerOpt = typer.Option(None, "--scheduler", help="Dask scheduler address tcp://HOST:PORT (default: a LocalCluster).")


def _study(tasks, out: Path, grid_keys: list[str], labels: dict, kpis: list[str], executor: str, workers, scheduler,
           resume: bool, force: bool, scenario_dump: dict | None, inputs: tuple[Path, ...] = ()) -> list[dict]:
    from boomtip.data.io.output_folder import locked_output
    from boomtip.tools.study.executor import (check_executor, make_executor, plot_kpis, prepare_study_dir, run_study,
                                         write_summary, write_sweep_json)

    check_executor(executor)
    study = {"scenario": scenario_dump, "grid": grid_keys, "tasks": [[t.id, list(t.overrides), t.duration_s, t.recording]
                                                                     for t in tasks]}
    def interrupted() -> str:  # the study writes OUT in place: --resume goes on once it has begun
        return INTERRUPTED_STUDY if (Path(out) / "study.json").is_file() else INTERRUPTED_STUDY_UNSTARTED

    with locked_output(out, inputs) as out, user_errors(interrupted):
        done = prepare_study_dir(out, force, resume, json.loads(json.dumps(study)), inputs)
        with progress_bar(len(tasks), "tasks") as advance, make_executor(executor, workers, scheduler) as pool:
            rows = run_study(tasks, out, grid_keys, pool, done, advance)
        summary = write_summary(out, rows, grid_keys)
        present = {r["kpi"] for r in summary}
        plots = plot_kpis(out, summary, grid_keys, [k for k in (kpis or DEFAULT_KPIS) if k in present], labels)
        write_sweep_json(out, sys.argv, scenario_dump, tasks, rows)
    failed = [r for r in rows if r["status"] != "ok"]
    console.print(f"wrote {out}: runs.csv ({len(rows)} runs, {len(failed)} failed), summary.csv, sweep.json"
                  + "".join(f", {p.name}" for p in plots))
    for r in failed[:5]:
        console.print("  failed: " + escape(f"{r['task']}: {r['error']}"), highlight=False)
    return rows


@app.command()
def sweep(
    scenario: str = typer.Option("sts-loaded", "--scenario", "-s"),
    grid: Optional[list[str]] = typer.Option(None, "--grid", help="KEY=V1,V2,... (repeatable: the product of the grids)."),
    preset: Optional[list[str]] = typer.Option(None, "--preset", help="A named axis of document 000's study: "
                                               "delay, mru_noise, mru_bias, rate, density, fov, false_reflectors, clock_offset; "
                                               "worlds: every seed a randomized world (world.randomize)."),
    seeds: int = typer.Option(1, "--seeds", min=1, help="Runs per grid point (Monte Carlo), seeds derived from the scenario's."),
    duration: Optional[float] = typer.Option(None, "--duration", help="Seconds per run (default: the scenario's)."),
    set_: Optional[list[str]] = SetOpt,
    out: Path = typer.Option(..., "--out", "-o"),
    kpi: Optional[list[str]] = typer.Option(None, "--kpi", help="KPI to plot (flattened kpis.json key; repeatable)."),
    workers: Optional[int] = WorkersOpt,
    executor: str = ExecutorOpt,
    scheduler: Optional[str] = SchedulerOpt,
    resume: bool = typer.Option(False, "--resume", help="Keep the finished runs in --out and do the rest."),
    force: bool = typer.Option(False, "--force", help="Replace a non-empty --out."),
) -> None:
    """Sweeps and Monte Carlo over any scenario keys: one task per run, on local processes or Dask."""
    from boomtip.tools.config.scenario import ScenarioError, load_scenario
    from boomtip.tools.study.tasks import axis_from_grid, axis_from_preset, sweep_tasks

    with user_errors():
        try:
            axes = [axis_from_preset(p) for p in preset or []] + [axis_from_grid(g) for g in grid or []]
        except ValueError as exc:
            raise ScenarioError(str(exc)) from None
        base = resolve_scenario(scenario, set_, duration)
        for ax in axes:  # refuse a bad key or value before spawning anything
            for over in ax.overrides:
                load_scenario(scenario, list(set_ or []) + list(over))
        tasks = sweep_tasks(scenario, axes, seeds, list(set_ or []), duration, base.seed)
        _study(tasks, out, [a.name for a in axes], {a.name: a.label for a in axes}, list(kpi or []), executor, workers,
               scheduler, resume, force, base.model_dump(mode="json"))


@app.command()
def batch(
    paths: list[Path] = typer.Argument(..., help="Recording folders."),
    out: Path = typer.Option(..., "--out", "-o"),
    kpi: Optional[list[str]] = typer.Option(None, "--kpi"),
    workers: Optional[int] = WorkersOpt,
    executor: str = ExecutorOpt,
    scheduler: Optional[str] = SchedulerOpt,
    resume: bool = typer.Option(False, "--resume"),
    force: bool = typer.Option(False, "--force"),
    set_: Optional[list[str]] = ProcessingSetOpt,
    processing: Optional[Path] = ProcessingFileOpt,
) -> None:
    """Process many recordings the same way, one task each, one summary."""
    from boomtip.data.io.recording import Recording
    from boomtip.data.keys import settings_dump
    from boomtip.tools.config.settings import processing_settings
    from boomtip.tools.study.tasks import Task

    with user_errors():
        tasks = []
        for i, p in enumerate(paths):
            rec = Recording(p)  # refuse an unreadable recording before spawning anything
            settings = (settings_dump(processing_settings(rec.meta.processing, processing, set_), exclude_unset=True)
                        if (processing or set_) else None)
            tasks.append(Task(f"{i}:{p}", "", (), None, 0, {"recording": str(p)}, recording=str(p.resolve()),
                              processing=settings))
        _study(tasks, out, ["recording"], {}, list(kpi or []), executor, workers, scheduler, resume, force, None,
               inputs=(*paths, processing))


if __name__ == "__main__":  # pragma: no cover
    from boomtip.tools.cli import main

    main()
