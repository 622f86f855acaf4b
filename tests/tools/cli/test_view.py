"""`boomtip view`: --web serves rerun's web viewer headless and stops it on SIGTERM; --spawn
without a display says so in one line."""

from __future__ import annotations

import signal
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest
from typer.testing import CliRunner

from boomtip.tools.cli import app
from boomtip.tools.cli.view import has_display


def _recording(folder):
    import rerun as rr

    folder.mkdir(parents=True, exist_ok=True)
    rec = rr.RecordingStream("boomtip-test")
    rec.save(str(folder / "boomtip.rrd"))
    rec.log("world/points", rr.Points3D([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]))
    rec.flush()
    rec.disconnect()
    return folder


def test_a_display_is_an_x11_or_wayland_one_on_linux(monkeypatch):
    monkeypatch.setattr(sys, "platform", "linux")
    assert not has_display({})
    assert has_display({"DISPLAY": ":0"}) and has_display({"WAYLAND_DISPLAY": "wayland-0"})


def test_spawn_without_a_display_says_so_in_one_line_and_points_to_web(tmp_path, monkeypatch):
    out = _recording(tmp_path / "run with spaces é")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(sys, "platform", "linux")
    res = CliRunner().invoke(app, ["view", str(out), "--spawn"])
    assert res.exit_code == 2
    lines = [s for s in res.output.splitlines() if s.strip()]
    assert len(lines) == 1 and "no display here" in lines[0] and "--web" in lines[0]


def processes_with(text: str) -> list[int]:
    """The processes whose command line holds `text` (e.g. a recording's folder)."""
    found = []
    for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
        try:
            if text.encode() in cmdline.read_bytes():
                found.append(int(cmdline.parent.name))
        except OSError:  # gone meanwhile
            continue
    return found


def test_web_serves_the_viewer_page_and_stops_on_sigterm(tmp_path, web_viewer):
    proc, url = web_viewer(_recording(tmp_path / "run with spaces é"))
    page = url.split("?")[0]
    with urllib.request.urlopen(page, timeout=10) as resp:
        assert resp.status == 200
        assert "rerun" in resp.read().decode("utf-8", "replace").lower()
    folder = tmp_path / "run with spaces é"
    assert processes_with(str(folder))  # rerun's server, its viewer binary among them
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=15) == 130
    time.sleep(0.5)
    with pytest.raises(urllib.error.URLError):  # the server went with it
        urllib.request.urlopen(page, timeout=2)
    assert processes_with(str(folder)) == []  # every process of it: none outlives the command