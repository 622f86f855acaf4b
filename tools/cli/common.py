"""What every `boomtip` command shares: the console, user-error handling, the progress bar,
scenario resolution and the common options."""

from __future__ import annotations

import sys
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator

import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, ProgressColumn, TextColumn, TimeRemainingColumn
from rich.text import Text

from boomtip.data.io.output_folder import COMMITTED, InterruptedAfterCommit

console = Console(stderr=True, soft_wrap=True)

ScenarioOpt = typer.Option(..., "--scenario", "-s", help="Built-in scenario name or a YAML file.")
SetOpt = typer.Option(None, "--set", help="Override a scenario key: dotted.key=value (repeatable).")


# the errors that mean bad input, by module: looked up only in the modules already imported (an
# error class never imported cannot have been raised), so that the command line starts without them
USER_ERRORS = {"boomtip.tools.config.scenario": "ScenarioError", "boomtip.data.io.recording": "RecordingError",
               "boomtip.data.io.pcd": "PcdError", "boomtip.tools.chains.chain": "ChainError",
               "boomtip.data.sim.lift_programme": "LiftProgramError"}

INTERRUPTED_RUN = "no output was replaced and no input was touched; the run's partial results were removed"
INTERRUPTED_STUDY = "no input was touched; the finished runs are in runs.csv: --resume does the rest"
INTERRUPTED_STUDY_UNSTARTED = "no input was touched; the study had not started (nothing to --resume)"


@contextmanager
def user_errors(interrupted: str | Callable[[], str] = INTERRUPTED_RUN) -> Iterator[None]:
    """Turn expected user-input errors into one clear message and exit code 2; an interrupt
    into one line saying what it leaves behind (`interrupted`, or a function that says it),
    and exit code 130."""
    COMMITTED.clear()  # this command's output folders only
    try:
        yield
    except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM (terminate_like_interrupt)
        why = str(exc) or "interrupt"
        if isinstance(exc, InterruptedAfterCommit) or COMMITTED:  # the results were already in place
            left = f"after the results were written to {', '.join(map(str, COMMITTED))}: they are complete"
        else:
            left = interrupted() if callable(interrupted) else interrupted
        console.print(f"[bold yellow]stopped ({escape(why)}):[/] {escape(left)}", highlight=False)
        raise typer.Exit(130) from None
    except Exception as exc:
        if isinstance(exc, user_error_types()):
            console.print("[bold red]error:[/] " + escape(str(exc)), highlight=False)  # a key's [a, b] is not markup
            raise typer.Exit(2) from None
        if not isinstance(exc, OSError):
            raise
        # a read-only or full disk: say so; the staging folder is already gone
        where = f" {exc.filename}" if exc.filename else ""
        console.print("[bold red]error:[/] " + escape(f"cannot read or write{where}: {exc.strerror or exc}; nothing was replaced"),
                      highlight=False)
        raise typer.Exit(2) from None


def user_error_types() -> tuple[type[Exception], ...]:
    """The bad-input errors among the modules imported so far, and a missing file."""
    loaded = [getattr(sys.modules[module], name) for module, name in USER_ERRORS.items() if module in sys.modules]
    return (*loaded, FileNotFoundError)


def terminate_like_interrupt() -> None:
    """SIGTERM (a job scheduler, `kill`) unwinds like Ctrl-C, so a run removes its staging
    folder instead of leaving a half-written one behind."""
    import signal

    def _raise(signum, frame):
        raise KeyboardInterrupt(f"signal {signum}")

    signal.signal(signal.SIGTERM, _raise)


PROGRESS_LINE_S = 10.0  # without a terminal (a log file, CI), a progress line this often


@contextmanager
def progress_bar(total: int, label: str) -> Iterator:
    """`advance(n)` moves a bar on a terminal; elsewhere a line every PROGRESS_LINE_S says how
    far the run is, so a long run in a log is never silent."""
    if not sys.stderr.isatty():
        yield progress_lines(total, label, lambda text: console.print(text, highlight=False))
        return
    with Progress(TextColumn(label), BarColumn(), MofNCompleteColumn(), RateColumn(), TimeRemainingColumn(),
                  console=console) as prog:
        task = prog.add_task(label, total=total)
        yield lambda n=1: prog.advance(task, n)


class RateColumn(ProgressColumn):
    """Items (frames, tasks) per second, once there is a rate to show."""

    def render(self, task) -> Text:
        return Text(f"{task.speed:.1f}/s" if task.speed else "")


def progress_lines(total: int, label: str, say, every_s: float = PROGRESS_LINE_S, clock=time.monotonic):
    """An `advance(n)` that calls say("LABEL: done/total (P %), T s, about R s left") at most
    every `every_s` seconds."""
    start = clock()
    state = {"done": 0, "next": start + every_s}

    def advance(n: int = 1) -> None:
        state["done"] += n
        now = clock()
        if now < state["next"]:
            return
        state["next"] = now + every_s
        done, elapsed = state["done"], now - start
        share = f" ({100 * done / total:.0f} %)" if total else ""
        left = f", about {elapsed * (total - done) / done:.0f} s left" if total and 0 < done < total else ""
        say(f"{label}: {done}/{total or '?'}{share}, {elapsed:.0f} s{left}")

    return advance


def scenario_inputs(scenario: str) -> tuple[Path, ...]:
    """A scenario given as a file is an input of the command: --force never deletes it."""
    path = Path(scenario)
    return (path,) if path.is_file() else ()


def resolve_scenario(scenario: str, overrides: list[str] | None, duration: float | None = None, seed: int | None = None):
    from boomtip.tools.config.scenario import load_scenario

    extra = list(overrides or [])
    if duration is not None:
        extra.append(f"duration_s={duration}")
    if seed is not None:
        extra.append(f"seed={seed}")
    return load_scenario(scenario, extra)
