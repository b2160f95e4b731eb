"""Training wall clock with the serial and the two-thread DSAC update, measured in the same run.

    python benchmarks/bench_train.py [--config configs/lsa_dsac_ent05.yaml] [--episodes 40]

Trains the same config and seed twice, once with ``dsac.parallel_update`` off and once on, and
checks that both runs produced identical episodes (the two-thread update is bitwise the same, so
the episode lengths, and with them the work, are identical). Prints a markdown table of training
seconds, hours per 10k episodes at this stage of training, and the speed-up. Early episodes are
long (random actions, time-outs), so hours per 10k episodes here are an upper bound for a whole
run; the speed-up is what this measures.

    python benchmarks/bench_train.py --device cuda --cuda-graph [--config ...] [--episodes 40]

instead trains twice on the GPU, with the eager update and with the update captured in one CUDA
graph (``dsac.cuda_graph``), and prints the same table. The two runs are not bitwise equal (the
captured LSTM runs over padded sequences instead of packed ones), so their episodes may part
ways; the table then also gives milliseconds per environment step, which compare either way.

    python benchmarks/bench_train.py --resume-from runs/lsa_dsac_ent05-s0 [RUN ...] [--episodes 100]

instead continues each trained run from its checkpoint (in a temporary copy) for ``--episodes``
more episodes with the run's own config (DSAC with the two-thread update), one run after the
other, and prints one row per run: the training time per environment step and per 10k episodes
at that stage, where the policy reaches the goal and episodes are short, and its ratio to the
first run's. Runs of different algorithms timed back to back on the same machine give a
training-hours column that compares (the paper's table VII). ``--torch-threads N`` runs every
continued run with N torch threads instead of its own (the numbers of a real run could change
with the thread count, so a real ``--resume`` keeps them; here only the time is wanted).
"""

from __future__ import annotations

import argparse
import dataclasses
import shutil
import tempfile
from pathlib import Path

import numpy as np
import torch

from crowdplan.training import TrainConfig, Trainer, load_config


def train(config, run_dir: Path) -> Trainer:
    trainer = Trainer(config, run_dir, progress=False)
    trainer.run()
    return trainer


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="configs/lsa_dsac_ent05.yaml")
    parser.add_argument("--episodes", type=int, default=40)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--device", default="cpu", help="cpu or a CUDA device")
    parser.add_argument(
        "--cuda-graph",
        action="store_true",
        help="compare the eager and the CUDA-graph update on --device (instead of the serial and "
        "the two-thread update)",
    )
    parser.add_argument(
        "--resume-from",
        type=Path,
        nargs="+",
        metavar="RUN",
        help="run folders whose checkpoints to continue, one after the other (see above)",
    )
    parser.add_argument(
        "--torch-threads",
        type=int,
        help="with --resume-from: torch threads of every continued run (default: each run's own)",
    )
    args = parser.parse_args()
    if args.cuda_graph and not args.device.startswith("cuda"):
        parser.error("--cuda-graph needs --device cuda")
    if args.resume_from is not None and args.device != "cpu":
        parser.error("--resume-from continues runs on the CPU they were trained on")
    if args.resume_from is not None:
        time_trained_runs(args.resume_from, args.episodes, args.torch_threads)
        return

    base = load_config(args.config)
    base = dataclasses.replace(
        base,
        seed=args.seed,
        episodes=args.episodes,
        val_interval=10**9,
        checkpoint_interval=10**9,
        log_interval=10**9,
        test_episodes=0,
        device=args.device,
    )
    if args.cuda_graph:
        variants = [("eager", {"cuda_graph": False}), ("CUDA graph", {"cuda_graph": True})]
    else:
        variants = [
            ("serial", {"parallel_update": False}),
            ("two threads", {"parallel_update": True}),
        ]
    torch.set_num_threads(base.torch_threads)
    rows, episodes = [], []
    with tempfile.TemporaryDirectory() as tmp:
        # one-off Numba compilation of the world kernels, outside the timed runs
        warm = Trainer(base, Path(tmp) / "warm", progress=False)
        warm.env.step(np.zeros(base.num_envs, dtype=np.int64))
        for label, options in variants:
            config = dataclasses.replace(
                base, algo_config=dataclasses.replace(base.algo_config, **options)
            )
            trainer = train(config, Path(tmp) / label.replace(" ", "-"))
            episodes.append(
                [{k: v for k, v in e.items() if k != "train_seconds"} for e in trainer.episodes]
            )
            rows.append((label, trainer))
    identical = episodes[0] == episodes[1]
    if not identical and not args.cuda_graph:
        raise SystemExit("serial and parallel runs differ: the two-thread update is not exact")

    first_seconds = rows[0][1].train_seconds
    print(
        f"torch {torch.__version__}, device={args.device}, threads={base.torch_threads}, "
        f"config={args.config}, seed={args.seed}, {args.episodes} episodes from scratch (random "
        f"actions for the first {base.algo_config.random_steps} transitions); identical "
        f"episodes in both runs: {'yes' if identical else 'no'}\n"
    )
    print(
        "| update | episodes | env steps | updates | train s | ms per env step | "
        "h / 10k episodes | speed-up |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for label, trainer in rows:
        done = len(trainer.episodes)
        hours = trainer.train_seconds / done * 10000 / 3600
        per_step = trainer.train_seconds / trainer.env_steps * 1e3
        print(
            f"| {label} | {done} | {trainer.env_steps} | {trainer.agent.n_updates} | "
            f"{trainer.train_seconds:.1f} | {per_step:.2f} | {hours:.2f} | "
            f"{first_seconds / trainer.train_seconds:.2f}x |"
        )


def time_trained_runs(sources: list[Path], episodes: int, threads: int | None = None) -> None:
    """Continue each run's checkpoint for ``episodes`` episodes; print one row per run."""
    for source in sources:
        if not (source / "checkpoint.pt").is_file():
            raise SystemExit(f"{source} has no checkpoint.pt; pass folders made by crowdplan train")
    print(f"torch {torch.__version__}, {episodes} episodes per run, one run at a time\n")
    print(
        "| run | algo | torch threads | continued from episode | episodes | "
        "env steps per episode | ms per env step | train s | h / 10k episodes | ratio to first |"
    )
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    first_hours = None
    for source in sources:
        start, done, steps, seconds, config = time_trained_run(source, episodes, threads)
        hours = seconds / done * 10000 / 3600
        first_hours = first_hours or hours
        print(
            f"| {source.name} | {config.algo} | {config.torch_threads} | {start} | {done} | "
            f"{steps / done:.1f} | {seconds / steps * 1e3:.2f} | {seconds:.1f} | {hours:.2f} | "
            f"{hours / first_hours:.2f}x |",
            flush=True,
        )


def time_trained_run(
    source: Path, episodes: int, threads: int | None
) -> tuple[int, int, int, float, TrainConfig]:
    """Continue ``source``'s checkpoint for ``episodes`` episodes in a temporary copy, with
    ``threads`` torch threads (None: the run's own).

    Returns (episode it continued from, episodes done, env steps, train seconds, config used).
    """
    # no validation inside the timed stretch, and DSAC's two-thread update as in the presets
    # (both may change on resume)
    config = load_config(source / "config.yaml")
    config = dataclasses.replace(config, val_interval=10**9)
    if hasattr(config.algo_config, "parallel_update"):
        params = dataclasses.replace(config.algo_config, parallel_update=True)
        config = dataclasses.replace(config, algo_config=params)
    torch.set_num_threads(config.torch_threads)
    with tempfile.TemporaryDirectory() as tmp:
        warm = Trainer(config, Path(tmp) / "warm", progress=False)
        warm.env.step(np.zeros(config.num_envs, dtype=np.int64))  # one-off Numba compilation
        run_dir = Path(tmp) / "run"
        run_dir.mkdir()
        shutil.copy(source / "checkpoint.pt", run_dir)
        trainer = Trainer(config, run_dir, progress=False)
        trainer.restore(run_dir / "checkpoint.pt")
        start_episodes, start_steps = len(trainer.episodes), trainer.env_steps
        start_seconds = trainer.train_seconds
        # torch threads may not change on a real resume (they can change the numbers); here only
        # the time matters
        trainer.config = config = dataclasses.replace(
            config,
            episodes=start_episodes + episodes,
            torch_threads=threads or config.torch_threads,
        )
        trainer.run()
        return (
            start_episodes,
            len(trainer.episodes) - start_episodes,
            trainer.env_steps - start_steps,
            trainer.train_seconds - start_seconds,
            config,
        )


if __name__ == "__main__":
    main()
