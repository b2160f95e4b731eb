"""Export a trained model to ONNX with a dynamic crowd size, plus its JSON manifest.

Exporters are looked up by the type of the loaded policy (:func:`register_exporter`), each
returning the module to export, its output names and what the manifest says about it: DSAC and
LSTM-A2C policies export their actor (encoder + policy head -> logits), DQN policies their Q
network (-> Q values), the value-based baselines (CADRL, LSTM-RL, SARL) their value network
(-> V(s)), which the runtime turns into actions by a one-step lookahead.
The graph comes from ``torch.onnx.export(dynamo=True)`` with symbolic batch and crowd sizes; the
encoders switch to branch-free code paths while exporting (``torch.compiler.is_exporting``).
"""

from __future__ import annotations

import math
import subprocess
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

import crowdplan
from crowdplan.algos.a2c import A2CPolicy
from crowdplan.algos.dqn import DQNPolicy
from crowdplan.algos.value_rl import ValuePolicy
from crowdplan.config import WorldConfig, to_dict
from crowdplan.deploy.manifest import (
    HUMAN_FEATURES,
    INPUTS,
    ONNX_FILE,
    ROBOT_FEATURES,
    VALUE_KIND,
    Manifest,
    check_deployable_lookahead,
    file_sha256,
    write_manifest,
)
from crowdplan.features import HUMAN_FEAT_DIM, ROBOT_FEAT_DIM, robot_centric
from crowdplan.models import DSACPolicy, load_model_policy
from crowdplan.nets.value import CADRL
from crowdplan.sim.actions import action_table

DEFAULT_MAX_HUMANS = 20
OPSET = 18


@dataclass
class ExportSpec:
    """What an exporter hands back: the module (robot, humans, mask) -> outputs, their names and
    the manifest's ``kind``, ``algo``, ``network`` (and for value networks ``lookahead`` and
    ``gamma_step``)."""

    module: nn.Module
    outputs: tuple[str, ...]
    kind: str
    algo: str
    network: str
    lookahead: str | None = None
    gamma_step: float | None = None


_EXPORTERS: list[tuple[type, Callable[[object], ExportSpec]]] = []


def register_exporter(policy_type: type) -> Callable:
    """Decorator: ``fn(policy) -> ExportSpec`` exports policies of ``policy_type``."""

    def wrap(fn: Callable[[object], ExportSpec]) -> Callable[[object], ExportSpec]:
        _EXPORTERS.append((policy_type, fn))
        return fn

    return wrap


def _names(module: nn.Module, first: str) -> tuple[str, ...]:
    """Output names of ``module``: ``first``, then "attention" if it returns scores."""
    with torch.no_grad():
        outputs = module(*_sample_inputs(1, 1))
    single = isinstance(outputs, torch.Tensor) or len(outputs) == 1
    return (first,) if single else (first, "attention")


@register_exporter(DSACPolicy)
def _dsac_spec(policy: DSACPolicy) -> ExportSpec:
    module = _NoneFree(policy.actor)
    return ExportSpec(module, _names(module, "logits"), "dsac-policy", "dsac", "actor")


@register_exporter(A2CPolicy)
def _a2c_spec(policy: A2CPolicy) -> ExportSpec:
    return ExportSpec(_Actor(policy.net), ("logits",), "a2c-policy", "a2c", "actor")


@register_exporter(DQNPolicy)
def _dqn_spec(policy: DQNPolicy) -> ExportSpec:
    module = _NoneFree(policy.q)
    return ExportSpec(module, _names(module, "q"), "dqn-policy", "dqn", "q")


@register_exporter(ValuePolicy)
def _value_spec(policy: ValuePolicy) -> ExportSpec:
    check_deployable_lookahead(policy.lookahead)
    net = policy.net
    module = _NoneFree(_WithEmptyRow(net) if isinstance(net, CADRL) else net)
    return ExportSpec(
        module,
        _names(module, "value"),
        VALUE_KIND,
        "value_rl",
        net.name,
        policy.lookahead,
        policy.gamma_step,
    )


class _Actor(nn.Module):
    """The actor of an actor-critic network: (robot, humans, mask) -> logits."""

    def __init__(self, net: nn.Module):
        super().__init__()
        self.net = net

    def forward(self, robot, humans, mask):
        features, _ = self.net.encoder(robot, humans, mask)
        return self.net.actor(features)


class _WithEmptyRow(nn.Module):
    """CADRL with a padding row put first: the network gives the same values (a padding row is
    read only when there is no real human, as the all-zero human CADRL uses for an empty crowd),
    and its branch on an empty crowd is never taken, so the crowd size stays symbolic."""

    def __init__(self, net: nn.Module):
        super().__init__()
        self.net = net

    def forward(self, robot, humans, mask):
        humans = torch.cat([humans.new_zeros(humans.shape[0], 1, humans.shape[2]), humans], dim=1)
        mask = torch.cat([mask.new_zeros(mask.shape[0], 1), mask], dim=1)
        return self.net(robot, humans, mask)


class _NoneFree(nn.Module):
    """Drops a ``None`` attention output (ONNX outputs are tensors)."""

    def __init__(self, module: nn.Module):
        super().__init__()
        self.module = module

    def forward(self, robot, humans, mask):
        return tuple(x for x in self.module(robot, humans, mask) if x is not None)


def _sample_inputs(batch: int, humans: int) -> tuple[torch.Tensor, ...]:
    gen = torch.Generator().manual_seed(0)
    return (
        torch.randn(batch, ROBOT_FEAT_DIM, generator=gen),
        torch.randn(batch, humans, HUMAN_FEAT_DIM, generator=gen),
        torch.ones(batch, humans, dtype=torch.bool),
    )


def goal_heading(world: WorldConfig) -> float | None:
    """Training goal direction of a world-frame model (None for goal-frame models).

    The robot of every generated scenario travels from (0, -4) to (0, 4) (+y), turned by
    ``goal_rotation``; a model trained with a random goal direction in the world frame cannot
    know where its goal is and is refused.
    """
    if getattr(world, "action_frame", "world") != "world":
        return None
    if getattr(world, "random_goal_direction", False):
        raise ValueError(
            "this model was trained with world-frame actions and random goal directions: its "
            "actions do not follow the goal, so it cannot be deployed"
        )
    return math.pi / 2 + math.radians(getattr(world, "goal_rotation", 0.0))


def export_model(
    model: str,
    out_dir: str | Path,
    max_humans: int = DEFAULT_MAX_HUMANS,
    fresh_process: bool = False,
) -> tuple[Manifest, Path]:
    """Export ``model`` (path, run folder or shipped name) to ``out_dir``/policy.onnx and
    ``out_dir``/manifest.json; returns the manifest and the ONNX path. ``fresh_process``: this
    call already runs in a fresh interpreter (no retry there)."""
    if max_humans < 1:
        raise ValueError(f"max_humans must be >= 1, got {max_humans}")
    policy, world = load_model_policy(model)
    spec = export_spec(policy)
    shield = getattr(policy, "shield", None)
    if shield is not None and getattr(world, "action_frame", "world") != "goal":
        raise ValueError(
            f"{model} asks for a safety shield over world-frame actions, which the runtime does "
            "not turn for other goal directions; export a goal-frame model"
        )
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    onnx_path = out / ONNX_FILE
    _export_onnx(spec, onnx_path, max_humans)
    if not _dynamic_crowd(onnx_path) and not fresh_process:
        # An earlier export in this process can leave the exporter tracing the LSTM step by
        # step, which fixes the crowd size; an export in a fresh interpreter does not.
        subprocess.run(
            [sys.executable, "-m", __name__, model, str(out), str(max_humans)],
            check=True,
            capture_output=True,
        )
    if not _dynamic_crowd(onnx_path):
        raise ValueError(f"the export of {model} fixed the number of humans; it is unusable")
    value_network = spec.kind == VALUE_KIND
    manifest = Manifest(
        kind=spec.kind,
        outputs=spec.outputs,
        max_humans=max_humans,
        encoder=str(policy.metadata.get("encoder", "")),
        kinematics=world.kinematics,
        speed_sampling=world.speed_sampling,
        v_pref=world.robot_v_pref,
        robot_radius=world.robot_radius,
        dt=world.dt,
        action_frame=getattr(world, "action_frame", "world"),
        # the lookahead plans in the world frame directly: no turn for goals elsewhere
        goal_heading=None if value_network else goal_heading(world),
        action_table=action_table(
            world.robot_v_pref, world.kinematics, world.speed_sampling
        ).tolist(),
        feature_layout={"robot": list(ROBOT_FEATURES), "human": list(HUMAN_FEATURES)},
        world=to_dict(world),
        source_model=str(policy.metadata.get("model", model)),
        crowdplan_version=crowdplan.__version__,
        onnx_sha256=file_sha256(onnx_path),
        algo=spec.algo,
        network=spec.network,
        lookahead=spec.lookahead,
        gamma_step=spec.gamma_step,
        shield_horizon=None if shield is None else shield.horizon,
    )
    write_manifest(out, manifest)
    return manifest, onnx_path


def export_spec(policy: object) -> ExportSpec:
    """What to export of a loaded policy; ValueError for model families without an exporter."""
    for policy_type, make_spec in _EXPORTERS:
        if isinstance(policy, policy_type):
            return make_spec(policy)
    raise ValueError(f"no ONNX exporter for {type(policy).__name__} models")


def _export_onnx(spec: ExportSpec, path: Path, max_humans: int) -> None:
    """One self-contained ONNX file with symbolic batch and crowd sizes."""
    batch = torch.export.Dim("batch", min=1, max=4096)
    humans = torch.export.Dim("humans", min=0, max=max(max_humans, 2))
    module = spec.module.eval()
    with tempfile.TemporaryDirectory() as tmp, torch.no_grad():
        # the exporter may write external weight files beside its output: build in a scratch
        # folder and keep only the single-file model
        program = torch.onnx.export(
            module,
            _sample_inputs(2, min(5, max_humans) if max_humans >= 2 else 2),
            dynamo=True,
            input_names=list(INPUTS),
            output_names=list(spec.outputs),
            dynamic_shapes=({0: batch}, {0: batch, 1: humans}, {0: batch, 1: humans}),
            opset_version=OPSET,
            verbose=False,
        )
        scratch = Path(tmp) / ONNX_FILE
        program.save(str(scratch), external_data=False)
        path.write_bytes(scratch.read_bytes())


AGREEMENT_CROWDS = (0, 1, 5, 10, 20)


def random_observations(
    rng: np.random.Generator, batch: int, humans: int, padding: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Random raw observations in a 10 m room: robot (B, 9), humans (B, N + padding, 5) and a
    mask whose last ``padding`` slots are padding filled with garbage."""
    robot = np.concatenate(
        [
            rng.uniform(-5, 5, (batch, 2)),
            rng.uniform(-1, 1, (batch, 2)),
            np.full((batch, 1), 0.3),
            rng.uniform(-5, 5, (batch, 2)),
            np.ones((batch, 1)),
            rng.uniform(-np.pi, np.pi, (batch, 1)),
        ],
        axis=1,
    )
    total = humans + padding
    crowd = np.concatenate(
        [
            rng.uniform(-5, 5, (batch, total, 2)),
            rng.uniform(-1, 1, (batch, total, 2)),
            rng.uniform(0.3, 0.5, (batch, total, 1)),
        ],
        axis=2,
    )
    mask = np.zeros((batch, total), dtype=bool)
    mask[:, :humans] = True
    crowd[:, humans:] = rng.normal(0, 100, (batch, padding, 5))
    return robot, crowd, mask


def verify_export(
    model: str, export_dir: str | Path, crowds: tuple[int, ...] = AGREEMENT_CROWDS, batch: int = 64
) -> dict[int, float]:
    """Largest |difference| of the first output (logits, Q values or values) between
    onnxruntime and torch per crowd size, on random observations (with padded slots where the
    export allows more humans)."""
    from crowdplan.deploy.onnx_policy import OnnxPolicy

    policy, _ = load_model_policy(model)
    module = export_spec(policy).module.eval()
    onnx_policy = OnnxPolicy(export_dir)
    rng = np.random.default_rng(0)
    result = {}
    for n in crowds:
        padding = min(3, onnx_policy.max_humans - n)
        if padding < 0:
            continue
        robot, humans, mask = random_observations(rng, batch, n, padding)
        feats = robot_centric(robot, humans, mask, policy.kinematics == "unicycle")
        with torch.no_grad():
            expected = module(*(torch.from_numpy(x) for x in feats))
        first = expected if isinstance(expected, torch.Tensor) else expected[0]
        result[n] = max_abs_difference(onnx_policy.outputs(robot, humans, mask)[0], first.numpy())
    return result


def _dynamic_crowd(path: Path) -> bool:
    """Whether the ONNX model's ``humans`` input has a symbolic crowd size."""
    import onnx

    graph = onnx.load(str(path), load_external_data=False).graph
    humans = next(i for i in graph.input if i.name == "humans")
    return bool(humans.type.tensor_type.shape.dim[1].dim_param)


def max_abs_difference(a: np.ndarray, b: np.ndarray) -> float:
    """Largest absolute difference (0 for empty arrays)."""
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b)), initial=0.0))


if __name__ == "__main__":  # python -m crowdplan.deploy.export MODEL OUT MAX_HUMANS
    export_model(sys.argv[1], sys.argv[2], int(sys.argv[3]), fresh_process=True)
