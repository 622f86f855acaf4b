"""The one runner: for each frame of the source, `chain.process(frame)`; then the chain's
outputs; scoring only when the source has truth. It knows chains only through their protocol
(tools/chains/chain.py).

A chain (heave, ship, hook) is built from the source's installation and the processing settings,
never from the simulated world, and the run's resources (how it uses memory and cores).
Everything is written into a staging folder and moved into place at the end.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from pydantic import ValidationError

from boomtip.data.frames import FrameSource
from boomtip.data.io.recording import RecordingError, commit_output, prepare_output, write_json
from boomtip.data.keys import format_validation, leaf_keys
from boomtip.tools.chains.chain import Chain, NullVisualiser
from boomtip.tools.chains.heave import HeaveChain
from boomtip.tools.chains.hook import HookChain
from boomtip.tools.chains.provenance import outage_windows, run_labels
from boomtip.tools.chains.resources import RunResources
from boomtip.tools.chains.ship import ShipChain
from boomtip.tools.config.processing import Processing


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
    if processing.feeder.enabled and source.meta.installation.lidar.enabled:
        return ShipChain(source, processing)
    return HeaveChain(source, processing)


def run(source: FrameSource, out: Path, force: bool = False, processing: Processing | None = None, rerun: bool = False,
        report: bool = True, inputs: tuple[Path, ...] = (), progress: Callable[[int], None] | None = None,
        resources: RunResources | None = None) -> RunResult:
    staging = prepare_output(out, force, inputs)
    try:
        result = run_into(source, staging, processing, rerun, report, progress, resources)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    commit_output(staging, out)
    return result


def run_into(source: FrameSource, staging: Path, processing: Processing | None = None, rerun: bool = False,
             report: bool = True, progress: Callable[[int], None] | None = None,
             resources: RunResources | None = None) -> RunResult:
    resources = resources or RunResources()
    resources.start()
    chain = build_chain(source, processing_for(source, processing), resources)
    viz = chain.visualiser(staging / "boomtip.rrd", source) if rerun else NullVisualiser()
    frames = 0
    for frame in chain.frames(source):
        viz.log_frame(chain.process(frame))
        frames += 1
        if progress:
            progress(1)
    result = chain.finish()
    written = chain.outputs(staging, result)
    kpis = {**run_labels(source, chain.name), **chain.kpis(result, source.truth, outage_windows(source))}
    if frames == 0:
        kpis.setdefault("warnings", []).append(f"{source.meta.name}: no frame to process (an empty recording?): "
                                               "no measurement, no estimate")
    if source.truth is not None and source.truth.end_s < source.duration_s - 0.05:
        kpis.setdefault("warnings", []).append(f"the truth ends at {source.truth.end_s:.2f} s of "
                                               f"{source.duration_s:.2f} s: only its span is scored")
    write_json(staging / "kpis.json", kpis)
    written.append("kpis.json")
    if report:
        written += chain.report(staging, kpis, result, source.truth)
    chain.visualise_result(viz, result, source.truth)
    viz.close()
    if rerun:
        written.append("boomtip.rrd")
    return RunResult(chain.name, result, kpis, written)
