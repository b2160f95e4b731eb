"""The training loop, written once for every algorithm: batched rollouts, the agent's updates,
validation and best-model selection, logs, atomic checkpoints with exact resume, the final test.

A run folder holds:
    config.yaml          resolved configuration (every default written out)
    meta.json            git hash, seeds, wall-clock time, hours per 10k episodes
    episodes.csv         one row per training episode (seed, outcome, steps, return)
    validation.csv       one row per validation (the validation cases, greedy policy; with
                         policy_average > 1 the average of the last validations' policies)
    updates.csv          the agent's update statistics every log interval
    curves.png           training and validation reward / success curves
    tb/                  TensorBoard logs of the same curves
    checkpoint.pt        everything needed to resume exactly (written atomically)
    best_model.pt        validated policy with the best validation reward (or success) so far
    final_model.pt       the agent's own policy at the end
    validation_models/   with keep_validation_models: the policy of every validation
    validation_networks/ with keep_validation_networks (DSAC): its networks at every validation
    test/                summary.json + episodes.jsonl of the test cases (best model)
"""

from __future__ import annotations

import contextlib
import copy
import math
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from crowdplan import evaluation
from crowdplan.algos.base import Transitions
from crowdplan.algos.registry import get_algorithm
from crowdplan.config import to_dict
from crowdplan.models import load_model_policy
from crowdplan.policies import git_hash, host_description, run_metadata
from crowdplan.policy import Policy
from crowdplan.progress import Progress
from crowdplan.sim.env import TRAIN_SEED_BASE, CrowdNavVectorEnv
from crowdplan.training.checkpoint import (
    CHECKPOINT_FORMAT,
    load_world_state,
    read_checkpoint,
    torch_save_atomic,
    world_state,
)
from crowdplan.training.config import TrainConfig, config_from_dict, with_legacy_defaults
from crowdplan.training.policy_average import average_payloads, payload_policy
from crowdplan.training.run_logs import RunLogs

# Summary metrics copied into validation.csv.
VALIDATION_METRICS = (
    "success_rate",
    "collision_rate",
    "timeout_rate",
    "time_to_goal",
    "mean_reward",
)
# Prefix of the validation.csv columns played in the paper's world (``val_paper_world``), and
# the column that tells a row has them.
PAPER_PREFIX = "paper_"
PAPER_SUCCESS = PAPER_PREFIX + "success_rate"


# Settings a run may change when it resumes: the budget and how it is validated.
RESUME_MUTABLE = (
    "episodes",
    "val_interval",
    "val_humans",
    "keep_validation_models",
    "keep_validation_networks",
    "policy_average",
)


class Trainer:
    """Owns the run: agent, vector env and logs; ``run()`` trains to the episode budget.

    Progress goes to stderr: a bar on a terminal (``progress=False``: plain lines every 10 s,
    as in a log file), nothing with ``quiet``.
    """

    def __init__(
        self,
        config: TrainConfig,
        run_dir: str | Path,
        progress: bool = True,
        quiet: bool = False,
    ):
        self.config = config
        self.run_dir = Path(run_dir)
        self.display = Progress(0, quiet=True)  # replaced by run()
        self._display_options = {"bar": progress, "quiet": quiet}
        # the commit of the code this process runs: read once, since the tree may move on
        self.code_version = git_hash()
        self.host = host_description()  # of this process: a resumed run records its own
        if config.device != "cpu" and not torch.cuda.is_available():
            raise ValueError(
                f"device {config.device!r} was asked for but CUDA is not available here: set "
                "device: cpu in the config (and dsac.cuda_graph: false if it is on)"
            )
        self.device = torch.device(config.device)
        self.agent = get_algorithm(config.algo).make_agent(config, self.device)
        world_options = {
            k: v for k, v in to_dict(config.world).items() if k not in ("scenario", "humans")
        }
        self.env = CrowdNavVectorEnv(
            config.num_envs, config.world.scenario, config.world.humans, **world_options
        )
        self.obs, _ = self.env.reset(seed=TRAIN_SEED_BASE)
        e = config.num_envs
        self.ep_return = np.zeros(e)
        self.ep_discounted = np.zeros(e)
        self.ep_steps = np.zeros(e, dtype=np.int64)
        self.env_steps = 0
        self.logs = RunLogs(self.run_dir)
        self.best_val_score: tuple[float, ...] | None = None
        self.recent_policies: list[dict[str, Any]] = []  # model files of the last validations
        self.train_seconds = 0.0
        self.pretrain_seconds: float | None = None
        self.pretrain_stats: dict[str, float] | None = None
        self._next_log = config.log_interval
        self._next_val = config.val_interval
        self._next_ckpt = config.checkpoint_interval
        self._last_stats: dict | None = None

    @property
    def episodes(self) -> list[dict[str, Any]]:
        """One row per finished training episode."""
        return self.logs.episodes

    @property
    def validations(self) -> list[dict[str, Any]]:
        """One row per validation."""
        return self.logs.validations

    # -------------------------------------------------------------- rollouts + updates
    def _step(self) -> None:
        world = self.config.world
        actions = self.agent.act(self.obs, self.env.world)
        next_obs, reward, terminated, truncated, info = self.env.step(actions)
        done = terminated | truncated
        true_next = next_obs
        if done.any():  # the transition's s' is the final observation, not the reset one
            true_next = {
                k: np.where(_expand(done, v), info["final_obs"][k], v) for k, v in next_obs.items()
            }
        self.agent.observe(Transitions(self.obs, actions, reward, true_next, terminated, truncated))
        self.ep_discounted += (
            evaluation.REPORT_GAMMA ** (self.ep_steps * world.dt * world.robot_v_pref) * reward
        )
        self.ep_return += reward
        self.ep_steps += 1
        self.env_steps += self.config.num_envs
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
        stats = self.agent.update()
        if stats is not None:
            self._last_stats = stats
        if done.any():
            self.agent.episodes_done(len(self.episodes))

    # -------------------------------------------------------------- validation / logs
    def validate(self) -> dict:
        """Greedy policy on the validation cases (with ``policy_average`` > 1, the average of
        the last validations' policies); keeps the best model by :func:`selection_score`."""
        payload = self.agent.model_payload(self._model_info())
        if self.config.policy_average == 1:
            policy = self.agent.policy(self.config.name)
        else:
            # a copy: the payload's tensors share storage with the parameters training updates
            kept = copy.deepcopy(payload)
            self.recent_policies = [*self.recent_policies, kept][-self.config.policy_average :]
            payload = average_payloads(self.recent_policies)
            policy = payload_policy(payload, self.config.name)
        row = validation_row(policy, self.config, len(self.episodes), self.env_steps)
        self.validations.append(row)
        if self.config.keep_validation_models:
            self._keep(
                "validation_models", row, _with_info(payload, success_rate=row["success_rate"])
            )
        if self.config.keep_validation_networks:
            self._keep("validation_networks", row, self.agent.networks_payload())
        score = selection_score(row, self.config.select_by)
        if improves(score, self.best_val_score):
            self.best_val_score = score
            torch_save_atomic(
                self.run_dir / "best_model.pt",
                _with_info(payload, selected_at_episode=row["episode"]),
            )
        return row

    def _keep(self, folder: str, row: dict, payload: dict[str, Any]) -> None:
        """Write ``payload`` as ``<folder>/episode-NNNNNN.pt`` of the validation ``row``."""
        path = self.run_dir / folder / f"episode-{row['episode']:06d}.pt"
        path.parent.mkdir(exist_ok=True)
        torch_save_atomic(path, payload)

    def _model_info(self) -> dict[str, Any]:
        return {
            "name": self.config.name,
            "algo": self.config.algo,
            "seed": self.config.seed,
            "git": self.code_version,
            "episodes_trained": len(self.episodes),
        }

    def save_model(self, path: Path, extra: dict) -> None:
        """The agent's current greedy policy as a model file, with where it came from."""
        torch_save_atomic(path, self.agent.model_payload({**self._model_info(), **extra}))

    def _recent(self, n: int = 100) -> tuple[float, float]:
        recent = self.episodes[-n:]
        success = sum(e["outcome"] == "goal" for e in recent) / max(len(recent), 1)
        reward = float(np.mean([e["discounted_return"] for e in recent])) if recent else 0.0
        return success, reward

    def _log(self) -> None:
        done = len(self.episodes)
        success, reward = self._recent()
        stats = self._last_stats or {}
        if stats:
            self.logs.updates.append({"episode": done, "env_steps": self.env_steps, **stats})
        self.logs.scalars(
            done,
            {
                "train/success_rate_100": success,
                "train/discounted_return_100": reward,
                **{f"update/{key}": value for key, value in stats.items()},
            },
        )

    def _show_progress(self, finished: int) -> None:
        success, reward = self._recent()
        hours = self.train_seconds / max(len(self.episodes), 1) * 10000 / 3600
        stats = self._last_stats or {}
        extra = {"alpha": stats["alpha"]} if "alpha" in stats else {}
        self.display.update(
            finished, success100=success, reward100=reward, **extra, h_per_10k=round(hours, 2)
        )

    def meta(self) -> dict[str, Any]:
        """What meta.json says about the run so far."""
        done = len(self.episodes)
        validation_seeds = evaluation.validation_seeds(self.config.val_episodes)
        return {
            "name": self.config.name,
            "algo": self.config.algo,
            "seed": self.config.seed,
            "git": self.code_version,
            "train_episode_seeds": [TRAIN_SEED_BASE, TRAIN_SEED_BASE + done - 1] if done else [],
            "validation_seeds": [validation_seeds[0], validation_seeds[-1]],
            "episodes": done,
            "episodes_budget": self.config.episodes,
            "env_steps": self.env_steps,
            "updates": getattr(self.agent, "n_updates", None),
            "pretrain_seconds": self.pretrain_seconds,
            "pretrain": self.pretrain_stats,
            "train_seconds": self.train_seconds,
            "hours_per_10k_episodes": self.train_seconds / max(done, 1) * 10000 / 3600,
            "torch_threads": torch.get_num_threads(),
            "host": self.host,
        }

    def write_logs(self) -> None:
        """CSV logs, curves and meta.json of the run so far."""
        self.logs.write(self.meta())

    # -------------------------------------------------------------- checkpoints
    def checkpoint(self) -> None:
        """Logs, then everything needed to resume, in one atomic file."""
        state = {
            "format": CHECKPOINT_FORMAT,
            "config": self.config.to_dict(),
            "agent": self.agent.state_dict(),
            "world": world_state(self.env),
            "obs": self.obs,
            "accumulators": (self.ep_return, self.ep_discounted, self.ep_steps),
            "counters": {
                "env_steps": self.env_steps,
                "best_val_score": self.best_val_score,
                "train_seconds": self.train_seconds,
                "pretrain_seconds": self.pretrain_seconds,
                "pretrain_stats": self.pretrain_stats,
                "next_log": self._next_log,
                "next_val": self._next_val,
                "next_ckpt": self._next_ckpt,
            },
            "logs": self.logs.state(),
            "last_stats": self._last_stats,
            "recent_policies": self.recent_policies,
        }
        self.write_logs()
        torch_save_atomic(self.run_dir / "checkpoint.pt", state)

    def restore(self, path: Path) -> None:
        """Continue from a checkpoint of the same configuration.

        Only the episode budget, the validation settings (:data:`RESUME_MUTABLE`) and the
        algorithm's own ``RESUME_MUTABLE`` settings may differ: none of them changes the training
        trajectory (validation runs its own worlds, greedily, without randomness).
        """
        state = read_checkpoint(path)
        # normalised through TrainConfig, so options added since the checkpoint take defaults
        saved = config_from_dict(with_legacy_defaults(state["config"])).to_dict()
        current = self.config.to_dict()
        for key in RESUME_MUTABLE:
            saved[key] = current[key]
        algo = self.config.algo
        for key in getattr(type(self.config.algo_config), "RESUME_MUTABLE", ()):
            if algo in saved:
                saved[algo][key] = current[algo][key]
        if saved != current:
            changed = sorted(k for k in saved if saved[k] != current.get(k))
            raise ValueError(
                f"checkpoint {path} was made with a different config (differs in {changed}); "
                "resume with the run's own config.yaml or start a new --out folder"
            )
        self.agent.load_state_dict(state["agent"])
        load_world_state(self.env, state["world"])
        self.obs = state["obs"]
        self.ep_return, self.ep_discounted, self.ep_steps = state["accumulators"]
        c = state["counters"]
        self.env_steps = c["env_steps"]
        self.best_val_score = _best_val_score(c)
        self.train_seconds = c["train_seconds"]
        self.pretrain_seconds = c.get("pretrain_seconds")
        self.pretrain_stats = c.get("pretrain_stats")
        self._next_log, self._next_val, self._next_ckpt = (
            c["next_log"],
            c["next_val"],
            c["next_ckpt"],
        )
        self.logs.load_state(state["logs"])
        if state["config"].get("val_interval") != self.config.val_interval:
            interval = self.config.val_interval
            self._next_val = (len(self.episodes) // interval + 1) * interval
        self._last_stats = state["last_stats"]
        self.recent_policies = state.get("recent_policies", [])[-self.config.policy_average :]

    # -------------------------------------------------------------- main loop
    def run(self) -> bool:
        """Train to the episode budget; returns False when SIGTERM / SIGINT stopped it early.

        A stop request finishes the current environment step, writes the checkpoint and the logs
        and returns, so that ``--resume`` continues from exactly there.
        """
        cfg = self.config
        torch.set_num_threads(cfg.torch_threads)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self.display = Progress(
            cfg.episodes,
            f"train {cfg.name}",
            initial=len(self.episodes),
            delay=0.0,
            **self._display_options,
        )
        with self.display:
            if self.pretrain_seconds is None:
                start = time.perf_counter()
                stats = self.agent.pretrain(self.display.write)
                self.pretrain_seconds = time.perf_counter() - start
                if stats is not None:
                    self.pretrain_stats = stats
                    self.display.write(f"pretraining done: {stats}")
                    self.checkpoint()
            if cfg.validate_at_start and not self.episodes and not self.validations:
                start = time.perf_counter()
                self._validate_and_show()
                self.train_seconds += time.perf_counter() - start
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
        self.logs.close()
        return True

    def _train_step(self) -> None:
        """One vector-env step with its updates, then whatever logging / validation is due."""
        cfg = self.config
        start = time.perf_counter()
        before = len(self.episodes)
        self._step()
        done = len(self.episodes)
        if done > before:
            self._show_progress(done - before)
        if done >= self._next_log:
            self._log()
            self._next_log += cfg.log_interval
        if done >= self._next_val:
            self._validate_and_show()
            # the next multiple of the interval: one step may finish several episodes
            self._next_val = (done // cfg.val_interval + 1) * cfg.val_interval
        # wall clock of rollouts, updates, logging and validation; checkpoints excluded so
        # that the time saved in a checkpoint is complete
        self.train_seconds += time.perf_counter() - start
        if done >= self._next_ckpt:
            self.checkpoint()
            self._next_ckpt += cfg.checkpoint_interval

    def _validate_and_show(self) -> None:
        row = self.validate()
        self.display.write(
            f"validation at episode {row['episode']}: success {row['success_rate']:.2f} "
            f"reward {row['mean_reward']:+.3f}"
        )

    def test(self) -> dict:
        """Evaluate the best-validation model on the test cases of the validation world (the
        training world, or ``val_humans`` humans when that is set: the world the model was
        selected in) or, with ``test_world: paper``, of the paper's world; writes
        run_dir/test/."""
        policy, _ = load_model_policy(str(self.run_dir / "best_model.pt"))
        world = self.config.validation_world()
        if self.config.test_world == "paper":
            world = world.paper_world()
        seeds = evaluation.test_seeds(self.config.test_episodes)
        records = evaluation.run_episodes(policy, world, seeds)
        summary = evaluation.summarize(records)
        meta = run_metadata(policy, world, seeds, "test")
        evaluation.write_results(self.run_dir / "test", summary, records, meta)
        return summary


@contextlib.contextmanager
def _stop_requests():
    """While active, SIGTERM and SIGINT set the yielded event instead of killing the process."""
    import signal

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


def validation_row(
    policy: Policy, config: TrainConfig, episode: int, env_steps: int
) -> dict[str, Any]:
    """One row of validation.csv: ``policy`` on the run's validation cases (with
    ``val_paper_world``, also in the paper's world: the ``paper_*`` columns)."""
    seeds = evaluation.validation_seeds(config.val_episodes)
    own = config.validation_world()
    worlds = {"": own, PAPER_PREFIX: own.paper_world()} if config.val_paper_world else {"": own}
    row: dict[str, Any] = {"episode": episode, "env_steps": env_steps}
    for prefix, world in worlds.items():
        summary = evaluation.summarize(evaluation.run_episodes(policy, world, seeds))
        row.update({prefix + k: summary[k]["value"] for k in VALIDATION_METRICS})
    return row


def validation_columns(config: TrainConfig) -> tuple[str, ...]:
    """The metric columns ``validation_row`` writes for ``config``, in its order."""
    prefixes = ("", PAPER_PREFIX) if config.val_paper_world else ("",)
    return tuple(prefix + metric for prefix in prefixes for metric in VALIDATION_METRICS)


def selection_score(row: dict[str, Any], select_by: str) -> tuple[float, ...]:
    """What best-model selection maximises for a validation ``row``: ``(mean_reward,)``, or
    with ``select_by == "success"`` ``(success_rate, mean_reward)``; where the row has the
    paper's world too (``val_paper_world``), each is the mean of the two worlds'. The first of
    equals wins."""
    prefixes = ("", PAPER_PREFIX) if PAPER_SUCCESS in row else ("",)
    reward = float(np.mean([row[p + "mean_reward"] for p in prefixes]))
    success = float(np.mean([row[p + "success_rate"] for p in prefixes]))
    return (success, reward) if select_by == "success" else (reward,)


def improves(score: tuple[float, ...], best: tuple[float, ...] | None) -> bool:
    """Whether a validation's selection ``score`` replaces the ``best`` so far (None: none yet);
    equals do not, so the first of them stays."""
    return best is None or score > best


def _best_val_score(counters: dict[str, Any]) -> tuple[float, ...] | None:
    """The best selection score of a checkpoint; older checkpoints kept the reward alone."""
    if "best_val_score" in counters:
        score = counters["best_val_score"]
        return None if score is None else tuple(score)
    reward = counters["best_val_reward"]
    return None if reward == -math.inf else (reward,)


def _with_info(payload: dict[str, Any], **extra: Any) -> dict[str, Any]:
    return {**payload, "info": {**payload["info"], **extra}}


def _expand(done: np.ndarray, value: np.ndarray) -> np.ndarray:
    return done.reshape(done.shape + (1,) * (value.ndim - 1))
