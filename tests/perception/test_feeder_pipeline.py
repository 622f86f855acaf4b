"""The feeder pipeline's per-frame steps (perception/feeder_pipeline.py): the static-returns
warm-up that holds observations back, frames without a deck, the keyframe and its renewal, when
the model grows and merges, when centre lines and hull edges are looked for, when the radar
registers, and the deck stage of a frame levelled with a forecast attitude. Geometry from a
short simulated sts-loaded run where a deck is needed; synthetic structure elsewhere."""

from __future__ import annotations

import math

import numpy as np
import pytest

from boomtip.data.frames import AttitudeNoise, Frame, LevellingAttitude
from boomtip.data.installation import Installation
from boomtip.data.poses import pose_matrix, transform
from boomtip.perception import feeder_pipeline
from boomtip.perception.feeder import FeederConfig, FeederPerception, LidarObservation, RadarObservation
from boomtip.perception.feeder_radar import RadarRegistration, RadarRegistrationConfig
from boomtip.perception.feeder_registration import Registration6, RegistrationConfig
from boomtip.perception.feeder_pipeline import FeederPipeline, FeederPipelineConfig
from boomtip.perception.pipeline import HeavePipeline, PipelineConfig
from boomtip.perception.static_returns import StaticReturnsConfig

WARMUP_S = 1.0  # a short warm-up: ten LiDAR frames


def config(warmup_s: float = WARMUP_S, registration: RegistrationConfig | None = None, **kw) -> FeederPipelineConfig:
    return FeederPipelineConfig(perception=FeederConfig(static=StaticReturnsConfig(warmup_s=warmup_s),
                                                        registration=registration or RegistrationConfig()), **kw)


def synthetic_pipeline(**kw) -> FeederPipeline:
    inst = Installation()
    cfg = config(**kw)
    return FeederPipeline(inst, cfg, FeederPerception(inst, cfg.perception), seed=3)


def structure(seed: int, n: int = 400) -> np.ndarray:
    """A feeder's structure in the level frame (deck 45 m below the tip): two containers and the
    bulwarks' inner faces, what the chain registers."""
    rng = np.random.default_rng(seed)
    parts = []
    for sy in (-1.0, 1.0):
        parts.append(np.column_stack([rng.uniform(-40, 40, n), np.full(n, sy * 9.85), rng.uniform(0.3, 1.2, n)]))
    for cx in (-15.0, 12.0):
        parts.append(np.column_stack([np.full(n, cx - 6), rng.uniform(-1.2, 1.2, n), rng.uniform(0.3, 2.6, n)]))
        parts.append(np.column_stack([np.full(n, cx + 6), rng.uniform(-1.2, 1.2, n), rng.uniform(0.3, 2.6, n)]))
        parts.append(np.column_stack([rng.uniform(cx - 6, cx + 6, n), np.full(n, -1.2), rng.uniform(0.3, 2.6, n)]))
        parts.append(np.column_stack([rng.uniform(cx - 6, cx + 6, n), np.full(n, 1.2), rng.uniform(0.3, 2.6, n)]))
        parts.append(np.column_stack([rng.uniform(cx - 6, cx + 6, n), rng.uniform(-1.2, 1.2, n), np.full(n, 2.6)]))
    return np.vstack(parts) + [0.0, 0.0, -45.0]


def lidar_obs(t_s: float, pts: np.ndarray | None = None, pipe: FeederPipeline | None = None) -> LidarObservation:
    """An observation whose sample is `pts` in the sensor frame (the level frame's axes, 0.5 m below
    the tip), its returns counted in the pipeline's static test."""
    pts = np.zeros((0, 3)) if pts is None else pts
    obs = LidarObservation(t_s, pts, np.eye(3), np.array([0.0, 0.0, -0.5]), None, "ok", sample_returns_sensor=pts)
    if pipe is not None:
        obs.static_keys = pipe.static.add(t_s, pts)
    return obs


T_MAP_LEVEL = pose_matrix(0.0, 0.0, 45.0, 0.0, 0.0, 0.0)  # the deck at the map's z = 0


def registration(fitness: float = 0.9) -> Registration6:
    return Registration6(T_MAP_LEVEL, np.eye(6), 1000, fitness, "ok")


# -- a short simulated run ---------------------------------------------------------------------

@pytest.fixture(scope="module")
def run():
    from boomtip.data.sim.simulator import Simulation
    from boomtip.tools.config.scenario import load_scenario

    sim = Simulation(load_scenario("sts-loaded", ["duration_s=2"]))
    return sim, list(sim)


def sim_pipeline(sim, warmup_s: float = WARMUP_S, with_heave: bool = True) -> tuple[FeederPipeline, HeavePipeline]:
    inst = sim.meta.installation
    heave = HeavePipeline(inst, sim.mru, PipelineConfig(), seed=0)
    cfg = config(warmup_s)
    pipe = FeederPipeline(inst, cfg, FeederPerception(inst, cfg.perception), seed=0, heave=heave if with_heave else None)
    return pipe, heave


def measured(sim, pipe: FeederPipeline, frame: Frame, forecast_var=None) -> LevellingAttitude:
    return LevellingAttitude(*sim.mru.attitude(frame.t_s), pipe.stages.noise, forecast_var)


def test_observations_are_held_through_the_warmup_and_handed_over_in_time_order(run):
    sim, frames = run
    pipe, heave = sim_pipeline(sim)
    seen, handed = [], []
    for frame in frames:
        if frame.t_s > WARMUP_S + 0.25:
            break
        out = pipe.observe(frame, heave.process(frame), measured(sim, pipe, frame))
        seen.append((frame.t_s, frame.sensor))
        handed.append([(o.t_s, "lidar" if isinstance(o, LidarObservation) else "radar") for o in out])
    first = next(i for i, h in enumerate(handed) if h)
    # the LiDAR frame WARMUP_S after the first is where the static test is ready
    assert seen[first] == (WARMUP_S, "lidar") and not any(handed[:first])
    assert handed[first] == seen[: first + 1]  # every observation so far, in the frames' order
    assert all(h == [s] for h, s in zip(handed[first + 1:], seen[first + 1:]))  # then each as it comes
    assert pipe.queue == [] and pipe.missing == []


def test_a_run_shorter_than_the_warmup_hands_its_observations_over_at_the_end(run):
    sim, frames = run
    pipe, heave = sim_pipeline(sim, warmup_s=4.0)
    for frame in frames[:9]:
        assert pipe.observe(frame, heave.process(frame), measured(sim, pipe, frame)) == []
    held = pipe.ready()
    assert [o.t_s for o in held] == [f.t_s for f in frames[:9]] and pipe.queue == [] and pipe.ready() == []


def test_a_lidar_frame_without_a_deck_is_counted_missing(run):
    sim, frames = run
    pipe, heave = sim_pipeline(sim)
    lidar = [f for f in frames if f.sensor == "lidar"]
    radar = next(f for f in frames if f.sensor == "radar")
    pipe.observe(lidar[0], None, measured(sim, pipe, lidar[0]))  # no deck stage at all
    pipe.observe(radar, None, measured(sim, pipe, radar))  # a radar frame is never missing here
    few = Frame("lidar", lidar[1].index, lidar[1].t_s, lidar[1].points_sensor[:20], {})  # too few returns for a deck
    res = heave.process(few)
    assert res.deck_lidar is not None and not res.deck_lidar.ok
    pipe.observe(few, res, measured(sim, pipe, few))
    ok = heave.process(lidar[2])
    pipe.observe(lidar[2], ok, measured(sim, pipe, lidar[2]))
    assert pipe.missing == [(lidar[0].t_s, "lidar", "no deck plane"),
                            (few.t_s, "lidar", f"no deck plane ({res.deck_lidar.status})")]
    held = pipe.ready()
    assert [o.plane is None for o in held] == [True, True, True, False]


def test_a_forecast_attitude_levels_the_deck_stage_and_leaves_the_heave_pipelines_own_deck(run):
    sim, frames = run
    pipe, heave = sim_pipeline(sim)
    for frame in frames[:12]:  # the heave pipeline's own decks, up to 0.35 s
        heave.process(frame)
    own = dict(heave.last_deck)
    assert set(own) == {"lidar", "radar"}
    lidar = next(f for f in frames[12:] if f.sensor == "lidar")
    radar = next(f for f in frames[12:] if f.sensor == "radar")
    var = np.full(6, 1e-9)
    tilt = np.array([2e-4, -1e-4, 0.0])  # the forecast is off the MRU: its deck is not the heave chain's
    atts = {}
    for frame in (lidar, radar):
        rpy, rate = sim.mru.attitude(frame.t_s)
        atts[frame.sensor] = LevellingAttitude(rpy + tilt, rate, AttitudeNoise(1e-4, 2e-4, 0.01), var)
        pipe.observe(frame, None, atts[frame.sensor])  # the frame's own heave result is not asked for
    assert heave.last_deck == own
    obs_lidar, obs_radar = pipe.ready()
    # the observations are the feeder's stages on the heave pipeline's stages, levelled with the forecast
    ref_decks: dict = {}
    ref = heave.levelled_stages(lidar, atts["lidar"].rpy_rad, ref_decks)
    expected = pipe.stages.lidar(lidar.t_s, lidar.points_sensor, atts["lidar"].rpy_rad, atts["lidar"].rpy_rate_radps,
                                 ref.deck_lidar, lidar.fields.get("t"), atts["lidar"].noise)
    assert obs_lidar.plane is not None and np.array_equal(obs_lidar.plane.abc, expected.plane.abc)
    assert np.array_equal(obs_lidar.plane.cov, expected.plane.cov) and obs_lidar.noise == atts["lidar"].noise
    ref = heave.levelled_stages(radar, atts["radar"].rpy_rad, ref_decks)
    assert obs_radar.velocity_level is not None
    expected = pipe.stages.radar(radar.t_s, atts["radar"].rpy_rad, atts["radar"].rpy_rate_radps, ref.doppler, ref.deck_radar,
                                 radar.points_sensor, atts["radar"].noise)
    assert np.array_equal(obs_radar.velocity_level, expected.velocity_level)
    # the decks found so are kept apart, as the next forecast frame's prior
    assert pipe.forecast_decks == ref_decks and pipe.forecast_decks["lidar"][0] == lidar.t_s
    # with the MRU's own attitude the heave pipeline's result is used as it is
    other = next(f for f in frames[12:] if f.sensor == "lidar" and f.t_s > lidar.t_s)
    pipe.observe(other, None, measured(sim, pipe, other))
    assert pipe.ready()[0].plane is None and pipe.forecast_decks == ref_decks


def test_a_later_gaps_first_forecast_frame_takes_the_heave_pipelines_recent_deck_as_its_prior(run, monkeypatch):
    from boomtip.perception import pipeline as heave_module

    sim, frames = run
    pipe, heave = sim_pipeline(sim)
    priors = []
    real = heave_module.detect_deck
    monkeypatch.setattr(heave_module, "detect_deck", lambda *a, **k: priors.append(k.get("prior_D_m")) or real(*a, **k))

    def forecast(frame):
        rpy, rate = sim.mru.attitude(frame.t_s)
        n = len(priors)
        pipe.observe(frame, None, LevellingAttitude(rpy, rate, AttitudeNoise(1e-4, 2e-4, 0.01), np.full(6, 1e-9)))
        return priors[n]

    def own(t0, t1):  # the MRU's own attitude: the heave pipeline's decks
        for f in frames:
            if t0 <= f.t_s <= t1:
                heave.process(f)

    lidar = {round(f.t_s, 3): f for f in frames if f.sensor == "lidar"}
    own(0.0, 0.3)
    assert forecast(lidar[0.4]) == heave.last_deck["lidar"][1]  # a first gap: the heave pipeline's deck of 0.1 s ago
    own(0.5, 1.5)  # the MRU back for a second
    assert forecast(lidar[1.6]) == heave.last_deck["lidar"][1]  # a second gap: the same, 0.1 s old


def test_without_a_heave_pipeline_a_forecast_frame_takes_the_result_it_is_given(run):
    sim, frames = run
    pipe, heave = sim_pipeline(sim, with_heave=False)
    lidar = frames[0]
    res = heave.process(lidar)
    pipe.observe(lidar, res, measured(sim, pipe, lidar, forecast_var=np.full(6, 1e-9)))
    assert pipe.ready()[0].plane is not None and pipe.forecast_decks == {}


# -- the keyframe and the registrations -----------------------------------------------------------

def test_the_first_structure_becomes_the_keyframe_not_a_registration():
    pipe = synthetic_pipeline()
    assert pipe.register(lidar_obs(0.0), structure(0)[:50], T_MAP_LEVEL, 0.01) is None  # too little: no model
    assert pipe.model.empty and pipe.missing == [] and pipe.failed_registrations == 0
    assert pipe.register(lidar_obs(0.1), structure(0), T_MAP_LEVEL, 0.01) is None
    assert not pipe.model.empty and pipe.model.keyframes == 1 and pipe.missing == []
    assert np.allclose(np.asarray(pipe.model.keyframe.points), transform(T_MAP_LEVEL, structure(0)), rtol=0, atol=1e-9)
    reg = pipe.register(lidar_obs(0.2), structure(1), T_MAP_LEVEL, 0.01)  # another scan of it
    assert reg is not None and reg.status == "ok" and reg.n_points == len(structure(1)) and pipe.model.keyframes == 1
    assert pipe.missing == [] and pipe.failed_registrations == 0


def test_failures_are_counted_missing_and_a_new_keyframe_taken_after_rekey_after_failures():
    pipe = synthetic_pipeline(rekey_after_failures=3)
    pipe.register(lidar_obs(0.0), structure(0), T_MAP_LEVEL, 0.01)
    few = structure(1)[:30]
    for k in range(3):
        assert pipe.register(lidar_obs(0.1 * (k + 1)), few, T_MAP_LEVEL, 0.01) is None
    assert pipe.failed_registrations == 3
    why = "registration: too few feeder points above the deck (30 < 100)"
    assert pipe.missing == [(0.1, "lidar", why), (0.2, "lidar", why), (pytest.approx(0.3), "lidar", why)]
    moved = structure(2) + [0.0, 5.0, 0.0]
    assert pipe.register(lidar_obs(0.4), moved, T_MAP_LEVEL, 0.01) is None  # the new keyframe
    assert pipe.model.keyframes == 2 and pipe.failed_registrations == 0 and len(pipe.missing) == 3
    assert np.allclose(np.asarray(pipe.model.keyframe.points), transform(T_MAP_LEVEL, moved), rtol=0, atol=1e-9)
    # a success resets the count
    pipe.register(lidar_obs(0.5), few, T_MAP_LEVEL, 0.01)
    assert pipe.failed_registrations == 1
    pipe.keep(lidar_obs(0.6), moved, pipe.register(lidar_obs(0.6), moved, T_MAP_LEVEL, 0.01), T_MAP_LEVEL, 0.01)
    assert pipe.failed_registrations == 0


def test_a_frame_is_registered_once_the_last_registered_frame_is_register_min_interval_s_older(run):
    """At 20 Hz every other frame (the filter takes registrations closer than 0.1 s as sharing
    their errors), decided from the frames' times where they are perceived; a frame not to be
    registered is neither counted nor tested as static and hands over no returns, its deck
    plane still does."""
    pipe = synthetic_pipeline(register_min_interval_s=0.075)
    due = [pipe.chosen_for_registration(t) for t in (0.0, 0.05, 0.1, 0.15, 0.18, 0.2, 0.26)]
    assert due == [True, False, True, False, True, False, True]
    assert all(synthetic_pipeline(register_min_interval_s=0.0).chosen_for_registration(t) for t in (0.0, 0.0, 0.01))

    sim, frames = run
    inst = sim.meta.installation
    heave = HeavePipeline(inst, sim.mru, PipelineConfig(), seed=0)
    cfg = config(register_min_interval_s=0.15)
    pipe = FeederPipeline(inst, cfg, FeederPerception(inst, cfg.perception), seed=0, heave=heave)
    obs = []
    for frame in frames:
        obs += pipe.observe(frame, heave.process(frame), measured(sim, pipe, frame))
    lidar = [o for o in obs if isinstance(o, LidarObservation)]
    registered = [o for o in lidar if o.to_register]
    assert len(lidar) >= 15 and 0.45 * len(lidar) <= len(registered) <= 0.55 * len(lidar)  # 10 Hz: every other frame
    assert all(o.static_mask is not None and len(o.sample_sensor) > 1000 for o in registered)
    assert all(o.static_mask is None and len(o.sample_sensor) == 0 and o.plane is not None for o in lidar if not o.to_register)
    assert len(pipe.static.frames) == len(registered)  # the static test counts only the frames it tests


@pytest.mark.parametrize("xy_after, merges, expected", [(50, (20, 50, 100, 200), 50), (300, (20, 200), 200), (50, (), 1)])
def test_a_young_model_until_merged_from_register_xy_after_frames(xy_after, merges, expected):
    pipe = synthetic_pipeline(register_xy_after_frames=xy_after, registration=RegistrationConfig(model_merges=merges))
    assert pipe.xy_after_frames == expected
    pipe.model.model_frames = expected - 1
    assert pipe.young_model
    pipe.model.model_frames = expected
    assert not pipe.young_model


def test_only_a_registered_frame_grows_the_model_and_its_merge_ends_the_youth():
    pipe = synthetic_pipeline(register_xy_after_frames=50, registration=RegistrationConfig(model_merges=(3,)))
    pipe.register(lidar_obs(0.0), structure(0), T_MAP_LEVEL, 0.01)
    assert pipe.young_model and len(pipe.model.collected) == 1
    pipe.keep(lidar_obs(0.1), structure(1), None, T_MAP_LEVEL, 0.01)  # not registered
    assert len(pipe.model.collected) == 1 and pipe.merges.records == []
    pipe.keep(lidar_obs(0.2), structure(2), registration(), T_MAP_LEVEL, 0.01)
    assert len(pipe.model.collected) == 2 and pipe.merges.records == [] and pipe.young_model
    pipe.next_lidar_frame()
    pipe.keep(lidar_obs(0.3), structure(3), registration(), T_MAP_LEVEL, 0.01)  # the third: merged, inline
    assert [(m.frames, m.status) for m in pipe.merges.records] == [(3, "ok")]
    assert pipe.model.model_frames == 3 and pipe.model.merged and not pipe.young_model
    assert pipe.lidar_frames == 3


@pytest.mark.parametrize("fitness, sigma_x_m, rekeyed", [(0.1, 0.01, True), (0.1, 0.06, False), (0.5, 0.01, False)])
def test_a_poor_fit_renews_the_keyframe_only_once_x_is_known(fitness, sigma_x_m, rekeyed):
    pipe = synthetic_pipeline(registration=RegistrationConfig(model_merges=()))
    pipe.register(lidar_obs(0.0), structure(0), T_MAP_LEVEL, 0.01)
    pipe.keep(lidar_obs(0.1), structure(1), registration(fitness), T_MAP_LEVEL, sigma_x_m)
    assert pipe.model.keyframes == (2 if rekeyed else 1)


def test_a_keyframe_of_several_frames_is_filled_by_the_registered_ones():
    pipe = synthetic_pipeline(registration=RegistrationConfig(model_merges=(), keyframe_frames=2))
    pipe.register(lidar_obs(0.0), structure(0), T_MAP_LEVEL, 0.01)
    n0 = len(pipe.model.keyframe.points)
    pipe.keep(lidar_obs(0.1), structure(1), registration(0.1), T_MAP_LEVEL, 0.01)  # filled, not renewed
    assert pipe.model.keyframe_size == 2 and pipe.model.keyframes == 1 and len(pipe.model.keyframe.points) > n0


def test_centre_lines_and_hull_edges_are_looked_for_every_centre_line_every_frames(monkeypatch):
    calls = []
    hull_points = iter([250, 150, 250, 250])  # the second hull edge is short: it does not count

    def centre_line(points, rng, band_m=(0.2, 2.5)):
        calls.append((points, rng, band_m))
        return (0.01, 500) if band_m == (0.2, 2.5) else (-0.02, next(hull_points))

    monkeypatch.setattr(feeder_pipeline, "centre_line_yaw", centre_line)
    pipe = synthetic_pipeline(centre_line_every=3, hull_edge_frames=3, registration=RegistrationConfig(model_merges=()))
    pts = structure(0)
    pipe.register(lidar_obs(0.0), pts, T_MAP_LEVEL, 0.01)  # the keyframe
    T = pose_matrix(0.5, -0.2, 45.0, 0.0, 0.0, 0.01)
    looked = []
    for k in range(16):
        n = len(calls)
        obs = lidar_obs(0.1 * k, pts, pipe)
        pipe.keep(obs, pts if k != 9 else pts[:0], registration() if k % 2 else None, T, 0.01)
        looked.append(len(calls) - n)
        assert obs.static_keys is None
    # frames 0, 3, 6, 9 (no structure: nothing), 12 and 15, registered or not; the hull's edge
    # until hull_edge_frames of them are found
    assert looked == [2, 0, 0, 2, 0, 0, 2, 0, 0, 0, 0, 0, 2, 0, 0, 1]
    assert pipe.lines == [(0.01, 500)] * 5 and pipe.hull_yaws == [-0.02] * 3 and pipe.edges_known == (5, 3)
    # the centre line in the map frame at the estimate's pose, with the pipeline's own draws
    points, rng, band = calls[0]
    assert np.array_equal(points, transform(T, pts)) and rng is pipe.rng and band == (0.2, 2.5)
    # the hull's edge among the static returns (level frame), in any band: none static in the first
    # frame, all of them (the same returns every frame) by the fourth
    hull = [c for c in calls if c[2] != (0.2, 2.5)]
    assert [c[2] for c in hull] == [(-np.inf, np.inf)] * 4
    assert hull[0][0].shape == (0, 3) and np.array_equal(hull[1][0], pts + [0.0, 0.0, -0.5])
    assert pipe.lidar_frames == 16


def test_the_pipelines_draws_are_the_runs_seeds():
    other_seed = FeederPipeline(Installation(), config(), FeederPerception(Installation()), seed=4)
    expected = np.random.default_rng([3, feeder_pipeline.FEEDER_SEED_SALT]).random(4)
    assert np.array_equal(synthetic_pipeline().rng.random(4), expected)
    assert np.array_equal(synthetic_pipeline().rng.random(4), expected)
    assert not np.array_equal(other_seed.rng.random(4), expected)


# -- the radar ------------------------------------------------------------------------------------

def radar_obs(detections: np.ndarray | None) -> RadarObservation:
    return RadarObservation(1.0, None, None, np.array([0.3, 0.0, -0.5]), None, "ok", detections_sensor=detections,
                            R_level_sensor=np.eye(3))


@pytest.mark.parametrize("status, count_failure, missing", [("ok", True, False), ("too few matches", True, True),
                                                            ("too few matches", False, False)])
def test_the_radar_registers_once_the_model_is_merged_from_min_model_frames(monkeypatch, status, count_failure, missing):
    got = RadarRegistration(np.array([0.1, 0.2, 0.003]), np.eye(3), 40, status)
    calls = []
    monkeypatch.setattr(feeder_pipeline, "register_radar", lambda *a: calls.append(a) or got)
    pipe = synthetic_pipeline(radar_registration=RadarRegistrationConfig(min_model_frames=20))
    det = structure(5)[::10]
    guess = np.array([0.0, 0.0, -45.0, 0.0, 0.0, 0.0])
    assert pipe.register_radar(radar_obs(det), guess, True) is None  # no model
    pipe.register(lidar_obs(0.0), structure(0), T_MAP_LEVEL, 0.01)
    pipe.model.model_frames = 19
    assert pipe.register_radar(radar_obs(det), guess, True) is None  # merged from too few frames
    pipe.model.model_frames = 20
    assert pipe.register_radar(radar_obs(None), guess, True) is None  # no detections
    assert pipe.register_radar(radar_obs(det[:0]), guess, True) is None
    assert calls == []
    obs = radar_obs(det)
    out = pipe.register_radar(obs, guess, count_failure)
    (args,) = calls
    assert args[0] is pipe.model.surface and args[1] is det and args[5] is guess
    assert args[6] is pipe.cfg.radar_registration
    assert out is (got if status == "ok" else None)
    assert pipe.missing == ([(1.0, "radar", status)] if missing else [])


def test_the_radar_does_not_register_when_switched_off(monkeypatch):
    monkeypatch.setattr(feeder_pipeline, "register_radar", lambda *a: pytest.fail("registered"))
    pipe = synthetic_pipeline(radar_registration=RadarRegistrationConfig(enabled=False, min_model_frames=1))
    pipe.register(lidar_obs(0.0), structure(0), T_MAP_LEVEL, 0.01)
    assert pipe.register_radar(radar_obs(structure(5)[::10]), np.zeros(6), True) is None


def test_the_detections_noise_is_the_installations():
    inst = Installation.model_validate({"radar": {"range_noise_m": 0.1, "azimuth_noise_deg": 0.5, "elevation_noise_deg": 1.0}})
    pipe = FeederPipeline(inst, config(), FeederPerception(inst), seed=0)
    assert pipe.detection_sigma == (0.1, math.radians(0.5), math.radians(1.0))


def test_finish_stops_the_merges_and_gives_the_models_points():
    pipe = synthetic_pipeline(registration=RegistrationConfig(model_merges=(), merge_lag_frames=(2,)))
    assert pipe.finish() is None
    pipe.register(lidar_obs(0.0), structure(0), T_MAP_LEVEL, 0.01)
    assert np.array_equal(pipe.finish(), np.asarray(pipe.model.keyframe.points))
