"""The one runner: for each frame of the source, `chain.process(frame)`; then the chain's
outputs; scoring only when the source has truth. It knows chains only through their protocol
(tools/chains/chain.py).

A chain (heave, ship, hook) is built from the source's installation and the processing settings,
never from the simulated world, and the run's resources (how it uses memory and cores).
Everything is written into a staging folder and moved into place at the end.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from pydantic import ValidationError

from boomtip.data.frames import FrameSource
from boomtip.data.io.output_folder import output_folder
from boomtip.data.io.recording import RecordingError, screened_log, write_json
from boomtip.data.keys import format_validation, leaf_keys, settings_dump
from boomtip.tools.chains.chain import Chain, NullVisualiser
from boomtip.tools.chains.heave import HeaveChain
from boomtip.tools.chains.hook import HookChain
from boomtip.tools.chains.lift import LiftChain
from boomtip.tools.chains.pictures import FramePictures
from boomtip.tools.chains.provenance import outage_windows, run_labels
from boomtip.tools.chains.resources import RunResources
from boomtip.tools.chains.ship import ShipChain
from boomtip.tools.config.processing import Processing
from boomtip.tools.config.settings import boomtip_commit, boomtip_version

MIN_SCREENED_SAMPLES = 2  # an attitude: level log (two level samples) has nothing to screen


@dataclass
class RunResult:
    chain: str
    result: object
    kpis: dict
    written: list[str]


def processing_for(source: FrameSource, processing: Processing | None = None) -> Processing:
    """The processing settings: given, else those the source asks for, else the defaults."""
    if processing is not None:
        return processing
    try:
        return Processing.model_validate(source.meta.processing)
    except ValidationError as exc:
        raise RecordingError(format_validation(exc, f"{source.meta.name}: processing", "processing.",
                                               keys=leaf_keys(Processing(), "processing"))) from None


def build_chain(source: FrameSource, processing: Processing, resources: RunResources | None = None) -> Chain:
    """The chain for this source: `processing.chain`, else the hook chain when the source has
    an encoder stream and the heave chain otherwise; with a LiDAR (and `feeder.enabled`), the
    feeder's 6-DOF chain runs beside the heave chain."""
    kind = processing.chain or ("hook" if source.encoders is not None else "heave")
    if kind == "hook":
        return HookChain(source, processing, resources)
    if kind == "lift":
        return LiftChain(source, processing, resources)
    if processing.feeder.enabled and source.meta.installation.lidar.enabled:
        return ShipChain(source, processing, resources)
    return HeaveChain(source, processing, resources)


def run(source: FrameSource, out: Path, force: bool = False, processing: Processing | None = None, rerun: bool = False,
        report: bool = True, inputs: tuple[Path, ...] = (), progress: Callable[[int], None] | None = None,
        resources: RunResources | None = None, command: dict | None = None) -> RunResult:
    """`run_into` a staging folder moved into place as OUT when complete (data/io/output_folder).
    command: what was run, for OUT/settings.json (the inputs' first is the recording)."""
    with output_folder(out, force, inputs) as staging:
        result = run_into(source, staging, processing, rerun, report, progress, resources,
                          run_record(command, inputs[0] if inputs else None))
    return result


def screen_attitude(source: FrameSource) -> None:
    """The source's attitude logs screened for what no vessel does (glitches, a frozen sensor,
    times out of order) whatever the source: a file's were screened as it was read, a
    simulation's or a bag's are here; what is dropped is counted in the source's notes."""
    for name in ("mru", "feeder_mru"):
        log = getattr(source, name, None)
        if log is not None and len(log.t_s) > MIN_SCREENED_SAMPLES:
            screened = screened_log(log, f"{source.meta.name}: {name}", source.meta.notes)
            if screened is not log:  # a clean log stays the object it was (a hook simulation's lives on disk)
                setattr(source, name, screened)


def run_record(command: dict | None, recording: Path | None) -> dict:
    """What settings.json says of how the run was made: the command and the recording's path and size."""
    out: dict = {"command": command}
    if recording is not None:
        path = Path(recording).resolve()
        size = path.stat().st_size if path.is_file() else sum(p.stat().st_size for p in path.rglob("*") if p.is_file())
        out["input"] = {"path": str(path), "bytes": size}
    return out


def settings_record(source: FrameSource, processing: Processing, record: dict | None = None) -> dict:
    """OUT/settings.json: everything the run was made from, so that it can be repeated
    (`--installation` and `--processing` take this file as it is)."""
    return {"boomtip": {"version": boomtip_version(), "commit": boomtip_commit()}, **(record or {}),
            "source": {"name": source.meta.name, "t_start_s": source.meta.t_start_s, "t_origin_s": source.meta.t_origin_s,
                       "duration_s": source.duration_s},
            "installation": settings_dump(source.meta.installation),
            # the settings as given (a default left unset follows the installation: the Doppler band, the
            # markers' height, ...), which repeat the run, and every setting as it resolved, to read
            "processing": settings_dump(processing, exclude_unset=True),
            "processing_resolved": settings_dump(processing)}


def run_into(source: FrameSource, staging: Path, processing: Processing | None = None, rerun: bool = False,
             report: bool = True, progress: Callable[[int], None] | None = None,
             resources: RunResources | None = None, record: dict | None = None) -> RunResult:
    resources = resources or RunResources()
    resources.start()
    screen_attitude(source)
    processing = processing_for(source, processing)
    chain = build_chain(source, processing, resources)
    viz = chain.visualiser(staging / "boomtip.rrd", source) if rerun else NullVisualiser()
    per_sensor = {"lidar": 0, "radar": 0}
    truth = source.truth
    pictures = FramePictures(source, (lambda output: chain.frame_score(output, truth)) if hasattr(chain, "frame_score") else None)
    try:
        for sensor, output in resources.processed(chain, source, pictures, keep_clouds=rerun):
            viz.log_frame(output)
            pictures.offer(sensor, output)
            per_sensor[sensor] = per_sensor.get(sensor, 0) + 1
            resources.frame_done(sum(per_sensor.values()))
            if progress:
                progress(1)
        resources.release()  # what the frames freed, before the estimators (and their forks) and the outputs
        result = chain.finish()
    except BaseException:
        if hasattr(chain, "close"):  # what a chain runs beside the frames (a merge in its own process) stops with the run
            chain.close()
        raise
    frames = sum(per_sensor.values())
    written = chain.outputs(staging, result)
    kpis = {**run_labels(source, chain.name), **chain.kpis(result, source.truth, outage_windows(source))}
    if frames == 0:
        kpis.setdefault("warnings", []).append(f"{source.meta.name}: no frame to process (an empty recording?): "
                                               "no measurement, no estimate")
    else:  # a sensor the installation has, that never sent a frame (a wrong topic, a dead sensor)
        inst = source.meta.installation
        silent = [f"installation.{s}.enabled is true, but {source.meta.name} has no {s} frame: nothing was measured "
                  "with it" for s in ("lidar", "radar") if getattr(inst, s).enabled and per_sensor[s] == 0]
        if silent:
            kpis.setdefault("warnings", []).extend(silent)
    if source.truth is not None and source.truth.end_s < source.duration_s - 0.05:
        kpis.setdefault("warnings", []).append(f"the truth ends at {source.truth.end_s:.2f} s of "
                                               f"{source.duration_s:.2f} s: only its span is scored")
    write_json(staging / "kpis.json", kpis)
    write_json(staging / "settings.json", settings_record(source, processing, record))
    written += ["kpis.json", "settings.json"]
    if report:
        written += [w for w in chain.report(staging, kpis, result, source.truth, pictures) if w not in written]
    chain.visualise_result(viz, result, source.truth)
    viz.close()
    if rerun:
        written.append("boomtip.rrd")
    return RunResult(chain.name, result, kpis, written)
