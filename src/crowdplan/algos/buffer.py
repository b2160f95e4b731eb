"""Uniform replay buffer of transitions, stored as preallocated numpy arrays."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

if TYPE_CHECKING:
    from crowdplan.algos.base import Transitions

ROBOT_DIM = 6
HUMAN_DIM = 7

# name -> (shape after the capacity axis, with H standing for max_humans; dtype)
_FIELDS: dict[str, tuple[tuple[str | int, ...], Any]] = {
    "robot": ((ROBOT_DIM,), np.float32),
    "humans": (("H", HUMAN_DIM), np.float32),
    "mask": (("H",), np.bool_),
    "action": ((), np.int64),
    "reward": ((), np.float32),
    "next_robot": ((ROBOT_DIM,), np.float32),
    "next_humans": (("H", HUMAN_DIM), np.float32),
    "next_mask": (("H",), np.bool_),
    "done": ((), np.float32),
    # entropy of the policy that chose the action (0 for a deterministic one, and where the
    # acting algorithm does not give it); DSAC's entropy penalty reads it
    "behaviour_entropy": ((), np.float32),
}


class ReplayBuffer:
    """Ring buffer of ``(s, a, r, s', done)`` with humans padded to ``max_humans``.

    ``done`` is 1 only for a *terminated* transition (collision or goal). A time-limit truncation
    is stored with ``done = 0`` so that the critic bootstraps through it.

    Args:
        capacity: maximum number of transitions; the oldest are overwritten first.
        max_humans: number of human slots; observations with fewer humans are zero-padded
            (mask False), more humans than this is an error.
        seed: seed of the buffer's own ``np.random.Generator`` used by :meth:`sample`.
    """

    def __init__(self, capacity: int, max_humans: int, seed: int = 0):
        if capacity <= 0:
            raise ValueError(f"capacity must be positive, got {capacity}")
        self.capacity = capacity
        self.max_humans = max_humans
        self.rng = np.random.default_rng(seed)
        self.pos = 0  # next slot to write
        self.size = 0
        self.added = 0  # transitions ever added (tells a cache of derived values what is new)
        self.data: dict[str, np.ndarray] = {
            name: np.zeros((capacity, *(max_humans if d == "H" else d for d in shape)), dtype=dtype)
            for name, (shape, dtype) in _FIELDS.items()
        }

    def __len__(self) -> int:
        return self.size

    def _pad(self, x: np.ndarray, fill: float | bool = 0) -> np.ndarray:
        n = x.shape[1]
        if n > self.max_humans:
            raise ValueError(f"{n} humans in a transition but the buffer holds {self.max_humans}")
        if n == self.max_humans:
            return x
        pad = [(0, 0)] * x.ndim
        pad[1] = (0, self.max_humans - n)
        return np.pad(x, pad, constant_values=fill)

    def add_batch(
        self,
        robot: np.ndarray,
        humans: np.ndarray,
        mask: np.ndarray,
        action: np.ndarray,
        reward: np.ndarray,
        next_robot: np.ndarray,
        next_humans: np.ndarray,
        next_mask: np.ndarray,
        done: np.ndarray,
        behaviour_entropy: np.ndarray | None = None,
    ) -> None:
        """Store E transitions at once (leading axis E on every argument).

        Shapes: robot (E, 6), humans (E, n, 7), mask (E, n) with n <= max_humans, action (E,),
        reward (E,), next_* like their counterparts, done (E,) = terminated (not truncated),
        behaviour_entropy (E,) the acting policy's entropy in each state (None: 0).
        """
        if behaviour_entropy is None:
            behaviour_entropy = np.zeros(len(action), np.float32)
        batch = {
            "robot": robot,
            "humans": self._pad(np.asarray(humans)),
            "mask": self._pad(np.asarray(mask, dtype=np.bool_), False),
            "action": action,
            "reward": reward,
            "next_robot": next_robot,
            "next_humans": self._pad(np.asarray(next_humans)),
            "next_mask": self._pad(np.asarray(next_mask, dtype=np.bool_), False),
            "done": done,
            "behaviour_entropy": behaviour_entropy,
        }
        n = len(batch["action"])
        if n > self.capacity:  # only the newest `capacity` transitions would survive anyway
            batch = {k: v[n - self.capacity :] for k, v in batch.items()}
            n = self.capacity
        index = (self.pos + np.arange(n)) % self.capacity
        for name, value in batch.items():
            self.data[name][index] = value
        self.pos = (self.pos + n) % self.capacity
        self.size = min(self.size + n, self.capacity)
        self.added += n

    def add_step(
        self,
        obs: Sequence[np.ndarray],
        step: Transitions,
        next_obs: Sequence[np.ndarray],
        behaviour_entropy: np.ndarray | None = None,
    ) -> None:
        """Store one vector-env step: ``obs`` and ``next_obs`` are (robot, humans, mask) feature
        arrays of ``step.obs`` and ``step.next_obs``, ``step`` a :class:`Transitions`."""
        self.add_batch(
            *obs,
            step.actions,
            step.rewards.astype(np.float32),
            *next_obs,
            step.terminated.astype(np.float32),
            behaviour_entropy,
        )

    def recent_slots(self, count: int) -> np.ndarray:
        """Slots of the ``count`` most recently added transitions (all slots when ``count`` is
        at least the number stored)."""
        count = min(count, self.size)
        return (self.pos - count + np.arange(count)) % self.capacity

    def sample(
        self, batch_size: int, device: torch.device | str = "cpu"
    ) -> dict[str, torch.Tensor]:
        """Draw ``batch_size`` transitions uniformly with replacement.

        Returns a dict with the keys of :meth:`add_batch` holding torch tensors (float32, except
        ``mask``/``next_mask`` bool and ``action`` int64).
        """
        return self.gather(self.sample_index(batch_size), tuple(self.data), device)

    def sample_index(self, batch_size: int) -> np.ndarray:
        """Slots of ``batch_size`` transitions drawn uniformly with replacement."""
        if self.size == 0:
            raise ValueError("cannot sample from an empty replay buffer")
        return self.rng.integers(0, self.size, size=batch_size)

    def gather(
        self, index: np.ndarray, names: tuple[str, ...], device: torch.device | str = "cpu"
    ) -> dict[str, torch.Tensor]:
        """The fields ``names`` of the transitions in slots ``index``, as torch tensors."""
        return {name: torch.from_numpy(self.data[name][index]).to(device) for name in names}

    def state_dict(self) -> dict[str, Any]:
        """Contents (as torch tensors, so ``torch.load(weights_only=True)`` works), write
        position and the sampling RNG state: a resumed buffer samples exactly as this one would."""
        return {
            "capacity": self.capacity,
            "max_humans": self.max_humans,
            "pos": self.pos,
            "size": self.size,
            "added": self.added,
            "rng_state": self.rng.bit_generator.state,
            "data": {k: torch.from_numpy(v[: self.size].copy()) for k, v in self.data.items()},
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore what :meth:`state_dict` returned (capacity and max_humans must match)."""
        if state["capacity"] != self.capacity or state["max_humans"] != self.max_humans:
            raise ValueError(
                f"buffer shape mismatch: saved capacity={state['capacity']}, "
                f"max_humans={state['max_humans']}; this buffer capacity={self.capacity}, "
                f"max_humans={self.max_humans}"
            )
        self.pos = int(state["pos"])
        self.size = int(state["size"])
        self.added = int(state.get("added", self.size))  # checkpoints before the counter
        self.rng.bit_generator.state = state["rng_state"]
        for name, value in state["data"].items():  # fields a checkpoint lacks stay 0
            self.data[name][: self.size] = value.numpy()
