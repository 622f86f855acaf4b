"""The relative-heave report (tools/report/heave.py) on a tiny synthetic run whose errors are
known: 20 s of a 1.5 m, 10 s heave about 30 m; a fused estimate off the truth by +-4 mm in D and
-+10 mm/s in D-dot (alternating, so every error's magnitude is exact); deck_lidar rows +-3 mm off,
one in six invalid; doppler_radar rows 20 mm/s off. The tables carry those numbers, the
percentages of the truth's amplitude and document 000's row beside ours; the report names its
plots, which are written without a matplotlib warning."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from boomtip.data.frames import Truth
from boomtip.fusion.solutions import Estimates
from boomtip.perception.pipeline import Measurement
from boomtip.tools.report import heave
from boomtip.tools.report.heave import DOC000, kpi_table, measurement_table, write_plots, write_report
from boomtip.tools.report.kpis import measurement_kpis, solution_kpis, truth_amplitudes

T = np.arange(1000) * 0.02  # two whole periods: the mean of the sine is 0, its maximum 1 (t = 2.5 s)
D = 30.0 + 1.5 * np.sin(2 * np.pi * T / 10)
V = 1.5 * 2 * np.pi / 10 * np.cos(2 * np.pi * T / 10)
SIGN = np.where(np.arange(len(T)) % 2 == 0, 1.0, -1.0)
AMP_V = 0.3 * np.pi  # 1.5 m x 2 pi / 10 s
TABLE_HEAD = 2  # header and rule


def truth() -> Truth:
    return Truth({"t": T, "D": D, "D_dot": V})


def estimates(name: str = "fused") -> dict[str, Estimates]:
    x = np.column_stack([D + 0.004 * SIGN, V - 0.010 * SIGN, np.zeros(len(T))])
    return {name: Estimates(name, T, x, np.full((len(T), 3), 1e-6), 2.0, 100, {"ok": 100})}


def rows(radar: bool = True) -> list[Measurement]:
    out = [Measurement(float(t), "deck_lidar", "D", float(d + 0.003 * s), 0.01, 1.5, "ok")
           for t, d, s in zip(T[::10], D[::10], SIGN[::2])]
    out += [Measurement(float(t), "deck_lidar", "D", float("nan"), float("nan"), 0.5, "no plane: 4 points") for t in T[5::50]]
    if radar:
        out += [Measurement(float(t), "doppler_radar", "D_dot", float(v + 0.02), 0.01, 0.7, "ok") for t, v in zip(T[::20], V[::20])]
    return out


def kpis(name: str = "fused", radar: bool = True) -> dict:
    tr, est, r = truth(), estimates(name), rows(radar)
    return {"scenario": "synthetic", "seed": 3, "duration_s": 20.0, "warnings": ["a note from the chain"],
            "measurements": measurement_kpis(r, tr),
            "sources": {name: {"D": ["deck_lidar"], "D_dot": ["doppler_radar"] if radar else []}},
            "solutions": {name: solution_kpis(est[name], tr, r, ("deck_lidar",))},
            "truth_max_amplitude": truth_amplitudes(tr)}


def cells(table: str, row: int) -> list[str]:
    return [c.strip() for c in table.splitlines()[TABLE_HEAD + row].strip("|").split("|")]


def test_the_synthetic_truth_has_the_amplitudes_the_percentages_use():
    amp = truth_amplitudes(truth())
    assert amp["D_m"] == pytest.approx(1.5, rel=1e-12) and amp["D_dot_mps"] == pytest.approx(AMP_V, rel=1e-12)


def test_kpi_table_rows_are_the_solutions_with_their_errors_and_percentages():
    table = kpi_table(kpis())
    assert len(table.splitlines()) == TABLE_HEAD + 1
    # 4 mm of 1.5 m = 0.27 %; 10 mm/s of 0.942 m/s = 1.06 %; APT: 1.5 ms of perception per
    # deck_lidar frame (100 ok, 20 not: 120 cycles, 100 x 1.5 + 20 x 0.5 = 160 ms) plus 2 ms of
    # filter: 162 / 120 = 1.35 ms; no fused row in document 000
    assert cells(table, 0) == ["fused", "4.0 (0.27 %)", "4.0 (0.27 %)", "10.0 (1.06 %)", "10.0 (1.06 %)", "1.35",
                               "not built", "not built", "-"]


def test_kpi_table_puts_document_000s_row_beside_ours():
    table = kpi_table(kpis("deck_lidar"))
    doc = DOC000["deck_lidar"]
    assert (doc["mae_D"], doc["max_D"], doc["mae_V"], doc["max_V"], doc["apt"]) == (0.010, 0.045, 0.048, 0.225, 91.7)
    # document 000's percentages are of its own amplitudes, 3.06 m and 2.3 m/s
    assert cells(table, 0)[6:] == ["10.0 (0.33 %) / 45.0", "48.0 (2.09 %) / 225.0", "91.7"]
    k = kpis("doppler_radar")
    assert cells(kpi_table(k), 0)[6] == "159.0 (5.20 %) / -"  # document 000 gave no max D for Doppler


def test_kpi_table_marks_a_missing_number_with_a_dash():
    k = kpis()
    k["solutions"]["fused"].update(mae_D_m=float("nan"), max_D_m=None)
    assert cells(kpi_table(k), 0)[1:3] == ["-", "-"]
    assert kpi_table({}).splitlines()[TABLE_HEAD:] == []  # no solutions, no rows


def test_measurement_table_rows_are_the_methods_with_their_raw_errors():
    table = measurement_table(kpis())
    assert len(table.splitlines()) == TABLE_HEAD + 2
    # 120 deck_lidar frames, 100 ok: 83.3 %; APT the mean time of every frame, (150 + 10) / 120 ms
    assert cells(table, 0) == ["deck_lidar", "D", "3.0 mm", "3.0 mm", "1.33", "83.3 %"]
    assert cells(table, 1) == ["doppler_radar", "D_dot", "20.0 mm/s", "20.0 mm/s", "0.70", "100.0 %"]


def test_measurement_table_without_truth_has_no_errors():
    k = {"measurements": measurement_kpis(rows(), None)}
    assert cells(measurement_table(k), 0) == ["deck_lidar", "D", "- mm", "- mm", "1.33", "83.3 %"]


def test_the_report_names_the_run_its_sources_and_its_plots(tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        write_report(tmp_path, kpis(), estimates(), truth(), rows())
    text = (tmp_path / "report.md").read_text()
    lines = text.splitlines()
    assert lines[0] == "# boomtip relative-heave report: synthetic (seed 3, 20 s)"
    assert "**Warning:** a note from the chain" in lines
    assert "Sources: fused: D from deck_lidar, D-dot from doppler_radar" in lines
    assert "truth's maximum amplitude: here 1.50 m for D and 0.94 m/s for D-dot" in text
    assert kpi_table(kpis()) in text and measurement_table(kpis()) in text
    plots = ["heave_D", "heave_D_dot", "error_histograms", "measurements"]
    assert [line for line in lines if line.startswith("![")] == [f"![{p}](plots/{p}.png)" for p in plots]
    for p in plots:
        assert (tmp_path / "plots" / f"{p}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(f.name for f in tmp_path.iterdir()) == ["plots", "report.md"]
    assert sorted(f.name for f in (tmp_path / "plots").iterdir()) == sorted(f"{p}.png" for p in plots)


def test_a_solution_without_d_dot_sources_says_it_takes_d_dot_from_d(tmp_path, monkeypatch):
    monkeypatch.setattr(heave, "write_plots", lambda out, *args: [])  # the text only (the plots: the test below)
    k = kpis(radar=False)
    write_report(tmp_path, k, estimates(), truth(), rows(radar=False))
    assert "Sources: fused: D from deck_lidar, D-dot from D" in (tmp_path / "report.md").read_text().splitlines()


def test_plots_of_a_lidar_only_run_raise_no_warning(tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        write_plots(tmp_path, estimates(), truth(), rows(radar=False))
