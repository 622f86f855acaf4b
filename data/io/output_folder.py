"""Output folders that lose nothing: results are written into a staging folder beside OUT and
moved into place when complete; OUT is locked while a run writes it (a second run into it is
refused with the holder's PID); replacing OUT (--force) is refused when that would delete an
input of the command or a folder that holds more than results (the current folder, its
parents, the home folder, the root); staging folders left by runs that died (SIGKILL, a power
cut) are removed by the next run into the same parent.

    with output_folder(out, force, inputs=(recording, installation)) as staging:
        ...write into staging...
    # complete: staging became OUT; failed or interrupted: staging removed, OUT as it was
"""

from __future__ import annotations

import os
import re
import shutil
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from boomtip.data.io.errors import RecordingError

__all__ = ["OutputError", "check_output_folder", "output_folder", "clear_dead_staging"]

STAGING = re.compile(r"^\..+\.(partial|old)-(\d+)$")  # what output_folder leaves beside OUT while it runs


class OutputError(RecordingError):
    """OUT may not be written: the message names it and why."""


def check_output_folder(out: Path, inputs: tuple[Path, ...] = ()) -> Path:
    """The resolved output folder, refused when replacing it (--force) could delete more than
    results: the current folder or one of its parents, the home folder, the root, an input or a
    folder that holds one."""
    if str(out).strip() in ("", "."):
        raise OutputError(f"--out '{out}': name a folder for the results (not the current folder)")
    out = Path(out).resolve()
    if out == Path.cwd() or out in Path.cwd().parents or out == Path.home() or out == Path(out.anchor):
        raise OutputError(f"--out {out}: is the current folder, one of its parents or your home; "
                          "name a folder of its own for the results")
    for inp in inputs:
        if inp is None:
            continue
        inp = Path(inp).resolve()
        if out == inp or inp in out.parents or out in inp.parents:
            raise OutputError(f"--out {out} overlaps the input {inp}; refusing to write over an input")
    return out


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process: alive
        return True
    return True


def clear_dead_staging(parent: Path) -> list[Path]:
    """Remove the staging folders in `parent` whose run is gone (their PID is no process's);
    returns what was removed."""
    removed = []
    if not parent.is_dir():
        return removed
    for p in parent.iterdir():
        m = STAGING.match(p.name)
        if m and p.is_dir() and not p.is_symlink() and not _alive(int(m.group(2))):
            shutil.rmtree(p, ignore_errors=True)
            removed.append(p)
    return removed


def _lock(out: Path) -> Path:
    """`.OUT.lock` beside OUT, created exclusively with this process's PID; a lock whose PID is
    no process's is stale and taken over."""
    lock = out.parent / f".{out.name}.lock"
    for _ in range(2):
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            try:
                pid = int(lock.read_text().strip() or "0")
            except (OSError, ValueError):
                pid = 0
            if pid > 0 and _alive(pid):
                raise OutputError(f"--out {out} is being written by another run (PID {pid}); wait for it or name "
                                  f"another --out (if no such run exists, remove {lock})") from None
            lock.unlink(missing_ok=True)
            continue
        with os.fdopen(fd, "w") as fh:
            fh.write(f"{os.getpid()}\n")
        return lock
    raise OutputError(f"--out {out}: could not take its lock {lock}")


@contextmanager
def output_folder(out: Path, force: bool, inputs: tuple[Path | None, ...] = ()) -> Iterator[Path]:
    """A staging folder for OUT's results, moved into place when the block completes (see the
    module). Refused: a non-empty OUT without `force`, an OUT another run holds, an OUT that
    replacing could delete an input."""
    out = check_output_folder(out, inputs)
    if out.exists() and (not out.is_dir() or any(out.iterdir())) and not force:
        raise OutputError(f"--out {out} exists and is not empty; pass --force to replace it")
    out.parent.mkdir(parents=True, exist_ok=True)
    lock = _lock(out)
    try:
        clear_dead_staging(out.parent)
        staging = out.parent / f".{out.name}.partial-{os.getpid()}"
        if staging.exists():
            shutil.rmtree(staging)
        staging.mkdir()
        try:
            yield staging
        except BaseException:
            shutil.rmtree(staging, ignore_errors=True)
            raise
        _commit(staging, out)
    finally:
        lock.unlink(missing_ok=True)


def _commit(staging: Path, out: Path) -> None:
    if out.exists():
        old = out.parent / f".{out.name}.old-{os.getpid()}"
        out.rename(old)
        staging.rename(out)
        shutil.rmtree(old) if old.is_dir() else old.unlink()
    else:
        staging.rename(out)
