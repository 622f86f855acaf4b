"""Benchmarks. Each measures boomtip and a baseline on the same input in the same run and
reports the ratio, so the figure does not depend on the machine's speed."""

from __future__ import annotations

import time

import numpy as np

from boomtip.tools.config.scenario import Scenario


def bench_perception(scenario: Scenario, frames: int = 30, voxel_m: float = 0.2, sor_nb: int = 20, sor_std: float = 2.0) -> dict:
    """Deck detection and its stages vs a baseline of Open3D's own calls, on the same frames.

    Stages: preprocessing with the same operations (non-finite removal, voxel grid,
    statistical outliers); the plane search (ours vs `segment_plane` repeated as in
    Algorithm 3, same selection metric); and deck detection end to end as each would run
    (ours as configured in the pipeline; baseline: Open3D preprocessing + repeated
    segment_plane), with D's error against the truth for both.
    """
    from boomtip.data.sim.simulator import Simulation
    from boomtip.perception.deck import LIDAR_DECK, detect_deck, lowest_large_plane
    from boomtip.perception.geometry import heave_distance, rotation_level_sensor, tip_in_sensor, wire_dir_sensor
    from boomtip.perception.pipeline import FRAME_STAGES, STAGES, HeavePipeline
    from boomtip.perception.preprocess import PreprocessConfig, open3d_baseline_multi_plane, open3d_baseline_preprocess, preprocess
    from boomtip.perception.timing import StageTimes

    sim = Simulation(scenario)
    meta = sim.meta
    p_tip = tip_in_sensor(meta.T_boomtip_sensor["lidar"])
    pre_cfg = PreprocessConfig(min_range_m=0.0, voxel_size_m=voxel_m, outlier_nb_neighbors=sor_nb, outlier_std_ratio=sor_std)
    thr = LIDAR_DECK.multi_plane.ransac.distance_threshold_m
    t_pre = {"boomtip": 0.0, "open3d": 0.0}
    t_plane = {"boomtip": 0.0, "open3d": 0.0}
    t_deck = {"boomtip": 0.0, "open3d": 0.0}
    err = {"boomtip": [], "open3d": []}
    for i in range(frames):
        t = i / scenario.installation.lidar.rate_hz
        f = sim.lidar_frame(i, t)
        rpy, _ = sim.mru.attitude(t)
        wire = wire_dir_sensor(rotation_level_sensor(rpy, meta.T_crane_boomtip, meta.T_boomtip_sensor["lidar"]))
        truth_D = float(sim.truth.at("D", np.array([t]))[0])
        rng = np.random.default_rng([scenario.seed, i])
        # Stage 1: preprocessing, same operations.
        t0 = time.perf_counter()
        pts_ours, _, _ = preprocess(f.points_sensor, None, pre_cfg, rng)
        t1 = time.perf_counter()
        pts_o3d = open3d_baseline_preprocess(f.points_sensor, voxel_m, sor_nb, sor_std)
        t2 = time.perf_counter()
        t_pre["boomtip"] += t1 - t0
        t_pre["open3d"] += t2 - t1
        # Stage 2: plane search on the same (Open3D-preprocessed) points.
        t0 = time.perf_counter()
        lowest_large_plane(pts_o3d, -wire, LIDAR_DECK, rng)
        t1 = time.perf_counter()
        open3d_baseline_multi_plane(pts_o3d, -wire, n_planes=LIDAR_DECK.multi_plane.max_planes, threshold=thr, seed=i)
        t2 = time.perf_counter()
        t_plane["boomtip"] += t1 - t0
        t_plane["open3d"] += t2 - t1
        # End to end: deck detection as each route would run it.
        times = StageTimes()
        t0 = time.perf_counter()
        ours = detect_deck(f.points_sensor, wire, p_tip, LIDAR_DECK, rng, times)
        t1 = time.perf_counter()
        res = open3d_baseline_multi_plane(open3d_baseline_preprocess(f.points_sensor, voxel_m, sor_nb, sor_std), -wire,
                                          n_planes=LIDAR_DECK.multi_plane.max_planes, threshold=thr, seed=i)
        D_o3d = heave_distance(res.deck.plane, wire, p_tip) if res is not None else np.nan
        t2 = time.perf_counter()
        t_deck["boomtip"] += t1 - t0
        t_deck["open3d"] += t2 - t1
        err["boomtip"].append(ours.D_m - truth_D)
        err["open3d"].append(D_o3d - truth_D)
    ms = lambda x: 1e3 * x / frames  # noqa: E731
    mae = {k: float(np.nanmean(np.abs(v))) for k, v in err.items()}
    mx = {k: float(np.nanmax(np.abs(v))) for k, v in err.items()}
    # The other methods' figures from the pipeline itself (its own stage timing), same scenario.
    pipe = HeavePipeline(meta.installation, sim.mru)
    per_method: dict[str, dict] = {}
    n_radar = int(frames * scenario.installation.radar.rate_hz / scenario.installation.lidar.rate_hz)
    # In acquisition order, as a run feeds them: the rotation-aware Doppler uses the latest deck.
    schedule = sorted([(i / scenario.installation.lidar.rate_hz, "lidar", i) for i in range(frames)]
                      + [(i / scenario.installation.radar.rate_hz, "radar", i) for i in range(n_radar)])
    recorded = []  # each frame with what its stages were given, for the stage comparison below
    for t, sensor, i in schedule:
        fr = sim.lidar_frame(i, t) if sensor == "lidar" else sim.radar_frame(i, t)
        doppler_prior = pipe.last_doppler[1] if pipe.last_doppler and t - pipe.last_doppler[0] <= 0.2 else None
        out = pipe.process(fr)
        recorded.append((fr, out, doppler_prior, pipe._deck_prior(t, "lidar", out.reflectors) if sensor == "lidar" else None))
        # the frame's attitude stage, which each of its rows carries an equal share of
        share_ms = out.times.total(*FRAME_STAGES) / max(len(out.measurements), 1)
        for m in out.measurements:
            d = per_method.setdefault(m.method, {"apt_ms": [], "err": [], "valid": 0, "frames": 0, "stages": {}})
            d["apt_ms"].append(m.time_ms)
            d["stages"].setdefault("attitude share", []).append(share_ms)
            for stage in STAGES[m.method]:  # where the APT goes (a stage a frame skipped counts 0)
                d["stages"].setdefault(stage, []).append(out.times.ms.get(stage, 0.0))
            d["frames"] += 1
            if m.ok:
                d["valid"] += 1
                d["err"].append(m.value - float(sim.truth.at(m.quantity, np.array([t]))[0]))
    methods = {
        m: {"apt_ms": float(np.mean(d["apt_ms"])), "mae": float(np.mean(np.abs(d["err"]))) if d["err"] else float("nan"),
            "valid_fraction": d["valid"] / d["frames"], "stages_ms": {k: float(np.mean(v)) for k, v in d["stages"].items()}}
        for m, d in per_method.items()
    }
    return {
        "frames": frames,
        "heave_stages": _heave_stages_vs_reference(pipe, recorded),
        "points_per_frame": float(np.mean([len(sim.lidar_frame(0, 0.0))])),
        "preprocess_ms": {k: ms(v) for k, v in t_pre.items()},
        "preprocess_ratio": t_pre["open3d"] / t_pre["boomtip"],
        "plane_search_ms": {k: ms(v) for k, v in t_plane.items()},
        "plane_search_ratio": t_plane["open3d"] / t_plane["boomtip"],
        "deck_detection_ms": {k: ms(v) for k, v in t_deck.items()},
        "deck_mae_m": mae,
        "deck_max_m": mx,
        "ratio": t_deck["open3d"] / t_deck["boomtip"],
        "methods": methods,
        "baseline": f"Open3D remove_non_finite_points + voxel_down_sample({voxel_m}) + remove_statistical_outlier({sor_nb}, {sor_std}) "
                    f"+ segment_plane x{LIDAR_DECK.multi_plane.max_planes} (Algorithm 3)",
    }


def _heave_stages_vs_reference(pipe, recorded: list, repeats: int = 5) -> dict:
    """The heave chain's stages (LiDAR deck, reflectors, the Doppler fit and the deck's spin for
    the rotation-aware D-dot) against their earlier implementation (tools/bench/references/
    heave_deck.py and heave.py), on the inputs the pipeline gave them. Each input is run `repeats`
    times by each, alternating, and the least wall time of each counts (as timeit does: on a
    shared machine a call that was preempted measures the machine, not the code). Ms per call
    (the mean of those least times), their ratio, and the largest difference between the two
    results (the same algorithm: zero up to rounding)."""
    from boomtip.perception.deck import detect_deck
    from boomtip.perception.doppler import doppler_velocity
    from boomtip.perception.geometry import NormalRate
    from boomtip.perception.pipeline import doppler_inputs
    from boomtip.perception.reflectors import detect_reflectors
    from boomtip.tools.bench.references import heave as ref
    from boomtip.tools.bench.references import heave_deck as ref_deck

    cfg = pipe.cfg
    calls: dict[str, list] = {"deck_lidar": [], "reflectors_lidar": [], "doppler_fit": [], "deck_spin": []}
    spins = (NormalRate(cfg.normal_window_s), ref.ReferenceNormalRate(cfg.normal_window_s))
    for fr, out, doppler_prior, deck_prior in recorded:
        wire, p_tip = out.extras.get("wire_dir_sensor"), pipe.p_tip[fr.sensor]
        if wire is None:
            continue
        if fr.sensor == "lidar":
            seed = [pipe.seed, 1, fr.index]
            args = (fr.points_sensor, wire, p_tip, cfg.deck_lidar)
            kw = {"prior_D_m": deck_prior[0], "prior_tol_m": deck_prior[1]}
            calls["deck_lidar"].append((
                lambda a=args, k=kw, s=seed: detect_deck(*a, np.random.default_rng(s), **k).D_m,
                lambda a=args, k=kw, s=seed: ref_deck.detect_deck(*a, np.random.default_rng(s), **k).D_m))
            if "intensity" in fr.fields:
                args = (fr.points_sensor, fr.fields["intensity"], wire, p_tip, cfg.reflectors)
                calls["reflectors_lidar"].append((lambda a=args: detect_reflectors(*a).D_m,
                                                  lambda a=args: ref.detect_reflectors(*a).D_m))
            if out.deck_lidar is not None and out.deck_lidar.ok:
                for nr in spins:
                    nr.add(fr.t_s, out.extras["R_level_sensor"] @ out.deck_lidar.plane_sensor[:3])
            continue
        inputs = doppler_inputs(fr, cfg.doppler_preprocess)
        if inputs is not None and len(inputs[0]) >= 3:
            args = (*inputs, cfg.doppler, np.random.default_rng(0), doppler_prior)
            calls["doppler_fit"].append((lambda a=args: _velocity(doppler_velocity(*a)),
                                         lambda a=args: _velocity(ref.doppler_velocity(*a))))
        if spins[0].omega(fr.t_s) is not None:
            # the fit is redone on the first query after a new normal: each call starts afresh
            calls["deck_spin"].append(tuple(lambda nr=nr, c=_spin_state(nr), t=fr.t_s: _fresh_omega(nr, c, t) for nr in spins))

    # A run calls each stage once per frame, right after the frame was simulated (or read): the
    # caches then hold the simulator's data, not the interpreter's and numpy's working set. Each
    # input is also run once by each right after a sweep through more memory than the last-level
    # cache holds, to show what that costs beside the least of the warm calls; timed by the
    # thread's CPU time, since one call's wall time on a shared machine is mostly its waits.
    sweep = np.zeros(64 << 17)  # 64 MiB
    out_stages = {}
    for stage, pairs in calls.items():
        best_ours, best_ref, cold_ours, cold_ref, diff = [], [], [], [], 0.0
        for ours, theirs in pairs:
            for fn, into in ((ours, cold_ours), (theirs, cold_ref)):
                sweep += 1.0
                t0 = time.thread_time()
                fn()
                into.append(time.thread_time() - t0)
            t_ours, t_ref = [], []
            for r in range(repeats):
                for fn, into in (((ours, t_ours), (theirs, t_ref)) if r % 2 == 0 else ((theirs, t_ref), (ours, t_ours))):
                    t0 = time.perf_counter()
                    value = fn()
                    into.append(time.perf_counter() - t0)
                    if fn is ours:
                        v_ours = value
                    else:
                        v_ref = value
            best_ours.append(min(t_ours))
            best_ref.append(min(t_ref))
            d = np.abs(np.asarray(v_ours, dtype=float) - np.asarray(v_ref, dtype=float))
            diff = max(diff, float(np.nanmax(d)) if np.any(np.isfinite(d)) else 0.0)
        n = max(len(pairs), 1)
        out_stages[stage] = {"calls": len(pairs), "boomtip_ms": 1e3 * sum(best_ours) / n, "reference_ms": 1e3 * sum(best_ref) / n,
                             "ratio": sum(best_ref) / sum(best_ours) if best_ours else float("nan"), "max_abs_difference": diff,
                             "boomtip_cold_cpu_ms": 1e3 * sum(cold_ours) / n, "reference_cold_cpu_ms": 1e3 * sum(cold_ref) / n}
    return out_stages


def _velocity(fit) -> np.ndarray:
    return fit.velocity_sensor if fit is not None else np.full(3, np.nan)


def _spin_state(nr) -> dict:
    return {k: list(v) if isinstance(v, list) else v for k, v in vars(nr).items()}


def _fresh_omega(nr, state: dict, t_s: float) -> np.ndarray:
    """The deck's spin at t_s from the normals held at the time (the cached fit dropped)."""
    vars(nr).update(state)
    nr._coef = None
    return nr.omega(t_s)


def bench_fusion(program: str = "hook-2", duration_s: float = 60.0, seed: int = 0) -> dict:
    """Hook filter runtime as a fraction of the simulated time: the flexible EKF with its
    exact Jacobian (code generated once from the model, checked against the complex step)
    vs the same filter with numerically differenced Jacobians, on the
    same measurement streams (truth + document 002's sensor noise), plus its accuracy; and the
    exact-Jacobian filter as boomtip's chain runs it, with the rope's direction in every LiDAR
    frame as well (0.1 mrad, the order of perception.rope's per-frame noise)."""
    from boomtip.data.crane_model import CraneParams
    from boomtip.data.sim.crane_programmes import HOOK_SCENARIOS
    from boomtip.data.sim.crane_truth import simulate_crane
    from boomtip.data.sim.hook_measurements import SensorSimConfig, measurements_from_truth
    from boomtip.fusion.hook_config import HookFilterConfig
    from boomtip.fusion.hook_run import run_hook_filter
    from boomtip.tools.report.hook_eval import rmse_per_axis, world_hook_from_states

    params = CraneParams()
    spec = HOOK_SCENARIOS[program](params)
    truth = simulate_crane(params, spec.joints, spec.vessel, duration_s=duration_s)
    meas = measurements_from_truth(truth, seed=seed)
    # the same streams (the rope's draws come after the others') plus the rope
    meas_rope = measurements_from_truth(truth, SensorSimConfig(sigma_rope_rad=1e-4), seed=seed)
    out: dict = {"program": program, "duration_s": duration_s}
    exact, numeric = HookFilterConfig(jacobian="autodiff"), HookFilterConfig(jacobian="numeric")
    for label, cfg, m in (("analytic", exact, meas), ("numeric", numeric, meas), ("analytic_rope", exact, meas_rope)):
        run = run_hook_filter(m, "ekf", "flexible", params, cfg)
        keep = run.t >= 5.0
        _, _, p, v = world_hook_from_states(params, run.x[keep])
        ref_p = np.column_stack([np.interp(run.t[keep], truth.t, truth.p_hook_world[:, k]) for k in range(3)])
        ref_v = np.column_stack([np.interp(run.t[keep], truth.t, truth.v_hook_world[:, k]) for k in range(3)])
        out[label] = {"runtime_s": run.runtime_s, "runtime_fraction": run.realtime_fraction,
                      "rmse_pos_m": rmse_per_axis(p, ref_p).tolist(), "rmse_vel_mps": rmse_per_axis(v, ref_v).tolist()}
    out["ratio"] = out["numeric"]["runtime_s"] / out["analytic"]["runtime_s"]
    return out
