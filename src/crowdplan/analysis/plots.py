"""Training curves drawn from a run folder's CSV files."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from crowdplan.io import atomic_write


def _read(path: Path) -> dict[str, np.ndarray]:
    """CSV columns as arrays: numbers as float, anything else kept as strings."""
    if not path.exists():
        return {}
    with open(path) as f:
        rows = list(csv.DictReader(f))
    if not rows:
        return {}
    columns = {}
    for key in rows[0]:
        values = [r[key] for r in rows]
        try:
            columns[key] = np.array([float(v) if v else np.nan for v in values])
        except ValueError:
            columns[key] = np.array(values)
    return columns


def rolling_mean(values: np.ndarray, window: int) -> np.ndarray:
    """Mean of the last ``window`` values at each position (shorter at the start)."""
    cumsum = np.concatenate([[0.0], np.cumsum(values)])
    idx = np.arange(1, len(values) + 1)
    lo = np.maximum(idx - window, 0)
    return (cumsum[idx] - cumsum[lo]) / (idx - lo)


def plot_training_curves(run_dir: str | Path, out: str | Path | None = None, window: int = 100):
    """Discounted return and success rate per training episode (rolling mean over ``window``),
    with the validation results on top; written to ``run_dir/curves.png`` by default."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    run_dir = Path(run_dir)
    episodes = _read(run_dir / "episodes.csv")
    validation = _read(run_dir / "validation.csv")
    if not episodes:
        raise FileNotFoundError(f"{run_dir / 'episodes.csv'} is missing or empty")
    fig = Figure(figsize=(9, 3.6))
    FigureCanvasAgg(fig)
    ax_reward, ax_success = fig.subplots(1, 2)
    x = episodes["episode"]
    success = (episodes["outcome"] == "goal").astype(float)
    ax_reward.plot(x, rolling_mean(episodes["discounted_return"], window), label="training")
    ax_success.plot(x, rolling_mean(success, window), label="training")
    if validation:
        ax_reward.plot(validation["episode"], validation["mean_reward"], "o-", label="validation")
        ax_success.plot(validation["episode"], validation["success_rate"], "o-", label="validation")
    ax_reward.set(xlabel="episode", ylabel=f"discounted return (mean of {window})")
    ax_success.set(xlabel="episode", ylabel=f"success rate (mean of {window})", ylim=(-0.02, 1.02))
    for ax in (ax_reward, ax_success):
        ax.grid(alpha=0.3)
        ax.legend(loc="lower right")
    fig.suptitle(run_dir.name)
    fig.tight_layout()
    out = Path(out) if out else run_dir / "curves.png"
    atomic_write(out, lambda f: fig.savefig(f, format="png", dpi=90), mode="wb")
    return out
