"""The report of a run without truth (tools/report/estimates.py): per solution where D and D-dot
came from, the range of D and the median sigmas; per method its frames, valid fraction, time and
why frames were not valid; the gaps in the LiDAR, radar and MRU streams. On a synthetic run whose
every number is known."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from boomtip.data.frames import MruLog
from boomtip.fusion.solutions import Estimates
from boomtip.perception.pipeline import Measurement
from boomtip.tools.report.estimates import method_table, stream_gaps, write_estimates_report

RATES = {"lidar": 10.0, "radar": 20.0}
LIDAR_K = [*range(0, 30), *range(40, 100)]  # LiDAR frames at k / 10 s: none from 2.9 s to 4.0 s
MRU_K = [*range(0, 500), *range(600, 1000)]  # MRU at k / 100 s: none from 4.99 s to 6.0 s
NO_PLANE = "no plane: 3 points within the band"


def lidar_rows() -> list[Measurement]:
    """90 deck_lidar frames of 2 ms: every 4th without a plane, the 6th and 7th levelled by no MRU."""
    out = []
    for i, k in enumerate(LIDAR_K):
        status = NO_PLANE if i % 4 == 0 else "no attitude" if i in (6, 7) else "ok"
        out.append(Measurement(k / 10, "deck_lidar", "D", 30.0, 0.01, 2.0, status))
    return out


def radar_rows(methods=("deck_radar", "doppler_radar")) -> list[Measurement]:
    return [Measurement(k / 20, m, "D" if m == "deck_radar" else "D_dot", 0.1, 0.01, 1.0 if m == "deck_radar" else 0.5, "ok")
            for k in range(200) for m in methods]


def mru() -> MruLog:
    t = np.array(MRU_K) / 100
    return MruLog(t, np.zeros((len(t), 3)), np.zeros((len(t), 3)))


def estimates() -> dict[str, Estimates]:
    t = np.arange(100) / 10
    k = np.arange(100)
    x = np.column_stack([30.0 + 0.25 * ((k % 8) - 2), 0.1 * np.ones(100), np.zeros(100)])  # D from 29.5 to 31.25
    var = np.column_stack([np.full(100, 0.002**2), np.full(100, 0.005**2), np.zeros(100)])
    lidar = x.copy()
    lidar[:40] = np.nan  # no estimate before its first fix
    lidar[40:, 0] = 31.0
    none = np.full_like(x, np.nan)
    return {"fused": Estimates("fused", t, x, var, 1.0, 10, {}),
            "deck_lidar": Estimates("deck_lidar", t, lidar, 4 * var, 1.0, 10, {}),
            "doppler_radar": Estimates("doppler_radar", t, none, var, 1.0, 0, {})}


KPIS = {"scenario": "recorded-run", "duration_s": 10.0, "warnings": ["the loader assumed a level boom tip"],
        "sources": {"fused": {"D": ["deck_lidar", "deck_radar"], "D_dot": ["doppler_radar"]},
                    "deck_lidar": {"D": ["deck_lidar"], "D_dot": []}}}


def cells(line: str) -> list[str]:
    return [c.strip() for c in line.strip("|").split("|")]


# ---------------------------------------------------------------------------------------
# Pieces


def test_stream_gaps_are_the_intervals_longer_than_one_and_a_half_periods():
    t = np.array([0.0, 0.1, 0.2, 0.5, 0.6, 0.7, 1.0, 1.1])
    assert stream_gaps(t, 0.1) == [(0.2, 0.5), (0.7, 1.0)]
    assert stream_gaps(t, 0.1, factor=3.5) == []  # 0.3 s is not beyond 3.5 periods
    assert stream_gaps(np.array([0.0, 0.1, 0.26]), 0.1) == [(0.1, 0.26)]  # 1.6 periods
    assert stream_gaps(np.array([0.0, 0.1, 0.25]), 0.1) == []  # 1.5 periods exactly: not a gap
    assert stream_gaps(np.array([0.3, 0.0, 0.1]), 0.1) == [(0.1, 0.3)]  # in time order
    assert stream_gaps(np.array([1.0]), 0.1) == [] and stream_gaps(np.zeros(0), 0.1) == []


def test_method_table_counts_frames_valid_fraction_time_and_reasons():
    r = lidar_rows() + radar_rows()
    lines = method_table(r)
    assert lines[:2] == ["| method | frames | valid | APT [ms] | why not valid (frames) |", "|---|---|---|---|---|"]
    # 90 frames: 23 without a plane (every 4th), 2 without attitude: 65 valid, 72.2 %; the reason
    # is the status up to its first colon, the most frequent first
    assert cells(lines[2]) == ["deck_lidar", "90", "72.2 %", "2.00", "no plane (23); no attitude (2)"]
    assert cells(lines[3]) == ["deck_radar", "200", "100.0 %", "1.00", "-"]
    assert cells(lines[4]) == ["doppler_radar", "200", "100.0 %", "0.50", "-"]
    assert len(lines) == 5


def test_method_table_keeps_the_four_most_frequent_reasons_cut_to_80_characters():
    long = "x" * 100
    statuses = ["a"] * 5 + ["b"] * 4 + ["c"] * 3 + ["d"] * 2 + ["e"] + [long] * 6
    r = [Measurement(i / 10, "deck_lidar", "D", 1.0, 0.1, 1.0, s) for i, s in enumerate(statuses)]
    assert cells(method_table(r)[2])[4] == f"{'x' * 80} (6); a (5); b (4); c (3)"


# ---------------------------------------------------------------------------------------
# The report


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    out = tmp_path_factory.mktemp("estimates")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the plot draws without a matplotlib warning
        written = write_estimates_report(out, KPIS, estimates(), lidar_rows() + radar_rows(), mru(), RATES)
    return out, written, (out / "report.md").read_text().splitlines()


def test_the_report_says_it_has_no_truth(report):
    out, written, lines = report
    assert written == ["report.md", "plots"]
    assert (out / "plots" / "estimates.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert lines[0] == "# boomtip relative-heave report: recorded-run (10 s, no truth)"
    assert "**Warning:** the loader assumed a level boom tip" in lines
    assert "No truth came with this recording: this report says what was estimated, not how well." in lines
    assert lines[-1] == "![estimates](plots/estimates.png)"


def test_the_solutions_table_gives_sources_range_and_sigmas(report):
    _, _, lines = report
    i = lines.index("## Solutions")
    assert lines[i + 2].startswith("Lost: the share of the estimates")
    table = lines[i + 4 : lines.index("## Measurements") - 1]
    assert table[0] == ("| solution | D from | D-dot from | D range [m] | median sigma D [mm] | "
                        "median sigma D-dot [mm/s] | lost |")
    assert [cells(row) for row in table[2:]] == [
        ["fused", "deck_lidar, deck_radar", "doppler_radar", "29.500 to 31.250", "2.00", "5.00", "-"],
        # no D-dot source: D-dot from D; the range and sigmas over its finite rows only
        ["deck_lidar", "deck_lidar", "D", "31.000 to 31.000", "4.00", "10.00", "-"],
        # doppler_radar estimated nothing (all NaN) and has no sources entry: no row
    ]


def test_the_measurements_section_is_the_method_table(report):
    _, _, lines = report
    i = lines.index("## Measurements")
    assert lines[i + 2 : i + 7] == method_table(lidar_rows() + radar_rows())


def test_the_gaps_section_lists_each_streams_frames_and_gaps(report):
    _, _, lines = report
    i = lines.index("## Gaps in the streams")
    assert lines[i + 2 : i + 5] == [
        "- lidar: 90 frames, 1 gaps; 2.90-4.00 s",
        "- radar: 200 frames, 0 gaps",  # two methods per radar frame: counted once
        "- MRU: 900 samples, 1 gaps; 4.99-6.00 s",  # nominal period: the MRU's median spacing
    ]


def test_a_stream_without_rows_is_left_out(tmp_path):
    write_estimates_report(tmp_path, KPIS, estimates(), lidar_rows(), mru(), RATES)
    lines = (tmp_path / "report.md").read_text().splitlines()
    gaps = [line for line in lines if line.startswith("- ")]
    assert gaps == ["- lidar: 90 frames, 1 gaps; 2.90-4.00 s", "- MRU: 900 samples, 1 gaps; 4.99-6.00 s"]


def test_at_most_ten_gaps_are_listed_per_stream(tmp_path):
    k = [k for k in range(100) if k % 4 != 1]  # one frame in every 4 missing: 25 gaps
    r = [Measurement(i / 10, "deck_lidar", "D", 30.0, 0.01, 2.0, "ok") for i in k]
    write_estimates_report(tmp_path, KPIS, estimates(), r, mru(), RATES)
    (line,) = [line for line in (tmp_path / "report.md").read_text().splitlines() if line.startswith("- lidar")]
    assert line.startswith("- lidar: 75 frames, 25 gaps; 0.00-0.20 s; 0.40-0.60 s")
    assert line.count("; ") == 10


def test_a_radar_run_of_doppler_radar_rot_alone_reports_its_stream(tmp_path):
    write_estimates_report(tmp_path, KPIS, estimates(), lidar_rows() + radar_rows(("doppler_radar_rot",)), mru(), RATES)
    assert "- radar: 200 frames, 0 gaps" in (tmp_path / "report.md").read_text().splitlines()


# ---------------------------------------------------------------------------------------
# Without truth: what was estimated, in kpis.json and on the console


def test_a_solution_without_truth_says_its_range_sigmas_and_last_estimate():
    from boomtip.tools.report.kpis import estimated_kpis

    e = estimated_kpis(estimates()["fused"])
    assert e["estimates"] == 100 and e["D_min_m"] == 29.5 and e["D_max_m"] == 31.25
    assert e["median_sigma_D_m"] == pytest.approx(0.002) and e["median_sigma_D_dot_mps"] == pytest.approx(0.005)
    assert e["last_t_s"] == pytest.approx(9.9) and e["last_D_m"] == 30.0 + 0.25 * (99 % 8 - 2)
    assert estimated_kpis(estimates()["doppler_radar"]) == {"estimates": 0}


def test_measurements_without_truth_say_what_they_measured():
    from boomtip.tools.report.kpis import measurement_kpis

    k = measurement_kpis(lidar_rows() + radar_rows(), None)
    assert k["deck_lidar"]["median"] == 30.0 and k["deck_lidar"]["median_sigma"] == 0.01 and "mae" not in k["deck_lidar"]


def test_the_feeders_motion_without_truth_is_its_spread_and_sigma():
    from types import SimpleNamespace

    from boomtip.tools.report.feeder import estimated_motion, estimated_motion_line

    t = np.arange(200) / 10
    pose = np.zeros((200, 6))
    pose[:, 2] = 0.5 * np.sin(t)  # heave
    pose[:, 3] = np.radians(2.0) * np.where(np.arange(200) % 2, 1.0, -1.0)  # roll +-2 deg: std 2 deg
    var = np.full((200, 12), 0.01**2)
    var[:, 3:6] = np.radians(0.1) ** 2
    warm = t >= 5.0
    e = estimated_motion(SimpleNamespace(pose=pose, var=var, t_s=t), warm)
    assert e["samples"] == 150 and e["std"][3] == pytest.approx(2.0) and e["median_sigma"][0] == pytest.approx(0.01)
    assert e["std"][2] == pytest.approx(np.std(0.5 * np.sin(t[warm])), abs=1e-5)
    line = estimated_motion_line(e)
    assert "r/p/y 2.00 / 0.00 / 0.00 deg" in line and "median sigma x/y/z 10 / 10 / 10 mm" in line
    assert estimated_motion_line({"samples": 0}) is None


def test_a_doppler_only_solution_keeps_its_d_dot_when_its_d_is_lost():
    from boomtip.fusion.solutions import FusionConfig, lost_estimates
    from boomtip.tools.report.kpis import estimated_kpis

    e = estimates()["fused"]
    var = e.var.copy()
    var[:, 0] = 2.0**2  # D from the start only: sigma 2 m
    x = e.x.copy()
    x[:, 1] = np.linspace(-0.5, 0.8, len(x))
    doppler = Estimates("doppler_radar", e.t_s, x, var, 1.0, 10, {}, lost_estimates(x, var, FusionConfig()))
    k = estimated_kpis(doppler)
    assert k["lost_fraction"] == 1.0 and "D_min_m" not in k
    assert k["D_dot_abs_max_mps"] == pytest.approx(0.8) and k["median_sigma_D_dot_mps"] == pytest.approx(0.005)
