"""The relative-heave chain: frames -> D and D-dot measurements (perception) -> the
solutions' estimates (fusion). Built from the installation and the processing settings.

OUT/measurements.csv   t, method, quantity, value, time_ms, status, sigma
OUT/estimates.csv      t, solution, D, D_dot, D_ddot, var_D, var_D_dot, status (ok, or why it is lost)
kpis.json              measurements.<method> and, with truth, solutions.<solution>; without, estimated.<solution>
OUT/report.md + plots  Table 5.4 layout beside document 000 (tools/report.py)
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from boomtip.data.frames import Frame, FrameSource, Truth
from boomtip.data.io.atomic import atomic_text_file
from boomtip.tools.config.processing import Processing
from boomtip.fusion.heave_filter import Measurement as FusionMeasurement
from boomtip.fusion.consistency import consistency_block, flagged_notes
from boomtip.fusion.solutions import SOLUTIONS, Estimates, run_solution
from boomtip.perception.pipeline import QUANTITY, SENSOR_OF, FrameResult, HeavePipeline, Measurement
from boomtip.tools.chains.chain import ChainError
from boomtip.tools.chains.measurement_rows import MeasurementRows
from boomtip.tools.chains.pictures import FramePictures
from boomtip.tools.chains.resources import RunResources
from boomtip.tools.report.plots import PLOTS_DIR, link_in_report
from boomtip.tools.report.kpis import WARMUP_S, estimated_kpis, measurement_kpis, solution_kpis, truth_amplitudes

MEASUREMENT_COLUMNS = ("t", "method", "quantity", "value", "time_ms", "status", "sigma")


@dataclass
class HeaveResult:
    rows: MeasurementRows  # every frame's measurements, in order
    estimates: dict[str, Estimates]
    sources: dict[str, dict[str, list[str]]] = field(default_factory=dict)  # per solution, what fed D and D-dot
    warnings: list[str] = field(default_factory=list)


LIDAR_D = ("deck_lidar", "reflectors_lidar")


def measurements_only(res: FrameResult) -> FrameResult:
    """A frame's result without its cloud and detections: its measurements and stage times."""
    frame = res.frame
    return FrameResult(Frame(frame.sensor, frame.index, frame.t_s, np.empty((0, 3)), path=frame.path, error=frame.error),
                       res.measurements, res.times)


def solution_sources(name: str, have: set[str]) -> tuple[str, ...]:
    """The methods a solution fuses: its own, except that the fused solution falls back on the
    radar's deck for D when the run has no LiDAR distance (a lost or absent LiDAR)."""
    if name == "fused" and not (set(LIDAR_D) & have) and "deck_radar" in have:
        return ("deck_radar", "doppler_radar_rot")
    return SOLUTIONS[name]


def to_fusion(row: Measurement, latency_s: dict[str, float], clock_sigma_s: dict[str, float] | None = None) -> FusionMeasurement:
    """A perception row as fusion's plain measurement, arriving after its sensor's latency."""
    sensor = SENSOR_OF[row.method]
    return FusionMeasurement(row.t_s, row.t_s + latency_s[sensor], row.quantity, row.value,
                             row.sigma, row.method, row.sigma_systematic, (clock_sigma_s or {}).get(sensor, 0.0))


class HeaveChain:
    name = "heave"

    def __init__(self, source: FrameSource, processing: Processing, resources: RunResources | None = None) -> None:
        inst = source.meta.installation
        self.resources = resources or RunResources()
        if not inst.sensors():
            raise ChainError("installation.lidar.enabled and installation.radar.enabled are both false: "
                             "the heave chain needs a LiDAR or a radar")
        self.pipeline = HeavePipeline(inst, source.mru, processing.heave, seed=processing.seed)
        self.fusion = processing.fusion
        self.sea_state = (processing.sea_state.hs_m, processing.sea_state.tp_s) if processing.sea_state else None
        self.latency_s = {"lidar": inst.lidar.latency_s, "radar": inst.radar.latency_s}
        self.clock_sigma_s = {"lidar": inst.lidar.clock_sigma_s, "radar": inst.radar.clock_sigma_s}
        self.max_D_m = max(getattr(inst, s).max_range_m for s in inst.sensors())  # a D beyond is lost
        self.rows = MeasurementRows(self.resources.block_store("boomtip-measurements-"))
        self.notes = (["attitude: level: the installation has no attitude stream; the boom-tip frame is taken as level"]
                      if inst.attitude == "level" else [])
        self.source_notes = source.meta.notes  # the loader may add to it while frames are read
        self.duration_s, self.t_start_s = source.duration_s, source.meta.t_start_s

    def frames(self, source: FrameSource):
        return iter(source)

    def process(self, frame: Frame) -> FrameResult:
        return self.fuse(self.perceive(frame))

    def perceive(self, frame: Frame) -> FrameResult:
        """The frame's measurements (the pipeline's stages; a worker may run it ahead of `fuse`)."""
        return self.pipeline.process(frame)

    def without_clouds(self, res: FrameResult) -> FrameResult:
        """What `fuse` needs of a perceived frame: not its points nor the stages' detections,
        which only a visualiser or a picture draws."""
        return measurements_only(res)

    def frame_score(self, res: FrameResult, truth: Truth | None) -> tuple[float, str] | None:
        """How bad a LiDAR frame's deck measurement is, for the pictures' worst frame (None: not
        a candidate): with truth, its D error in its stated sigmas; without, a failed deck stage
        (the first of them wins) or else its stated sigma."""
        if res.frame.sensor != "lidar" or res.deck_lidar is None:  # the deck stage ran (no attitude, an empty frame: not)
            return None
        row = next((r for r in res.measurements if r.method == "deck_lidar"), None)
        if row is None:
            return None
        if truth is None:
            if not row.ok:
                return math.inf, f"the first frame whose LiDAR deck stage found nothing ({row.status}); no truth here"
            return row.sigma, f"the least certain LiDAR deck measurement (sigma {row.sigma * 1e3:.1f} mm); no truth here"
        error_m = row.value - float(truth.at("D", np.array([row.t_s]))[0]) if row.ok else math.nan
        if not np.isfinite(error_m) or not row.sigma > 0:
            return None
        z = abs(error_m) / row.sigma
        return z, f"the worst LiDAR deck measurement: D error {error_m * 1e3:+.1f} mm, {z:.1f} of its sigmas"

    def fuse(self, res: FrameResult) -> FrameResult:
        """The frame's measurements kept for the filters (which run at the end)."""
        self.rows.extend(res.measurements)
        return res

    def finish(self) -> HeaveResult:
        t_start_s = self.t_start_s
        ran, have, t_last = set(), set(), -math.inf  # the methods that ran, those that measured, the last row's time
        for r in self.rows:
            ran.add(r.method)
            t_last = max(t_last, r.t_s)
            if r.ok:
                have.add(r.method)
        duration = (t_last if len(self.rows) else 0.0) if self.duration_s <= 0 else self.duration_s
        built: list = []

        def measurements() -> list[FusionMeasurement]:
            """The filters' inputs, made where the solutions run (in a forked child: each child
            its own, so the parent never holds them beside its outputs)."""
            if not built:
                built.append([to_fusion(r, self.latency_s, self.clock_sigma_s) for r in self.rows if r.ok])
            return built[0]

        sources, warnings, solved = {}, list(self.notes) + list(self.source_notes), {}
        for name in self.fusion.solutions:
            methods = solution_sources(name, have)
            if methods != SOLUTIONS[name]:
                warnings.append(f"{name}: no LiDAR distance in this run; it fuses {', '.join(methods)} instead")
            d_sources = [m for m in methods if QUANTITY[m] == "D" and m in have]
            if name == "doppler_radar" and "deck_radar" in have:
                d_sources = ["deck_radar (start only)"]
            sources[name] = {"D": d_sources, "D_dot": [m for m in methods if QUANTITY[m] == "D_dot" and m in have]}
            if not d_sources:
                # a filter with nothing that measures D would report D with a sigma of 100 m
                if set(methods) & ran:  # its sensor ran but never measured D: say so
                    warnings.append(f"{name}: no distance source in this run; no estimate")
                continue
            solved[name] = methods
        # the solutions are independent filters over the same measurements: shared between two
        # processes by how many methods each fuses, when the run has two
        estimates = self.resources.map_split(list(solved), {n: float(len(m)) for n, m in solved.items()},
                                             lambda name: run_solution(name, measurements(), self.fusion, duration, self.sea_state,
                                                                       solved[name], t_start_s, self.max_D_m))
        return HeaveResult(self.rows, estimates, sources, warnings)

    # -- outputs -------------------------------------------------------------------------
    def outputs(self, out: Path, result: HeaveResult) -> list[str]:
        write_measurements(out / "measurements.csv", result.rows)
        write_estimates(out / "estimates.csv", result.estimates)
        return ["measurements.csv", "estimates.csv"]

    def kpis(self, result: HeaveResult, truth: Truth | None, windows: list[tuple[float, float]] = ()) -> dict:
        warnings = list(result.warnings)
        if truth is not None and not {"D", "D_dot"} <= set(truth.columns):
            warnings.append("the truth has no D and D_dot columns (a hook recording?): nothing scored")
            truth = None
        kpis: dict = {"measurements": measurement_kpis(result.rows, truth), "sources": result.sources,
                      "consistency": {n: consistency_block(e.innovations) for n, e in result.estimates.items()
                                      if e.innovations is not None}}
        for name, block in kpis["consistency"].items():
            warnings += flagged_notes(block, name)
        if warnings:
            kpis["warnings"] = warnings
        if truth is not None:
            used = {n: tuple(v["D"] + v["D_dot"]) for n, v in result.sources.items()}  # the methods each one fused
            kpis["solutions"] = {n: solution_kpis(e, truth, result.rows, used.get(n, SOLUTIONS[n]), windows)
                                 for n, e in result.estimates.items()}
            kpis["solutions_note"] = f"solution errors exclude the first {WARMUP_S:g} s (filter convergence)"
            kpis["truth_max_amplitude"] = truth_amplitudes(truth)
        else:
            kpis["estimated"] = {n: estimated_kpis(e) for n, e in result.estimates.items()}
        fused = (kpis.get("solutions") or kpis.get("estimated") or {}).get("fused", {})
        if fused.get("lost_fraction"):  # the estimate a controller uses was not one at times: say so first
            kpis.setdefault("warnings", []).insert(0, (
                f"fused: lost for {100 * fused['lost_fraction']:.1f} % of the run after its first {WARMUP_S:g} s, first at "
                f"t = {fused['first_lost_t_s']:.2f} s ({fused['first_lost_reason']}); estimates.csv leaves their D empty and says why"))
        return kpis

    def report(self, out: Path, kpis: dict, result: HeaveResult, truth: Truth | None,
               pictures: FramePictures | None = None) -> list[str]:
        written = self.report_text(out, kpis, result, truth)
        if pictures is not None:
            link_in_report(out, "Detections", self.detections_plot(out, pictures, result))
            written += [] if PLOTS_DIR in written else [PLOTS_DIR]
        return written

    def report_text(self, out: Path, kpis: dict, result: HeaveResult, truth: Truth | None) -> list[str]:
        """report.md and its plots, without the pictured frames."""
        if truth is None:
            from boomtip.tools.report.estimates import write_estimates_report

            inst = self.pipeline.installation
            mru = self.pipeline.mru if inst.attitude != "level" else None
            return write_estimates_report(out, kpis, result.estimates, result.rows, mru,
                                          {"lidar": inst.lidar.rate_hz, "radar": inst.radar.rate_hz})
        from boomtip.tools.report.heave import write_report

        write_report(out, kpis, result.estimates, truth, result.rows)
        return ["report.md", "plots"]

    def detections_plot(self, out: Path, pictures: FramePictures, result: HeaveResult,
                        as_frame_result: Callable[[object], FrameResult] = lambda output: output) -> Path:
        """plots/detections.png: the pictured LiDAR frames' detections, every method's status."""
        from boomtip.tools.report.detections import write_detections

        frames = [(p.output, p.why) for p in pictures.frames(as_frame_result)]
        return write_detections(out, frames, result.rows, self.pipeline.p_tip["lidar"])

    def visualiser(self, path: Path, source: FrameSource):
        from boomtip.tools.report.recording.heave import RerunLogger

        return RerunLogger(path, source)

    def visualise_result(self, viz, result: HeaveResult, truth: Truth | None) -> None:
        viz.log_estimates(result.estimates, truth)
        viz.log_world()


def write_measurements(path: Path, rows: Iterable[Measurement]) -> None:
    with atomic_text_file(path) as fh:  # written as it goes: a long run's file is never whole in memory
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(MEASUREMENT_COLUMNS)
        for r in rows:
            w.writerow([f"{r.t_s:.6f}", r.method, r.quantity, "" if not np.isfinite(r.value) else f"{r.value:.6f}",
                        f"{r.time_ms:.4f}", r.status, "" if not np.isfinite(r.sigma) else f"{r.sigma:.6g}"])


def write_estimates(path: Path, estimates: dict[str, Estimates]) -> None:
    """estimates.csv: every solution's estimates at the output rate. A lost D or D-dot
    (fusion.solutions.lost_estimates) is left empty and `status` says why: never a number to
    use; `status` is ok otherwise. The variances stay: they show why."""
    with atomic_text_file(path) as fh:
        _write_estimate_rows(fh, estimates)


def _write_estimate_rows(buf, estimates: dict[str, Estimates]) -> None:
    buf.write("t,solution,D,D_dot,D_ddot,var_D,var_D_dot,status,consistent\n")
    for name, e in estimates.items():
        ok = np.isfinite(e.x[:, 0])
        n = int(ok.sum())
        lost = e.lost
        lost_D, lost_V = (lost.D[ok], lost.D_dot[ok]) if lost is not None else (np.zeros(n, bool), np.zeros(n, bool))
        why = lost.why[ok] if lost is not None else np.full(n, "")
        consistent = e.consistent[ok] if e.consistent is not None else np.ones(n, bool)
        for t, x, v, no_D, no_V, w, c in zip(e.t_s[ok], e.x[ok], e.var[ok], lost_D, lost_V, why, consistent):
            D = "" if no_D else f"{x[0]:.6f}"
            V = "" if no_V else f"{x[1]:.6f}"
            A = "" if no_D or no_V else f"{x[2]:.6f}"
            buf.write(f"{t:.4f},{name},{D},{V},{A},{v[0]:.6g},{v[1]:.6g},{w or 'ok'},{int(c)}\n")
