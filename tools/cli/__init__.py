"""The `boomtip` command line. `main` is the console script: it sets the process's thread
tuning (see `tune_threads`) before numpy and Open3D load, then runs the typer app. Importing
this package changes nothing: a library user's process keeps its own settings."""

from __future__ import annotations

import os
import sys

__all__ = ["main", "tune_threads"]

# boomtip's numerics are small dense products (3x3 solves, N x 3 scoring). Multithreaded
# OpenBLAS stalls on those when the machine is busy (a sub-millisecond product can take tens of ms), so
# the command line pins BLAS to one thread unless the user says otherwise. OpenMP workers that
# spin after a parallel region (the default wait policy) steal a core from the pipeline thread
# when simulation and perception alternate frame by frame: passive waiting puts them to sleep.
# Open3D's ray casting has its own thread pool and is not affected.
THREAD_TUNING = {"OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OMP_WAIT_POLICY": "PASSIVE"}
NO_TUNING_FLAG = "--no-thread-tuning"


def tune_threads(environ=os.environ) -> dict[str, str]:
    """Set the thread tuning's variables the user has not set; returns those it set. Takes
    effect only before numpy and Open3D are imported."""
    added = {k: v for k, v in THREAD_TUNING.items() if k not in environ}
    environ.update(added)
    return added


def main() -> None:
    if NO_TUNING_FLAG not in sys.argv[1:]:
        tune_threads()
    from boomtip.tools.cli.commands import app

    app()


def __getattr__(name: str):
    if name == "app":  # `from boomtip.tools.cli import app` for tests and embedding
        from boomtip.tools.cli.commands import app

        return app
    raise AttributeError(name)
