"""Sensitivity sweeps (document 000, 5.3.2): one scenario, a grid of one parameter, runs in
parallel processes, KPIs plotted against the parameter."""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor
from pathlib import Path


from boomtip.data.io.recording import commit_output, prepare_output, write_json

# parameter -> (scenario overrides for a value, default grid, axis label)
PARAMS: dict[str, tuple] = {
    "delay": (lambda v: [f"lidar.latency_s={v}", f"radar.latency_s={v}"], [0.0, 0.05, 0.1, 0.2, 0.3], "measurement delay [s]"),
    "mru_noise": (lambda v: [f"mru.angle_noise_deg={v}", f"mru.rate_noise_degps={1.25 * v}"], [0.0, 0.02, 0.05, 0.1, 0.2], "MRU angle noise [deg]"),
    "rate": (lambda v: [f"lidar.rate_hz={v}", f"radar.rate_hz={2 * v}"], [1.0, 2.0, 5.0, 10.0, 20.0], "LiDAR rate [Hz] (radar twice)"),
    "density": (lambda v: [f"lidar.res_h_deg={v}", f"lidar.res_v_deg={v}", f"radar.res_az_deg={2 * v}", f"radar.res_el_deg={3 * v}"],
                [0.25, 0.5, 1.0, 2.0], "LiDAR angular resolution [deg] (radar 2x/3x)"),
    "false_reflectors": (lambda v: [f"feeder.reflectors.false_bright_points={int(v)}"], [0, 5, 10, 20, 40], "false bright patches"),
}


def _one(args: tuple) -> dict:
    scenario, overrides, duration, value = args
    import tempfile

    from boomtip.data.scenario import load_scenario
    from boomtip.data.sources import simulation_for
    from boomtip.tools.runner import run_into

    s = load_scenario(scenario, overrides + [f"duration_s={duration}"])
    with tempfile.TemporaryDirectory() as tmp:
        res = run_into(simulation_for(s), Path(tmp), rerun=False, report=False)
    return {"value": value, "overrides": overrides, "kpis": res.kpis}


def run_sweep(scenario: str, param: str, values: list[float] | None, duration_s: float, out: Path, jobs: int,
              force: bool, base_overrides: list[str] | None = None, progress=None) -> dict:
    if param not in PARAMS:
        raise KeyError(f"unknown sweep parameter '{param}'; expected one of {', '.join(PARAMS)}")
    to_overrides, default_grid, label = PARAMS[param]
    grid = values or default_grid
    staging = prepare_output(out, force)
    try:
        tasks = [(scenario, list(base_overrides or []) + to_overrides(v), duration_s, v) for v in grid]
        results = []
        with ProcessPoolExecutor(max_workers=max(1, jobs)) as pool:
            for r in pool.map(_one, tasks):
                results.append(r)
                if progress:
                    progress(1)
        summary = {"scenario": scenario, "parameter": param, "label": label, "duration_s": duration_s, "runs": results}
        write_json(staging / "sweep.json", summary)
        plot_sweep(staging / f"sweep_{param}.png", summary)
    except BaseException:
        import shutil

        shutil.rmtree(staging, ignore_errors=True)
        raise
    commit_output(staging, out)
    return summary


def plot_sweep(path: Path, summary: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from boomtip.tools.report import COLORS

    x = [r["value"] for r in summary["runs"]]
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    names = list(summary["runs"][0]["kpis"].get("solutions", {}))
    for name in names:
        for ax, key, unit in ((axes[0], "mae_D_m", "mm"), (axes[1], "mae_D_dot_mps", "mm/s")):
            if name == "doppler_radar" and key == "mae_D_m":
                continue  # drifts by design
            y = [1e3 * r["kpis"]["solutions"][name][key] for r in summary["runs"]]
            ax.plot(x, y, "o-", color=COLORS.get(name), label=name)
            ax.set_ylabel(f"MAE {'D' if key == 'mae_D_m' else 'D-dot'} [{unit}]")
    for ax in axes:
        ax.set_xlabel(summary["label"])
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(f"Sensitivity to {summary['label']} ({summary['scenario']}, {summary['duration_s']:g} s per run)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
