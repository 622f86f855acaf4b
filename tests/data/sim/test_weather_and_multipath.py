"""The world's rain and sea echoes: LiDAR returns from drops near the sensor (any ray, surface or
not), and radar ghosts mirrored below the waterline with the mirror image's range rate."""

from __future__ import annotations

import numpy as np
import pytest

from boomtip.data.meshes import Label
from boomtip.data.sim.simulator import Simulation
from boomtip.tools.config.scenario import load_scenario


def lidar(*keys: str):
    return Simulation(load_scenario("sts-loaded", ["duration_s=0.2", *keys])).lidar_frame(1, 0.1)


RAIN = ("lidar.backscatter_probability=0.05", "lidar.backscatter_scale_m=2")


def test_drops_return_near_the_sensor_from_rays_with_a_surface_and_without():
    clear, rain = lidar(), lidar(*RAIN, "installation.lidar.returns=first")
    drops = rain.fields["label"] == int(Label.PRECIPITATION)
    rays = len(Simulation(load_scenario("sts-loaded", ["duration_s=0.2"])).lidar_pattern.dirs_sensor)
    assert drops.sum() == pytest.approx(0.05 * rays, rel=0.25)  # 5 % of every ray, not only of those with a surface
    surface = len(rain) - drops.sum()
    assert surface < len(clear) < len(rain)  # drops hide some surfaces and add points where rays met nothing
    r = np.linalg.norm(rain.points_sensor[drops], axis=1)
    assert r.min() >= 0.5 - 1e-6 and np.mean(r) == pytest.approx(0.5 + 2.0, rel=0.2)  # min range + exponential, mean 2 m
    # a drop returns backscatter_reflectivity of a white target's light at its range (the measured
    # range is noisy, a few cm on these weak returns: the ratio is 1 in the median)
    ratio = rain.fields["intensity"][drops] / (0.002 * (50.0 / r) ** 2)
    assert np.median(ratio) == pytest.approx(1.0, abs=0.03)


def test_the_return_mode_keeps_the_drop_the_surface_the_stronger_or_both():
    clear = len(lidar())
    n = {}
    for mode in ("first", "last", "strongest", "dual"):
        f = lidar(*RAIN, f"installation.lidar.returns={mode}")
        drops = int(np.count_nonzero(f.fields["label"] == int(Label.PRECIPITATION)))
        n[mode] = (drops, len(f) - drops)  # (drops, surfaces)
    # last: every surface stays, drops only where a ray met nothing; dual: every surface and every drop
    assert n["last"][1] == n["dual"][1] == clear and n["dual"][0] == n["first"][0]
    assert n["first"][0] + n["first"][1] == n["last"][0] + n["last"][1]  # a point per ray that returned
    # strongest: the drops nearer than a surface's strength allows, between first and last
    assert n["last"][0] < n["strongest"][0] < n["first"][0] and n["strongest"][1] + n["strongest"][0] == n["first"][1] + n["first"][0]


def test_without_drops_the_frame_is_the_same():
    a, b = lidar(), lidar("lidar.backscatter_scale_m=9")
    np.testing.assert_array_equal(a.points_sensor, b.points_sensor)


def test_radar_ghosts_lie_below_the_waterline_and_move_as_the_mirror_image():
    sim = Simulation(load_scenario("sts-loaded", ["duration_s=0.5", "radar.multipath_probability=0.5"]))
    f = sim.radar_frame(4, 0.2)
    ghost = f.fields["label"] == int(Label.MULTIPATH)
    assert ghost.sum() > 20 and (~ghost).sum() > 100
    st = sim.world.crane_motion.states(np.array([0.2]))
    R_ws, p_ws = sim.world.sensor_pose(st, "radar")
    z_world = (f.points_sensor @ R_ws[0].T + p_ws[0])[:, 2]
    assert np.all(z_world[ghost] < 0.5) and np.median(z_world[~ghost]) > 0  # below the sea (range noise aside)
    # the deck heaves: its mirror image moves the other way, and the Doppler says so
    deck = np.isin(f.fields["label"], [int(Label.FEEDER_DECK)])
    assert np.sign(np.median(f.fields["range_rate"][ghost])) != np.sign(np.median(f.fields["range_rate"][deck]))
    clean = Simulation(load_scenario("sts-loaded", ["duration_s=0.5"])).radar_frame(4, 0.2)
    assert not np.any(clean.fields["label"] == int(Label.MULTIPATH))


def test_radar_ranges_range_rates_and_angles_sit_in_their_bins():
    keys = ["duration_s=0.2", "installation.radar.range_noise_m=0.01", "installation.radar.range_rate_noise_mps=0.01"]
    plain = Simulation(load_scenario("sts-loaded", keys)).radar_frame(3, 0.15)
    binned = Simulation(load_scenario("sts-loaded", [*keys, "installation.radar.range_resolution_m=0.04",
                                                     "installation.radar.range_rate_resolution_mps=0.05",
                                                     "installation.radar.angle_resolution_deg=0.5"])).radar_frame(3, 0.15)
    half_deg = np.deg2rad(0.5)
    for field, step in (("range", 0.04), ("range_rate", 0.05), ("azimuth", half_deg), ("elevation", half_deg)):
        v = binned.fields[field].astype(float)
        np.testing.assert_allclose(v / step, np.rint(v / step), atol=1e-4)  # on the bins (float32 fields)
        assert not np.allclose(plain.fields[field] / step, np.rint(plain.fields[field] / step), atol=1e-4)
        # the same draws: each detection moves to its nearest bin, at most half a bin
        np.testing.assert_array_less(np.abs(v - plain.fields[field]), step / 2 + 1e-5)
    np.testing.assert_allclose(np.linalg.norm(binned.points_sensor, axis=1), binned.fields["range"], rtol=1e-6)
