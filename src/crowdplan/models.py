"""Trained models as files: save a DSAC policy, load it back as a :class:`~crowdplan.policy.Policy`.

A model file (``model.pt``) holds only plain data: the configs (as dicts) and the policy weights,
so it loads with ``torch.load(weights_only=True)``. Shipped models live in the repository's
``models/<name>/``; an installed wheel carries them to ``<prefix>/share/crowdplan/models/<name>/``
(pyproject.toml, ``data-files``), so a shipped name resolves wherever the command runs.
"""

from __future__ import annotations

import re
import site
import sys
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import torch

from crowdplan.algos.dsac import Actor, DSACConfig
from crowdplan.config import WorldConfig, to_dict
from crowdplan.features import robot_centric
from crowdplan.nets.encoders import EncoderConfig, make_encoder
from crowdplan.policy import Policy, PolicyOutput
from crowdplan.sim.actions import N_ACTIONS
from crowdplan.sim.shield import Shield

MODEL_FORMAT = "crowdplan-dsac-policy/1"
MODEL_FILES = ("model.pt", "best_model.pt", "final_model.pt")


def _shipped_dirs() -> tuple[Path, ...]:
    """Where shipped models are: the source tree's ``models/`` (a checkout or an editable
    install), then the data folder of the installation (a wheel, system-wide or ``--user``)."""
    dirs = []
    source = Path(__file__).resolve().parents[2]
    if (source / "pyproject.toml").is_file():
        dirs.append(source / "models")
    for prefix in (sys.prefix, site.getuserbase()):
        if prefix:
            dirs.append(Path(prefix) / "share" / "crowdplan" / "models")
    return tuple(dict.fromkeys(dirs))


SHIPPED_DIRS = _shipped_dirs()


class GreedyPolicy:
    """The argmax over a network's per-action outputs, on raw observations.

    ``network(robot, humans, mask)`` returns ``(per-action scores (B, A), second output)``; the
    second output is the per-human attention when ``attention_output`` (DSAC actors, Q
    networks), something else otherwise (an A2C critic's value). With a ``shield``
    (:class:`~crowdplan.sim.shield.Shield`) the argmax is taken over the actions it lets through.
    """

    attention_output = True
    shield: Shield | None = None

    def __init__(
        self, network: torch.nn.Module, world: WorldConfig, name: str, metadata: dict | None = None
    ):
        self.network = network
        self.world = world
        self.name = name
        self.metadata = metadata or {}
        self.kinematics = world.kinematics
        self.unicycle = world.kinematics == "unicycle"

    @torch.no_grad()
    def network_outputs(
        self, robot: np.ndarray, humans: np.ndarray, mask: np.ndarray
    ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """The network's per-action scores (E, A) and its second output, before any shield."""
        feats = robot_centric(robot, humans, mask, self.unicycle)
        device = next(self.network.parameters()).device
        return self.network(*(torch.from_numpy(x).to(device) for x in feats))

    @torch.no_grad()
    def act(self, robot: np.ndarray, humans: np.ndarray, mask: np.ndarray) -> PolicyOutput:
        scores, second = self.network_outputs(robot, humans, mask)
        attention = second.cpu().numpy() if self.attention_output and second is not None else None
        if self.shield is None:
            return PolicyOutput(scores.argmax(dim=1).cpu().numpy(), attention)
        actions = self.shield.act(scores.cpu().numpy(), robot, humans, mask, self.world)
        return PolicyOutput(actions, attention)

    def set_shield(self, shield: Shield | None) -> None:
        """Use ``shield`` (None: none) from the next decision on; recorded in the metadata."""
        self.shield = shield
        self.metadata["shield_horizon"] = shield.horizon if shield else None


class DSACPolicy(GreedyPolicy):
    """Greedy (argmax) DSAC policy over raw observations; exposes attention as per-human scores."""

    def __init__(self, actor: Actor, world: WorldConfig, name: str, metadata: dict | None = None):
        super().__init__(actor.eval(), world, name, metadata)
        self.actor = actor


def model_payload(
    actor: Actor, encoder: EncoderConfig, dsac: DSACConfig, world: WorldConfig, info: dict
) -> dict[str, Any]:
    """Plain-data dict describing a trained policy."""
    return {
        "format": MODEL_FORMAT,
        "encoder": to_dict(encoder),
        "dsac": {k: list(v) if isinstance(v, tuple) else v for k, v in to_dict(dsac).items()},
        "world": to_dict(world),
        "info": info,
        "actor": {k: v.cpu() for k, v in actor.state_dict().items()},
    }


def shipped_models() -> list[str]:
    """Names of the shipped models (folders holding a model.pt)."""
    return sorted({p.parent.name for d in SHIPPED_DIRS if d.is_dir() for p in d.glob("*/model.pt")})


def resolve_model_path(spec: str) -> Path:
    """A model file from a path (file or run folder) or a shipped model name.

    A folder yields the first of model.pt, best_model.pt (a run's best-validation model) and
    final_model.pt it holds; a name that is no path is looked up among the shipped models.
    """
    path = Path(spec)
    if path.is_file():
        return path
    if path.is_dir():
        for name in MODEL_FILES:
            if (path / name).is_file():
                return path / name
        raise FileNotFoundError(
            f"folder {path} holds no model ({', '.join(MODEL_FILES)}); a training run writes "
            "best_model.pt at its first validation"
        )
    for shipped in SHIPPED_DIRS:
        if (shipped / spec / "model.pt").is_file():
            return shipped / spec / "model.pt"
    raise FileNotFoundError(
        f"no model found at {spec!r}: pass a model file, a run folder containing best_model.pt, "
        f"or a shipped model name ({', '.join(shipped_models()) or 'none shipped'})"
    )


_CHECKPOINT_FORMAT = re.compile(rb"crowdplan-[\w-]+-checkpoint/\d+")


def _is_archive(path: Path) -> bool:
    """Whether ``path`` starts like a zip archive (what torch.save writes), intact or not."""
    with open(path, "rb") as file:
        return file.read(4) == b"PK\x03\x04"


def _not_a_model(path: Path) -> str:
    """Why ``path`` cannot be a model file, for files that torch cannot load as plain data."""
    expected = (
        f"--model takes a model file written by crowdplan train ({', '.join(MODEL_FILES)}), "
        f"a run folder or a shipped model name ({', '.join(shipped_models()) or 'none shipped'})"
    )
    if not _is_archive(path):
        kind = {".yaml": "a YAML file", ".yml": "a YAML file", ".json": "a JSON file"}.get(
            path.suffix.lower(), "not a torch archive"
        )
        return f"{path} is {kind}, not a model file; {expected}"
    try:
        with zipfile.ZipFile(path) as archive:
            pickles = [n for n in archive.namelist() if n.endswith("data.pkl")]
            data = archive.read(pickles[0]) if pickles else b""
    except zipfile.BadZipFile:
        data = b""
    if _CHECKPOINT_FORMAT.search(data):
        return (
            f"{path} is a training checkpoint (read by crowdplan train --resume), not a model "
            f"file; evaluate its run folder {path.parent} (its best_model.pt) or final_model.pt"
        )
    return f"{path} is a torch file that is not a crowdplan model; {expected}"


def load_payload(path: Path) -> dict[str, Any]:
    """Read a model file of any algorithm; corrupted or foreign files raise a ValueError."""
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # torch raises many types for damaged files
        if not _is_archive(path) or "weights_only" in str(error):
            raise ValueError(_not_a_model(path)) from None
        raise ValueError(f"cannot read model file {path}: {error}") from error
    if isinstance(payload, dict) and _CHECKPOINT_FORMAT.fullmatch(
        str(payload.get("format")).encode()
    ):
        raise ValueError(_not_a_model(path))
    if not isinstance(payload, dict) or "format" not in payload:
        raise ValueError(f"{path} is not a crowdplan model file (it has no 'format' entry)")
    return payload


def require_format(payload: dict[str, Any], path: Path, expected: str, what: str) -> None:
    """Refuse a model file whose ``format`` is not ``expected`` (``what``: e.g. "a DQN")."""
    if payload.get("format") != expected:
        raise ValueError(
            f"{path} is a {payload.get('format')!r} model file, not {what} model ({expected}); "
            "load it with crowdplan.models.load_model_policy"
        )


def load_weights(module: torch.nn.Module, state: dict[str, Any], path: Path, what: str) -> None:
    """``module.load_state_dict(state)``; a mismatch names the file and ``what`` it was for."""
    try:
        module.load_state_dict(state)
    except RuntimeError as error:
        raise ValueError(f"weights in {path} do not match {what}: {error}") from error


def initial_model_payload(
    spec: str, section: str, expected: str, what: str, world: WorldConfig
) -> tuple[dict[str, Any], Path]:
    """The model file ``spec`` that initialises a run (``<section>.init_model``) and its path,
    refused unless it has the ``expected`` format and acts in the run ``world``'s action frame
    and kinematics."""
    path = resolve_model_path(spec)
    payload = load_payload(path)
    if payload.get("format") != expected:
        raise ValueError(
            f"{section}.init_model {path} is a {payload.get('format')!r} model file, "
            f"not {what} model ({expected})"
        )
    frame = payload["world"].get("action_frame", "world")
    if frame != world.action_frame:
        raise ValueError(
            f"{section}.init_model {path} acts in the {frame} frame, the run in the "
            f"{world.action_frame} frame (see crowdplan.algos.action_frames)"
        )
    kinematics = payload["world"].get("kinematics", "holonomic")
    if kinematics != world.kinematics:
        raise ValueError(
            f"{section}.init_model {path} drives a {kinematics} robot, the run a "
            f"{world.kinematics} one: their actions differ"
        )
    return payload, path


def load_model_policy(spec: str, shield: float | None = None) -> tuple[Policy, WorldConfig]:
    """Load a trained model of any algorithm as a greedy policy and the world config it was
    trained in; the file's ``format`` says which algorithm reads it.

    ``shield``: horizon in seconds of the safety shield (:mod:`crowdplan.sim.shield`), 0 for
    none; None takes the model file's own (``planner.shield_horizon``, none if absent).
    """
    from crowdplan.algos.registry import algorithm_of_model

    path = resolve_model_path(spec)
    payload = load_payload(path)
    policy, world = algorithm_of_model(payload["format"], path).load_policy(payload, path)
    horizon = shield if shield is not None else model_shield_horizon(payload)
    if horizon and not isinstance(policy, GreedyPolicy):
        raise ValueError(
            f"{path} is a {payload['format']!r} model; the safety shield filters the scores "
            "of policies that rank the 81 actions (DSAC, DQN, A2C): drop --shield"
        )
    if isinstance(policy, GreedyPolicy):
        policy.set_shield(Shield(horizon) if horizon else None)
    return policy, world


def model_shield_horizon(payload: dict[str, Any]) -> float | None:
    """The shield horizon a model file asks for (``planner.shield_horizon``), None if none."""
    horizon = payload.get("planner", {}).get("shield_horizon")
    return None if horizon is None else float(horizon)


def load_dsac_payload(payload: dict[str, Any], path: Path) -> tuple[DSACPolicy, WorldConfig]:
    """The greedy policy of a DSAC model file (format :data:`MODEL_FORMAT`)."""
    encoder = EncoderConfig(**payload["encoder"])
    dsac = DSACConfig(
        **{k: tuple(v) if isinstance(v, list) else v for k, v in payload["dsac"].items()}
    )
    # Model files from before action frames existed were trained with world-frame actions.
    world = WorldConfig.from_dict({"action_frame": "world", **payload["world"]})
    if dsac.n_actions != N_ACTIONS:
        raise ValueError(
            f"{path} was trained for {dsac.n_actions} actions; the world's action table has "
            f"{N_ACTIONS} (stop + 16 directions x 5 speeds)"
        )
    actor = Actor(make_encoder(encoder), dsac.n_actions, dsac.policy_hidden, detach_encoder=False)
    load_weights(actor, payload["actor"], path, f"encoder {encoder.name!r}")
    name = payload["info"].get("name", f"{encoder.name}-dsac")
    metadata = {"model": str(path), "algo": "dsac", "encoder": encoder.name, **payload["info"]}
    return DSACPolicy(actor, world, name, metadata), world
