"""Output folders that lose nothing: results are written into a staging folder beside OUT and
moved into place when complete; OUT is locked while a run writes it (a second run into it is
refused with the holder's PID); replacing OUT (--force) is refused when that would delete an
input of the command or a folder that holds more than results (the current folder, its
parents, the home folder, the root); what a run that died (SIGKILL, a power cut) left beside
an OUT is cleared by the next run that takes that OUT's lock.

    with output_folder(out, force, inputs=(recording, installation)) as staging:
        ...write into staging...
    # complete: staging became OUT; failed or interrupted: staging removed, OUT as it was

The lock is an OS lock (`flock`) on `.OUT.lock`, held for the whole run: the kernel releases it
when its process dies, however it dies, so a lock is never stale and no PID is ever guessed
alive or dead. The PID written into the lock file only names the holder in the message.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from boomtip.data.io.errors import RecordingError

__all__ = ["OutputError", "InterruptedAfterCommit", "check_output_folder", "output_folder", "locked_output", "clear_dead_staging"]

# what output_folder leaves beside OUT while it runs: `.OUT.partial-PID` (the results being
# written, holding STAGING_MARKER) and, for the instant of the swap, `.OUT.old-PID` (the former OUT)
STAGING = re.compile(r"^\.(?P<name>.+)\.(?P<kind>partial|old|swap)-(?P<pid>\d{1,10})$")
STAGING_MARKER = ".boomtip-staging"
SWAP_JOURNAL = "boomtip swap\n"  # what `.OUT.swap-PID` holds while `.OUT.old-PID` is the former OUT
TRASH = re.compile(r"^\.boomtip-trash-\d{1,10}-\d{1,10}$")  # dead runs' folders, removed without a lock


class OutputError(RecordingError):
    """OUT may not be written: the message names it and why."""


class InterruptedAfterCommit(KeyboardInterrupt):
    """Ctrl-C or SIGTERM that arrived while the results were swapped in: OUT is complete."""


def check_output_folder(out: Path, inputs: tuple[Path | None, ...] = ()) -> Path:
    """The resolved output folder, refused when replacing it (--force) could delete more than
    results: the current folder or one of its parents, the home folder, the root, an input or a
    folder that holds one."""
    if str(out).strip() in ("", "."):
        raise OutputError(f"--out '{out}': name a folder for the results (not the current folder)")
    out = Path(out).resolve()
    if out == Path.cwd() or out in Path.cwd().parents or out == Path.home() or out == Path(out.anchor):
        raise OutputError(f"--out {out}: is the current folder, one of its parents or your home; "
                          "name a folder of its own for the results")
    for inp in _resolved(inputs):
        if out == inp or inp in out.parents or out in inp.parents:
            raise OutputError(f"--out {out} overlaps the input {inp}; refusing to write over an input")
    return out


def _resolved(paths: tuple[Path | None, ...]) -> list[Path]:
    return [Path(p).resolve() for p in paths if p is not None]


# --- the lock ---------------------------------------------------------------------------------

def _try_lock(fd: int) -> bool:
    """Take the OS's exclusive lock on `fd` without waiting; False when another process holds it."""
    try:
        import fcntl
    except ImportError:  # Windows
        import msvcrt

        try:
            msvcrt.locking(fd, msvcrt.LK_NBLCK, 1)
        except OSError:
            return False
        return True
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    return True


def _lock_path(out: Path) -> Path:
    return out.parent / f".{out.name}.lock"


def _acquire(out: Path) -> int | None:
    """The descriptor holding OUT's lock, or None when another process holds it. A lock file
    that its holder removed while this process waited is not the lock any more: take it again."""
    path = _lock_path(out)
    while True:
        fd = os.open(path, os.O_CREAT | os.O_RDWR, 0o644)
        if not _try_lock(fd):
            os.close(fd)
            return None
        try:
            same = os.fstat(fd).st_ino == os.stat(path).st_ino
        except FileNotFoundError:
            same = False
        if same:
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode())
            return fd
        os.close(fd)


def _release(out: Path, fd: int) -> None:
    """Remove the lock file while still holding the lock (so nobody takes a file about to go),
    then let go of it. Windows cannot remove an open file: there the lock file stays."""
    try:
        if os.name != "nt":
            _lock_path(out).unlink(missing_ok=True)
    finally:
        os.close(fd)


def _holder(out: Path) -> str:
    try:
        pid = _lock_path(out).read_text().strip()
    except OSError:
        pid = ""
    return f"PID {pid}" if pid.isdigit() else "another process"


@contextmanager
def locked_output(out: Path, inputs: tuple[Path | None, ...] = ()) -> Iterator[Path]:
    """Hold OUT's lock for the block (a run writing OUT in place, such as a study with --resume);
    refused, naming the holder, while another run holds it. Clears what dead runs left beside OUT."""
    out = check_output_folder(out, inputs)
    out.parent.mkdir(parents=True, exist_ok=True)
    fd = _acquire(out)
    if fd is None:
        raise OutputError(f"--out {out} is being written by another run ({_holder(out)}); wait for it or "
                          "name another --out")
    try:
        _recover(out, inputs)
        clear_dead_staging(out.parent, inputs)
        yield out
    finally:
        _release(out, fd)


# --- what dead runs left ----------------------------------------------------------------------

def _recover(out: Path, inputs: tuple[Path | None, ...] = ()) -> list[Path]:
    """With OUT's lock held, what a dead run left beside OUT: a swap cut short (its journal
    `.OUT.swap-N` beside `.OUT.old-N`) gets the former OUT back if OUT is missing; a staging
    folder (its marker inside) and a finished swap's former OUT are moved to trash (removed
    after the lock is let go, so no run waits on a long delete). Nothing without boomtip's
    marker or journal is touched, and never an input. Returns the trash."""
    keep = set(_resolved(inputs))
    found: dict[str, dict[str, Path]] = {}
    for p in out.parent.iterdir():
        m = STAGING.match(p.name)
        if m and m["name"] == out.name and not p.is_symlink() and p.resolve() not in keep:
            found.setdefault(m["pid"], {})[m["kind"]] = p
    trash = []
    for pid, parts in found.items():
        journal, old, partial = parts.get("swap"), parts.get("old"), parts.get("partial")
        if journal is not None and not _is_journal(journal):
            journal = old = None  # a user's file of that name: not boomtip's swap
        if old is not None and journal is not None:
            if not out.exists() and not out.is_symlink():
                old.rename(out)
            else:
                trash.append(_to_trash(old, mark=True))
        if partial is not None and partial.is_dir() and (partial / STAGING_MARKER).is_file():
            trash.append(_to_trash(partial))
        if journal is not None:
            journal.unlink(missing_ok=True)
    return [t for t in trash if t is not None]


def _is_journal(p: Path) -> bool:
    try:
        return p.is_file() and p.read_text() == SWAP_JOURNAL
    except (OSError, UnicodeDecodeError):
        return False


def _to_trash(p: Path, mark: bool = False) -> Path | None:
    """Rename a dead run's folder (or file) to a trash name in the same folder."""
    if mark and p.is_dir():
        (p / STAGING_MARKER).touch()
    for n in range(1000):
        target = p.parent / f".boomtip-trash-{os.getpid()}-{n}"
        if not target.exists():
            try:
                p.rename(target)
            except OSError:
                return None
            return target
    return None


def _empty_trash(parent: Path) -> list[Path]:
    removed = []
    for p in parent.iterdir():
        if TRASH.match(p.name) and not p.is_symlink():
            if p.is_dir() and (p / STAGING_MARKER).is_file():
                shutil.rmtree(p, ignore_errors=True)
                removed.append(p)
            elif p.is_file():
                p.unlink(missing_ok=True)
                removed.append(p)
    return removed


def clear_dead_staging(parent: Path, inputs: tuple[Path | None, ...] = ()) -> list[Path]:
    """What dead runs left in `parent` beside any output folder whose lock nobody holds (a held
    lock means that run is alive and its folders are its own); never an input. Each lock is
    held only for renames; the deletes come after. Returns what was removed."""
    if not parent.is_dir():
        return []
    names = {m["name"] for p in parent.iterdir() if (m := STAGING.match(p.name))}
    for name in sorted(names):
        out = parent / name
        if out.resolve() in set(_resolved(inputs)):
            continue
        fd = _acquire(out)
        if fd is None:
            continue
        try:
            _recover(out, inputs)
        finally:
            _release(out, fd)
    return _empty_trash(parent)


# --- the run ----------------------------------------------------------------------------------

@contextmanager
def output_folder(out: Path, force: bool, inputs: tuple[Path | None, ...] = ()) -> Iterator[Path]:
    """A staging folder for OUT's results, moved into place when the block completes (see the
    module). Refused: a non-empty OUT without `force`, an OUT another run holds, an OUT that
    replacing could delete an input."""
    with locked_output(out, inputs) as out:
        if out.exists() and (not out.is_dir() or any(out.iterdir())) and not force:
            raise OutputError(f"--out {out} exists and is not empty; pass --force to replace it")
        staging = out.parent / f".{out.name}.partial-{os.getpid()}"
        if staging.exists():
            shutil.rmtree(staging)
        staging.mkdir()
        (staging / STAGING_MARKER).touch()
        try:
            yield staging
            _commit(staging, out)
        finally:
            if staging.exists():
                shutil.rmtree(staging, ignore_errors=True)


COMMITTED: list[Path] = []  # the output folders this process has put in place (what an interrupt leaves)


def _commit(staging: Path, out: Path) -> None:
    """Swap the finished staging folder in for OUT with Ctrl-C and SIGTERM held back (they take
    effect right after, as InterruptedAfterCommit): OUT is the old results or the new, never
    neither. A journal beside OUT marks the swap, so a run killed in it gets the former OUT
    back (_recover); should the second rename fail, the old OUT is put back at once."""
    with _signals_held() as held:
        if not out.exists() and not out.is_symlink():
            staging.rename(out)
            (out / STAGING_MARKER).unlink()
        else:
            pid = os.getpid()
            old, journal = out.parent / f".{out.name}.old-{pid}", out.parent / f".{out.name}.swap-{pid}"
            _write_synced(journal, SWAP_JOURNAL)
            out.rename(old)
            try:
                staging.rename(out)
            except BaseException:
                old.rename(out)
                journal.unlink(missing_ok=True)
                raise
            (out / STAGING_MARKER).unlink()
            trash = _to_trash(old, mark=True)  # the new results are in place; the old ones go
            journal.unlink(missing_ok=True)
            if trash is not None:
                shutil.rmtree(trash, ignore_errors=True) if trash.is_dir() else trash.unlink(missing_ok=True)
        COMMITTED.append(out)
    if held:
        raise InterruptedAfterCommit(f"signal {held[0]}")


def _write_synced(path: Path, text: str) -> None:
    fd = os.open(path, os.O_CREAT | os.O_WRONLY | os.O_TRUNC, 0o644)
    try:
        os.write(fd, text.encode())
        os.fsync(fd)
    finally:
        os.close(fd)


@contextmanager
def _signals_held() -> Iterator[list[int]]:
    """Ctrl-C and SIGTERM recorded instead of acted on for the block (yields the list they are
    recorded in). Python runs signal handlers in the main thread only, whichever thread the
    operating system gave the signal to, so swapping the handlers holds them all; outside the
    main thread nothing can be swapped and none is held."""
    import threading

    held: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield held
        return
    wanted = [sig for sig in (getattr(signal, "SIGINT", None), getattr(signal, "SIGTERM", None)) if sig is not None]
    before = {sig: signal.getsignal(sig) for sig in wanted}
    for sig in wanted:
        signal.signal(sig, lambda signum, frame: held.append(signum))
    try:
        yield held
    finally:
        for sig, handler in before.items():
            signal.signal(sig, handler)
