"""LSTM-RL's state encoder (SPEC section 6): one LSTM reads every robot-human pair.

The 13-d pairs ``[s_r, o_i]`` (robot part + human part of :mod:`crowdplan.features`) enter an
LSTM 13 -> 50 ordered by decreasing distance to the robot, so that the closest human is read
last and weighs most on the final hidden state; the output is ``[s_r, h_last]`` (6 + 50 = 56).
Padding never enters the LSTM, and a state with no real human gives ``h_last = 0``. This is the
encoder of the LSTM-A2C baseline and fits the LSTM-RL value network as well.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from crowdplan.nets.encoders import PAIR_DIM, ROBOT_DIM, Encoder, lstm_last_hidden, order_humans

LSTM_HIDDEN = 50


class LSTMRLEncoder(Encoder):
    """``forward(robot (B, 6), humans (B, N, 7), mask (B, N)) -> ([s_r, h_last] (B, 56), None)``."""

    def __init__(self, hidden: int = LSTM_HIDDEN):
        super().__init__()
        self.lstm = nn.LSTM(PAIR_DIM, hidden, batch_first=True)
        self.out_dim = ROBOT_DIM + hidden

    def forward(self, robot: Tensor, humans: Tensor, mask: Tensor) -> tuple[Tensor, None]:
        humans = humans.masked_fill(~mask.unsqueeze(-1), 0.0)
        index = order_humans(humans, mask, "distance_desc")  # real humans first, closest last
        humans = humans.gather(1, index.unsqueeze(-1).expand(-1, -1, humans.shape[-1]))
        pairs = torch.cat([robot.unsqueeze(1).expand(-1, humans.shape[1], -1), humans], dim=-1)
        last = lstm_last_hidden(self.lstm, pairs, mask.sum(dim=1))
        return torch.cat([robot, last], dim=1), None
