"""The lift chain's recording: the hook's (tools/report/recording/hook.py) and, per LiDAR frame,
the load's points, the deck's ring about it, the clearance's line from the load's lowest point
down to the deck, and the landing point; per radar scan, the load's and the deck's detections
its rates came from; the clearance and its estimate as series."""

from __future__ import annotations

import numpy as np

from boomtip.tools.report.classes import by_name, rgb
from boomtip.tools.report.recording.hook import HookRerunLogger

__all__ = ["LiftRerunLogger"]

PANEL = "clearance [m]: the load's lowest point above the deck below it"
DECK_POINTS = 400  # of the deck's ring drawn per frame


class LiftRerunLogger(HookRerunLogger):
    def log_frame(self, res) -> None:
        if getattr(res, "sensor", None) == "radar":
            self._log_radar(res)
            return
        super().log_frame(res)
        obs = getattr(res, "clearance", None) if res is not None else None
        if obs is None or res.points_level is None:
            return
        rec = self.recording
        rec.time(res.row["t"])
        if obs.load_mask is not None and obs.deck_mask is not None:
            deck = res.points_level[obs.deck_mask]
            rec.points("detections/lift/load", res.points_level[obs.load_mask], "load", 0.08)
            rec.points("detections/lift/deck", deck[:: max(1, len(deck) // DECK_POINTS)], "deck", 0.06)
        if obs.ok:
            low = obs.lowest_point_m
            rec.line("detections/lift/clearance", np.array([low, [low[0], low[1], obs.deck_z_m]]), "clearance", 0.05)
            rec.points("detections/lift/landing", obs.landing_m[None], "clearance", 0.25, labels=["landing"])
        else:
            rec.clear("detections/lift/clearance")
            rec.clear("detections/lift/landing")

    def _log_radar(self, res) -> None:
        """A radar scan's detections on the load and on the deck (those its rates came from)."""
        rate, rec = res.rate, self.recording
        rec.time(res.t_s)
        if res.points_level is None or rate.load_mask is None:
            rec.clear("detections/lift/radar_load")
            rec.clear("detections/lift/radar_deck")
            return
        deck = res.points_level[rate.deck_mask]
        rec.points("detections/lift/radar_load", res.points_level[rate.load_mask], "load", 0.15)
        rec.points("detections/lift/radar_deck", deck[:: max(1, len(deck) // DECK_POINTS)], "deck", 0.12)

    def log_clearance(self, t_s: np.ndarray, estimate_m: np.ndarray, sigma_m: np.ndarray, truth_m: np.ndarray | None) -> None:
        """The filtered clearance with its 3-sigma band, and the truth's."""
        colour = rgb(by_name("clearance").colour)
        self.recording.series(PANEL, "estimates/lift/clearance", t_s, estimate_m, "clearance", colour, sigma_m)
        if truth_m is not None:
            self.recording.series(PANEL, "truth/lift/clearance", t_s, truth_m, "truth", rgb(by_name("truth").colour))
