"""rerun recordings (tools/report/recording) read back with rerun's own reader (rerun.chunk.RrdReader,
rerun-sdk 0.41; `rerun rrd verify` for the file as a whole): which entities a heave and a hook
logger write in the convention's roots, the clouds in the levelled boom-tip frame, the full LiDAR
cloud once a second and the points around the wire in between, the series with their NaN rows
dropped and their 3-sigma bands, and the errors against the truth, value for value."""

from __future__ import annotations

import subprocess
import sys
import types
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
from rerun.chunk import RrdReader

from boomtip.data.frames import Frame, SourceMeta, Truth
from boomtip.data.installation import Installation
from boomtip.fusion.solutions import Estimates
from boomtip.perception.deck import DeckResult
from boomtip.perception.pipeline import FrameResult
from boomtip.perception.timing import StageTimes
from boomtip.tools.report.classes import CLASSES
from boomtip.tools.report.recording.convention import TIMELINE
from boomtip.tools.report.recording.heave import RerunLogger
from boomtip.tools.report.recording.hook import HookRerunLogger

INSTALLATION = Installation()
T = np.arange(10) / 10  # the series' times, 0 to 0.9 s
R_LEVEL = np.eye(3)  # a level sensor: the levelled frame differs from the sensor's by the tip offset only
# the default LiDAR mount: the tip in sensor coordinates, -R^T t
T_LIDAR = INSTALLATION.T_boomtip_sensor()["lidar"]
TIP_IN_LIDAR = -T_LIDAR[:3, :3].T @ T_LIDAR[:3, 3]
LIDAR_PTS = np.array([[0.0, 0.0, -30.0], [20.0, 0.0, -30.0], [1.0, 1.0, -29.0], [3.0, -5.0, -29.5]])


def read(path: Path) -> dict[str, list]:
    """Entity path -> its chunks (static and temporal) in the recording store of an .rrd."""
    out: dict[str, list] = {}
    for chunk in RrdReader(path).stream().to_chunks():
        out.setdefault(chunk.entity_path, []).append(chunk)
    return out


def temporal(chunks: dict, entity: str, column: str) -> tuple[np.ndarray, list]:
    """(times in ns on the sensor timeline, the column's rows) of an entity's temporal chunks."""
    times, rows = [], []
    for c in chunks[entity]:
        if c.is_static:
            continue
        rb = c.to_record_batch()
        times += rb.column(TIMELINE).cast(pa.int64()).to_pylist()
        rows += rb.column(column).to_pylist()
    order = np.argsort(times, kind="stable")
    return np.array(times)[order], [rows[i] for i in order]


def lidar_frame(index: int, t_s: float) -> FrameResult:
    f = Frame("lidar", index, t_s, LIDAR_PTS.copy(), {"intensity": np.array([1.0, 2.0, 3.0, 4.0])})
    return FrameResult(f, [], StageTimes(), extras={"R_level_sensor": R_LEVEL})


@pytest.fixture(scope="module")
def heave_rrd(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("rerun") / "heave.rrd"
    logger = RerunLogger(path, types.SimpleNamespace(meta=SourceMeta(INSTALLATION, 1.0)))
    res = lidar_frame(0, 0.0)
    res.deck_lidar = DeckResult(30.0, np.array([0.0, 0.0, 1.0, 30.0]), None, LIDAR_PTS, "ok")
    logger.log_frame(res)
    logger.log_frame(lidar_frame(1, 0.5))  # within a second of the full cloud: the wire's surroundings only
    logger.log_frame(lidar_frame(2, 1.0))  # a second later: the full cloud again
    radar = Frame("radar", 0, 0.05, np.array([[0.0, 0.0, -30.0], [2.0, 0.0, -30.0]]), {"range_rate": np.array([0.1, -0.2])})
    logger.log_frame(FrameResult(radar, [], StageTimes(), extras={"R_level_sensor": R_LEVEL}))
    logger.log_frame(FrameResult(Frame("lidar", 3, 1.5, np.zeros((0, 3))), [], StageTimes(), extras={"R_level_sensor": R_LEVEL}))
    truth = Truth({"t": T, "D": 30.0 + T, "D_dot": np.ones(10)})
    fused = np.column_stack([30.0 + T + 0.001 * np.arange(10), np.ones(10), np.zeros(10)])
    fused[3] = np.nan
    doppler = np.column_stack([30.0 + 2 * T, 1.5 * np.ones(10), np.zeros(10)])
    logger.log_estimates({"fused": Estimates("fused", T, fused, np.ones((10, 3)), 0.0, 0, {}),
                          "doppler_radar": Estimates("doppler_radar", T, doppler, np.ones((10, 3)), 0.0, 0, {})}, truth)
    logger.close()
    return path


def test_the_file_verifies_with_the_rerun_cli(heave_rrd):
    exe = Path(sys.executable).with_name("rerun")  # rerun-sdk installs its CLI beside the interpreter
    r = subprocess.run([str(exe), "rrd", "verify", str(heave_rrd)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr


def test_one_recording_and_its_blueprint(heave_rrd):
    reader = RrdReader(heave_rrd)
    (rec,) = reader.recordings()
    assert rec.application_id == "boomtip"
    assert len(reader.blueprints()) == 1  # the default layout travels with the data


def test_the_heave_recording_has_these_entities(heave_rrd):
    band = {"", "/sigma3_high", "/sigma3_low"}
    series = ({f"/estimates/fused/{q}{b}" for q in ("D", "D_dot") for b in band} | {"/estimates/doppler_radar/D_dot"}
              | {"/truth/D", "/truth/D_dot"} | {f"/truth/error_D_mm/fused{b}" for b in band})
    deck = {f"/detections/deck_lidar/{e}" for e in ("plane", "wire", "p_d")}
    expected = {"/__properties", "/", "/world/boom_tip", "/sensors/lidar", "/sensors/radar", "/detections/reflectors_lidar",
                "/detections/deck_lidar", "/detections/deck_radar", "/estimates/fused/deck_point"} | deck | series
    # no D nor error series for doppler_radar (its D drifts by design); no deck inliers without a fit;
    # the stages that found nothing in a frame are cleared (their roots)
    assert set(read(heave_rrd)) == expected


def test_one_annotation_context_names_every_class(heave_rrd):
    (chunk,) = [c for c in read(heave_rrd)["/"] if "AnnotationContext:context" in c.to_record_batch().schema.names]
    (context,) = chunk.to_record_batch().column("AnnotationContext:context").to_pylist()[0]
    rgba = [(int(c.colour[1:], 16) << 8) | 0xFF for c in CLASSES]  # rerun packs a colour as 0xRRGGBBAA
    assert [(a["class_id"], a["class_description"]["info"]["label"], a["class_description"]["info"]["color"])
            for a in context] == [(c.id, c.label, x) for c, x in zip(CLASSES, rgba)]


def test_lidar_points_are_levelled_at_the_tip_the_full_cloud_once_a_second(heave_rrd):
    times, rows = temporal(read(heave_rrd), "/sensors/lidar", "Points3D:positions")
    assert times.tolist() == [0, 500_000_000, 1_000_000_000]  # the empty frame at 1.5 s logs nothing
    level = LIDAR_PTS - TIP_IN_LIDAR
    near = np.einsum("ij,ij->i", level[:, :2], level[:, :2]) < 4.0**2
    assert near.tolist() == [True, False, True, False]  # 20 m and 5.8 m out are beyond the wire's 4 m
    for got, want in zip(rows, (level, level[near], level)):
        assert np.allclose(np.array(got), want, rtol=1e-7, atol=0)  # stored as float32


def test_the_radar_frame_is_logged_whole(heave_rrd):
    times, rows = temporal(read(heave_rrd), "/sensors/radar", "Points3D:positions")
    T_radar = INSTALLATION.T_boomtip_sensor()["radar"]
    tip = -T_radar[:3, :3].T @ T_radar[:3, 3]
    assert times.tolist() == [50_000_000]
    assert np.allclose(np.array(rows[0]), np.array([[0.0, 0.0, -30.0], [2.0, 0.0, -30.0]]) - tip, rtol=1e-7, atol=0)


def test_the_deck_is_drawn_at_minus_d_with_its_label(heave_rrd):
    chunks = read(heave_rrd)
    _, pd = temporal(chunks, "/detections/deck_lidar/p_d", "Points3D:positions")
    _, labels = temporal(chunks, "/detections/deck_lidar/p_d", "Points3D:labels")
    assert pd == [[[0.0, 0.0, -30.0]]] and labels == [["D = 30.000 m"]]
    _, quad = temporal(chunks, "/detections/deck_lidar/plane", "Mesh3D:vertex_positions")
    assert np.allclose(np.array(quad[0])[:, 2], -30.0)  # a level deck: every corner at -D
    assert np.ptp(np.array(quad[0])[:, 0]) == pytest.approx(90.0) and np.ptp(np.array(quad[0])[:, 1]) == pytest.approx(24.0)


def test_the_series_drop_nan_rows_and_keep_every_value(heave_rrd):
    chunks = read(heave_rrd)
    ns = np.round(T * 1e9).astype(np.int64)
    ok = np.arange(10) != 3
    t, v = temporal(chunks, "/truth/D", "Scalars:scalars")
    assert t.tolist() == ns.tolist() and [x[0] for x in v] == (30.0 + T).tolist()
    D = (30.0 + T + 0.001 * np.arange(10))[ok]
    t, v = temporal(chunks, "/estimates/fused/D", "Scalars:scalars")
    assert t.tolist() == ns[ok].tolist() and [x[0] for x in v] == D.tolist()
    for side, sign in (("high", 1), ("low", -1)):  # var 1 m^2: the band 3 m either side
        t, v = temporal(chunks, f"/estimates/fused/D/sigma3_{side}", "Scalars:scalars")
        assert t.tolist() == ns[ok].tolist() and np.allclose([x[0] for x in v], D + sign * 3.0, rtol=0, atol=1e-12)
    t, v = temporal(chunks, "/truth/error_D_mm/fused", "Scalars:scalars")
    assert t.tolist() == ns[ok].tolist()
    assert np.allclose([x[0] for x in v], np.arange(10)[ok], rtol=0, atol=1e-9)  # (estimate - truth) in mm
    _, v = temporal(chunks, "/estimates/doppler_radar/D_dot", "Scalars:scalars")
    assert [x[0] for x in v] == [1.5] * 10


def test_the_fused_deck_point_carries_its_3_sigma_ellipsoid(heave_rrd):
    t, centers = temporal(read(heave_rrd), "/estimates/fused/deck_point", "Ellipsoids3D:centers")
    _, half = temporal(read(heave_rrd), "/estimates/fused/deck_point", "Ellipsoids3D:half_sizes")
    ok = np.arange(10) != 3
    assert t.tolist() == np.round(T[ok] * 1e9).astype(np.int64).tolist()  # 10 Hz: every sample of this series
    assert np.allclose([c[0][2] for c in centers], -(30.0 + T + 0.001 * np.arange(10))[ok], rtol=1e-6)
    assert np.allclose([h[0][2] for h in half], 3.0)  # 3 sigma of D, sigma 1 m


# ---------------------------------------------------------------------------------------
# The hook run


@pytest.fixture(scope="module")
def hook_rrd(tmp_path_factory) -> tuple[Path, np.ndarray, np.ndarray]:
    path = tmp_path_factory.mktemp("rerun") / "hook.rrd"
    logger = HookRerunLogger(path, types.SimpleNamespace(meta=SourceMeta(INSTALLATION, 1.0)))
    t = np.arange(5) / 20
    est = np.column_stack([0.1 * np.arange(5), np.zeros(5), -20.0 - 0.01 * np.arange(5)])
    est[2] = np.nan
    true = est.copy()
    true[np.isfinite(est[:, 0])] += [0.01, -0.02, 0.03]
    logger.log_hook_tracks(t, est, true, "ekf_flexible", np.broadcast_to(np.diag([1e-4, 4e-4, 9e-4]), (5, 3, 3)))
    logger.close()
    return path, est, true


def test_the_hook_recording_has_these_entities(hook_rrd):
    path, _, _ = hook_rrd
    assert RrdReader(path).recordings()[0].application_id == "boomtip-hook"
    est = "/estimates/ekf_flexible/hook"
    assert set(read(path)) == {"/__properties", "/", "/world/boom_tip", f"{est}/rope", f"{est}/position", f"{est}/trail",
                               f"{est}/sigma3", "/truth/hook/position", "/truth/hook/trail",
                               *(f"/truth/error_cm/{a}{b}" for a in "xyz" for b in ("", "/sigma3_high", "/sigma3_low"))}


def test_hook_errors_are_estimate_minus_truth_in_cm(hook_rrd):
    path, est, true = hook_rrd
    chunks = read(path)
    ok = np.isfinite(est[:, 0])
    for i, axis in enumerate("xyz"):
        t, v = temporal(chunks, f"/truth/error_cm/{axis}", "Scalars:scalars")
        assert t.tolist() == [k * 50_000_000 for k in range(5) if ok[k]]
        assert np.allclose([x[0] for x in v], ((est - true) * 100)[ok, i], rtol=0, atol=1e-9)
        assert np.allclose([x[0] for x in v], [-1.0, 2.0, -3.0][i], rtol=0, atol=1e-9)
    t, pts = temporal(chunks, "/estimates/ekf_flexible/hook/position", "Points3D:positions")
    assert len(pts) == 4  # a NaN estimate is not drawn
    assert np.allclose(np.array([p[0] for p in pts]), est[ok], rtol=1e-7, atol=0)
