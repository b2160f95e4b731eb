"""The JSON manifest that travels with an exported ONNX policy (numpy only, no torch).

The manifest says everything a runtime needs besides the network: what the network computes (its
kind, algorithm and, for value networks, the lookahead that turns values into actions), the
kinematics and the action table its outputs index, the action frame, the feature layout of the
network's inputs, the largest crowd it was checked for, where it came from, and the SHA-256 of the
ONNX file it describes.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from crowdplan.config import WorldConfig
from crowdplan.sim.actions import action_table

MANIFEST_FORMAT = "crowdplan-onnx-policy/1"
MANIFEST_FILE = "manifest.json"
ONNX_FILE = "policy.onnx"
INPUTS = ("robot", "humans", "mask")
ROBOT_FEATURES = ("dist_to_goal", "v_pref", "theta_rel", "radius", "vx_rel", "vy_rel")
HUMAN_FEATURES = ("px_rel", "py_rel", "vx_rel", "vy_rel", "radius", "distance", "radius_sum")
# networks whose first output scores the 81 actions; the greedy action is its argmax
ARGMAX_KINDS = ("dsac-policy", "a2c-policy", "dqn-policy")
# a state-value network V(s); the greedy action comes from a one-step lookahead
VALUE_KIND = "value-network"
KINDS = (*ARGMAX_KINDS, VALUE_KIND)
# the lookahead a robot can run: it predicts the humans itself (no simulator to ask)
DEPLOYABLE_LOOKAHEAD = "constant_velocity"


@dataclass(frozen=True)
class Manifest:
    """Description of one exported network.

    Attributes:
        kind: what the network computes: "dsac-policy" and "a2c-policy" (features -> logits
            over the action table), "dqn-policy" (-> Q values over the action table) or
            "value-network" (-> the state value V(s)).
        outputs: output names in order: "logits", "q" or "value", then "attention" where the
            network has per-human attention scores.
        max_humans: the largest crowd the export was checked for; a runtime refuses more.
        encoder: the encoder's name (raw, rg, aw, sa, lsa).
        kinematics, speed_sampling, v_pref, robot_radius, dt: the robot the model was trained for.
        action_frame: "goal" (holonomic headings relative to the robot->goal direction) or
            "world" (absolute headings, valid for goals in the direction ``goal_heading``).
        goal_heading: world-frame models only: direction (rad) of the goal in training; a runtime
            rotates the actions by (goal direction - goal_heading) for goals elsewhere.
        action_table: (81, 2) rows (speed, angle) as in ``crowdplan.sim.actions.action_table``.
        feature_layout: names of the robot (6) and human (7) feature columns.
        world: the world config the model was trained in.
        source_model: the model file that was exported.
        crowdplan_version: version of the exporting package.
        onnx_sha256: digest of the ONNX file.
        algo: the training algorithm (dsac, a2c, dqn, value_rl).
        network: the network exported: "actor", "q" or the value network (cadrl, lstm_rl, sarl).
        lookahead: value networks only: how the humans' next states are predicted in the
            one-step lookahead (only "constant_velocity" deploys).
        gamma_step: value networks only: the lookahead's discount per step.
        shield_horizon: the safety shield's horizon in seconds (:mod:`crowdplan.sim.shield`)
            that the runtime applies to the network's action scores; None: no shield.
    """

    kind: str
    outputs: tuple[str, ...]
    max_humans: int
    encoder: str
    kinematics: str
    speed_sampling: str
    v_pref: float
    robot_radius: float
    dt: float
    action_frame: str
    goal_heading: float | None
    action_table: list[list[float]]
    feature_layout: dict[str, list[str]]
    world: dict[str, Any]
    source_model: str
    crowdplan_version: str
    onnx_sha256: str
    format: str = MANIFEST_FORMAT
    inputs: tuple[str, ...] = INPUTS
    algo: str = "dsac"  # manifests written before other algorithms exported were DSAC's
    network: str = "actor"
    lookahead: str | None = None
    gamma_step: float | None = None
    shield_horizon: float | None = None

    @property
    def has_attention(self) -> bool:
        """Whether the network's second output holds per-human attention scores."""
        return "attention" in self.outputs

    @property
    def is_value_network(self) -> bool:
        """Whether the network is a state-value network acted on by a one-step lookahead."""
        return self.kind == VALUE_KIND

    def to_json(self) -> dict[str, Any]:
        """Plain-data form written to ``manifest.json``."""
        data = asdict(self)
        data["outputs"], data["inputs"] = list(self.outputs), list(self.inputs)
        return data

    def check_world(self, world: WorldConfig) -> None:
        """Raise ValueError if ``world``'s robot or action table differ from the manifest's."""
        for name, value in (
            ("kinematics", world.kinematics),
            ("speed_sampling", world.speed_sampling),
            ("v_pref", world.robot_v_pref),
        ):
            if getattr(self, name) != value:
                raise ValueError(
                    f"the exported model has {name} {getattr(self, name)!r} but the world has "
                    f"{value!r}: export a model trained for this robot"
                )
        expected = action_table(world.robot_v_pref, world.kinematics, world.speed_sampling)
        if not np.allclose(np.asarray(self.action_table), expected, rtol=0, atol=1e-9):
            raise ValueError("the manifest's action table differs from the world's action table")


def file_sha256(path: Path) -> str:
    """Hex SHA-256 of a file."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def write_manifest(out_dir: Path, manifest: Manifest) -> Path:
    """Write ``manifest.json`` into ``out_dir``."""
    path = Path(out_dir) / MANIFEST_FILE
    path.write_text(json.dumps(manifest.to_json(), indent=2) + "\n")
    return path


def load_manifest(export_dir: str | Path) -> tuple[Manifest, Path]:
    """Read and check an export folder; returns the manifest and the ONNX file's path.

    A folder without a crowdplan manifest, a manifest of another format, an ONNX file that is not
    the one the manifest describes, or an action table inconsistent with the manifest's own
    kinematics raise ValueError (FileNotFoundError for a missing folder or file).
    """
    folder = Path(export_dir)
    path = folder / MANIFEST_FILE
    if not path.is_file():
        raise FileNotFoundError(
            f"{folder} is not a crowdplan export: no {MANIFEST_FILE} (make one with "
            "`crowdplan export --model NAME --out DIR`)"
        )
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as error:
        raise ValueError(f"{path} is not valid JSON: {error}") from error
    if not isinstance(data, dict) or data.get("format") != MANIFEST_FORMAT:
        raise ValueError(f"{path} is not a crowdplan ONNX manifest (format {MANIFEST_FORMAT})")
    try:
        data["outputs"], data["inputs"] = tuple(data["outputs"]), tuple(data["inputs"])
        manifest = Manifest(**data)
    except (KeyError, TypeError) as error:
        raise ValueError(f"{path} is missing or has unknown manifest fields: {error}") from error
    onnx_path = folder / ONNX_FILE
    if not onnx_path.is_file():
        raise FileNotFoundError(f"{onnx_path} is missing (the manifest describes it)")
    if file_sha256(onnx_path) != manifest.onnx_sha256:
        raise ValueError(
            f"{onnx_path} is not the network described by {path} (SHA-256 differs): export again"
        )
    table = np.asarray(manifest.action_table, dtype=np.float64)
    expected = action_table(manifest.v_pref, manifest.kinematics, manifest.speed_sampling)
    if table.shape != expected.shape or not np.allclose(table, expected, rtol=0, atol=1e-9):
        raise ValueError(
            f"{path}: its action table is not the {manifest.kinematics} / "
            f"{manifest.speed_sampling} table of crowdplan.sim.actions"
        )
    if manifest.kind not in KINDS:
        raise ValueError(f"{path}: unknown kind {manifest.kind!r} (one of {', '.join(KINDS)})")
    if manifest.shield_horizon is not None and (
        manifest.is_value_network or manifest.action_frame != "goal"
    ):
        raise ValueError(
            f"{path}: a safety shield needs a policy over goal-frame actions (kind "
            f"{manifest.kind!r}, action frame {manifest.action_frame!r})"
        )
    if manifest.is_value_network:
        _check_value_fields(manifest, path)
    elif manifest.action_frame == "world" and (
        manifest.goal_heading is None or not math.isfinite(manifest.goal_heading)
    ):
        raise ValueError(f"{path}: a world-frame model needs a finite goal_heading")
    return manifest, onnx_path


def check_deployable_lookahead(mode: str | None) -> None:
    """Raise ValueError unless a robot can run the lookahead ``mode`` by itself."""
    if mode == "oracle":
        raise ValueError(
            "this value network was trained with the oracle lookahead, which reads the humans' "
            "next states from the simulator; a robot has no simulator, so it cannot be deployed "
            f"(train it with lookahead {DEPLOYABLE_LOOKAHEAD!r})"
        )
    if mode != DEPLOYABLE_LOOKAHEAD:
        raise ValueError(
            f"unknown lookahead {mode!r}: a deployed value network needs {DEPLOYABLE_LOOKAHEAD!r}"
        )


def _check_value_fields(manifest: Manifest, path: Path) -> None:
    """A value network's manifest must say how the runtime turns values into actions."""
    missing = [name for name in ("lookahead", "gamma_step") if getattr(manifest, name) is None]
    if missing:
        raise ValueError(
            f"{path}: a value network's manifest needs {' and '.join(missing)} (the one-step "
            "lookahead that chooses its actions): export it again"
        )
    try:
        check_deployable_lookahead(manifest.lookahead)
    except ValueError as error:
        raise ValueError(f"{path}: {error}") from None
    gamma = manifest.gamma_step
    if isinstance(gamma, bool) or not isinstance(gamma, (int, float)) or not 0.0 <= gamma <= 1.0:
        raise ValueError(f"{path}: gamma_step must lie in [0, 1], got {manifest.gamma_step}")
    if manifest.goal_heading is not None:
        raise ValueError(
            f"{path}: a value network plans in the world frame and has no goal_heading"
        )
    if manifest.outputs[0] != "value":
        raise ValueError(f"{path}: a value network's first output is 'value'")
