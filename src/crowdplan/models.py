"""Trained models as files: save a DSAC policy, load it back as a :class:`~crowdplan.policy.Policy`.

A model file (``model.pt``) holds only plain data: the configs (as dicts) and the policy weights,
so it loads with ``torch.load(weights_only=True)``. Shipped models live in ``models/<name>/``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from crowdplan.algos.dsac import Actor, DSACConfig
from crowdplan.config import WorldConfig, to_dict
from crowdplan.features import robot_centric
from crowdplan.nets.encoders import EncoderConfig, make_encoder
from crowdplan.policy import PolicyOutput
from crowdplan.sim.actions import N_ACTIONS

MODEL_FORMAT = "crowdplan-dsac-policy/1"
SHIPPED_DIRS = (Path(__file__).resolve().parents[2] / "models", Path.cwd() / "models")


class DSACPolicy:
    """Greedy (argmax) DSAC policy over raw observations; exposes attention as per-human scores."""

    def __init__(self, actor: Actor, world: WorldConfig, name: str, metadata: dict | None = None):
        self.actor = actor.eval()
        self.world = world
        self.name = name
        self.metadata = metadata or {}
        self.kinematics = world.kinematics
        self.unicycle = world.kinematics == "unicycle"

    @torch.no_grad()
    def act(self, robot: np.ndarray, humans: np.ndarray, mask: np.ndarray) -> PolicyOutput:
        feats = robot_centric(robot, humans, mask, self.unicycle)
        device = next(self.actor.parameters()).device
        logits, attention = self.actor(
            *(torch.from_numpy(x).to(device) for x in (feats.robot, feats.humans, feats.mask))
        )
        actions = logits.argmax(dim=1).cpu().numpy()
        return PolicyOutput(actions, None if attention is None else attention.cpu().numpy())


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


def resolve_model_path(spec: str) -> Path:
    """A model file from a path (file or run folder) or a shipped model name."""
    path = Path(spec)
    candidates = [path, path / "model.pt", path / "best_model.pt", path / "final_model.pt"]
    candidates += [d / spec / "model.pt" for d in SHIPPED_DIRS]
    for candidate in candidates:
        if candidate.is_file():
            return candidate
    shipped = sorted(
        {p.name for d in SHIPPED_DIRS if d.is_dir() for p in d.iterdir() if p.is_dir()}
    )
    raise FileNotFoundError(
        f"no model found at {spec!r}: pass a model file, a run folder containing best_model.pt, "
        f"or a shipped model name ({', '.join(shipped) or 'none shipped'})"
    )


def load_payload(path: Path) -> dict[str, Any]:
    """Read and check a model file; corrupted or foreign files raise a ValueError."""
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # torch raises many types for damaged files
        raise ValueError(f"cannot read model file {path}: {error}") from error
    if not isinstance(payload, dict) or payload.get("format") != MODEL_FORMAT:
        raise ValueError(f"{path} is not a crowdplan model file (expected format {MODEL_FORMAT})")
    return payload


def load_model_policy(spec: str) -> tuple[DSACPolicy, WorldConfig]:
    """Load a trained model as a greedy policy and the world config it was trained on."""
    path = resolve_model_path(spec)
    payload = load_payload(path)
    encoder = EncoderConfig(**payload["encoder"])
    dsac = DSACConfig(
        **{k: tuple(v) if isinstance(v, list) else v for k, v in payload["dsac"].items()}
    )
    world = WorldConfig.from_dict(payload["world"])
    if dsac.n_actions != N_ACTIONS:
        raise ValueError(
            f"{path} was trained for {dsac.n_actions} actions; the world's action table has "
            f"{N_ACTIONS} (stop + 16 directions x 5 speeds)"
        )
    actor = Actor(make_encoder(encoder), dsac.n_actions, dsac.policy_hidden, detach_encoder=False)
    try:
        actor.load_state_dict(payload["actor"])
    except RuntimeError as error:
        raise ValueError(
            f"weights in {path} do not match encoder {encoder.name!r}: {error}"
        ) from error
    name = payload["info"].get("name", f"{encoder.name}-dsac")
    metadata = {"model": str(path), "encoder": encoder.name, **payload["info"]}
    return DSACPolicy(actor, world, name, metadata), world
