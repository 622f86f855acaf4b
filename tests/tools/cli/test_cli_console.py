"""The console's feeder lines: the online figures (causal calibration) beside the offline ones,
only when kpis has them."""

from __future__ import annotations

from boomtip.tools.cli.summary import feeder_online_line, print_kpis as _print_kpis


def _feeder(online: dict | None) -> dict:
    f = {"note": "errors exclude the first 5 s", "rmse_pos_m": [0.004, 0.005, 0.002], "max_pos_m": [0.01, 0.02, 0.01],
         "rmse_rpy_deg": [0.01, 0.012, 0.02], "nees_mean": 5.5, "apt_ms": 12.0}
    if online is not None:
        f["online"] = online
    return f


ONLINE = {"calibrated_at_s": 12.0, "update_every_s": 2.0, "rmse_pos_m": [0.00412, 0.0061, 0.00234],
          "rmse_rpy_deg": [0.0114, 0.0126, 0.0215], "nees_mean": 7.254}


def test_the_online_line_gives_position_in_mm_angles_in_deg_and_nees():
    line = feeder_online_line(_feeder(ONLINE))
    assert line == "  online (causal calibration): position RMSE x/y/z 4.1 / 6.1 / 2.3 mm, angles r/p/y 0.011 / 0.013 / 0.021 deg, NEES 7.25 (6)"


def test_no_online_line_without_scored_online_figures():
    assert feeder_online_line(_feeder(None)) is None
    # a run without truth: the block has its calibration time but no figures
    assert feeder_online_line(_feeder({"calibrated_at_s": None, "update_every_s": 2.0})) is None


def test_the_console_prints_the_online_line_right_after_the_offline_one(capsys):
    kpis = {"scenario": "sts-loaded", "seed": 7, "duration_s": 60.0, "feeder": _feeder(ONLINE)}
    _print_kpis(kpis)
    lines = capsys.readouterr().out.splitlines()
    i = next(k for k, s in enumerate(lines) if s.startswith("Feeder 6-DOF"))
    assert "position RMSE x/y/z 4.0 / 5.0 / 2.0 mm" in lines[i]
    assert lines[i + 1] == feeder_online_line(kpis["feeder"])
    del kpis["feeder"]["online"]
    _print_kpis(kpis)
    assert not any("online" in s for s in capsys.readouterr().out.splitlines())


def test_without_a_terminal_a_progress_line_every_ten_seconds():
    from boomtip.tools.cli.common import progress_lines

    now = [0.0]
    said: list[str] = []
    advance = progress_lines(100, "processing", said.append, every_s=10.0, clock=lambda: now[0])
    for _ in range(30):  # 30 frames in 15 s: one line, at 10 s
        now[0] += 0.5
        advance()
    assert said == ["processing: 20/100 (20 %), 10 s, about 40 s left"]
    now[0] += 10.0
    advance(70)
    assert said[-1] == "processing: 100/100 (100 %), 25 s"
