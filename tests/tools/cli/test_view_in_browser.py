"""`boomtip view --web` looked at in a real browser: a short ship run's recording served by rerun's
web viewer, opened in headless Chromium (Debian's, software-rasterised: `make test` installs it)
driven by playwright, until its screenshot shows the 3-D view (the crane vessel's mesh in its
class colour) and the time series (the fused D in its colour) drawn, not a blank or loading page."""

from __future__ import annotations

import os
import shutil
import time
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from boomtip.tools.cli import app
from boomtip.tools.report.classes import by_name, rgb
from boomtip.tools.report.heave import COLORS

pytestmark = pytest.mark.slow

CHROMIUM = os.environ.get("BOOMTIP_CHROMIUM", "/usr/bin/chromium")
# software rendering (no GPU here), and no background traffic to hosts a closed network refuses
CHROMIUM_ARGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--no-sandbox", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]
LOAD_TIMEOUT_S = 240.0  # the viewer's wasm takes about a minute to load on 2 cores
VIEWPORT = {"width": 1600, "height": 900}
# measured when written: the crane vessel fills ~12 % of the 3-D view, the fused D ~0.02 % of the panels
MESH_SHARE, SERIES_SHARE = 0.02, 1e-4


def _share_near(region: np.ndarray, colour: list[int], tol: int) -> float:
    """The share of the region's pixels within `tol` (sum of absolute differences) of `colour`."""
    return float((np.abs(region - np.array(colour)).sum(axis=-1) < tol).mean())


def drawn(png: Path) -> tuple[float, float]:
    """(share of the 3-D view's pixels in the crane vessel's colour, share of the series panels'
    pixels in the fused solution's colour): the blueprint puts the 3-D view left, the series right."""
    from PIL import Image

    img = np.asarray(Image.open(png).convert("RGB")).astype(int)
    h, w, _ = img.shape
    body = img[60 : h - 40]  # below the viewer's top bar, above its timeline
    left, right = body[:, : int(0.58 * w)], body[:, int(0.62 * w) :]
    return (_share_near(left, rgb(by_name("crane_vessel").colour), 30), _share_near(right, rgb(COLORS["fused"]), 40))


@pytest.fixture
def served_run(tmp_path, web_viewer) -> str:
    out = tmp_path / "run é"
    res = CliRunner().invoke(app, ["run", "-s", "sts-loaded", "--duration", "4", "--rerun", "--workers", "1", "-o", str(out)])
    assert res.exit_code == 0, res.output
    return web_viewer(out)[1]


def test_the_viewer_draws_the_3d_view_and_the_series_in_headless_chromium(served_run, tmp_path):
    from playwright.sync_api import sync_playwright

    assert shutil.which(CHROMIUM) or Path(CHROMIUM).exists(), (
        f"no Chromium at {CHROMIUM}: `make test` installs Debian's (tools/install_system_deps.sh --test)")
    shot = tmp_path / "viewer.png"
    mesh = series = 0.0
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport=VIEWPORT)
            page.goto(served_run, timeout=LOAD_TIMEOUT_S * 1000)
            deadline = time.monotonic() + LOAD_TIMEOUT_S
            while time.monotonic() < deadline:
                page.screenshot(path=str(shot))
                mesh, series = drawn(shot)
                if mesh > MESH_SHARE and series > SERIES_SHARE:
                    break
                time.sleep(5.0)
        finally:
            browser.close()
    assert mesh > MESH_SHARE and series > SERIES_SHARE, (
        f"after {LOAD_TIMEOUT_S:.0f} s the page shows no 3-D view or no series (shares {mesh:.4f}, {series:.5f}): see {shot}")


def test_a_blank_or_loading_page_does_not_pass(tmp_path):
    from PIL import Image

    for colour in ((255, 255, 255), (13, 16, 17)):  # blank; rerun's dark loading screen
        Image.new("RGB", (VIEWPORT["width"], VIEWPORT["height"]), colour).save(tmp_path / "page.png")
        mesh, series = drawn(tmp_path / "page.png")
        assert mesh < MESH_SHARE and series < SERIES_SHARE
