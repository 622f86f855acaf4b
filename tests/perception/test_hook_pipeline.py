"""The hook pipeline's steps (perception/hook_pipeline.py): the levelling of a frame, the prior
the block is searched about, the seeding of the rope's and the block's random draws, and a
block fix's sigma from the LiDAR's beam spacing. Synthetic clouds: the known block's visible
surface (data.block_model) and a rope of points along a line."""

from __future__ import annotations

import math

import numpy as np
import pytest

from boomtip.data.block_model import lower_block_mesh, visible_model_points
from boomtip.data.installation import Installation, LidarSpec, Mount
from boomtip.perception import hook_pipeline
from boomtip.perception.hook import HookConfig
from boomtip.perception.hook_pipeline import (
    HOOK_SEED_SALT,
    MIN_SIGMA_M,
    RECENT_DETECTION_S,
    ROPE_SEED_SALT,
    HookPipeline,
    LevelledFrame,
    detection_sigma_m,
    sigma_across,
)
from boomtip.perception.hook_types import HookDetection
from boomtip.perception.rope import RopeConfig
from boomtip.perception.timing import StageTimes

HOIST_M = 40.0
REF = np.array([0.6, -0.4, -HOIST_M])  # the block's reference point, levelled frame at the tip


def Rx(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def Ry(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def Rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


# -- the levelling -----------------------------------------------------------------------------

def test_level_applies_the_mount_then_the_tips_attitude():
    """The mount as surveyed (R = Rz Ry Rx of its angles, then its offset), then the tip's roll
    and pitch, then its heading: each rotation written out by hand."""
    mount = Mount(xyz_m=(0.8, 0.1, -0.5), rpy_deg=(90.0, 85.0, 10.0))
    pipe = HookPipeline(Installation(lidar=LidarSpec(mount=mount)))
    R_mount = Rz(math.radians(10.0)) @ Ry(math.radians(85.0)) @ Rx(math.radians(90.0))
    t_mount = np.array([0.8, 0.1, -0.5])
    roll, pitch, heading = 0.03, -0.02, 1.1
    R_tip = Ry(pitch) @ Rx(roll) @ Rz(heading)
    pts = np.random.default_rng(0).uniform(-60.0, 60.0, (50, 3))
    out = pipe.level(pts, roll, pitch, heading)
    assert isinstance(out, LevelledFrame)
    # round-off of a few products of 60 m coordinates: 1e-12 m is some 100 ulps
    np.testing.assert_allclose(out.points_level, (pts @ R_mount.T + t_mount) @ R_tip.T, rtol=0, atol=1e-12)
    np.testing.assert_allclose(out.sensor_level, R_tip @ t_mount, rtol=0, atol=1e-15)
    # the sensor's own origin lands where the sensor is
    np.testing.assert_allclose(pipe.level(np.zeros((1, 3)), roll, pitch, heading).points_level[0], out.sensor_level,
                               rtol=0, atol=1e-15)
    # level and heading 0: only the mount
    np.testing.assert_allclose(pipe.level(pts, 0.0, 0.0, 0.0).points_level, pts @ R_mount.T + t_mount, rtol=0, atol=1e-12)


def test_the_rope_and_block_are_the_installations_unless_set():
    inst = Installation.model_validate({"crane": {"rope_radius_m": 0.05, "block_height_m": 3.0}})
    pipe = HookPipeline(inst)
    assert pipe.rope_cfg.radius_m == 0.05 and pipe.cfg.block_height_m == 3.0
    pipe = HookPipeline(inst, HookConfig(block_height_m=4.5), RopeConfig(radius_m=0.03))
    assert pipe.rope_cfg.radius_m == 0.03 and pipe.cfg.block_height_m == 4.5


# -- the prior ---------------------------------------------------------------------------------

class Recorder:
    """A block fit that records what it was asked and returns a fix at `position` (or none)."""

    def __init__(self):
        self.calls = []
        self.position: np.ndarray | None = None
        self.cov: np.ndarray | None = None

    def __call__(self, points, prior, hoist_m, cfg, rng, times, sensor_position_m=None, prior_cov_m2=None):
        self.calls.append({"prior": np.array(prior), "prior_cov": prior_cov_m2, "draws": rng.random(4),
                           "sensor": sensor_position_m, "hoist": hoist_m, "cfg": cfg})
        if self.position is None:
            return HookDetection(np.full(3, np.nan), np.zeros(len(points), bool), 0, float("nan"), "no cluster", float("nan"))
        return HookDetection(self.position.copy(), np.ones(len(points), bool), len(points), 0.01, "ok", 2.5,
                             cov_m2=self.cov)


FRAME = LevelledFrame(np.zeros((10, 3)), np.array([0.8, 0.0, 0.3]))
TIGHT = np.diag([0.04, 0.09, 0.01])  # 0.3 m across: the tracker is sure


def pipeline(seed: int = 5) -> tuple[HookPipeline, Recorder]:
    rec = Recorder()
    return HookPipeline(Installation(), seed=seed, detect=rec), rec


def test_the_prior_is_the_prediction_when_tracked():
    pipe, rec = pipeline()
    p_pred = np.array([0.2, 0.1, -39.0])
    det, cov, prior = pipe.block(FRAME, 1.0, p_pred, TIGHT, HOIST_M, 3, StageTimes())
    assert prior is p_pred and np.array_equal(rec.calls[0]["prior"], p_pred)
    assert rec.calls[0]["prior_cov"] is TIGHT  # a tracked prior comes with its covariance
    assert rec.calls[0]["sensor"] is FRAME.sensor_level and rec.calls[0]["hoist"] == HOIST_M
    assert not det.has_fix and np.isnan(cov).all() and cov.shape == (3, 3) and pipe.last is None


def test_a_loose_or_missing_prediction_falls_back_on_a_recent_detection_else_below_the_tip():
    pipe, rec = pipeline()
    loose = np.diag([2.6 ** 2, 0.01, 0.01])  # across the rope beyond sparse_max_prior_sigma_m (2.5)
    p_pred = np.array([0.2, 0.1, -39.0])
    _, _, prior = pipe.block(FRAME, 1.0, p_pred, loose, HOIST_M, 0, StageTimes())
    assert np.array_equal(prior, [0.0, 0.0, -HOIST_M]) and rec.calls[-1]["prior_cov"] is None  # no detection yet
    rec.position = REF
    pipe.block(FRAME, 1.0, p_pred, loose, HOIST_M, 1, StageTimes())  # a fix: the last detection
    assert pipe.last[0] == 1.0 and np.array_equal(pipe.last[1], REF)
    rec.position = None
    for t, expected in ((1.25, REF), (1.0 + RECENT_DETECTION_S, REF), (1.5 + 1e-9, [0.0, 0.0, -HOIST_M])):
        _, _, prior = pipe.block(FRAME, t, p_pred, loose, HOIST_M, 2, StageTimes())
        assert np.array_equal(prior, expected) and rec.calls[-1]["prior_cov"] is None, t
    # a prediction with no position (the tracker not started) is no prior either, however tight
    _, _, prior = pipe.block(FRAME, 1.25, np.full(3, np.nan), TIGHT, HOIST_M, 3, StageTimes())
    assert np.array_equal(prior, REF)
    # the last detection is the last fix: frames without one leave it
    assert pipe.last[0] == 1.0


def test_the_tracked_threshold_is_the_across_sigma():
    pipe, rec = pipeline()
    s = pipe.cfg.sparse_max_prior_sigma_m
    p_pred = np.array([0.2, 0.1, -39.0])
    at = np.diag([s * s, 0.0, 25.0])  # along the rope (z) as loose as it likes; across exactly at the limit
    _, _, prior = pipe.block(FRAME, 1.0, p_pred, at, HOIST_M, 0, StageTimes())
    assert prior is p_pred
    _, _, prior = pipe.block(FRAME, 1.0, p_pred, at * 1.0001, HOIST_M, 0, StageTimes())
    assert np.array_equal(prior, [0.0, 0.0, -HOIST_M])


def test_a_fix_without_its_own_covariance_takes_the_beam_spacings_sigma():
    pipe, rec = pipeline()
    rec.position = REF
    _, cov, _ = pipe.block(FRAME, 1.0, REF, TIGHT, HOIST_M, 0, StageTimes())
    s = detection_sigma_m(REF, pipe.lidar)
    assert np.array_equal(cov, np.eye(3) * s ** 2)
    rec.cov = np.diag([0.5, 0.6, 0.7])  # a sparse fix brings its own
    _, cov, _ = pipe.block(FRAME, 1.1, REF, TIGHT, HOIST_M, 1, StageTimes())
    assert cov is rec.cov


# -- the random draws ----------------------------------------------------------------------------

def test_the_block_draws_are_seeded_by_the_seed_the_salt_and_the_frame():
    pipe, rec = pipeline(seed=11)
    for index in (0, 7, 7):
        pipe.block(FRAME, 1.0, REF, TIGHT, HOIST_M, index, StageTimes())
    draws = [c["draws"] for c in rec.calls]
    assert np.array_equal(draws[0], np.random.default_rng([11, HOOK_SEED_SALT, 0]).random(4))
    assert np.array_equal(draws[1], draws[2]) and not np.array_equal(draws[0], draws[1])
    other, rec2 = pipeline(seed=12)
    other.block(FRAME, 1.0, REF, TIGHT, HOIST_M, 7, StageTimes())
    assert not np.array_equal(rec2.calls[0]["draws"], draws[1])


def test_the_rope_draws_are_seeded_by_the_seed_the_salt_and_the_frame(monkeypatch):
    seen = []

    def fit(points, u, sigma_rad, hoist_m, cfg, rng, times):
        seen.append((u, sigma_rad, hoist_m, cfg, rng.random(4)))

    monkeypatch.setattr(hook_pipeline, "fit_rope", fit)
    pipe = HookPipeline(Installation(), seed=11)
    p_pred = np.array([3.0, 0.0, -4.0])  # 5 m away
    pipe.rope(FRAME, p_pred, 0.5, HOIST_M, 7, StageTimes())
    u, sigma_rad, hoist_m, cfg, draws = seen[0]
    assert np.array_equal(u, [0.6, 0.0, -0.8]) and sigma_rad == 0.1 and hoist_m == HOIST_M and cfg is pipe.rope_cfg
    assert np.array_equal(draws, np.random.default_rng([11, ROPE_SEED_SALT, 7]).random(4))
    assert ROPE_SEED_SALT != HOOK_SEED_SALT  # the two stages' draws are not the same numbers


def _block_cloud(seed: int) -> np.ndarray:
    """The block's visible surface at REF (1 cm noise) above a deck 6 m below it."""
    rng = np.random.default_rng(seed)
    block = visible_model_points(lower_block_mesh(4.0), 1500, seed=seed) + REF + rng.normal(0, 0.01, (1500, 3))
    deck = np.column_stack([rng.uniform(-8, 8, 3000), rng.uniform(-8, 8, 3000), np.full(3000, REF[2] - 10.0)])
    rope = np.linspace(2.0, HOIST_M - 1.0, 400)[:, None] * (REF / np.linalg.norm(REF)) + rng.normal(0, 0.01, (400, 3))
    return np.vstack([block, deck, rope])


def test_a_repeated_frame_gives_the_identical_rope_and_block():
    pipe = HookPipeline(Installation(lidar=LidarSpec(pattern="spinning", channels=128)), seed=3)
    frame = LevelledFrame(_block_cloud(0), np.array([0.8, 0.0, 0.3]))
    cov_pred = np.diag([0.1, 0.1, 0.1])
    results = []
    for _ in range(2):
        rope = pipe.rope(frame, REF, 0.3, HOIST_M, 9, StageTimes())
        det, cov, _ = pipe.block(frame, 1.0, REF + [0.1, -0.1, 0.0], cov_pred, HOIST_M, 9, StageTimes())
        results.append((rope, det, cov))
    (r1, d1, c1), (r2, d2, c2) = results
    assert r1.ok and d1.has_fix  # the draws were used on a real fit
    assert np.linalg.norm(d1.position_m - REF) < 0.1
    assert np.array_equal(r1.direction, r2.direction) and np.array_equal(r1.cov, r2.cov) and np.array_equal(r1.mask, r2.mask)
    assert np.array_equal(d1.position_m, d2.position_m) and np.array_equal(d1.points_mask, d2.points_mask)
    assert np.array_equal(c1, c2, equal_nan=True)
    # the draws matter: another frame's index gives another fix
    other, _, _ = pipe.block(frame, 1.0, REF + [0.1, -0.1, 0.0], cov_pred, HOIST_M, 10, StageTimes())
    assert other.has_fix and not np.array_equal(other.position_m, d1.position_m)


# -- a fix's sigma ---------------------------------------------------------------------------------

def test_detection_sigma_is_the_edges_beam_spacing_with_its_floors():
    spinning = LidarSpec(pattern="spinning", columns=1024, channels=128, channel_fov_deg=30.0)
    step = 2 * math.pi / 1024  # the columns' spacing is the larger of the two
    assert spinning.angular_step_rad == step
    assert detection_sigma_m(np.array([0.0, 30.0, -40.0]), spinning) == 50.0 * step / math.sqrt(24.0)
    # near, below the 5 mm floor: the floor
    assert detection_sigma_m(np.array([0.0, 0.0, -1.0]), spinning) == MIN_SIGMA_M
    # a noisy range is a floor too
    noisy = spinning.model_copy(update={"range_noise_m": 0.3})
    assert detection_sigma_m(np.array([0.0, 30.0, -40.0]), noisy) == 0.3
    grid = LidarSpec(res_h_deg=0.2, res_v_deg=0.5)
    assert detection_sigma_m(np.array([0.0, 0.0, -100.0]), grid) == 100.0 * math.radians(0.5) / math.sqrt(24.0)


def test_sigma_across_is_the_larger_horizontal_sigma():
    assert sigma_across(np.diag([0.04, 0.09, 100.0])) == pytest.approx(0.3, rel=1e-15)
    a = math.radians(30.0)
    R = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    cov = np.eye(3)
    cov[:2, :2] = R @ np.diag([0.25, 0.01]) @ R.T
    assert sigma_across(cov) == pytest.approx(0.5, rel=1e-14)
    assert sigma_across(np.diag([-1e-12, -2e-12, 1.0])) == 0.0  # round-off below zero is no sigma
