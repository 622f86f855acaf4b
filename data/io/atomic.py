"""Files written atomically: through a temporary file in the same folder, renamed into place when
complete, so a reader never sees half a file and a failure leaves none."""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from typing import IO, Iterator

__all__ = ["atomic_text_file", "atomic_write_bytes"]

_UMASK = os.umask(0)  # read once: outputs get the usual permissions (mkstemp makes 0600)
os.umask(_UMASK)


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write `data` to `path` atomically."""
    with _atomic(Path(path), "wb") as fh:
        fh.write(data)


@contextlib.contextmanager
def atomic_text_file(path: Path) -> Iterator[IO[str]]:
    """A text file written in pieces (a long run's table is never whole in memory), atomically."""
    with _atomic(Path(path), "w", encoding="utf-8", newline="") as fh:  # UTF-8 and "\n" whatever the locale
        yield fh


@contextlib.contextmanager
def _atomic(path: Path, mode: str, **text) -> Iterator[IO]:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, mode, **text) as fh:
            yield fh
        os.chmod(tmp, 0o666 & ~_UMASK)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
