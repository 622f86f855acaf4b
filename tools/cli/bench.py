"""`boomtip bench ...`: each benchmark prints a ratio against a baseline measured in the same
run; `--json PATH` writes the figures."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from boomtip.tools.cli.common import SetOpt, resolve_scenario, user_errors

bench_app = typer.Typer(no_args_is_help=True, help="Benchmarks: each prints a ratio against a baseline measured in the same run.")


def write_bench_json(path: Optional[Path], result: dict, force: bool) -> None:
    if path is None:
        return
    from boomtip.data.io.recording import RecordingError, write_json

    if path.exists() and not force:
        raise RecordingError(f"--json {path} exists; pass --force to replace it")
    path.parent.mkdir(parents=True, exist_ok=True)
    write_json(path, result)


JsonOpt = typer.Option(None, "--json", help="Also write the figures (ratio, times, accuracies) to this JSON file.")
ForceOpt = typer.Option(False, "--force", help="Replace an existing --json file.")


@bench_app.command("startup")
def bench_startup_cmd(
    repeats: int = typer.Option(7, "--repeats", min=1, help="Fresh interpreters per command; the median counts."),
    json_path: Optional[Path] = JsonOpt,
    force: bool = ForceOpt,
) -> None:
    """`boomtip --help` and `boomtip scenarios` from a fresh interpreter, beside loading every chain."""
    from boomtip.tools.bench.startup import bench_startup

    with user_errors():
        r = bench_startup(repeats)
        write_bench_json(json_path, r, force)
    print(f"startup  median of {repeats} fresh interpreters (the interpreter alone {r['interpreter_s']:.3f} s)")
    for name, c in r["commands"].items():
        print(f"  boomtip {name:10s} {c['median_s']:6.3f} s  (min {c['min_s']:.3f}, max {c['max_s']:.3f})")
    print(f"  loading every chain   {r['load_all_s']:6.3f} s")
    verdict = "within" if r["within_ceiling"] else "ABOVE"
    print(f"  ratio {r['ratio']:.1f} (loading every chain / the slower command); {verdict} the {r['ceiling_s']:g} s ceiling")


@bench_app.command("process")
def bench_process_cmd(
    scenario: str = typer.Option("sts-loaded", "--scenario", "-s", help="The scenario simulated (128 x 1024, 20 Hz LiDAR)."),
    duration: float = typer.Option(20.0, "--duration", help="Seconds simulated."),
    repeats: int = typer.Option(3, "--repeats", min=1, help="Runs of each; the median counts."),
    recording: Optional[Path] = typer.Option(None, "--recording", help="Bench this recording instead of a simulated one."),
    installation: Optional[Path] = typer.Option(None, "--installation", help="Its installation file, where its format carries none."),
    json_path: Optional[Path] = JsonOpt,
    force: bool = ForceOpt,
) -> None:
    """`boomtip process` in real time factors (default workers and one), beside kiss-icp's own pipeline."""
    from boomtip.tools.bench.process import bench_process

    with user_errors():
        r = bench_process(scenario, duration, repeats, recording, installation)
        write_bench_json(json_path, r, force)
    print(f"process  {r['recording']}: {r['recording_s']:.1f} s, {r['lidar_frames']} LiDAR frames, median of {repeats}")
    labels = {"default": "boomtip process", "workers_1": "boomtip process --workers 1", "kiss_icp": "kiss-icp pipeline"}
    for key, label in labels.items():
        k = r[key]
        print(f"  {label:28s} {k['wall_s']:7.2f} s (min {k['min_s']:.2f}, max {k['max_s']:.2f})  {k['realtime_factor']:5.2f}x real time")
    print(f"  workers: {r['speedup_workers']:.2f}x over one; the feeder chain {r['feeder_apt_ms']:.1f} ms per LiDAR frame "
          f"(its worker's share included); kiss-icp {r['kiss_icp']['ms_per_lidar_frame']:.1f} ms per LiDAR frame")
    a = r["accuracy"]
    if "fused_mae_D_m" in a:
        print(f"  accuracy: fused D MAE {1000 * a['fused_mae_D_m']:.2f} mm, D-dot {1000 * a['fused_mae_D_dot_mps']:.2f} mm/s"
              + (f"; feeder position RMSE x/y/z {' / '.join(f'{1000 * v:.1f}' for v in a['feeder_rmse_pos_m'])} mm"
                 if "feeder_rmse_pos_m" in a else ""))
    print(f"  ratio {r['ratio']:.2f} (real-time factor, start-up and every output included)")


@bench_app.command("batch")
def bench_batch_cmd(
    scenario: str = typer.Option("sts-loaded", "--scenario", "-s"),
    recordings: int = typer.Option(6, "--recordings", min=2, help="Recordings simulated once, processed by each executor."),
    duration: float = typer.Option(6.0, "--duration", help="Seconds per recording."),
    json_path: Optional[Path] = JsonOpt,
    force: bool = ForceOpt,
) -> None:
    """`boomtip batch`'s speed-up of two workers over one, on Dask and on local processes."""
    from boomtip.tools.bench.batch import bench_batch

    with user_errors():
        r = bench_batch(scenario, recordings, duration)
        write_bench_json(json_path, r, force)
    print(f"batch  {recordings} recordings of {scenario}, {duration:g} s each")
    for kind in ("dask", "local"):
        k = r[kind]
        print(f"  {kind:5s}  1 worker {k['one_worker_wall_s']:6.2f} s, 2 workers {k['two_workers_wall_s']:6.2f} s: "
              f"{k['speedup']:.2f}x (the tasks' own time {k['tasks_own_s']['one_worker']:.2f} s on one, "
              f"{k['tasks_own_s']['two_workers']:.2f} s on two)")
    print(f"  ratio {r['ratio']:.2f} (Dask, two workers over one)")


@bench_app.command("raycast")
def bench_raycast_cmd(
    scenario: str = typer.Option("sts-loaded", "--scenario", "-s"),
    frames: int = typer.Option(20, "--frames", min=1),
    spinning_frames: int = typer.Option(10, "--spinning-frames", min=1, help="Frames of the 128 x 1024 spinning LiDAR."),
    repeats: int = typer.Option(30, "--repeats", min=1, help="Runs of each frame and of its raw cast, alternately; the fastest counts."),
    simulate_s: float = typer.Option(60.0, "--simulate-s", help="Also time `simulate` over this many seconds (0: skip)."),
    set_: Optional[list[str]] = SetOpt,
    json_path: Optional[Path] = JsonOpt,
    force: bool = ForceOpt,
) -> None:
    """LiDAR frames/s vs Open3D's raw cast of the same rays (the scenario's LiDAR; 128 x 1024
    spinning with motion during the sweep), hits vs the per-ray reference; vs the trimesh route; simulate vs real time."""
    from boomtip.tools.bench.raycast import bench_raycast

    with user_errors():
        s = resolve_scenario(scenario, set_)
        r = bench_raycast(s, frames=frames, simulate_s=simulate_s, spinning_frames=spinning_frames, repeats=repeats)
        write_bench_json(json_path, r, force)
    print(f"raycast  {r['triangles']} triangles, {r['points_per_frame']:.0f} points/frame, fastest of {repeats} runs per frame")
    print(f"  {'LiDAR':34s} {'rays':>7s} {'frames':>6s} {'boomtip f/s':>12s} {'raw cast f/s':>13s} {'efficiency':>10s}  hits vs reference")
    for label, key, n in ((f"{s.name} (scenario's)", "grid", frames), ("128 x 1024 spinning, sweep motion", "spinning", spinning_frames)):
        k = r[key]
        h = k["hits_vs_reference"]
        print(f"  {label:34s} {k['rays_per_frame']:7d} {n:6d} {k['boomtip_fps']:12.1f} {k['raw_cast_fps']:13.1f} {k['efficiency']:10.2f}  "
              f"{h['different']} of {h['rays']} differ (max range diff {h['max_range_diff_m']:.1e} m)")
    print(f"  baseline (posed trimesh + embreex per frame): {r['baseline_fps']:8.1f} frames/s vs boomtip {r['boomtip_fps']:.1f}: "
          f"{r['ratio_trimesh']:.1f}x, hit agreement {100 * r['hit_agreement']:.2f} %")
    print(f"  ratio {r['ratio']:.2f} (efficiency_grid {r['efficiency_grid']:.2f}, efficiency_spinning {r['efficiency_spinning']:.2f})")
    if "simulate_realtime_factor" in r:
        print(f"simulate {r['simulate_duration_s']:g} s of {s.name} in {r['simulate_wall_s']:.1f} s: "
              f"{r['simulate_realtime_factor']:.1f}x real time")


@bench_app.command("perception")
def bench_perception_cmd(
    scenario: str = typer.Option("sts-loaded", "--scenario", "-s"),
    frames: int = typer.Option(30, "--frames", min=1),
    set_: Optional[list[str]] = SetOpt,
    json_path: Optional[Path] = JsonOpt,
    force: bool = ForceOpt,
) -> None:
    """Deck detection and its stages vs Open3D's own calls on the same frames; every method's APT and MAE."""
    from boomtip.tools.bench.stages import bench_perception

    with user_errors():
        s = resolve_scenario(scenario, set_)
        r = bench_perception(s, frames=frames)
        write_bench_json(json_path, r, force)
    print(f"perception  {s.name}, {frames} LiDAR frames, {r['points_per_frame']:.0f} points/frame")
    print(f"  baseline: {r['baseline']}")
    print(f"  {'stage':28s} {'boomtip ms':>11s} {'Open3D ms':>10s} {'ratio':>7s}")
    for label, key in (("preprocess (same operations)", "preprocess"), ("plane search (same points)", "plane_search"),
                       ("deck detection end to end", "deck_detection")):
        ms = r[f"{key}_ms"]
        print(f"  {label:28s} {ms['boomtip']:11.2f} {ms['open3d']:10.2f} {ms['open3d'] / ms['boomtip']:6.1f}x")
    print(f"  deck D MAE: boomtip {1e3 * r['deck_mae_m']['boomtip']:.2f} mm (max {1e3 * r['deck_max_m']['boomtip']:.2f}), "
          f"Open3D {1e3 * r['deck_mae_m']['open3d']:.2f} mm (max {1e3 * r['deck_max_m']['open3d']:.2f})")
    print(f"  ratio {r['ratio']:.1f}x")
    print("  the heave stages vs their frozen references (tools/bench/references/heave*.py), on the pipeline's inputs, least of 5 calls each:")
    print(f"    {'stage':20s} {'boomtip ms':>11s} {'reference ms':>13s} {'ratio':>7s} {'max |difference|':>17s} {'cold, CPU: boomtip, reference ms':>34s}")
    for stage, k in r["heave_stages"].items():
        print(f"    {stage:20s} {k['boomtip_ms']:11.3f} {k['reference_ms']:13.3f} {k['ratio']:6.2f}x {k['max_abs_difference']:17.2e} "
              f"{k['boomtip_cold_cpu_ms']:20.3f} {k['reference_cold_cpu_ms']:13.3f}")
    print("  every method, as the pipeline times it:")
    for m, k in r["methods"].items():
        unit = "mm/s" if m.startswith("doppler") else "mm"
        print(f"    {m:20s} APT {k['apt_ms']:6.2f} ms   MAE {1e3 * k['mae']:6.2f} {unit}   valid {100 * k['valid_fraction']:.0f} %")
        print("      " + ", ".join(f"{s} {v:.3f}" for s, v in k["stages_ms"].items()))


@bench_app.command("fusion")
def bench_fusion_cmd(
    program: str = typer.Option("hook-2", "--program", help="hook-1 .. hook-4 (document 002, 5.2)"),
    duration: float = typer.Option(60.0, "--duration"),
    json_path: Optional[Path] = JsonOpt,
    force: bool = ForceOpt,
) -> None:
    """Hook EKF (flexible) runtime vs the same filter with numerically differenced Jacobians."""
    from boomtip.tools.bench.stages import bench_fusion
    from boomtip.tools.config.scenario import ScenarioError

    with user_errors():
        if program not in ("hook-1", "hook-2", "hook-3", "hook-4"):
            raise ScenarioError(f"--program '{program}': expected hook-1, hook-2, hook-3 or hook-4")
        r = bench_fusion(program, duration)
        write_bench_json(json_path, r, force)
    print(f"fusion  EKF flexible on {program}, {duration:g} s, LiDAR = truth + 1.5 cm noise (document 002's measurement)")
    names = {"analytic": "exact Jacobian", "numeric": "numeric Jacobian", "analytic_rope": "exact, + rope 0.1 mrad"}
    for label, name in names.items():
        k = r[label]
        f = lambda v: "/".join(f"{100 * x:.2f}" for x in v)  # noqa: E731
        print(f"  {name:22s}: {k['runtime_s']:6.2f} s = {100 * k['runtime_fraction']:5.2f} % of real time, "
              f"RMSE pos {f(k['rmse_pos_m'])} cm, vel {f(k['rmse_vel_mps'])} cm/s")
    print(f"  ratio numeric / exact {r['ratio']:.2f}x")


@bench_app.command("sweep")
def bench_sweep_cmd(
    scenario: str = typer.Option("sts-empty", "--scenario", "-s"),
    tasks: int = typer.Option(16, "--tasks", min=2),
    duration: float = typer.Option(1.0, "--duration", help="Simulated seconds per task."),
    json_path: Optional[Path] = JsonOpt,
    force: bool = ForceOpt,
) -> None:
    """Per-task overhead of the local and Dask executors; two workers against one."""
    from boomtip.tools.bench.sweep import bench_sweep

    with user_errors():
        r = bench_sweep(scenario, tasks, duration)
        write_bench_json(json_path, r, force)
    print(f"sweep  {r['tasks']} tasks of {scenario}, {duration:g} s simulated each")
    for kind in ("local", "dask"):
        k = r[kind]
        print(f"  {kind:5s} 1 worker: {k['wall_s']:6.2f} s wall, tasks' own {k['tasks_own_s']:6.2f} s, "
              f"overhead {1e3 * k['overhead_per_task_s']:6.1f} ms/task (against the local worker's own time)")
    print(f"  local 2 workers: {r['two_workers_wall_s']:6.2f} s wall")
    print(f"  ratio {r['ratio']:.2f} (two workers / one)")


@bench_app.command("io")
def bench_io_cmd(
    pcap: Optional[Path] = typer.Option(None, "--pcap", help="An Ouster pcap (its metadata JSON beside it); default: "
                                        "the OS1-128 capture in tests/data/real/ouster."),
    frames: int = typer.Option(60, "--frames", min=1, help="Frames to read (the pcap is read again until there are)."),
    rate_hz: float = typer.Option(20.0, "--rate-hz", min=0.1, help="The frame rate the real-time ratio assumes."),
    mcap_s: float = typer.Option(5.0, "--mcap-s", help="Also time reading an MCAP of this many simulated seconds (0: skip)."),
    json_path: Optional[Path] = JsonOpt,
    force: bool = ForceOpt,
) -> None:
    """Loader read rates: an Ouster pcap against real time and against ouster-sdk's own loop; an MCAP."""
    from boomtip.tools.bench.io import bench_io

    with user_errors():
        r = bench_io(pcap, frames, rate_hz, mcap_s)
        write_bench_json(json_path, r, force)
    print(f"io  {r['pcap']}: {r['frames']} frames of {r['points_per_frame']:.0f} points")
    print(f"  boomtip loader:     {r['pcap_ms_per_frame']:6.2f} ms/frame")
    print(f"  ouster-sdk's loop:  {r['ouster_sdk_ms_per_frame']:6.2f} ms/frame (overhead {r['overhead_vs_ouster_sdk']:.2f}x)")
    print(f"  ratio {r['ratio']:.1f}x real time at {r['assumed_rate_hz']:g} Hz")
    if "mcap_ratio" in r:
        print(f"  MCAP: {r['mcap_frames']} frames of {r['mcap_duration_s']:g} s read in {r['mcap_wall_s']:.2f} s: "
              f"{r['mcap_ratio']:.1f}x real time")


@bench_app.command("ground")
def bench_ground_cmd(
    pcap: Optional[list[Path]] = typer.Option(None, "--pcap", help="Ouster pcaps (default: the three in tests/data/real/ouster)."),
    seeds: int = typer.Option(20, "--seeds", min=1),
    tolerance_m: float = typer.Option(0.01, "--tolerance-m", help="|D - Open3D's D| counted as agreeing."),
    reference_iterations: int = typer.Option(20000, "--reference-iterations", min=100),
    json_path: Optional[Path] = JsonOpt,
    force: bool = ForceOpt,
) -> None:
    """Real LiDAR scans, the ground as the deck: deck D over seeds against Open3D's exhaustive segment_plane."""
    from boomtip.tools.bench.io import bench_ground

    with user_errors():
        r = bench_ground(pcap, seeds, tolerance_m, reference_iterations)
        write_bench_json(json_path, r, force)
    print(f"ground  {seeds} seeds, band {100 * r['threshold_m']:.0f} cm, reference: Open3D segment_plane with "
          f"{r['reference_iterations']} hypotheses, no early stop")
    print(f"  {'scan':40s} {'ground':>6s} {'D ref':>7s} {'<=tol':>6s} {'max err':>8s} {'ms':>6s} | Open3D 1000: {'<=tol':>5s} {'max err':>8s} {'ms':>6s}")
    for s in r["scans"]:
        print(f"  {s['scan']:40s} {100 * s['ground_fraction']:5.1f}% {s['D_reference_m']:7.3f} {s['within_tolerance']:4d}/{seeds} "
              f"{100 * s['max_error_m']:6.1f}cm {s['deck_ms']:6.1f} | {s['open3d_default_within_tolerance']:9d}/{seeds} "
              f"{100 * s['open3d_default_max_error_m']:6.1f}cm {s['open3d_default_ms']:6.1f}")
    print(f"  worst scan: {r['worst_within_tolerance']}/{seeds} within {100 * tolerance_m:g} cm; ratio (Open3D ms / ours) {r['ratio']:.1f}x")


@bench_app.command("hook")
def bench_hook_cmd(
    scenario: str = typer.Option("hook-2", "--scenario", "-s"),
    duration: float = typer.Option(20.0, "--duration", help="Seconds of the scenario to run."),
    set_: Optional[list[str]] = SetOpt,
    json_path: Optional[Path] = JsonOpt,
    force: bool = ForceOpt,
) -> None:
    """A hook run taken apart: simulation, perception, each estimator, outputs, against real time."""
    from boomtip.tools.bench.hook import bench_hook

    with user_errors():
        r = bench_hook(scenario, duration, set_)
        write_bench_json(json_path, r, force)
    print(f"hook  {r['program']}, {r['duration_s']:g} s, {r['lidar_frames']} LiDAR frames")
    print(f"  {'part':28s} {'wall s':>8s} {'x real time':>12s}")
    for part in ("simulation", "perception", "estimators", "end_to_end"):
        print(f"  {part:28s} {r['wall_s'][part]:8.2f} {r['realtime_factor'][part]:11.2f}x")
    print(f"  {'outputs':28s} {r['wall_s']['outputs']:8.2f}")
    for name, e in r["estimators"].items():
        print(f"  {name:28s} {e['runtime_s']:8.2f} {e['percent_of_real_time']:10.2f} % of real time")
    print(f"  block segmentation + fit: {r['block_ms_per_frame']['mean']:.1f} ms/frame (p95 {r['block_ms_per_frame']['p95']:.1f}; "
          f"the first frame, which builds the block model, {r['block_ms_per_frame']['first_frame']:.0f} ms); "
          f"rope fit {r['rope_ms_per_frame']['mean']:.1f} ms/frame; peak RSS {r['peak_rss_mb']:.0f} MB")
    b = r["block_against_reference"]
    print(f"  block segmentation + fit against its reference (tools/hook_reference.py), same frames, CPU: "
          f"{b['current_cpu_ms_per_frame']:.1f} vs {b['reference_cpu_ms_per_frame']:.1f} ms/frame, ratio {b['cpu_ratio']:.2f}; "
          f"the same fix in {b['same_fix']} of {b['frames']} frames")
    c = r["realtime_factor_cpu"]
    print(f"  by CPU time: simulation {c['simulation']:.2f}x, perception {c['perception']:.2f}x, estimators "
          f"{c['estimators']:.2f}x, end to end {c['end_to_end']:.2f}x; estimators "
          + ", ".join(f"{k} {e['cpu_percent_of_real_time']:.2f} %" for k, e in r["estimators"].items()))
    for name, u in r["ukf_against_core_model"].items():
        print(f"  {name}: the core model on the sigma points {u['cpu_s']:.2f} s CPU, {u['cpu_ratio']:.2f}x the generated "
              f"model's ({'the same estimate' if u['same_estimate'] else 'a different estimate'})")
    for name, u in r["estimators_against_rk4"].items():
        print(f"  {name} with RK4: {u['cpu_s']:.2f} s CPU, {u['cpu_ratio']:.2f}x the chain's {u['cpu_s_chain']:.2f} s; the hook within "
              f"{1e3 * u['max_pos_difference_m']:.4f} mm, {1e3 * u['max_vel_difference_mps']:.4f} mm/s")
        print(f"  {name} stepwise (before the UKF's window, the EKF's mean by the model): {u['cpu_s_stepwise']:.2f} s CPU, "
              f"{u['cpu_ratio_stepwise']:.2f}x the chain's; the hook within {1e3 * u['max_pos_difference_stepwise_m']:.4f} mm, "
              f"{1e3 * u['max_vel_difference_stepwise_mps']:.4f} mm/s")
    t = r["end_to_end_two_cores"]
    print(f"  the run end to end: serial {t['wall_s']['serial']:.2f} s ({t['realtime_factor']['serial']:.2f}x real time), "
          f"on two cores {t['wall_s']['two_cores']:.2f} s, {t['speedup']:.2f}x faster; same outputs: "
          + ", ".join(f"{k} {'yes' if v else 'NO'}" for k, v in t["same_outputs"].items()))
    print(f"  by CPU time: serial {t['cpu_s_own']['serial']:.2f} s; on two cores {t['cpu_s_with_children']['two_cores']:.2f} s "
          f"in all, {t['cpu_s_own']['two_cores']:.2f} s in the parent (an idle machine at best "
          f"{t['realtime_factor_parent_cpu']:.2f}x real time)")
    c = r["command"]
    print(f"  the whole command ({' '.join(c['argv'])}, start-up included): {c['wall_s']:.2f} s "
          f"(runs {', '.join(f'{w:.2f}' for w in c['wall_s_each'])})")
    for name, a in r["accuracy"].items():
        print(f"  {name}: hook RMSE x/y/z " + " / ".join(f"{100 * v:.2f}" for v in a["rmse_pos_m"]) + " cm, velocity "
              + " / ".join(f"{100 * v:.2f}" for v in a.get("rmse_vel_mps", [])) + f" cm/s, NEES {a.get('nees_pos_mean', float('nan')):.2f}")
    if not r["accuracy_same_in_process"]:
        print("  (the bench's own run of the scenario gave other accuracies than the timed command's)")
    print(f"  ratio {r['ratio']:.2f}x real time end to end (the whole command)")


@bench_app.command("feeder")
def bench_feeder_cmd(
    scenario: str = typer.Option("sts-loaded", "--scenario", "-s"),
    duration: float = typer.Option(60.0, "--duration", help="Seconds of the scenario to run."),
    set_: Optional[list[str]] = SetOpt,
    json_path: Optional[Path] = JsonOpt,
    force: bool = ForceOpt,
) -> None:
    """The feeder's 6-DOF chain against plain kiss-icp odometry on the same frames."""
    from boomtip.tools.bench.feeder import bench_feeder

    with user_errors():
        r = bench_feeder(scenario, duration, set_)
        write_bench_json(json_path, r, force)
    c, k = r["chain"], r["kiss_icp"]
    print(f"feeder  {r['scenario']}, {r['duration_s']:g} s, {r['lidar_frames']} LiDAR frames")
    print(f"  {'':10s} {'pos RMSE x/y/z [mm]':>24s} {'angle RMSE r/p/y [deg]':>26s} {'ms/frame':>9s}")
    for name, b in (("chain", c), ("kiss-icp", k)):
        print(f"  {name:10s} {' / '.join(f'{1000 * v:6.1f}' for v in b['rmse_pos_m']):>24s} "
              f"{' / '.join(f'{v:.4f}' for v in b['rmse_rpy_deg']):>26s} {b['ms_per_lidar_frame']:9.2f}")
    print(f"  kiss-icp / chain: position {' / '.join(f'{v:.1f}' for v in r['ratio_pos'])}, "
          f"angles {' / '.join(f'{v:.1f}' for v in r['ratio_rpy'])}")
    beside = any(m["taken_frame"] != m["started_frame"] for m in c["model_merges"] if m["status"] == "ok")
    merges = (f"waits for its model's merges (run beside the frames) {c['merge_wait_ms']['total']:.0f} ms in all, "
              f"{c['merge_wait_ms']['max']:.0f} ms at most" if beside else
              "its model's merges ran inline: " + ", ".join(f"{m['frames']} frames {m['worker_s']:.2f} s" for m in c["model_merges"]))
    print(f"  chain: worst LiDAR frame {c['ms_worst_lidar_frame']:.1f} ms; {merges}; everything in its ms/frame")
    stages = sorted(c["ms_per_lidar_frame_by_stage"].items(), key=lambda kv: -kv[1])
    print("  chain's ms/frame by stage: " + ", ".join(f"{name} {ms:.2f}" for name, ms in stages))
    print(f"  ratio {r['ratio']:.2f} (smallest over the six axes; above 1 the chain is better on every one)")


@bench_app.command("lift")
def bench_lift_cmd(
    scenario: str = typer.Option("lift", "--scenario", "-s", help="The lift scenario simulated."),
    duration: Optional[float] = typer.Option(None, "--duration", help="Seconds simulated (default: the scenario's)."),
    repeats: int = typer.Option(3, "--repeats", min=1, help="Runs of each; the median counts."),
    json_path: Optional[Path] = JsonOpt,
    force: bool = ForceOpt,
) -> None:
    """The lift chain's real-time factor (`boomtip process`), beside the hook chain alone and one worker."""
    from boomtip.tools.bench.lift import bench_lift

    with user_errors():
        r = bench_lift(scenario, duration, repeats)
        write_bench_json(json_path, r, force)
    print(f"lift  {r['recording']}, median of {repeats}")
    labels = {"lift": "the lift chain", "hook_alone": "the hook chain alone", "lift_workers_1": "the lift chain, --workers 1"}
    for key, label in labels.items():
        k = r[key]
        print(f"  {label:28s} {k['wall_s']:7.2f} s (min {k['min_s']:.2f}, max {k['max_s']:.2f})  {k['realtime_factor']:5.2f}x real time")
    print(f"  a LiDAR frame's stages {r['frame_ms']:.1f} ms; the lift costs {r['lift_over_hook']:.2f}x the hook chain alone")
    a = r["accuracy"]
    if a:
        print("  accuracy: " + ", ".join(f"{k} {v:.4g}" for k, v in a.items()))
    print(f"  ratio {r['ratio']:.2f} (real-time factor, start-up and every output included)")

