"""The policy interface shared by evaluation, rendering and deployment."""

from __future__ import annotations

from typing import NamedTuple, Protocol

import numpy as np


class PolicyOutput(NamedTuple):
    """Actions for E environments: integer indices (E,) or velocity commands (E, 2), plus the
    per-human scores (E, N) the policy attends with, when it has them."""

    actions: np.ndarray
    scores: np.ndarray | None = None


class Policy(Protocol):
    """Anything that maps batched raw observations to robot actions."""

    name: str

    def act(self, robot: np.ndarray, humans: np.ndarray, mask: np.ndarray) -> PolicyOutput:
        """robot (E, 9), humans (E, N, 5), mask (E, N) -> actions for every environment."""
        ...
