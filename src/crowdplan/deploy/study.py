"""Robustness study of a deployed model: success and collision rates against position noise and
pose latency, in simulated deployment (``crowdplan.deploy.simulate``).

    python -m crowdplan.deploy.study --model lsa-dsac --out results/deploy/noise

writes one ``summary.json`` per setting, ``study.csv`` (one row per setting) and, with
``--plots DIR``, ``deploy_noise.png`` and ``deploy_latency.png`` drawn from the CSV.
"""

from __future__ import annotations

import argparse
import csv
import logging
import tempfile
from pathlib import Path

POSITION_NOISE = (0.0, 0.02, 0.05, 0.1, 0.2)  # m
VELOCITY_TAUS = (0.0, 0.5)  # s
LATENCY = (0.25, 0.5, 0.75, 1.0)  # s (zero latency is the first noise row)
COLUMNS = (
    "position_noise",
    "latency",
    "velocity_tau",
    "episodes",
    "success_rate",
    "collision_rate",
    "timeout_rate",
    "time_to_goal",
    "safety_stop_share",
)


def settings() -> list[tuple[float, float, float]]:
    """(position noise, latency, velocity tau) of every run."""
    rows = [(noise, 0.0, tau) for tau in VELOCITY_TAUS for noise in POSITION_NOISE]
    return rows + [(0.0, latency, 0.0) for latency in LATENCY]


def run_study(model: str, out: Path, episodes: int) -> Path:
    """Run every setting on the first ``episodes`` test cases; returns the CSV path."""
    from crowdplan import evaluation
    from crowdplan.config import WorldConfig
    from crowdplan.deploy.cli import _export_folder
    from crowdplan.deploy.onnx_policy import OnnxPolicy
    from crowdplan.deploy.runtime import RuntimeConfig
    from crowdplan.deploy.simulate import SensorModel, run_deployment, sensor_dict
    from crowdplan.io import write_json

    with tempfile.TemporaryDirectory() as scratch:
        policy = OnnxPolicy(_export_folder(model, scratch))
    config = WorldConfig.from_dict(policy.manifest.world)
    seeds = evaluation.test_seeds(episodes)
    logging.getLogger("crowdplan.deploy").setLevel(logging.ERROR)  # stops are counted instead
    rows = []
    for noise, latency, tau in settings():
        sensor = SensorModel(position_noise=noise, latency=latency)
        # poses arrive `latency` late by design: stale only beyond that
        runtime = RuntimeConfig(
            control_rate=1.0 / config.dt, velocity_tau=tau, max_pose_age=latency + 0.5
        )
        records, stats = run_deployment(policy, config, seeds, sensor, runtime)
        summary = evaluation.summarize(records)
        name = f"noise{noise:g}-latency{latency:g}-tau{tau:g}"
        meta = {"model": model, "sensor": sensor_dict(sensor), "velocity_tau": tau, **stats}
        write_json(out / name / "summary.json", {**summary, "meta": meta})
        rows.append(
            {
                "position_noise": noise,
                "latency": latency,
                "velocity_tau": tau,
                "episodes": len(records),
                **{k: summary[k]["value"] for k in COLUMNS[4:8]},
                "safety_stop_share": stats["safety_stop_share"],
            }
        )
        print(name, {k: round(v, 3) for k, v in rows[-1].items()}, flush=True)
    path = out / "study.csv"
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    return path


def plot_study(csv_path: Path, out_dir: Path) -> list[Path]:
    """``deploy_noise.png`` and ``deploy_latency.png`` from a ``study.csv``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with csv_path.open() as handle:
        rows = [{k: float(v) for k, v in row.items()} for row in csv.DictReader(handle)]
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, x_key, groups in (
        ("deploy_noise.png", "position_noise", VELOCITY_TAUS),
        ("deploy_latency.png", "latency", (0.0,)),
    ):
        fig, ax = plt.subplots(figsize=(5.5, 3.6))
        for tau in groups:
            if x_key == "position_noise":
                sel = [r for r in rows if r["latency"] == 0 and r["velocity_tau"] == tau]
            else:
                sel = [r for r in rows if r["position_noise"] == 0 and r["velocity_tau"] == tau]
            sel.sort(key=lambda r: r[x_key])
            xs = [r[x_key] for r in sel]
            label = f", velocity filter {tau:g} s" if len(groups) > 1 else ""
            ax.plot(xs, [r["success_rate"] for r in sel], "o-", label=f"success{label}")
            ax.plot(xs, [r["collision_rate"] for r in sel], "s--", label=f"collision{label}")
        ax.set_xlabel("position noise std (m)" if x_key == "position_noise" else "latency (s)")
        ax.set_ylabel("rate")
        ax.set_ylim(0, 1)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        ax.set_title(f"{int(rows[0]['episodes'])} circle_crossing test cases")
        fig.tight_layout()
        path = out_dir / name
        fig.savefig(path, dpi=110)
        plt.close(fig)
        paths.append(path)
    return paths


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="lsa-dsac")
    parser.add_argument("--out", default="results/deploy/noise")
    parser.add_argument("--episodes", type=int, default=500)
    parser.add_argument("--plots", default=None, help="folder for the two PNG plots")
    parser.add_argument("--plot-only", action="store_true", help="redraw from study.csv")
    args = parser.parse_args(argv)
    out = Path(args.out)
    path = out / "study.csv" if args.plot_only else run_study(args.model, out, args.episodes)
    if args.plots:
        for png in plot_study(path, Path(args.plots)):
            print(f"wrote {png}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
