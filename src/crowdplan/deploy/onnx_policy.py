"""An exported policy run by onnxruntime (numpy + onnxruntime only, no torch).

:class:`OnnxPolicy` implements the :class:`~crowdplan.policy.Policy` protocol over raw
observations, through the project's one feature transform (``crowdplan.features``), and turns
action indices into world-frame velocities through the one action table (``crowdplan.sim.actions``).
Its greedy action is the argmax of the network's first output (DSAC and A2C logits, DQN Q values)
or, for a value network, of the one-step lookahead of :mod:`crowdplan.deploy.value_lookahead`;
where the manifest names a safety shield (:mod:`crowdplan.sim.shield`), over the actions it lets
through.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from crowdplan.deploy.manifest import ONNX_FILE, load_manifest
from crowdplan.deploy.value_lookahead import ValueLookahead
from crowdplan.features import Features, robot_centric
from crowdplan.policy import PolicyOutput
from crowdplan.sim.actions import action_velocities
from crowdplan.sim.shield import Shield


class OnnxPolicy:
    """Greedy policy of a ``crowdplan export`` folder.

    Args:
        export_dir: the folder with ``policy.onnx`` and ``manifest.json`` (or the .onnx file).
        threads: onnxruntime intra-op threads (1: the runtime's latency is measured so).
    """

    def __init__(self, export_dir: str | Path, threads: int = 1):
        import onnxruntime as ort

        folder = Path(export_dir)
        if folder.suffix == ".onnx":
            if folder.name != ONNX_FILE:
                raise ValueError(f"{folder} is not a crowdplan export (expected {ONNX_FILE})")
            folder = folder.parent
        self.manifest, onnx_path = load_manifest(folder)
        options = ort.SessionOptions()
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
        try:
            self.session = ort.InferenceSession(
                str(onnx_path), options, providers=["CPUExecutionProvider"]
            )
        except Exception as error:  # onnxruntime raises its own exception types
            raise ValueError(f"{onnx_path} is not a loadable ONNX model: {error}") from error
        names = (
            tuple(i.name for i in self.session.get_inputs()),
            tuple(o.name for o in self.session.get_outputs()),
        )
        if names != (self.manifest.inputs, self.manifest.outputs):
            raise ValueError(f"{onnx_path} has inputs/outputs {names}, its manifest says otherwise")
        m = self.manifest
        self.name = f"{m.network if m.is_value_network else m.encoder}-{m.algo} (onnx)"
        self.kinematics = m.kinematics
        self.max_humans = m.max_humans
        self.metadata = {"export": str(folder), "source_model": m.source_model, "algo": m.algo}
        self.lookahead = ValueLookahead(m, self.run_features) if m.is_value_network else None
        self.shield = None if m.shield_horizon is None else Shield(m.shield_horizon)
        self.metadata["shield_horizon"] = m.shield_horizon

    def run_features(self, feats: Features) -> list[np.ndarray]:
        """The network's outputs on robot-centric features (robot (B, 6), humans (B, N, 7),
        mask (B, N))."""
        return self.session.run(
            None, {"robot": feats.robot, "humans": feats.humans, "mask": feats.mask}
        )

    def features(self, robot: np.ndarray, humans: np.ndarray, mask: np.ndarray) -> Features:
        """Robot-centric features of raw observations; ValueError for more humans than the
        export was checked for."""
        humans = np.asarray(humans)
        if humans.ndim != 3 or humans.shape[1] > self.max_humans:
            raise ValueError(
                f"{humans.shape[1] if humans.ndim == 3 else '?'} humans: the export was checked "
                f"for at most {self.max_humans} (export again with a larger --max-humans)"
            )
        return robot_centric(robot, humans, mask, self.kinematics == "unicycle")

    def outputs(self, robot: np.ndarray, humans: np.ndarray, mask: np.ndarray) -> list[np.ndarray]:
        """The network's outputs for raw observations robot (E, 9), humans (E, N, 5), mask:
        (E, 81) logits or Q values, or (E,) state values, then (E, N) attention scores where the
        network has them."""
        return self.run_features(self.features(robot, humans, mask))

    def logits(self, robot: np.ndarray, humans: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """(E, 81) scores of the actions: the logits (DSAC, A2C), the Q values (DQN) or, for a
        value network, the lookahead values ``r + gamma_step V(s')``."""
        if self.lookahead is not None:
            return self.lookahead.evaluate(robot, humans, mask, None)[0]
        return self.outputs(robot, humans, mask)[0]

    def act(self, robot: np.ndarray, humans: np.ndarray, mask: np.ndarray) -> PolicyOutput:
        """Greedy action indices (E,) and attention scores (E, N) where the network has them."""
        if self.lookahead is None:
            outputs = self.outputs(robot, humans, mask)
            scores = outputs[0]
        else:
            feats = self.features(robot, humans, mask)
            current = feats if self.manifest.has_attention else None
            scores, outputs = self.lookahead.evaluate(robot, humans, mask, current)
        attention = outputs[1] if self.manifest.has_attention else None
        if self.shield is None:
            return PolicyOutput(scores.argmax(axis=1), attention)
        actions = self.shield.act(scores, robot, humans, mask, self.manifest)
        return PolicyOutput(actions, attention)

    def attention(self, robot: np.ndarray, humans: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """(E, N) attention scores; ValueError for networks without attention (raw, ...)."""
        if not self.manifest.has_attention:
            raise ValueError(f"{self.name} has no attention scores")
        return self.outputs(robot, humans, mask)[1]

    def velocities(
        self, actions: np.ndarray, robot: np.ndarray, trip_heading: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """World-frame velocities (E, 2) and headings (E,) of actions for raw robot states.

        A world-frame model's headings are absolute in the scene it was trained in, where every
        trip runs in the direction ``goal_heading`` (+y). For a trip in direction
        ``trip_heading`` (E,) (from where the robot started towards its goal; default: the
        current direction to the goal) its velocities are rotated by the angle between the two,
        which is what the model does in a scene turned so that the trip runs along +y. A value
        network's lookahead plans in the world frame directly: its velocities are not turned.
        """
        m = self.manifest
        robot = np.asarray(robot, dtype=np.float64)
        vel, theta = action_velocities(
            actions, robot, m.kinematics, m.action_frame, m.speed_sampling
        )
        if m.kinematics == "holonomic" and m.action_frame == "world" and self.lookahead is None:
            if trip_heading is None:
                trip_heading = np.arctan2(robot[:, 6] - robot[:, 1], robot[:, 5] - robot[:, 0])
            turn = np.asarray(trip_heading, dtype=np.float64) - m.goal_heading
            c, s = np.cos(turn), np.sin(turn)
            vel = np.stack([vel[:, 0] * c - vel[:, 1] * s, vel[:, 0] * s + vel[:, 1] * c], axis=1)
        return vel, theta
