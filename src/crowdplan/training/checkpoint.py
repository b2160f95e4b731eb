"""Atomic checkpoint files and the state of the vector env inside them."""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import numpy as np
import torch

from crowdplan.io import atomic_write
from crowdplan.sim.env import CrowdNavVectorEnv

CHECKPOINT_FORMAT = "crowdplan-checkpoint/2"
_DSAC_CHECKPOINT_FORMAT = "crowdplan-dsac-checkpoint/1"  # before the algorithm plug-ins


def torch_save_atomic(path: Path, obj: Any) -> None:
    """``torch.save`` that never leaves a half-written file behind."""
    buffer = io.BytesIO()
    torch.save(obj, buffer)
    atomic_write(path, lambda f: f.write(buffer.getvalue()), mode="wb")


def read_checkpoint(path: Path, also: tuple[str, ...] = ()) -> dict[str, Any]:
    """Load a training checkpoint, turning damage or foreign files into a clear ValueError.

    ``also``: other file formats to return as they are (e.g. a networks file taken from a
    checkpoint, :func:`crowdplan.algos.dsac_networks.save_networks`)."""
    try:
        state = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as error:  # a truncated or foreign file raises many types
        raise ValueError(
            f"checkpoint {path} is unreadable or corrupted ({error}); "
            "restore it or start a new run folder"
        ) from error
    if isinstance(state, dict) and state.get("format") in also:
        return state
    if isinstance(state, dict) and state.get("format") == _DSAC_CHECKPOINT_FORMAT:
        return _from_dsac_checkpoint(state)
    if not isinstance(state, dict) or state.get("format") != CHECKPOINT_FORMAT:
        raise ValueError(f"{path} is not a crowdplan training checkpoint")
    return state


def _from_dsac_checkpoint(state: dict[str, Any]) -> dict[str, Any]:
    """A checkpoint of the DSAC-only training loop, in today's layout."""
    agent = {
        "dsac": state["agent"],
        "buffer": state["buffer"],
        "rng": state["rng"],
        "generator": state["generator"],
        "env_steps": state["counters"]["env_steps"],
        "update_credit": state.get("update_credit", 0.0),
    }
    return {**state, "format": CHECKPOINT_FORMAT, "agent": agent}


def world_state(env: CrowdNavVectorEnv) -> dict[str, Any]:
    """Arrays and per-episode generators of the vector env's world, and its next seed."""
    world = env.world
    return {
        "arrays": {k: v for k, v in vars(world).items() if isinstance(v, np.ndarray)},
        "rng_states": [None if r is None else r.bit_generator.state for r in world._rngs],
        "next_seed": env.next_seed,
    }


def load_world_state(env: CrowdNavVectorEnv, state: dict[str, Any]) -> None:
    """Restore what :func:`world_state` returned."""
    world = env.world
    for key, value in state["arrays"].items():
        setattr(world, key, value)
    for i, rng_state in enumerate(state["rng_states"]):
        if rng_state is not None:
            world._rngs[i] = np.random.default_rng()
            world._rngs[i].bit_generator.state = rng_state
    env.next_seed = state["next_seed"]
