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

from data.pcd import PcdError
from data.recording import RecordingError
from data.scenario import ScenarioError, available_scenarios, load_scenario, scenario_to_yaml, valid_keys

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
    except (ScenarioError, RecordingError, PcdError, FileNotFoundError) as exc:
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
    from data.recording import write_recording
    from data.simulator import Simulation

    with user_errors():
        s = resolve_scenario(scenario, set_, duration, seed)
        t0 = time.perf_counter()
        sim = Simulation(s)
        with progress_bar(len(sim), "simulating") as advance:
            meta = write_recording(sim, out, force=force, progress=advance)
        wall = time.perf_counter() - t0
    frames = meta["frames"]
    console.print(
        f"wrote {out}: {frames['lidar']} LiDAR + {frames['radar']} radar frames, {s.duration_s:g} s simulated "
        f"in {wall:.1f} s ({s.duration_s / wall:.1f}x real time)"
    )


def main() -> None:  # pragma: no cover - console entry point
    app()


if __name__ == "__main__":  # pragma: no cover
    app()
