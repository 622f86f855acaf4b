"""A run on two cores: what can go ahead made in a child process while this one works on the
previous frames (a hook run's simulated frames; a ship run's per-frame perception, whose fusion
stays here), and a hook run's estimators shared between two children.

The children are forks that run exactly the code a serial run would (same inputs, same random
draws, same order), so a run's outputs do not depend on it; only the wall clock does. Processes
and not threads: the simulator and the filters are mostly small numpy calls holding the GIL
(a frame-producing thread gains nothing).
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import signal
import threading
import traceback
from concurrent.futures import Executor, Future
from queue import Empty, Full
from typing import Callable, Iterable, Iterator, Sequence

from boomtip.data.frames import Frame, FrameSource
from boomtip.tools.chains.chain import ChainError

__all__ = ["serial", "parallel_enabled", "frames_in_child", "mapped_in_child", "run_split", "split_by_cost", "WorkerDied",
           "ForkExecutor"]

FRAMES_AHEAD = 32  # frames a child may run ahead of this process (a hook frame: 0.6 MB, a perceived 128 x 1024 one: ~1 MB)
CHILD_POLL_S = 0.5  # how often a wait for a child checks that it is still alive
STOP_WAIT_S = 5.0  # a child asked to stop gets this long before it is killed
_serial_depth = 0


@contextlib.contextmanager
def serial() -> Iterator[None]:
    """Everything in this process, as one core would run it (benchmark baselines, tests)."""
    global _serial_depth
    _serial_depth += 1
    try:
        yield
    finally:
        _serial_depth -= 1


def parallel_enabled() -> bool:
    """A second core to use, the fork start method (Linux), not inside `serial()`, and not in a
    worker of ours (a daemonic process may not have children of its own)."""
    return (_serial_depth == 0 and len(os.sched_getaffinity(0)) > 1
            and "fork" in mp.get_all_start_methods() and not mp.current_process().daemon)


def _as_child() -> None:
    """A child's signals: the parent decides. Ctrl-C reaches the whole process group, so the child
    ignores it (the parent stops it); SIGTERM, which the CLI turns into KeyboardInterrupt so that a
    run cleans up, ends the child at once (its parent's clean-up sends it). They were blocked
    from before the fork (`_started`) until now: one sent in between waits for these handlers."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, _CHILD_SIGNALS)


_CHILD_SIGNALS = {signal.SIGINT, signal.SIGTERM}


def _started(proc) -> None:
    """proc.start() with SIGINT and SIGTERM blocked across the fork: a child signalled before it
    set its own handlers would raise the parent's KeyboardInterrupt through its copy of the
    parent's stack (and run the parent's clean-up) instead of ending."""
    saved = signal.pthread_sigmask(signal.SIG_BLOCK, _CHILD_SIGNALS)
    try:
        proc.start()
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, saved)


def _put(queue, item, parent_pid: int) -> None:
    """queue.put, giving up when the parent is gone (nobody would ever read it)."""
    while True:
        try:
            queue.put(item, timeout=1.0)
            return
        except Full:
            if os.getppid() != parent_pid:
                queue.cancel_join_thread()
                os._exit(1)


def _produce(items: Iterable, fn: Callable | None, at_end: Callable | None, queue, parent_pid: int) -> None:
    _as_child()
    try:
        for item in items:
            _put(queue, ("item", item if fn is None else fn(item)), parent_pid)
        if at_end is not None:
            _put(queue, ("item", at_end()), parent_pid)
        _put(queue, ("end", None), parent_pid)
    except BaseException as exc:  # the parent re-raises it
        _put(queue, ("error", _picklable(exc)), parent_pid)
    queue.close()
    queue.join_thread()


def _picklable(exc: BaseException) -> BaseException:
    import pickle

    try:
        pickle.loads(pickle.dumps(exc))
        return exc
    except Exception:
        return RuntimeError("".join(traceback.format_exception(exc)))


def frames_in_child(source: FrameSource) -> Iterator[Frame]:
    """The source's frames in order, made by a forked child up to FRAMES_AHEAD ahead."""
    return mapped_in_child(source, None, name="boomtip-frames")


def mapped_in_child(items: Iterable, fn: Callable | None, at_end: Callable | None = None,
                    name: str = "boomtip-perception") -> Iterator:
    """fn(item) for each item in order (the items themselves when fn is None), then at_end()
    if given, made by a forked child up to FRAMES_AHEAD ahead: the child iterates `items` and
    calls `fn` on its own copy of everything they use, so `fn` may keep state (a pipeline's
    priors) but must not need any this process changes meanwhile; `at_end` hands back what the
    child's copy gathered. A child that dies (killed, out of memory) stops the iteration with
    WorkerDied."""
    ctx = mp.get_context("fork")
    queue = ctx.Queue(FRAMES_AHEAD)
    proc = ctx.Process(target=_produce, args=(items, fn, at_end, queue, os.getpid()), name=name, daemon=True)
    _started(proc)
    # the queue's sending end is the child's: closed here, a child that dies halfway through a
    # message ends the read with EOF (WorkerDied) instead of a wait for the rest forever
    queue._writer.close()
    try:
        while True:
            kind, payload = _get(queue, proc)
            if kind == "item":
                yield payload
            elif kind == "end":
                break
            else:
                raise payload
        proc.join()
    finally:
        _stop(proc)  # when the consumer stopped early or failed: the child's work is not wanted
        queue.close()


class WorkerDied(ChainError):
    """A worker process ended without finishing its work (killed, out of memory)."""


def _get(queue, proc):
    """The child's next message; WorkerDied if it ended without sending one."""
    while True:
        try:
            return queue.get(timeout=CHILD_POLL_S)
        except (EOFError, OSError):  # it ended halfway through a message
            proc.join()
            raise _died(proc) from None
        except Empty:
            if proc.exitcode is None:
                continue
            try:  # what it sent just before it ended
                return queue.get(timeout=CHILD_POLL_S)
            except (Empty, EOFError, OSError):
                raise _died(proc) from None


def _died(proc) -> "WorkerDied":
    code = proc.exitcode
    how = f"killed by signal {-code}" if code is not None and code < 0 else f"exit code {code}"
    hint = " (out of memory?)" if code == -signal.SIGKILL else ""
    return WorkerDied(f"the worker process {proc.name} ended before its work was done: {how}{hint}; "
                      "the run stopped and wrote nothing")


def _stop(proc) -> None:
    if proc.is_alive():
        proc.terminate()
        proc.join(5.0)
    if proc.is_alive():
        proc.kill()
    proc.join()


def split_by_cost(costs: dict[str, float]) -> tuple[list[str], list[str]]:
    """Two groups of about equal total cost (largest first, each to the lighter group); the
    first group is the one with the largest job."""
    a: list[str] = []
    b: list[str] = []
    load = [0.0, 0.0]
    for name in sorted(costs, key=lambda k: -costs[k]):
        i = 0 if load[0] <= load[1] else 1
        (a, b)[i].append(name)
        load[i] += costs[name]
    return a, b


def _run_group(jobs: Sequence[str], work: Callable[[str], object], conn) -> None:
    _as_child()
    try:
        conn.send(("ok", [(name, work(name)) for name in jobs]))
    except BaseException as exc:
        conn.send(("error", _picklable(exc)))
    conn.close()


def run_split(names: Sequence[str], costs: dict[str, float], work: Callable[[str], object]) -> dict[str, object]:
    """{name: work(name)} for every name, the names split by cost between two forked children
    (each runs its share first to last, as a serial run would). Both in children, not one here:
    an estimator's working memory then goes back to the system when its child ends (estimators
    run here would leave a long run's process larger at the run's peak, the report).
    What ``work`` returns must pickle; it may write to files opened before the call (the
    children share them)."""
    names = list(names)
    if len(names) < 2 or not parallel_enabled():
        return {name: work(name) for name in names}
    ctx = mp.get_context("fork")
    children = []
    try:
        for jobs in split_by_cost({n: costs.get(n, 1.0) for n in names}):
            recv, send = ctx.Pipe(duplex=False)
            proc = ctx.Process(target=_run_group, args=(jobs, work, send), name="boomtip-estimators", daemon=True)
            _started(proc)
            send.close()
            children.append((proc, recv))
        out: dict[str, object] = {}
        failure = None
        for proc, recv in children:
            kind, payload = recv.recv()
            proc.join()
            if kind == "error":
                failure = failure or payload
            else:
                out.update(dict(payload))
    finally:
        for proc, recv in children:
            _stop(proc)
            recv.close()
    if failure is not None:
        raise failure
    return {name: out[name] for name in names}


def _call_in_child(fn: Callable, args: tuple, conn) -> None:
    _as_child()
    try:
        conn.send(("ok", fn(*args)))
    except BaseException as exc:  # the parent's future raises it
        conn.send(("error", _picklable(exc)))
    conn.close()


class ForkExecutor(Executor):
    """Each call in a forked child of its own: its inputs are the child's copy of this process
    (nothing is pickled on the way in), its result comes back pickled; a thread here waits for
    it. For a few long calls (the feeder model's merges), not many short ones: a fork costs
    milliseconds. A child that dies fails its future with WorkerDied."""

    fatal = (WorkerDied,)  # a caller that tolerates a call's failure must not tolerate a lost worker

    def __init__(self, name: str = "boomtip-call") -> None:
        self.name = name
        self._children: list = []

    def submit(self, fn: Callable, /, *args) -> Future:
        ctx = mp.get_context("fork")
        recv, send = ctx.Pipe(duplex=False)
        proc = ctx.Process(target=_call_in_child, args=(fn, args, send), name=self.name, daemon=True)
        _started(proc)
        send.close()
        future: Future = Future()

        def wait() -> None:
            try:
                kind, payload = recv.recv()
            except (EOFError, OSError):
                proc.join()
                future.set_exception(WorkerDied(f"the worker process {proc.name} ended before its work was done "
                                                f"(exit code {proc.exitcode})"))
                return
            finally:
                recv.close()
            proc.join()
            (future.set_result if kind == "ok" else future.set_exception)(payload)

        waiter = threading.Thread(target=wait, name=f"{self.name}-wait", daemon=True)
        waiter.start()
        self._children.append((proc, waiter))
        return future

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        """Children still running are stopped (cancel_futures, or not wait) or waited for. Only
        each child's waiting thread reaps it (two threads waiting for one process race for its
        exit status): here it is signalled, and its thread waited for."""
        for proc, waiter in self._children:
            if cancel_futures or not wait:
                for stop in (proc.terminate, proc.kill):
                    if not waiter.is_alive():
                        break
                    with contextlib.suppress(OSError):
                        stop()
                    waiter.join(STOP_WAIT_S)
            waiter.join()
        self._children = []

