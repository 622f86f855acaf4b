"""The run's resources: a plain run keeps everything here and leaves the allocator alone; a lean
one keeps its tables on disk and tunes glibc; both give the same outputs."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from boomtip.tools.report.hook_rows import DiskTable
from boomtip.tools.chains.resources import RunResources


def test_a_plain_run_keeps_its_tables_in_memory_and_a_lean_one_on_disk():
    table = np.arange(12.0).reshape(4, 3)
    plain, lean = RunResources().table(table), RunResources(lean=True).table(table)
    assert isinstance(plain, np.ndarray) and isinstance(lean, DiskTable)
    assert np.array_equal(plain[1:3], lean[1:3]) and np.array_equal(np.asarray(lean), table)


def test_a_plain_run_maps_its_work_here_in_order():
    out = RunResources().map_split(["b", "a"], {}, lambda name: (name, __import__("os").getpid()))
    assert list(out) == ["b", "a"] and {pid for _, pid in out.values()} == {__import__("os").getpid()}


def test_importing_boomtip_tunes_nothing():
    """No environment variable or allocator setting changes on import or on building a pipeline:
    the thread and memory tuning are the command line's (and a lean run's)."""
    code = (
        "import os; before = dict(os.environ)\n"
        "import boomtip.tools, boomtip.tools.cli, boomtip.tools.chains.runner, boomtip.perception, boomtip.fusion\n"
        "from boomtip.perception.pipeline import HeavePipeline\n"
        "from boomtip.data.installation import Installation\n"
        "from boomtip.data.frames import MruLog\n"
        "HeavePipeline(Installation(), MruLog.level(0, 1))\n"
        "assert dict(os.environ) == before, set(os.environ.items()) ^ set(before.items())\n"
    )
    env = {k: v for k, v in __import__("os").environ.items() if k not in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_WAIT_POLICY")}
    subprocess.run([sys.executable, "-c", code], check=True, env=env)


def test_the_command_line_sets_its_thread_tuning_only_where_unset():
    from boomtip.tools.cli import THREAD_TUNING, tune_threads

    env = {"OMP_WAIT_POLICY": "ACTIVE"}
    added = tune_threads(env)
    assert env["OMP_WAIT_POLICY"] == "ACTIVE" and added == {k: v for k, v in THREAD_TUNING.items() if k != "OMP_WAIT_POLICY"}


@pytest.mark.skipif(not __import__("sys").platform.startswith("linux"), reason="glibc's mallopt")
def test_keep_freed_memory_reuses_freed_frames_without_page_faults():
    """After keep_freed_memory, a 1 MiB array freed and allocated again comes back from the
    heap: no page faults (by default glibc trims the freed heap and faults it in again: some
    240 over these 20 on the development VM)."""
    import resource

    from boomtip.tools.chains.resources import keep_freed_memory

    assert keep_freed_memory()
    a = np.ones(1 << 17)  # 1 MiB: above glibc's default 128 KiB mapping threshold
    del a
    faults0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(20):
        a = np.ones(1 << 17)
        del a
    assert resource.getrusage(resource.RUSAGE_SELF).ru_minflt - faults0 < 64
