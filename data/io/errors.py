"""The readers' and writers' one error type: its message names the file (and line or key) and
what was expected, so the command line prints it as it is, never as a traceback."""

from __future__ import annotations

__all__ = ["RecordingError"]


class RecordingError(ValueError):
    """A recording is unusable, or an output cannot be written; the message names the file (and
    line) and what was expected."""
