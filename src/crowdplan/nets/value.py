"""State-value networks of the value-based baselines (SPEC section 6): CADRL, LSTM-RL and SARL.

Every network takes the robot-centric tensors of :mod:`crowdplan.features` (robot (B, 6),
humans (B, N, 7), mask (B, N) bool) and returns ``(value (B,), scores (B, N) or None)``. N may be
0 and padding rows (mask False) never change an output.

- CADRL: MLP 13 -> 150 -> 100 -> 100 -> 1 on one robot-human pair. With several humans the value
  is the minimum over the pairs; with no human the pair is the robot with an all-zero human row
  (the network has no input for "no human"). Scores: None.
- LSTM-RL: LSTM 13 -> 50 over the pairs sorted by decreasing distance (closest last), value MLP
  on ``[s_r, h_last]`` 56 -> 150 -> 100 -> 100 -> 1. Scores: None.
- SARL: ``e_i`` = MLP 13 -> 150 -> 100, ``h_i`` = MLP 100 -> 100 -> 50, attention score
  ``alpha_i`` = MLP 200 -> 100 -> 100 -> 1 on ``[e_i, mean_j e_j]`` (mean over the real humans),
  masked softmax, value MLP on ``[s_r, sum_i softmax(alpha)_i h_i]`` 56 -> 150 -> 100 -> 100 -> 1.
  Scores: the attention weights.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from crowdplan.nets.encoders import (
    PAIR_DIM,
    ROBOT_DIM,
    masked_softmax,
    mlp,
)
from crowdplan.nets.heads import ValueHead
from crowdplan.nets.lstm_rl import LSTM_HIDDEN, LSTMRLEncoder

VALUE_NETWORKS = ("cadrl", "lstm_rl", "sarl")


def _pairs(robot: Tensor, humans: Tensor, mask: Tensor) -> Tensor:
    """(B, N, 13) rows ``[s_r, o_i]``, padding rows' human part zeroed."""
    humans = humans.masked_fill(~mask.unsqueeze(-1), 0.0)
    return torch.cat([robot.unsqueeze(1).expand(-1, humans.shape[1], -1), humans], dim=-1)


class ValueNetwork(nn.Module):
    """Base class: ``forward(robot, humans, mask) -> (value (B,), scores (B, N) | None)``."""

    name: str
    has_scores = False  # whether forward returns per-human scores

    def forward(
        self, robot: Tensor, humans: Tensor, mask: Tensor
    ) -> tuple[Tensor, Tensor | None]:  # pragma: no cover - interface
        raise NotImplementedError(f"{type(self).__name__} must implement forward()")


class CADRL(ValueNetwork):
    """Pairwise value network; the value of a crowd is the minimum over robot-human pairs."""

    name = "cadrl"

    def __init__(self) -> None:
        super().__init__()
        self.value = ValueHead(PAIR_DIM)

    def forward(self, robot: Tensor, humans: Tensor, mask: Tensor) -> tuple[Tensor, None]:
        if humans.shape[1] == 0:
            humans = humans.new_zeros(humans.shape[0], 1, humans.shape[2])
            mask = mask.new_zeros(mask.shape[0], 1)
        pair_values = self.value(_pairs(robot, humans, mask)).squeeze(-1)  # (B, N)
        # rows without any real human keep their first (all-zero) pair
        any_human = mask.any(dim=1, keepdim=True)
        valid = mask | (~any_human & (torch.arange(mask.shape[1], device=mask.device) == 0))
        value = pair_values.masked_fill(~valid, float("inf")).min(dim=1).values
        return value, None


class LSTMRL(ValueNetwork):
    """LSTM over the distance-sorted pairs (closest last), then a value MLP."""

    name = "lstm_rl"

    def __init__(self, hidden: int = LSTM_HIDDEN) -> None:
        super().__init__()
        self.encoder = LSTMRLEncoder(hidden)
        self.value = ValueHead(self.encoder.out_dim)

    def forward(self, robot: Tensor, humans: Tensor, mask: Tensor) -> tuple[Tensor, None]:
        features, _ = self.encoder(robot, humans, mask)
        return self.value(features).squeeze(-1), None


class SARL(ValueNetwork):
    """Socially attentive value network (CrowdNav's SARL with the global state)."""

    name = "sarl"
    has_scores = True

    def __init__(self) -> None:
        super().__init__()
        self.f_e = mlp([PAIR_DIM, 150, 100], last_relu=True)
        self.f_h = mlp([100, 100, 50])
        self.f_a = mlp([200, 100, 100, 1])
        self.value = ValueHead(ROBOT_DIM + 50)

    def forward(self, robot: Tensor, humans: Tensor, mask: Tensor) -> tuple[Tensor, Tensor]:
        # The layers' algebra is regrouped so that nothing is computed per human that can be
        # computed per state (the lookahead evaluates 81 x N pairs per decision):
        # f_e's first layer is W [s_r, o_i] = W_r s_r + W_o o_i; f_a's first layer on
        # [e_i, mean] is W_e e_i + W_m mean; and f_h's last (linear) layer commutes with the
        # attention-weighted sum. The first layers of f_a and f_h that read e_i run as one.
        # The per-pair activations (81 x E x N rows in a batched lookahead) are updated in place:
        # the same values, without allocating each large buffer twice.
        humans = humans.masked_fill(~mask.unsqueeze(-1), 0.0)
        first, second = self.f_e[0], self.f_e[2]
        x = F.linear(humans, first.weight[:, ROBOT_DIM:])
        x.add_(F.linear(robot, first.weight[:, :ROBOT_DIM], first.bias).unsqueeze(1)).relu_()
        e = second(x).relu_()  # (B, N, 100)
        weights = mask.unsqueeze(-1).to(e.dtype)
        mean = (e * weights).sum(dim=1) / weights.sum(dim=1).clamp(min=1.0)
        a_in, h_in = self.f_a[0], self.f_h[0]
        width = a_in.out_features
        joint = F.linear(
            e,
            torch.cat([a_in.weight[:, : e.shape[-1]], h_in.weight]),
            torch.cat([a_in.bias, h_in.bias]),
        )
        a_hidden = (
            joint[..., :width] + F.linear(mean, a_in.weight[:, e.shape[-1] :]).unsqueeze(1)
        ).relu_()
        scores = self.f_a[2:](a_hidden).squeeze(-1)
        attention = masked_softmax(scores, mask)
        pooled = (attention.unsqueeze(-1) * torch.relu(joint[..., width:])).sum(dim=1)
        h_out = self.f_h[2]
        crowd = F.linear(pooled, h_out.weight) + attention.sum(dim=1, keepdim=True) * h_out.bias
        return self.value(torch.cat([robot, crowd], dim=1)).squeeze(-1), attention


def make_value_network(name: str) -> ValueNetwork:
    """A freshly initialised value network by name (``cadrl``, ``lstm_rl`` or ``sarl``)."""
    classes = {cls.name: cls for cls in (CADRL, LSTMRL, SARL)}
    if name not in classes:
        raise ValueError(f"unknown value network {name!r}; valid networks: {', '.join(classes)}")
    return classes[name]()
