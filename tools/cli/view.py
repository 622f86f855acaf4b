"""`boomtip view`: a run's rerun recording in rerun's viewer, native (`--spawn`, on a display)
or in a browser (`--web`, rerun's own web viewer served on this machine, headless included)."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Callable

__all__ = ["has_display", "no_display_message", "serve_web", "ViewerError", "web_viewer_command"]

URL_LINE = re.compile(r"connect at (http://\S+\?url=\S+)")
ANSI = re.compile(r"\x1b\[[0-9;]*m")
STOP_WAIT_S = 5.0
GROUP_POLL_S = 0.05


class ViewerError(RuntimeError):
    """rerun's viewer could not be started: the message says what it printed."""


def has_display(environ=os.environ) -> bool:
    """A window can be opened: not Linux, or an X11 or Wayland display is set."""
    return not sys.platform.startswith("linux") or bool(environ.get("DISPLAY") or environ.get("WAYLAND_DISPLAY"))


def no_display_message(out: Path) -> str:
    return (f"no display here (DISPLAY and WAYLAND_DISPLAY are unset): `boomtip view {out} --web` serves the viewer to "
            "a browser instead")


def web_viewer_command(rrd: Path, port: int, grpc_port: int | None) -> list[str]:
    """rerun's web viewer on `rrd`, on this machine only (127.0.0.1); port 0: a free port; no
    grpc_port: a free one if rerun's default (9876) is taken."""
    return [sys.executable, "-m", "rerun", str(rrd), "--web-viewer", "--web-viewer-port", str(port),
            "--port", "auto" if grpc_port is None else str(grpc_port), "--bind", "127.0.0.1"]


def serve_web(rrd: Path, port: int, grpc_port: int | None, on_url: Callable[[str], None]) -> int:
    """Serve `rrd` in rerun's web viewer until interrupted (Ctrl-C, or SIGTERM as the command line
    turns it into one): `on_url(url)` once the viewer's page is up (the URL with `?url=`), then
    wait; the server is stopped on the way out. Returns the server's exit code."""
    env = {**os.environ, "NO_COLOR": "1", "RUST_LOG_STYLE": "never"}
    # its own process group: `python -m rerun` runs rerun's binary as a child of its own, and the
    # whole group is stopped on the way out
    proc = subprocess.Popen(web_viewer_command(rrd, port, grpc_port), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, env=env, start_new_session=True)
    try:
        said: list[str] = []
        for line in proc.stdout:
            line = ANSI.sub("", line)
            said.append(line.strip())
            got = URL_LINE.search(line)
            if got:
                on_url(got.group(1))
                break
        else:
            proc.wait()
            raise ViewerError(f"rerun's web viewer did not start on {rrd} (exit code {proc.returncode}): "
                              + " | ".join(s for s in said[-3:] if s))
        # keep reading what it prints, so that a full pipe never stalls it
        threading.Thread(target=lambda: [None for _ in proc.stdout], daemon=True).start()
        return proc.wait()
    finally:
        _stop_group(proc)


def _stop_group(proc: subprocess.Popen) -> None:
    """SIGTERM to the server's process group, then SIGKILL to whatever of the group is still
    there after STOP_WAIT_S: rerun's viewer binary may outlive its Python wrapper (`proc`)."""
    group = proc.pid
    _signal_group(group, signal.SIGTERM)
    deadline = time.monotonic() + STOP_WAIT_S
    while time.monotonic() < deadline:
        proc.poll()  # reaped: a zombie wrapper would keep the group alive
        if not _signal_group(group, 0):
            break
        time.sleep(GROUP_POLL_S)
    _signal_group(group, signal.SIGKILL)
    proc.wait()


def _signal_group(group: int, sig: int) -> bool:
    """Send `sig` to the process group; False when no process of it is left."""
    try:
        os.killpg(group, sig)
    except ProcessLookupError:
        return False
    return True
