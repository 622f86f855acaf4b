"""What `boomtip run` and `boomtip process` print when a run is done: its figures, read from
kpis.json's blocks."""

from __future__ import annotations

from rich.markup import escape

from boomtip.tools.cli.common import console

__all__ = ["print_kpis", "feeder_online_line"]


def print_kpis(kpis: dict) -> None:
    """A run's figures on the console: the tables of report.md, shortened."""
    from boomtip.tools.report.feeder import estimated_motion_line
    from boomtip.tools.report.heave import estimated_tables, kpi_table, measurement_table

    seed = kpis['seed'] if kpis.get('seed') is not None else '-'
    print(f"\n{kpis['scenario']} (seed {seed}, {kpis['duration_s']:.0f} s)\n")
    for w in kpis.get("warnings", []):
        console.print("[bold yellow]warning:[/] " + escape(w), highlight=False)
    if "hook" in kpis:
        h = kpis["hook"]
        seg = h["segmentation"]
        scored = (f"precision {seg['precision']:.4f}, recall {seg['recall']:.4f}, " if "precision" in seg else "")
        print(f"hook segmentation: model fit in {100 * seg['found_fraction']:.1f} % and sparse fix in "
              f"{100 * seg.get('sparse_fraction', 0.0):.1f} % of {seg['frames']} frames, {scored}{seg['apt_ms']:.1f} ms/frame")
        if "rope" in h:
            from boomtip.tools.report.hook import rope_summary

            print(rope_summary(h["rope"]))
        if "estimated" in h:  # no truth: the path each estimator made of the hook
            print("No truth to score against; the hook's path as estimated (world frame):")
            print(f"{'estimator':14s} {'x range [m]':>18s} {'y range [m]':>18s} {'z range [m]':>18s} {'top speed':>10s} "
                  f"{'sigma rel. tip x/y/z [cm]':>26s}")
            for name, e in h["estimated"].items():
                if e.get("samples"):
                    rng = [f"{a:.2f} to {b:.2f}" for a, b in zip(e["min_m"], e["max_m"])]
                    sig = "/".join(f"{100 * x:.2f}" for x in e["median_sigma_rel_m"])
                    print(f"{name:14s} {rng[0]:>18s} {rng[1]:>18s} {rng[2]:>18s} {e['top_speed_mps']:8.2f}m/s {sig:>26s}")
            return
        print(f"{'estimator':14s} {'RMSE pos x/y/z [cm]':>24s} {'RMSE vel x/y/z [cm/s]':>24s} {'runtime':>9s} {'NEES (3)':>9s}"
              f" {'rel. tip pos [cm]':>20s}")
        for name, k in h.items():
            if isinstance(k, dict) and "rmse_pos_m" in k:
                f = lambda v: "/".join(f"{100 * x:.2f}" for x in v)  # noqa: E731
                print(f"{name:14s} {f(k['rmse_pos_m']):>24s} {f(k['rmse_vel_mps']):>24s} {100 * k['runtime_fraction']:8.2f}% "
                      f"{k.get('nees_pos_mean', float('nan')):9.2f} {f(k.get('rmse_rel_pos_m', [float('nan')] * 3)):>20s}")
        return
    if "estimated" in kpis:  # no truth: what was measured and estimated, not how well
        print("No truth to score against; what was measured and estimated:")
        print(estimated_tables(kpis))
    else:
        print("Raw measurements (before any filter):")
        print(measurement_table(kpis))
    if "solutions" in kpis:
        print("\nSolutions after the Kalman filter (" + kpis["solutions_note"] + "), document 000's Table 5.4 beside ours:")
        print(kpi_table(kpis))
    f = kpis.get("feeder")
    side = (f or {}).get("D_side_by_side", {})
    if f and "rmse_pos_m" in f:
        mm = lambda v: " / ".join(f"{1000 * x:.1f}" for x in v)  # noqa: E731
        print(f"\nFeeder 6-DOF relative to the crane vessel ({f['note']}): position RMSE x/y/z {mm(f['rmse_pos_m'])} mm "
              f"(max {mm(f['max_pos_m'])}), angles r/p/y {' / '.join(f'{x:.3f}' for x in f['rmse_rpy_deg'])} deg, "
              f"NEES {f['nees_mean']:.2f} (6), {f['apt_ms']:.1f} ms per LiDAR frame")
        online = feeder_online_line(f)
        if online:
            print(online)
        if "feeder_rmse_m" in side:
            print(f"D from the feeder's pose {1000 * side['feeder_rmse_m']:.2f} mm RMSE; the heave chain's fused D "
                  f"{1000 * side['heave_fused_rmse_m']:.2f} mm")
    elif f:
        why = f"nothing scored: {f['note']}" if "note" in f else "no truth to score"
        print(f"\nFeeder 6-DOF: {f.get('apt_ms', float('nan')):.1f} ms per LiDAR frame ({why})")
        motion = estimated_motion_line(f.get("estimated"))
        if motion:
            print(motion)
    if side and "feeder_rmse_m" not in side:
        print(f"D from the feeder's pose and the heave chain's fused D: {1000 * side['feeder_minus_fused_rms_m']:.2f} mm RMS apart")


def feeder_online_line(f: dict) -> str | None:
    """The feeder's figures as a live controller had them (kpis' `feeder.online`: each row
    levelled and defined with what was known at its time), for the line beside the offline
    ones; None when the run has no scored online block."""
    o = f.get("online") or {}
    if "rmse_pos_m" not in o:
        return None
    mm = " / ".join(f"{1000 * x:.1f}" for x in o["rmse_pos_m"])
    deg = " / ".join(f"{x:.3f}" for x in o["rmse_rpy_deg"])
    return f"  online (causal calibration): position RMSE x/y/z {mm} mm, angles r/p/y {deg} deg, NEES {o['nees_mean']:.2f} (6)"
