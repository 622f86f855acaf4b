"""The one runner: for each frame of the source, `chain.process(frame)`; then the chain's
outputs; scoring only when the source has truth.

A chain (heave, hook) is built from the source's installation and the processing settings,
never from the simulated world. Everything is written into a staging folder and moved into
place at the end.
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
from boomtip.tools.config.processing import Processing


class ChainError(ValueError):
    """A chain cannot be built from what the source provides: the message names the key."""


class NullVisualiser:
    """The visualiser when none is wanted: every logging call does nothing."""

    def __getattr__(self, name: str) -> Callable[..., None]:
        return lambda *args, **kwargs: None


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


def build_chain(source: FrameSource, processing: Processing):
    """The chain for this source: `processing.chain`, else the hook chain when the source has
    an encoder stream and the heave chain otherwise; with a LiDAR (and `feeder.enabled`), the
    feeder's 6-DOF chain runs beside the heave chain."""
    kind = processing.chain or ("hook" if source.encoders is not None else "heave")
    if kind == "hook":
        from boomtip.tools.chains.hook import HookChain

        return HookChain(source, processing)
    inst = source.meta.installation
    if processing.feeder.enabled and inst.lidar.enabled:
        from boomtip.tools.chains.ship import ShipChain

        return ShipChain(source, processing)
    from boomtip.tools.chains.heave import HeaveChain

    return HeaveChain(source, processing)


def run_labels(source: FrameSource, chain: str) -> dict:
    """What kpis.json says the run was: the source's name, the chain and, for a simulated
    source, its seed and hook programme (from the provenance: labels for the report, never
    an input of processing)."""
    prov = source.meta.provenance or {}
    labels = {"scenario": source.meta.name, "seed": prov.get("seed"), "duration_s": source.duration_s, "chain": chain}
    program = ((prov.get("world") or {}).get("hook") or {}).get("program")
    if chain == "hook" and program:
        labels["program"] = program
    return labels


def outage_windows(source: FrameSource, sensors: tuple[str, ...] = ("lidar", "radar", "mru")) -> list[tuple[float, float]]:
    """The simulated sensors' outage windows (from the provenance: for scoring only)."""
    world = (source.meta.provenance or {}).get("world") or {}
    return sorted(tuple(w) for s in sensors for w in (world.get(s) or {}).get("outages_s", []))


def run(source: FrameSource, out: Path, force: bool = False, processing: Processing | None = None, rerun: bool = False,
        report: bool = True, inputs: tuple[Path, ...] = (), progress: Callable[[int], None] | None = None) -> RunResult:
    staging = prepare_output(out, force, inputs)
    try:
        result = run_into(source, staging, processing, rerun, report, progress)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    commit_output(staging, out)
    return result


def run_into(source: FrameSource, staging: Path, processing: Processing | None = None, rerun: bool = False,
             report: bool = True, progress: Callable[[int], None] | None = None) -> RunResult:
    chain = build_chain(source, processing_for(source, processing))
    viz = chain.visualiser(staging / "boomtip.rrd", source) if rerun else NullVisualiser()
    frames = 0
    for frame in (chain.frames(source) if hasattr(chain, "frames") else source):
        viz.log_frame(chain.process(frame))
        frames += 1
        if progress:
            progress(1)
    result = chain.finish(source.duration_s, source.meta.t_start_s)
    written = chain.write(staging, result)
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
