"""The DSAC training loop: batched rollouts, per-step updates, validation, checkpoints, resume.

A run folder holds:
    config.yaml          resolved configuration (every default written out)
    meta.json            git hash, seeds, wall-clock time, hours per 10k episodes
    episodes.csv         one row per training episode (seed, outcome, steps, return)
    validation.csv       one row per validation (the 100 validation cases, greedy policy)
    updates.csv          losses / alpha / entropy every log interval
    curves.png           training and validation reward / success curves
    tb/                  TensorBoard logs of the same curves
    checkpoint.pt        everything needed to resume exactly (written atomically)
    best_model.pt        policy with the best validation reward so far; final_model.pt at the end
    test/                summary.json + episodes.jsonl of the 500 test cases (best model)
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import io
import math
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
import yaml

from crowdplan import evaluation
from crowdplan.algos.buffer import ReplayBuffer
from crowdplan.algos.dsac import DSAC, DSACConfig
from crowdplan.analysis.plots import plot_training_curves
from crowdplan.config import WorldConfig, to_dict
from crowdplan.features import robot_centric
from crowdplan.io import atomic_write, write_json
from crowdplan.models import DSACPolicy, load_model_policy, model_payload
from crowdplan.nets.encoders import EncoderConfig
from crowdplan.policies import git_hash, run_metadata
from crowdplan.sim.env import TRAIN_SEED_BASE, CrowdNavVectorEnv

CHECKPOINT_FORMAT = "crowdplan-dsac-checkpoint/1"


@dataclass
class TrainConfig:
    """A training run (YAML: these keys at top level, plus world/encoder/dsac sections).

    Attributes:
        name: run name, used for the default run folder runs/<name>-s<seed>.
        seed: seeds network initialisation, exploration and replay sampling (the training
            episodes themselves are always seeds 2000, 2001, ... as SPEC.md section 1 fixes).
        episodes: training episodes.
        num_envs: environments stepped together; each env step is one transition.
        random_steps: transitions collected with uniform random actions before the policy acts.
        learning_starts: transitions in the buffer before the first update.
        buffer_size: replay capacity in transitions.
        val_interval: episodes between validations on the 100 validation cases.
        val_episodes: validation cases per validation.
        checkpoint_interval: episodes between checkpoints.
        log_interval: episodes between progress lines and update-statistics rows.
        test_episodes: test cases evaluated at the end (0 skips the final test).
        torch_threads: torch intra-op threads (1 is fastest for these small networks).
        device: where the networks train, "cpu" or a CUDA device such as "cuda" (optional).
    """

    name: str = "lsa_dsac"
    seed: int = 0
    episodes: int = 10000
    num_envs: int = 8
    random_steps: int = 2000
    learning_starts: int = 1000
    buffer_size: int = 200_000
    val_interval: int = 500
    val_episodes: int = 100
    checkpoint_interval: int = 250
    log_interval: int = 50
    test_episodes: int = 500
    torch_threads: int = 1
    device: str = "cpu"
    world: WorldConfig = field(default_factory=WorldConfig)
    encoder: EncoderConfig = field(default_factory=EncoderConfig)
    dsac: DSACConfig = field(default_factory=DSACConfig)

    def to_dict(self) -> dict[str, Any]:
        data = to_dict(self)
        data["dsac"] = {k: list(v) if isinstance(v, tuple) else v for k, v in data["dsac"].items()}
        return data


def _section(cls: type, data: Any, where: str) -> Any:
    if data is None:
        return cls()
    if not isinstance(data, dict):
        raise ValueError(f"section {where!r} of the config must be a mapping")
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ValueError(f"unknown key(s) {unknown} in section {where!r}; valid: {sorted(known)}")
    values = {k: tuple(v) if isinstance(v, list) else v for k, v in data.items()}
    return cls(**values)


def config_from_dict(data: dict[str, Any]) -> TrainConfig:
    """Build and validate a TrainConfig from parsed YAML."""
    if not isinstance(data, dict):
        raise ValueError("a training config must be a YAML mapping of keys to values")
    data = dict(data)
    world = WorldConfig.from_dict(data.pop("world", None) or {})
    encoder = _section(EncoderConfig, data.pop("encoder", None), "encoder")
    dsac = _section(DSACConfig, data.pop("dsac", None), "dsac")
    config = _section(TrainConfig, data, "top level")
    config = dataclasses.replace(config, world=world, encoder=encoder, dsac=dsac)
    if config.encoder.name == "raw":
        config.encoder = dataclasses.replace(config.encoder, max_humans=world.humans)
    for name in (
        "episodes",
        "num_envs",
        "buffer_size",
        "val_interval",
        "checkpoint_interval",
        "log_interval",
        "torch_threads",
    ):
        if not isinstance(getattr(config, name), int) or getattr(config, name) < 1:
            raise ValueError(f"{name} must be an integer >= 1, got {getattr(config, name)!r}")
    return config


def load_config(path: str | Path) -> TrainConfig:
    """Read a YAML training config, with errors that name the file and the problem."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"config file {path} does not exist (see configs/*.yaml)")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as error:
        raise ValueError(f"config file {path} is not valid YAML: {error}") from error
    try:
        return config_from_dict(data)
    except (ValueError, TypeError) as error:
        raise ValueError(f"config file {path}: {error}") from error


# ---------------------------------------------------------------------- run state
def _features(obs: dict[str, np.ndarray], unicycle: bool):
    return robot_centric(obs["robot"], obs["humans"], obs["mask"].astype(bool), unicycle)


def _tensors(feats) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    return (
        torch.from_numpy(feats.robot),
        torch.from_numpy(feats.humans),
        torch.from_numpy(feats.mask),
    )


class Trainer:
    """Owns the run: agent, buffer, vector env and logs; ``run()`` trains to the episode budget."""

    def __init__(self, config: TrainConfig, run_dir: str | Path, progress: bool = True):
        self.config = config
        self.run_dir = Path(run_dir)
        self.progress = progress
        # the commit of the code this process runs: read once, since the tree may move on
        self.code_version = git_hash()
        cfg = config
        if cfg.device != "cpu" and not torch.cuda.is_available():
            raise ValueError(f"device {cfg.device!r} was asked for but CUDA is not available")
        self.device = torch.device(cfg.device)
        self.agent = DSAC(cfg.dsac, cfg.encoder, seed=cfg.seed, device=self.device)
        self.buffer = ReplayBuffer(cfg.buffer_size, cfg.world.humans, seed=cfg.seed + 1)
        world_options = {
            k: v for k, v in to_dict(cfg.world).items() if k not in ("scenario", "humans")
        }
        self.env = CrowdNavVectorEnv(
            cfg.num_envs, cfg.world.scenario, cfg.world.humans, **world_options
        )
        self.unicycle = cfg.world.kinematics == "unicycle"
        self.rng = np.random.default_rng(cfg.seed + 2)
        self.generator = torch.Generator(device=self.device).manual_seed(cfg.seed + 3)
        obs, _ = self.env.reset(seed=TRAIN_SEED_BASE)
        self.obs = obs
        e = cfg.num_envs
        self.ep_return = np.zeros(e)
        self.ep_discounted = np.zeros(e)
        self.ep_steps = np.zeros(e, dtype=np.int64)
        self.env_steps = 0
        self.episodes: list[dict] = []
        self.validations: list[dict] = []
        self.update_stats: list[dict] = []
        self.best_val_reward = -math.inf
        self.train_seconds = 0.0
        self._next_log = cfg.log_interval
        self._next_val = cfg.val_interval
        self._next_ckpt = cfg.checkpoint_interval
        self._tb = None
        self._last_stats: dict | None = None
        self._update_credit = 0.0

    # -------------------------------------------------------------- rollouts + updates
    def _act(self, feats) -> np.ndarray:
        if self.env_steps < self.config.random_steps:
            return self.rng.integers(0, self.config.dsac.n_actions, size=self.config.num_envs)
        inputs = [t.to(self.device) for t in _tensors(feats)]
        actions, _ = self.agent.act(*inputs, generator=self.generator)
        return actions.cpu().numpy()

    def _step(self) -> None:
        cfg = self.config
        feats = _features(self.obs, self.unicycle)
        actions = self._act(feats)
        next_obs, reward, terminated, truncated, info = self.env.step(actions)
        done = terminated | truncated
        true_next = next_obs
        if done.any():  # the transition's s' is the final observation, not the reset one
            true_next = {
                k: np.where(_expand(done, v), info["final_obs"][k], v) for k, v in next_obs.items()
            }
        next_feats = _features(true_next, self.unicycle)
        self.buffer.add_batch(
            feats.robot,
            feats.humans,
            feats.mask,
            actions,
            reward.astype(np.float32),
            next_feats.robot,
            next_feats.humans,
            next_feats.mask,
            terminated.astype(np.float32),
        )
        world = cfg.world
        self.ep_discounted += (
            evaluation.REPORT_GAMMA ** (self.ep_steps * world.dt * world.robot_v_pref) * reward
        )
        self.ep_return += reward
        self.ep_steps += 1
        self.env_steps += cfg.num_envs
        for env in np.flatnonzero(done):
            self.episodes.append(
                {
                    "episode": len(self.episodes) + 1,
                    "seed": int(info["seed"][env]),
                    "outcome": str(info["outcome"][env]),
                    "steps": int(self.ep_steps[env]),
                    "return": float(self.ep_return[env]),
                    "discounted_return": float(self.ep_discounted[env]),
                    "env_steps": self.env_steps,
                    "train_seconds": round(self.train_seconds, 3),  # up to the previous step
                }
            )
        self.ep_return[done] = 0.0
        self.ep_discounted[done] = 0.0
        self.ep_steps[done] = 0
        self.obs = next_obs
        if len(self.buffer) >= cfg.learning_starts:
            # fractional update-to-data ratios carry their remainder to the next step
            self._update_credit += cfg.num_envs * cfg.dsac.updates_per_step
            while self._update_credit >= 1.0:
                batch = self.buffer.sample(cfg.dsac.batch_size, self.device)
                self._last_stats = self.agent.update(batch)
                self._update_credit -= 1.0

    # -------------------------------------------------------------- validation / logs
    def policy(self) -> DSACPolicy:
        return DSACPolicy(self.agent.actor, self.config.world, self.config.name)

    def validate(self) -> dict:
        records = evaluation.run_episodes(
            self.policy(), self.config.world, evaluation.validation_seeds(self.config.val_episodes)
        )
        self.agent.actor.train()
        summary = evaluation.summarize(records)
        row = {
            "episode": len(self.episodes),
            "env_steps": self.env_steps,
            **{
                k: summary[k]["value"]
                for k in (
                    "success_rate",
                    "collision_rate",
                    "timeout_rate",
                    "time_to_goal",
                    "mean_reward",
                )
            },
        }
        self.validations.append(row)
        if row["mean_reward"] > self.best_val_reward:
            self.best_val_reward = row["mean_reward"]
            self.save_model(self.run_dir / "best_model.pt", {"selected_at_episode": row["episode"]})
        return row

    def save_model(self, path: Path, extra: dict) -> None:
        info = {
            "name": self.config.name,
            "seed": self.config.seed,
            "git": self.code_version,
            "episodes_trained": len(self.episodes),
            **extra,
        }
        payload = model_payload(
            self.agent.actor, self.config.encoder, self.config.dsac, self.config.world, info
        )
        _torch_save_atomic(path, payload)

    def _recent(self, n: int = 100) -> tuple[float, float]:
        recent = self.episodes[-n:]
        success = sum(e["outcome"] == "goal" for e in recent) / max(len(recent), 1)
        reward = float(np.mean([e["discounted_return"] for e in recent])) if recent else 0.0
        return success, reward

    def _log(self) -> None:
        done = len(self.episodes)
        success, reward = self._recent()
        stats = self._last_stats
        if stats:
            self.update_stats.append({"episode": done, "env_steps": self.env_steps, **stats})
        tb = self._tensorboard()
        tb.add_scalar("train/success_rate_100", success, done)
        tb.add_scalar("train/discounted_return_100", reward, done)
        for key, value in (stats or {}).items():
            tb.add_scalar(f"update/{key}", value, done)
        hours = self.train_seconds / max(done, 1) * 10000 / 3600
        filled = int(20 * min(done / self.config.episodes, 1.0))
        line = (
            f"[{'#' * filled}{'.' * (20 - filled)}] "
            f"episode {done:>6}/{self.config.episodes}  success(100) {success:5.2f}  "
            f"reward(100) {reward:+.3f}  alpha {stats['alpha'] if stats else float('nan'):.3f}  "
            f"{hours:.2f} h/10k episodes"
        )
        self._print(line)

    def _print(self, line: str) -> None:
        if self.progress and sys.stderr.isatty():
            print("\r" + line, end="", file=sys.stderr, flush=True)
        else:
            print(line, flush=True)

    def _tensorboard(self):
        if self._tb is None:
            from torch.utils.tensorboard import SummaryWriter

            self._tb = SummaryWriter(str(self.run_dir / "tb"))
        return self._tb

    def write_logs(self) -> None:
        _write_csv(self.run_dir / "episodes.csv", self.episodes)
        _write_csv(self.run_dir / "validation.csv", self.validations)
        _write_csv(self.run_dir / "updates.csv", self.update_stats)
        if self.episodes:
            plot_training_curves(self.run_dir)
        done = len(self.episodes)
        write_json(
            self.run_dir / "meta.json",
            {
                "name": self.config.name,
                "seed": self.config.seed,
                "git": self.code_version,
                "train_episode_seeds": [TRAIN_SEED_BASE, TRAIN_SEED_BASE + done - 1]
                if done
                else [],
                "validation_seeds": evaluation.validation_seeds(self.config.val_episodes)[::99],
                "episodes": done,
                "env_steps": self.env_steps,
                "updates": self.agent.n_updates,
                "train_seconds": self.train_seconds,
                "hours_per_10k_episodes": self.train_seconds / max(done, 1) * 10000 / 3600,
                "torch_threads": torch.get_num_threads(),
            },
        )

    # -------------------------------------------------------------- checkpoints
    def checkpoint(self) -> None:
        state = {
            "format": CHECKPOINT_FORMAT,
            "config": self.config.to_dict(),
            "agent": self.agent.state_dict(),
            "buffer": self.buffer.state_dict(),
            "world": _world_state(self.env),
            "obs": self.obs,
            "rng": self.rng.bit_generator.state,
            "generator": self.generator.get_state(),
            "accumulators": (self.ep_return, self.ep_discounted, self.ep_steps),
            "counters": {
                "env_steps": self.env_steps,
                "best_val_reward": self.best_val_reward,
                "train_seconds": self.train_seconds,
                "next_log": self._next_log,
                "next_val": self._next_val,
                "next_ckpt": self._next_ckpt,
            },
            "logs": (self.episodes, self.validations, self.update_stats),
            "last_stats": self._last_stats,
            "update_credit": self._update_credit,
        }
        self.write_logs()
        _torch_save_atomic(self.run_dir / "checkpoint.pt", state)

    def restore(self, path: Path) -> None:
        state = read_checkpoint(path)
        # Only the episode budget, the validation interval and the two-thread update may change
        # on resume: none of them touches the training trajectory (validation runs its own
        # worlds, greedy, no RNG; the two-thread update is bitwise the serial one).
        # Normalised through TrainConfig, so options added since the checkpoint take defaults.
        saved = config_from_dict(state["config"]).to_dict()
        current = self.config.to_dict()
        saved.update(episodes=current["episodes"], val_interval=current["val_interval"])
        saved["dsac"]["parallel_update"] = current["dsac"]["parallel_update"]
        if saved != current:
            changed = sorted(k for k in saved if saved[k] != current.get(k))
            raise ValueError(
                f"checkpoint {path} was made with a different config (differs in {changed}); "
                "resume with the run's own config.yaml or start a new --out folder"
            )
        self.agent.load_state_dict(state["agent"])
        self.buffer.load_state_dict(state["buffer"])
        _load_world_state(self.env, state["world"])
        self.obs = state["obs"]
        self.rng.bit_generator.state = state["rng"]
        self.generator.set_state(state["generator"])
        self.ep_return, self.ep_discounted, self.ep_steps = state["accumulators"]
        c = state["counters"]
        self.env_steps = c["env_steps"]
        self.best_val_reward = c["best_val_reward"]
        self.train_seconds = c["train_seconds"]
        self._next_log, self._next_val, self._next_ckpt = (
            c["next_log"],
            c["next_val"],
            c["next_ckpt"],
        )
        self.episodes, self.validations, self.update_stats = state["logs"]
        if state["config"].get("val_interval") != self.config.val_interval:
            self._next_val = (len(self.episodes) // self.config.val_interval + 1) * (
                self.config.val_interval
            )
        self._last_stats = state["last_stats"]
        self._update_credit = state.get("update_credit", 0.0)

    # -------------------------------------------------------------- main loop
    def run(self) -> bool:
        """Train to the episode budget; returns False when SIGTERM / SIGINT stopped it early.

        A stop request finishes the current environment step, writes the checkpoint and the logs
        and returns, so that ``--resume`` continues from exactly there.
        """
        cfg = self.config
        torch.set_num_threads(cfg.torch_threads)
        with _stop_requests() as stop:
            while len(self.episodes) < cfg.episodes:
                if stop.is_set():
                    self.checkpoint()
                    return False
                self._train_step()
        if not self.validations or self.validations[-1]["episode"] != len(self.episodes):
            self.validate()  # the converged reward: validation at the end of training
        self.save_model(self.run_dir / "final_model.pt", {})
        self.checkpoint()
        if self._tb is not None:
            self._tb.close()
        if self.progress and sys.stderr.isatty():
            print(file=sys.stderr)
        return True

    def _train_step(self) -> None:
        """One vector-env step with its updates, then whatever logging / validation is due."""
        cfg = self.config
        start = time.perf_counter()
        self._step()
        done = len(self.episodes)
        if done >= self._next_log:
            self._log()
            self._next_log += cfg.log_interval
        if done >= self._next_val:
            row = self.validate()
            self._print(
                f"validation at episode {done}: success {row['success_rate']:.2f} "
                f"reward {row['mean_reward']:+.3f}"
            )
            self._next_val += cfg.val_interval
        # wall clock of rollouts, updates, logging and validation; checkpoints excluded so
        # that the time saved in a checkpoint is complete
        self.train_seconds += time.perf_counter() - start
        if done >= self._next_ckpt:
            self.checkpoint()
            self._next_ckpt += cfg.checkpoint_interval

    def test(self) -> dict:
        """Evaluate the best-validation model on the test cases; writes run_dir/test/."""
        policy, world = load_model_policy(str(self.run_dir / "best_model.pt"))
        seeds = evaluation.test_seeds(self.config.test_episodes)
        records = evaluation.run_episodes(policy, world, seeds)
        summary = evaluation.summarize(records)
        meta = run_metadata(policy, world, seeds, "test")
        evaluation.write_results(self.run_dir / "test", summary, records, meta)
        return summary


@contextlib.contextmanager
def _stop_requests():
    """While active, SIGTERM and SIGINT set the yielded event instead of killing the process."""
    stop = threading.Event()
    if threading.current_thread() is not threading.main_thread():
        yield stop  # signal handlers can only be installed from the main thread
        return
    previous = {sig: signal.getsignal(sig) for sig in (signal.SIGTERM, signal.SIGINT)}
    for sig in previous:
        signal.signal(sig, lambda *_: stop.set())
    try:
        yield stop
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _expand(done: np.ndarray, value: np.ndarray) -> np.ndarray:
    return done.reshape(done.shape + (1,) * (value.ndim - 1))


def _world_state(env: CrowdNavVectorEnv) -> dict:
    world = env.world
    return {
        "arrays": {k: v for k, v in vars(world).items() if isinstance(v, np.ndarray)},
        "rng_states": [None if r is None else r.bit_generator.state for r in world._rngs],
        "next_seed": env.next_seed,
    }


def _load_world_state(env: CrowdNavVectorEnv, state: dict) -> None:
    world = env.world
    for key, value in state["arrays"].items():
        setattr(world, key, value)
    for i, rng_state in enumerate(state["rng_states"]):
        if rng_state is not None:
            world._rngs[i] = np.random.default_rng()
            world._rngs[i].bit_generator.state = rng_state
    env.next_seed = state["next_seed"]


def _torch_save_atomic(path: Path, obj: Any) -> None:
    buffer = io.BytesIO()
    torch.save(obj, buffer)
    atomic_write(path, lambda f: f.write(buffer.getvalue()), mode="wb")


def read_checkpoint(path: Path) -> dict:
    """Load a training checkpoint, turning damage or foreign files into a clear ValueError."""
    try:
        state = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as error:  # a truncated or foreign file raises many types
        raise ValueError(
            f"checkpoint {path} is unreadable or corrupted ({error}); "
            "restore it or start a new run folder"
        ) from error
    if not isinstance(state, dict) or state.get("format") != CHECKPOINT_FORMAT:
        raise ValueError(f"{path} is not a crowdplan training checkpoint")
    return state


def _write_csv(path: Path, rows: list[dict]) -> None:
    if not rows:
        return

    # columns in first-seen order: rows logged before a column existed leave it empty
    fieldnames = list(dict.fromkeys(key for row in rows for key in row))

    def write(f):
        writer = csv.DictWriter(f, fieldnames=fieldnames)
        writer.writeheader()
        writer.writerows(rows)

    atomic_write(path, write)


# ---------------------------------------------------------------------- CLI glue
def train_from_cli(args) -> int:
    """``crowdplan train``: fresh run or ``--resume`` of the run in ``--out``."""
    if args.resume:
        if not args.out:
            raise ValueError("--resume needs --out pointing at the run folder to continue")
        run_dir = Path(args.out)
        config = load_config(run_dir / "config.yaml")
    else:
        if not args.config:
            raise ValueError("--config is required for a new run (e.g. configs/lsa_dsac.yaml)")
        config = load_config(args.config)
        if args.seed is not None:
            config = dataclasses.replace(config, seed=args.seed)
        if args.humans is not None:
            config = dataclasses.replace(config, world=config.world.replace(humans=args.humans))
            if config.encoder.name == "raw":
                config.encoder = dataclasses.replace(config.encoder, max_humans=args.humans)
        run_dir = Path(args.out or f"runs/{config.name}-s{config.seed}")
        if (run_dir / "checkpoint.pt").exists():
            raise ValueError(f"{run_dir} already holds a run; use --resume or another --out")
    overrides = {"episodes": args.episodes, "val_interval": args.val_interval}
    config = dataclasses.replace(config, **{k: v for k, v in overrides.items() if v is not None})
    if args.parallel_update is not None:
        dsac = dataclasses.replace(config.dsac, parallel_update=args.parallel_update)
        config = dataclasses.replace(config, dsac=dsac)
    config = config_from_dict(config.to_dict())  # the same checks as a YAML file gets
    trainer = Trainer(config, run_dir, progress=not args.no_progress)
    if args.resume:
        trainer.restore(run_dir / "checkpoint.pt")
        print(f"resuming {run_dir} at episode {len(trainer.episodes)}")
    run_dir.mkdir(parents=True, exist_ok=True)
    atomic_write(
        run_dir / "config.yaml", lambda f: yaml.safe_dump(config.to_dict(), f, sort_keys=False)
    )
    if not trainer.run():
        print(
            f"stopped at episode {len(trainer.episodes)}; checkpoint written. "
            f"Continue with: crowdplan train --out {run_dir} --resume"
        )
        return 130
    summary = trainer.test() if config.test_episodes else None
    trainer.write_logs()
    if summary:
        print(
            evaluation.format_table(
                summary,
                f"{config.name} (seed {config.seed}), best model, "
                f"{config.test_episodes} test cases",
            )
        )
    return 0
