"""How far a DSAC critic is from its target critic: the scale that ``dsac.q_clip`` acts on.

Q-clip (``DSACConfig.q_clip``) holds each critic's prediction within ``q_clip`` of the target
critic's value of the same (s, a) when that lowers the loss's pull, so a useful clip is one that
binds in a runaway and not in steady training. This module reads a run's last checkpoint and
measures, on transitions drawn from its own replay buffer, ``|Q_i(s, a) - Q_i'(s, a)|`` for both
twins, with the level of Q beside it::

    python -m crowdplan.analysis.critic_gap RUN... [--samples 4096] [--clip 0.05 0.1 0.5]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from crowdplan.algos.buffer import ReplayBuffer
from crowdplan.algos.dsac import DSAC
from crowdplan.training.checkpoint import read_checkpoint
from crowdplan.training.config import config_from_dict

QUANTILES = (0.5, 0.9, 0.99)


def critic_gaps(run: Path, samples: int, seed: int = 0) -> dict[str, object]:
    """``|Q_i(s, a) - Q_i'(s, a)|`` over ``samples`` transitions of the run's replay buffer (both
    twins pooled), Q1's mean over the same transitions and the episode and update counts."""
    state = read_checkpoint(run / "checkpoint.pt")
    config = config_from_dict(state["config"])
    if config.algo != "dsac":
        raise ValueError(f"{run} is a {config.algo!r} run; the critic gap is DSAC's")
    agent_state = state["agent"]
    core = DSAC(config.algo_config, config.encoder)
    core.load_state_dict(agent_state["dsac"])
    stored = agent_state["buffer"]
    buffer = ReplayBuffer(stored["capacity"], stored["max_humans"], seed=seed)
    buffer.load_state_dict({**stored, "rng_state": buffer.rng.bit_generator.state})
    batch = buffer.sample(samples)
    obs = (batch["robot"], batch["humans"], batch["mask"])
    index = batch["action"].unsqueeze(1)
    with torch.no_grad():
        q = [x.gather(1, index).squeeze(1) for x in core.critic(*obs)]
        q_target = [x.gather(1, index).squeeze(1) for x in core.critic_target(*obs)]
    gaps = torch.cat([(a - b).abs() for a, b in zip(q, q_target, strict=True)]).numpy()
    return {
        "run": str(run),
        "episodes": len(state["logs"][0]),  # the run's episode log
        "updates": core.n_updates,
        "q_mean": float(q[0].mean()),
        "gaps": gaps,
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=Path, help="DSAC run folders with checkpoint.pt")
    parser.add_argument("--samples", type=int, default=4096, help="transitions drawn per run")
    parser.add_argument(
        "--clip", type=float, nargs="+", default=[0.05, 0.1, 0.5], help="q_clip values to count"
    )
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    quantile_names = [f"p{round(q * 100)}" for q in QUANTILES]
    header = ["run", "episodes", "updates", "mean Q1(s, a)", *quantile_names, "max"]
    header += [f"share > {c:g}" for c in args.clip]
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for run in args.runs:
        row = critic_gaps(run, args.samples)
        gaps = row["gaps"]
        cells = [row["run"], row["episodes"], row["updates"], f"{row['q_mean']:.3f}"]
        cells += [f"{v:.2e}" for v in np.quantile(gaps, QUANTILES)] + [f"{gaps.max():.2e}"]
        cells += [f"{(gaps > c).mean():.4f}" for c in args.clip]
        print("| " + " | ".join(str(c) for c in cells) + " |")


if __name__ == "__main__":
    main()
