"""What a simulated source's provenance says of the run, for labels and scoring only: never an
input of processing (deleting the provenance changes no estimate)."""

from __future__ import annotations

from boomtip.data.frames import FrameSource

__all__ = ["run_labels", "outage_windows"]


def run_labels(source: FrameSource, chain: str) -> dict:
    """What kpis.json says the run was: the source's name, the chain and, for a simulated
    source, its seed and hook programme."""
    prov = source.meta.provenance or {}
    labels = {"scenario": source.meta.name, "seed": prov.get("seed"), "duration_s": source.duration_s, "chain": chain}
    if source.meta.t_origin_s:  # t = 0 is the recording's first stamp; its own clock there
        labels["t_origin_s"] = source.meta.t_origin_s
    program = ((prov.get("world") or {}).get("hook") or {}).get("program")
    if chain == "hook" and program:
        labels["program"] = program
    return labels


def outage_windows(source: FrameSource, sensors: tuple[str, ...] = ("lidar", "radar", "mru")) -> list[tuple[float, float]]:
    """The simulated sensors' outage windows, sorted."""
    world = (source.meta.provenance or {}).get("world") or {}
    return sorted(tuple(w) for s in sensors for w in (world.get(s) or {}).get("outages_s", []))
