"""A study worker's threads: one task at a time on one core. Set in a fresh worker process before
it loads numpy or Open3D (their thread pools read these once, when they load); imports nothing
heavy itself, for the same reason."""

from __future__ import annotations

import os

__all__ = ["ONE_THREAD", "one_thread_each"]

ONE_THREAD = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def one_thread_each() -> None:
    """The pool's initializer: one thread per library unless the user set it."""
    for key, value in ONE_THREAD.items():
        os.environ.setdefault(key, value)
