"""The feeder chain through a gap in the crane MRU's log (world key `mru.outages_s`).

Without an attitude a frame cannot be levelled: the chain paused, no rows for the gap. With
`feeder.mru_gap.enabled`, the attitude in the gap is the MRU's own forecast (fusion.mru_bridge:
an AR model of its samples before the gap, with the forecast's variance), and the LiDAR and
radar frames are processed as usual with it:
  - the heave chain has no deck and no Doppler fit for a frame without an attitude; the same
    stages (perception.deck, perception.doppler) run here on the frame with the predicted
    levelling, with the heave pipeline's settings, its seed for the frame and its last deck as
    the prior, reading the pipeline and changing nothing in it;
  - the perception's attitude sigmas grow by the prediction's: the angle's (a tilt of d rad
    about the sensor tilts the levelled deck by d and moves it sideways by its range times d:
    the deck plane's, the deck spin's, the radar's and the registration's covariance), the
    rates' (the tip's velocity, the spin, the Doppler's rotation);
  - the forecast's error is one error for the whole gap, not a new draw per frame: every frame
    moves the same way, and so does the filter, which averages the frames as independent. The
    rows written in the gap carry it on top of the filter's covariance (attitude_pose_cov at
    the prediction's variance then), and when the MRU is back the filter's own covariance gets
    it once (the last prediction's), so that the first true levelling corrects the state rather
    than being gated as an outlier. (Multiplying each frame's covariance by the frames taken in
    the gap instead let the feeder's motion model drift: 255 mm in y on sts-irregular seed 1.)
  - once the predicted angle's 1-sigma passes `max_sigma_deg`, the frames have no attitude
    and the chain pauses as before, until the MRU is back.
Only the MRU's samples before the gap are used (never the world's truth or sea state).

Measured (60 s, a 5 s MRU gap at 20 s, seeds 1-3, against the pause):
  - sts-loaded (a regular sea: the forecast holds 0.002-0.004 deg): rows through the whole gap
    at 1.7-10.5 / 3.0-4.9 / 0.6-0.8 mm RMS x / y / z (max 17 mm), NEES 0.5-1.3 of 6 (outside
    the gap the chain's is 0.8-0.9: its covariance is as cautious there as anywhere); after
    the gap max 12-16 / 14-19 mm in x / y where the pause's first frames reach 12-120 / 36-66.
  - sts-irregular (broadband: the forecast is 0.04-0.18 deg off in 5 s): the sigma limit of
    0.05 deg is passed after 1.3-1.6 s, 28-32 rows at 16-30 / 11-24 mm RMS (max 72 mm), NEES
    2.0-3.5; then the pause. Its first row after the gap (a prediction over the 3.5 s
    paused, from velocities that the predicted levelling disturbed) was off by 378 and 148 mm
    on seeds 1 and 3 where the plain pause's was 105 and 71 mm (seed 2: 56 against 156 mm).
    With a 0.2 deg limit the whole gap is bridged at 28-177 mm RMS, NEES 2.6-9.8.
Hence off by default: clearly better on a regular sea, not on an irregular one.
"""

from __future__ import annotations

import math
from contextlib import contextmanager

import numpy as np
from boomtip.data.frames import Frame
from boomtip.perception.deck import detect_deck
from boomtip.perception.doppler import doppler_velocity
from boomtip.perception.feeder import FeederPerception
from boomtip.perception.geometry import level_rotation_rows
from boomtip.perception.pipeline import FrameResult, HeavePipeline, carried_deck_prior, doppler_inputs
from boomtip.perception.timing import StageTimes


def stages_with_attitude(pipeline: HeavePipeline, frame: Frame, rpy: np.ndarray, last_deck: dict) -> FrameResult:
    """The heave pipeline's deck (and, for a radar frame, its Doppler fit) of a frame levelled
    with `rpy`: the pipeline's own stages and settings, its random draws for the frame.
    last_deck: sensor -> (t, D) of the last deck found, the deck search's prior (updated here)."""
    times = StageTimes()
    wire = -np.array(level_rotation_rows(rpy, pipeline._R_crane_sensor_rows[frame.sensor])[2])
    p_tip = pipeline.p_tip[frame.sensor]
    rng = pipeline.frame_rng(frame)
    out = FrameResult(frame, [], times)
    cfg = pipeline.cfg
    prior, tol = carried_deck_prior(cfg, frame.t_s, last_deck.get(frame.sensor) or pipeline.last_deck.get(frame.sensor))
    if frame.sensor == "lidar":
        out.deck_lidar = deck = detect_deck(frame.points_sensor, wire, p_tip, cfg.deck_lidar, rng, times, "deck",
                                            prior_D_m=prior, prior_tol_m=tol)
    else:
        out.deck_radar = deck = detect_deck(frame.points_sensor, wire, p_tip, cfg.deck_radar, rng, times, "radar_deck")
        inputs = doppler_inputs(frame, cfg.doppler_preprocess)
        if inputs is not None and len(inputs[0]) >= 3:
            out.doppler = doppler_velocity(inputs[0], inputs[1], cfg.doppler, rng, None)
    if deck.ok:
        last_deck[frame.sensor] = (frame.t_s, deck.D_m)
    return out


class MruGap:
    """The chain's state through a gap: the heave pipeline (ShipChain's) whose stages run on the
    gap's frames, the decks found there, the last prediction's angle variance."""

    def __init__(self) -> None:
        self.pipeline: HeavePipeline | None = None
        self.decks: dict = {}
        self.angle_var: float | None = None  # in a gap, or after it until the first LiDAR frame
        self.tip_reset = False

    def stages(self, frame: Frame, rpy: np.ndarray, var: np.ndarray) -> FrameResult:
        self.angle_var, self.tip_reset = max(var[0], var[1]), False
        return stages_with_attitude(self.pipeline, frame, rpy, self.decks)

    def in_gap_rows(self, out, first: int) -> None:
        """The rows written in the gap (from `first`): the prediction's error on top."""
        for k in range(first, len(out.P)):
            out.P[k][:6, :6] += attitude_pose_cov(out.x[k][:3], self.angle_var)

    def mru_back(self, filt, sensor: str) -> None:
        """The first frames with the MRU's own attitude after a gap. The tip's place jumps from
        the predicted levelling's to the measured one's: the first step is predicted with the
        tip's velocity instead (its place moved the state by 18 cm and 85 mm in z on
        sts-irregular seed 1, and the next decks were gated for a second). The state carries
        the gap's error: the first LiDAR frame's deck and registration fix it."""
        if self.angle_var is None or not filt.started:
            return
        if not self.tip_reset:
            filt.tip_position, self.tip_reset = None, True
        if sensor == "lidar":
            filt.P[:6, :6] += attitude_pose_cov(filt.x[:3], self.angle_var)
            self.angle_var = None


@contextmanager
def inflated_sigmas(perception: FeederPerception, var: np.ndarray):
    """The perception's attitude sigmas with a predicted attitude's variances added (var: roll,
    pitch, yaw, their rates; the larger of roll's and pitch's for the tilt) for the time of the
    block: each frame's measurement covariance carries the prediction's error."""
    saved = perception.angle_sigma_rad, perception.rate_sigma_radps, perception.tip_velocity_sigma
    angle_var, rate_var = max(var[0], var[1]), max(var[3], var[4])
    lever = float(np.linalg.norm(perception.t_crane_tip))
    perception.angle_sigma_rad = math.sqrt(saved[0] ** 2 + angle_var)
    perception.rate_sigma_radps = math.sqrt(saved[1] ** 2 + rate_var)
    perception.tip_velocity_sigma = math.sqrt(saved[2] ** 2 + lever ** 2 * rate_var)
    try:
        yield
    finally:
        perception.angle_sigma_rad, perception.rate_sigma_radps, perception.tip_velocity_sigma = saved


def attitude_pose_cov(p_level_m: np.ndarray, angle_var_rad2: float) -> np.ndarray:
    """(6, 6): the covariance a levelling error (about the level x and y axes, variance
    angle_var each) puts on a pose whose origin is p_level (from the tip, where the level frame
    turns): the origin moves by d x p (sideways by its depth times d, vertically by its
    horizontal offset times d), the roll and pitch by d."""
    x, y, z = p_level_m
    J = np.array([[0.0, z], [-z, 0.0], [y, -x], [1.0, 0.0], [0.0, 1.0], [0.0, 0.0]])
    return angle_var_rad2 * (J @ J.T)
