"""Temperature, entropy and critic traces of DSAC runs, and the collapse diagnostics of
docs/training.md.

A run folder (``results/train/<run>`` or ``runs/<run>``) holds ``config.yaml``,
``episodes.csv`` (one row per training episode, sampled actions), ``updates.csv`` (the
statistics of one update every ``log_interval`` episodes) and ``validation.csv`` (the greedy
policy on the validation cases). From them this module draws, per run, the temperature, the
policy entropy against its target, the mean Q value against the reachable return range and the
success rates, and computes the events of the collapse diagnosis::

    python -m crowdplan.analysis.dsac_traces RUN... --out docs/img/training
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from crowdplan.algos.dsac import DSAC, DSACConfig
from crowdplan.analysis.plots import _read, rolling_mean
from crowdplan.io import atomic_write
from crowdplan.training.config import load_config
from crowdplan.training.loop import PAPER_SUCCESS

REACHED = 0.95  # validation success that counts as learned (issue 12's criterion)
FLOOR = 0.9  # ... which it must never fall below again
COLLAPSED = 0.5  # validation success below this after REACHED: a collapse
TRAIN_WINDOW = 100  # training episodes in the sampled policy's success rate
SHORT_WINDOW = 25  # ... and in its recent success in the collapse windows
VALIDATION_COLUMNS = ("episode", "success_rate", "timeout_rate")


@dataclass
class RunTraces:
    """The logs of one DSAC run folder and the hyper-parameters they were made with."""

    folder: Path
    config: DSACConfig
    updates: dict[str, np.ndarray]
    validation: dict[str, np.ndarray]
    episodes: dict[str, np.ndarray]

    @property
    def name(self) -> str:
        return self.folder.name

    @property
    def n_updates(self) -> np.ndarray:
        """Gradient updates made by each updates.csv row: one per transition (times the UTD
        ratio) once the buffer holds ``learning_starts`` transitions (exact to one env step)."""
        steps = np.maximum(self.updates["env_steps"] - self.config.learning_starts, 0.0)
        return steps * self.config.updates_per_step

    @property
    def target_entropy(self) -> np.ndarray:
        """The target entropy in force at each updates.csv row (the agent's own definition,
        schedule included, evaluated without building networks)."""
        target = DSAC.target_entropy.fget
        return np.array(
            [target(SimpleNamespace(config=self.config, n_updates=n)) for n in self.n_updates]
        )

    @property
    def alpha_lr(self) -> float:
        return self.config.alpha_lr or self.config.lr

    def soft_q_bound(self, alpha: np.ndarray) -> np.ndarray:
        """Highest soft Q value any policy can reach at temperature ``alpha``: ``return_max``
        plus the entropy bonus at its largest (log n_actions every step), the upper end of the
        range ``dsac.clip_q_targets`` clips targets to."""
        cfg = self.config
        return cfg.return_max + alpha * math.log(cfg.n_actions) * cfg.gamma / (1.0 - cfg.gamma)

    def train_success(self, at_episodes: np.ndarray, window: int = TRAIN_WINDOW) -> np.ndarray:
        """Success of the sampled (training) policy over the ``window`` training episodes up to
        each of ``at_episodes``."""
        success = rolling_mean((self.episodes["outcome"] == "goal").astype(float), window)
        index = np.clip(np.asarray(at_episodes, dtype=int), 1, len(success)) - 1
        return success[index]


def load_run(folder: str | Path) -> RunTraces:
    """Read a DSAC run folder; the config's missing keys take DSACConfig's defaults. A run still
    before its first validation has no validation rows."""
    folder = Path(folder)
    config = load_config(folder / "config.yaml", legacy_defaults=True).algo_config
    if not isinstance(config, DSACConfig):
        raise ValueError(f"{folder} is not a DSAC run")
    logs = {name: _read(folder / f"{name}.csv") for name in ("updates", "validation", "episodes")}
    for name in ("updates", "episodes"):
        if not logs[name]:
            raise FileNotFoundError(f"{folder / (name + '.csv')} is missing or empty")
    if not logs["validation"]:  # a run before its first validation
        logs["validation"] = {key: np.zeros(0) for key in VALIDATION_COLUMNS}
    return RunTraces(folder, config, **logs)


@dataclass
class Diagnostics:
    """Events and levels of one run (episodes are training-episode counts; None: never)."""

    run: str
    target_entropy: str
    episodes: int
    training_goals: int  # training episodes (sampled actions) that reached the goal
    first_reached: int | None  # first validation with success >= REACHED
    first_below: int | None  # first validation after that with success < FLOOR
    collapse: int | None  # first validation after first_reached with success < COLLAPSED
    collapse_onsets: list[int]  # every validation below COLLAPSED after one at or above it
    greedy_dips: int  # validations after first_reached below FLOOR while training success >= FLOOR
    alpha_rate_start: float  # d log(alpha) / d update up to the first log row, in alpha_lr units
    alpha_rate_fit: float  # least-squares d log(alpha) / d update over the run, in alpha_lr units
    alpha_settled: float  # median alpha of the rows from half-way to the collapse (or the end)
    entropy_settled: float  # median entropy of the same rows
    q_settled: float  # median qf_mean of the same rows
    bonus_settled: (
        float  # alpha H gamma / (1 - gamma) at the settled medians: the entropy share of Q
    )
    max_q: float
    max_q_episode: int
    # Crossings count once qf_mean has first come under the bound. Q follows a falling
    # temperature with a lag, so the soft bound takes the larger alpha of the row and the one
    # before it.
    q_over_return_max: int | None  # first row above return_max
    q_over_soft_bound: int | None  # first row above the soft bound
    alpha_at_collapse: float | None  # last log row at or before the collapse
    entropy_at_collapse: float | None


def _first(episodes: np.ndarray, mask: np.ndarray) -> int | None:
    hits = np.flatnonzero(mask)
    return int(episodes[hits[0]]) if len(hits) else None


def _first_after_under(episodes: np.ndarray, values: np.ndarray, bound: np.ndarray) -> int | None:
    """First episode where ``values`` exceed ``bound`` after having first been at or under it."""
    under = np.flatnonzero(values <= bound)
    if not len(under):
        return None
    return _first(episodes[under[0] :], (values > bound)[under[0] :])


def _row_at(trace: RunTraces, episode: int) -> int:
    """Index of the last updates.csv row at or before ``episode`` (the first row if none)."""
    return max(int(np.searchsorted(trace.updates["episode"], episode, side="right")) - 1, 0)


def _log_alpha_rate(updates: np.ndarray, log_alpha: np.ndarray) -> float:
    valid = np.isfinite(log_alpha)
    if valid.sum() < 2:
        return math.nan
    return float(np.polyfit(updates[valid], log_alpha[valid], 1)[0])


def diagnose(trace: RunTraces) -> Diagnostics:
    """The events and levels of the collapse diagnosis for one run."""
    cfg = trace.config
    val_ep, val_success = trace.validation["episode"], trace.validation["success_rate"]
    first_reached = _first(val_ep, val_success >= REACHED)
    after = val_ep > (first_reached if first_reached is not None else math.inf)
    first_below = _first(val_ep, after & (val_success < FLOOR))
    collapse = _first(val_ep, after & (val_success < COLLAPSED))
    sampled_fine = trace.train_success(val_ep) >= FLOOR
    greedy_dips = int(np.sum(after & (val_success < FLOOR) & sampled_fine))

    ep, alpha, entropy, q = (
        trace.updates[key] for key in ("episode", "alpha", "entropy", "qf_mean")
    )
    n_updates = trace.n_updates
    with np.errstate(divide="ignore"):
        log_alpha = np.log(alpha)
    start = n_updates[0] * trace.alpha_lr
    rate_start = (log_alpha[0] - math.log(cfg.init_alpha)) / start if start > 0 else math.nan
    end = _row_at(trace, collapse) if collapse is not None else len(ep) - 1
    settled = slice(end // 2, max(end, 1))
    lagged_alpha = np.maximum(alpha, np.concatenate([[cfg.init_alpha], alpha[:-1]]))
    at = _row_at(trace, collapse) if collapse is not None else None
    below = val_success < COLLAPSED
    onsets = val_ep[after & below & ~np.concatenate([[True], below[:-1]])]
    target = trace.target_entropy
    target_text = f"{target[0]:.4g}"
    if not np.allclose(target, target[0]):
        target_text += f" -> {target[-1]:.4g}"
    return Diagnostics(
        run=trace.name,
        target_entropy=target_text,
        episodes=int(trace.episodes["episode"][-1]),
        training_goals=int(np.sum(trace.episodes["outcome"] == "goal")),
        first_reached=first_reached,
        first_below=first_below,
        collapse=collapse,
        collapse_onsets=[int(e) for e in onsets],
        greedy_dips=greedy_dips,
        alpha_rate_start=float(rate_start),
        alpha_rate_fit=_log_alpha_rate(n_updates, log_alpha) / trace.alpha_lr,
        alpha_settled=float(np.median(alpha[settled])),
        entropy_settled=float(np.median(entropy[settled])),
        q_settled=float(np.median(q[settled])),
        bonus_settled=float(
            np.median(alpha[settled]) * np.median(entropy[settled]) * cfg.gamma / (1 - cfg.gamma)
        ),
        max_q=float(q.max()),
        max_q_episode=int(ep[int(q.argmax())]),
        q_over_return_max=_first_after_under(ep, q, np.full_like(q, cfg.return_max)),
        q_over_soft_bound=_first_after_under(ep, q, trace.soft_q_bound(lagged_alpha)),
        alpha_at_collapse=float(alpha[at]) if at is not None else None,
        entropy_at_collapse=float(entropy[at]) if at is not None else None,
    )


def _cell(value: float | int | None, fmt: str = "{}") -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    return fmt.format(value)


def markdown_tables(diagnostics: list[Diagnostics]) -> str:
    """Two Markdown tables: the validation events, then the traces' levels and crossings."""
    events = [
        "| run | target entropy | episodes | training episodes at goal | "
        "first success >= 0.95 | first < 0.9 after | collapses (< 0.5) | greedy dips |",
        "|---|---|---|---|---|---|---|---|",
    ]
    traces = [
        "| run | log alpha rate, first row (x lr) | log alpha rate, fit (x lr) | alpha, settled | "
        "entropy, settled | qf_mean, settled | entropy bonus in Q, settled | "
        "max qf_mean (episode) | qf_mean > return_max at | qf_mean > soft bound at | "
        "alpha at collapse | entropy at collapse |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for d in diagnostics:
        events.append(
            f"| {d.run} | {d.target_entropy} | {d.episodes} | {d.training_goals} | "
            f"{_cell(d.first_reached)} | {_cell(d.first_below)} | "
            f"{', '.join(map(str, d.collapse_onsets)) or '-'} | {d.greedy_dips} |"
        )
        traces.append(
            f"| {d.run} | {_cell(d.alpha_rate_start, '{:+.2f}')} | "
            f"{_cell(d.alpha_rate_fit, '{:+.3f}')} | {d.alpha_settled:.2e} | "
            f"{d.entropy_settled:.2f} | {d.q_settled:.3f} | {d.bonus_settled:.3f} | "
            f"{d.max_q:.2f} ({d.max_q_episode}) | "
            f"{_cell(d.q_over_return_max)} | {_cell(d.q_over_soft_bound)} | "
            f"{_cell(d.alpha_at_collapse, '{:.2e}')} | {_cell(d.entropy_at_collapse, '{:.2f}')} |"
        )
    return "\n".join(events) + "\n\n" + "\n".join(traces) + "\n"


def window_table(trace: RunTraces, first: int, last: int) -> str:
    """The log rows of episodes ``first..last`` as Markdown: the order of events around a
    collapse. A validation is shown on the first log row at or after it."""
    ep = trace.updates["episode"]
    rows = np.flatnonzero((ep >= first) & (ep <= last))
    val_ep = trace.validation["episode"]
    lines = [
        f"{trace.name}, episodes {first}-{last}:",
        "",
        "| episode | validation success | validation timeouts | training success (100) | "
        f"training success ({SHORT_WINDOW}) | alpha | entropy | qf_mean | qf_loss |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    previous = ep[rows[0] - 1] if len(rows) and rows[0] > 0 else -math.inf
    for i in rows:
        hit = np.flatnonzero((val_ep > previous) & (val_ep <= ep[i]))
        val = timeouts = ""
        if len(hit):
            val = f"{trace.validation['success_rate'][hit[-1]]:.2f}"
            timeouts = f"{trace.validation['timeout_rate'][hit[-1]]:.2f}"
        u = trace.updates
        lines.append(
            f"| {int(ep[i])} | {val} | {timeouts} | {trace.train_success(ep[i : i + 1])[0]:.2f} | "
            f"{trace.train_success(ep[i : i + 1], SHORT_WINDOW)[0]:.2f} | "
            f"{u['alpha'][i]:.2e} | {u['entropy'][i]:.2f} | {u['qf_mean'][i]:.3f} | "
            f"{u['qf_loss'][i]:.1e} |"
        )
        previous = ep[i]
    return "\n".join(lines) + "\n"


def _figure(rows: int, cols: int, size: tuple[float, float]):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=size)
    FigureCanvasAgg(fig)
    return fig, fig.subplots(rows, cols, squeeze=False)


def _save(fig, out: Path) -> Path:
    fig.tight_layout()
    atomic_write(out, lambda f: fig.savefig(f, format="png", dpi=80), mode="wb")
    return out


def plot_run(trace: RunTraces, out: str | Path) -> Path:
    """Four panels of one run against training episodes: alpha (log scale) beside the fastest
    fall Adam allows, entropy against its target, qf_mean against the reachable return range,
    and the greedy (validation) and sampled (training) success rates."""
    diag = diagnose(trace)
    cfg = trace.config
    ep, u = trace.updates["episode"], trace.updates
    fig, axes = _figure(2, 2, (10, 6.4))
    (ax_alpha, ax_entropy), (ax_q, ax_success) = axes

    ax_alpha.semilogy(ep, u["alpha"], label="alpha")
    fastest = cfg.init_alpha * np.exp(-trace.alpha_lr * trace.n_updates)
    ax_alpha.semilogy(ep, fastest, "k--", lw=0.8, label="init_alpha exp(-lr x updates)")
    if cfg.alpha_min > 0:
        ax_alpha.axhline(cfg.alpha_min, color="r", lw=0.8, label="alpha_min")
    positive = u["alpha"][u["alpha"] > 0]
    if len(positive):
        ax_alpha.set_ylim(positive.min() / 5, max(positive.max(), cfg.init_alpha) * 2)
    ax_alpha.set(ylabel="alpha (temperature)")

    ax_entropy.plot(ep, u["entropy"], label="policy entropy (batch mean)")
    ax_entropy.plot(ep, trace.target_entropy, "k--", lw=0.8, label="target entropy")
    ax_entropy.axhline(math.log(cfg.n_actions), color="grey", lw=0.8, label="log 81 (uniform)")
    ax_entropy.set(ylabel="entropy (nats)", ylim=(0, math.log(cfg.n_actions) * 1.05))

    ax_q.plot(ep, u["qf_mean"], label="qf_mean (Q1 of batch actions)")
    ax_q.plot(ep, trace.soft_q_bound(u["alpha"]), "r:", lw=0.8, label="soft bound at alpha")
    ax_q.axhline(cfg.return_max, color="k", ls="--", lw=0.8, label="return_min / return_max")
    ax_q.axhline(cfg.return_min, color="k", ls="--", lw=0.8)
    top = max(float(np.nanmax(u["qf_mean"])), cfg.return_max) * 1.1
    ax_q.set(ylabel="Q", ylim=(cfg.return_min * 1.1, top))

    val_ep = trace.validation["episode"]
    ax_success.plot(val_ep, trace.validation["success_rate"], "o-", ms=3, label="validation")
    if PAPER_SUCCESS in trace.validation:
        ax_success.plot(
            val_ep, trace.validation[PAPER_SUCCESS], "s--", ms=3, label="validation, paper's world"
        )
    train_ep = trace.episodes["episode"]
    ax_success.plot(train_ep, trace.train_success(train_ep), lw=0.8, label="training (100)")
    ax_success.axhline(REACHED, color="g", lw=0.6)
    ax_success.axhline(FLOOR, color="r", lw=0.6)
    ax_success.set(ylabel="success rate", ylim=(-0.02, 1.02))

    for ax in axes.flat:
        for event, style in ((diag.first_reached, "g"), (diag.collapse, "r")):
            if event is not None:
                ax.axvline(event, color=style, lw=0.6, alpha=0.6)
        ax.set(xlabel="training episode")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="best")
    fig.suptitle(f"{trace.name} (target entropy {diag.target_entropy})")
    return _save(fig, Path(out))


def plot_overview(traces: list[RunTraces], out: str | Path) -> Path:
    """Alpha, entropy as a fraction of log 81, and validation success of several runs (dashed:
    in the paper's world, for runs with ``val_paper_world``)."""
    fig, axes = _figure(1, 3, (13, 3.8))
    ax_alpha, ax_entropy, ax_success = axes[0]
    for trace in traces:
        ep, u = trace.updates["episode"], trace.updates
        ax_alpha.semilogy(ep, u["alpha"], lw=0.9, label=trace.name)
        ax_entropy.plot(ep, u["entropy"] / math.log(trace.config.n_actions), lw=0.9)
        (line,) = ax_success.plot(
            trace.validation["episode"], trace.validation["success_rate"], lw=0.9
        )
        if PAPER_SUCCESS in trace.validation:
            ax_success.plot(
                trace.validation["episode"],
                trace.validation[PAPER_SUCCESS],
                "--",
                color=line.get_color(),
                lw=0.9,
            )
    ax_alpha.set(ylabel="alpha")
    ax_entropy.set(ylabel="entropy / log 81", ylim=(0, 1.05))
    ax_success.set(ylabel="validation success", ylim=(-0.02, 1.02))
    for ax in axes.flat:
        ax.set(xlabel="training episode")
        ax.grid(alpha=0.3)
    ax_alpha.legend(fontsize=7)
    return _save(fig, Path(out))


def _merged(windows) -> list[tuple[int, int]]:
    """Overlapping (first, last) windows joined into one."""
    merged: list[tuple[int, int]] = []
    for first, last in sorted(windows):
        if merged and first <= merged[-1][1]:
            merged[-1] = (merged[-1][0], max(merged[-1][1], last))
        else:
            merged.append((first, last))
    return merged


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description="Draw the temperature / entropy / Q traces of DSAC runs and print the "
        "collapse diagnostics as Markdown."
    )
    parser.add_argument("runs", nargs="+", help="run folders (results/train/<run> or runs/<run>)")
    parser.add_argument("--out", required=True, help="folder for <run>.png")
    parser.add_argument("--overview", help="also draw all runs together into this file in --out")
    parser.add_argument(
        "--window",
        type=int,
        nargs=2,
        default=(300, 100),
        metavar=("BEFORE", "AFTER"),
        help="log rows printed around each collapse onset (episodes before and after; 300 100)",
    )
    args = parser.parse_args(argv)
    traces = [load_run(folder) for folder in args.runs]
    out = Path(args.out)
    for trace in traces:
        plot_run(trace, out / f"{trace.name}.png")
    if args.overview:
        plot_overview(traces, out / args.overview)
    diagnostics = [diagnose(trace) for trace in traces]
    print(markdown_tables(diagnostics))
    before, after = args.window
    for trace, diag in zip(traces, diagnostics, strict=True):
        for first, last in _merged((e - before, e + after) for e in diag.collapse_onsets):
            print(window_table(trace, first, last))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
