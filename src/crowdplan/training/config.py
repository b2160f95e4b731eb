"""The training-run configuration and its strict YAML loader."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from crowdplan.algos.registry import ALGORITHMS, get_algorithm
from crowdplan.config import WorldConfig, check_fields, from_dict, spec, to_dict
from crowdplan.evaluation import VAL_CASES, VAL_DEFAULT_CASES
from crowdplan.nets.encoders import EncoderConfig

# Keys that lived at the top level before they moved into the DSAC section; configs and
# checkpoints of runs made then still load.
_MOVED_TO_DSAC = ("random_steps", "learning_starts", "buffer_size")


@dataclass
class TrainConfig:
    """A training run. YAML: these keys at top level, plus the sections ``world``, ``encoder``
    and one named after the algorithm (e.g. ``dsac``) holding its hyper-parameters.

    Attributes:
        name: run name, used for the default run folder runs/<name>-s<seed>.
        algo: the learning algorithm (``crowdplan.algos.registry``), e.g. ``dsac``.
        seed: seeds network initialisation, exploration and replay sampling (the training
            episodes themselves are always seeds 2000, 2001, ... as SPEC.md section 1 fixes).
        episodes: training episodes.
        num_envs: environments stepped together; each env step is one transition per env.
        val_interval: episodes between validations on the validation cases.
        val_episodes: validation cases per validation, the split's first (seeds 0..999; more
            than the default 100 tell closer policies apart: docs/training.md section 11).
        val_humans: humans in the validation worlds (default: the training world's). For a
            planner judged with more humans than it trains with, e.g. CADRL (1 human in
            training, 5 in the paper's tests), so that best-model selection sees that world.
        keep_validation_models: also write each validation's greedy policy to
            ``validation_models/episode-NNNNNN.pt`` (for ``crowdplan.analysis.argmax_flips``;
            about 0.4 MB each for LSA-DSAC).
        keep_validation_networks: DSAC only: also write the networks and temperature at each
            validation to ``validation_networks/episode-NNNNNN.pt`` (the format of
            ``crowdplan.algos.dsac_networks``, about 1.5 MB each for LSA-DSAC), to read the
            critic where a kept policy fails (``crowdplan.analysis.frozen_critic``) or to start
            a run from that point (``dsac.init_networks``).
        policy_average: validate, keep as best model and test the mean of the weights of the
            policies of the last ``policy_average`` validations instead of the current policy
            (1: the current one). Training never sees it (``crowdplan.training.policy_average``;
            docs/training.md, section 6).
        select_by: what best-model selection maximises over the validations: ``reward``, the
            mean validation reward (CrowdNav's rule), or ``success``, the success rate first and
            the mean reward among equal rates (the reward alone can prefer a faster policy with
            fewer successes: docs/training.md, section 9).
        val_paper_world: also play the validation cases in the paper's world (the default
            world with the run's robot, as ``test_world: paper``) and select on the mean of the
            two worlds' scores: for a mixture judged on both the mixture and the paper's
            protocol. validation.csv gains the ``paper_*`` columns; training never sees them.
        validate_at_start: also validate the policy the run starts with, before its first
            training episode (after pretraining, where the algorithm has one), as the
            validation row of episode 0: a run started from a trained model (``init_model``)
            then keeps that model as its best unless training beats it (with
            ``policy_average`` > 1 the starting policy is one of the first averages' policies).
        checkpoint_interval: episodes between checkpoints.
        log_interval: episodes between progress lines and update-statistics rows.
        test_episodes: test cases evaluated at the end (0 skips the final test).
        test_world: the world of that test: ``validation`` (the world the model was selected
            in) or ``paper`` (the default world with the run's robot, as ``crowdplan eval
            --default-world``: for mixtures judged on the paper's protocol).
        torch_threads: torch intra-op threads (1 is fastest for most of these small networks;
            SARL's updates gain from 2 on an idle 2-core machine, docs/benchmarks.md).
        device: where the networks train, "cpu" or a CUDA device such as "cuda" (optional).
        world: the training world.
        encoder: the representation learner of algorithms that take one.
        algo_config: the algorithm's hyper-parameters (YAML section named after ``algo``).
    """

    name: str = "lsa_dsac"
    algo: str = "dsac"
    seed: int = spec(0, low=0)
    episodes: int = spec(10000, low=1)
    num_envs: int = spec(8, low=1)
    val_interval: int = spec(500, low=1)
    val_episodes: int = spec(VAL_DEFAULT_CASES, low=1, high=VAL_CASES)
    val_humans: int | None = None
    keep_validation_models: bool = False
    keep_validation_networks: bool = False
    policy_average: int = spec(1, low=1)
    select_by: str = spec("reward", choices=("reward", "success"))
    val_paper_world: bool = False
    validate_at_start: bool = False
    checkpoint_interval: int = spec(250, low=1)
    log_interval: int = spec(50, low=1)
    test_episodes: int = spec(500, low=0, high=500)
    test_world: str = spec("validation", choices=("validation", "paper"))
    torch_threads: int = spec(1, low=1)
    device: str = "cpu"
    world: WorldConfig = field(default_factory=WorldConfig)
    encoder: EncoderConfig = field(default_factory=EncoderConfig)
    algo_config: Any = None

    def __post_init__(self) -> None:
        algo = get_algorithm(self.algo)
        if self.algo_config is None:
            self.algo_config = algo.config_class()
        check_fields(self, "")
        if self.val_humans is not None and self.val_humans < 0:
            raise ValueError(
                f"val_humans must be >= 0 (or left out for the training world's count), "
                f"got {self.val_humans}"
            )
        if self.keep_validation_networks and self.algo != "dsac":
            raise ValueError(
                f"keep_validation_networks keeps DSAC's critic beside each validated policy; "
                f"a {self.algo} run's model files (keep_validation_models) hold all it acts with"
            )
        if not isinstance(self.algo_config, algo.config_class):
            raise ValueError(
                f"algo_config of a {self.algo} run must be a {algo.config_class.__name__}, "
                f"got {type(self.algo_config).__name__}"
            )

    def to_dict(self) -> dict[str, Any]:
        """Plain data for YAML: the algorithm's section under its own name."""
        data = to_dict(self)
        params = data.pop("algo_config")
        data[self.algo] = {k: list(v) if isinstance(v, tuple) else v for k, v in params.items()}
        return data

    def validation_world(self) -> WorldConfig:
        """The world of the validation cases: the training world, with ``val_humans`` humans
        (a fixed count) when that is set."""
        if self.val_humans is None:
            return self.world
        return dataclasses.replace(self.world, humans=self.val_humans, humans_min=None)


def config_from_dict(data: Any) -> TrainConfig:
    """Build and validate a TrainConfig from parsed YAML (every field type- and range-checked)."""
    if not isinstance(data, dict):
        raise ValueError("a training config must be a YAML mapping of keys to values")
    data = dict(data)
    algo = get_algorithm(data.get("algo", "dsac"))
    foreign = sorted(k for k in ALGORITHMS if k != algo.name and k in data)
    if foreign:
        raise ValueError(
            f"section(s) {foreign} belong to another algorithm; this config trains "
            f"{algo.name!r} (set algo: {foreign[0]} to train that one)"
        )
    section = dict(data.pop(algo.name, None) or {})
    if algo.name == "dsac":
        for key in _MOVED_TO_DSAC:
            if key in data:
                section.setdefault(key, data.pop(key))
    params = from_dict(algo.config_class, section, algo.name)
    config = from_dict(TrainConfig, data, "top level")
    config.algo_config = params
    if config.encoder.name == "raw":
        config.encoder = dataclasses.replace(config.encoder, max_humans=config.world.humans)
        validated = [("val_humans", "", config.val_humans or 0)]
        if config.val_paper_world:
            validated.append(("val_paper_world", "the paper's ", config.world.paper_world().humans))
        for key, whose, humans in validated:
            if humans > config.world.humans:
                raise ValueError(
                    f"{key} validates with {whose}{humans} humans, more than the raw encoder's "
                    f"fixed {config.world.humans} human slots; use an encoder that pools "
                    "(lsa, sa, aw, rg)"
                )
    return config


def with_legacy_defaults(data: Any) -> Any:
    """A run's saved config with the defaults of the version that made it: runs from before
    the action frame option acted in the world frame (today's default is the goal frame)."""
    if isinstance(data, dict) and isinstance(data.get("world"), dict):
        data = {**data, "world": {"action_frame": "world", **data["world"]}}
    return data


def load_config(path: str | Path, legacy_defaults: bool = False) -> TrainConfig:
    """Read a YAML training config, with errors that name the file and the problem.

    ``legacy_defaults``: the file is the config.yaml of an existing run (see
    :func:`with_legacy_defaults`).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"config file {path} does not exist (see configs/*.yaml)")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as error:
        raise ValueError(f"config file {path} is not valid YAML: {error}") from error
    if legacy_defaults:
        data = with_legacy_defaults(data)
    try:
        return config_from_dict(data)
    except (ValueError, TypeError) as error:
        raise ValueError(f"config file {path}: {error}") from error
