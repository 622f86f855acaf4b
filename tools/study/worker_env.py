"""A study worker's threads and life: one task at a time on one core, and no life beyond its
parent's. Set in a fresh worker process before it loads numpy or Open3D (their thread pools read
these once, when they load); imports nothing heavy itself, for the same reason."""

from __future__ import annotations

import os
import threading
import time

__all__ = ["ONE_THREAD", "one_thread_each", "exit_with_parent", "study_worker", "PARENT_POLL_S"]

ONE_THREAD = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
PARENT_POLL_S = 1.0  # how often a worker checks that the process that started it is alive


def one_thread_each() -> None:
    """One thread per library unless the user set it."""
    for key, value in ONE_THREAD.items():
        os.environ.setdefault(key, value)


def exit_with_parent(poll_s: float = PARENT_POLL_S) -> None:
    """End this process within `poll_s` of its parent's end. A pool's parent that is killed (a
    sweep stopped with SIGKILL, out of memory) cannot stop its workers, and they would wait for
    tasks forever, each holding its memory: a daemon thread watches the parent's pid instead."""
    parent = os.getppid()

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(poll_s)
        os._exit(1)  # no cleanup to run: the task's result has nowhere to go

    threading.Thread(target=watch, name="boomtip-parent-watch", daemon=True).start()


def study_worker() -> None:
    """The local pool's initializer: one thread per library, and no life beyond the parent's."""
    one_thread_each()
    exit_with_parent()
