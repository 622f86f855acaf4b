"""`boomtip view --web` started as a user starts it, for the tests that look at what it serves."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import pytest

from boomtip.tools.cli.view import URL_LINE


@pytest.fixture
def web_viewer():
    """start(folder) -> (the server's process, the viewer page's URL with `?url=`); every server
    started is stopped after the test as a user stops it (SIGTERM; killed if it does not stop)."""
    started: list[subprocess.Popen] = []

    def start(folder: Path) -> tuple[subprocess.Popen, str]:
        cmd = [sys.executable, "-c", "from boomtip.tools.cli import main; main()", "view", str(folder), "--web", "--port", "0"]
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        started.append(proc)
        line = proc.stdout.readline()
        url = URL_LINE.search("connect at " + line.split(": ", 1)[-1])
        assert url, f"no URL in {line!r}"
        return proc, url.group(1)

    yield start
    for proc in started:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=30)

