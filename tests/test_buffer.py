"""Replay buffer: shapes, padding, wrap-around and exact resume."""

from __future__ import annotations

import io

import numpy as np
import pytest
import torch

from crowdplan.algos.buffer import ReplayBuffer


def transitions(e: int, n: int, start: int = 0) -> dict[str, np.ndarray]:
    """E transitions whose every field encodes its index ``start + k`` (so order is checkable)."""
    ids = np.arange(start, start + e, dtype=np.float32)
    return {
        "robot": np.repeat(ids[:, None], 6, axis=1),
        "humans": np.broadcast_to(ids[:, None, None], (e, n, 7)).copy(),
        "mask": np.ones((e, n), dtype=bool),
        "action": np.arange(start, start + e, dtype=np.int64) % 81,
        "reward": ids * 0.5,
        "next_robot": np.repeat(ids[:, None] + 0.25, 6, axis=1),
        "next_humans": np.broadcast_to(ids[:, None, None] + 0.25, (e, n, 7)).copy(),
        "next_mask": np.ones((e, n), dtype=bool),
        "done": (ids % 2).astype(np.float32),
    }


def test_add_and_sample_shapes_and_dtypes():
    buf = ReplayBuffer(capacity=100, max_humans=5, seed=0)
    buf.add_batch(**transitions(8, 3))
    assert len(buf) == 8
    batch = buf.sample(16)
    shapes = {k: tuple(v.shape) for k, v in batch.items()}
    assert shapes == {
        "robot": (16, 6),
        "humans": (16, 5, 7),
        "mask": (16, 5),
        "action": (16,),
        "reward": (16,),
        "next_robot": (16, 6),
        "next_humans": (16, 5, 7),
        "next_mask": (16, 5),
        "done": (16,),
        "behaviour_entropy": (16,),
    }
    assert not batch["behaviour_entropy"].any()  # not given: 0
    assert batch["mask"].dtype == torch.bool and batch["action"].dtype == torch.int64
    assert batch["robot"].dtype == torch.float32 and batch["done"].dtype == torch.float32
    # fewer humans than slots: padded with zeros and mask False
    assert batch["mask"][:, :3].all() and not batch["mask"][:, 3:].any()
    assert (batch["humans"][:, 3:] == 0).all()
    # each sampled row is one consistent transition
    ids = batch["robot"][:, 0]
    torch.testing.assert_close(batch["reward"], ids * 0.5)
    torch.testing.assert_close(batch["next_robot"][:, 0], ids + 0.25)


def test_behaviour_entropy_travels_with_its_transition():
    buf = ReplayBuffer(capacity=10, max_humans=2, seed=0)
    rows = transitions(6, 2)
    buf.add_batch(**rows, behaviour_entropy=rows["reward"] * 2)
    batch = buf.sample(32)
    torch.testing.assert_close(batch["behaviour_entropy"], batch["robot"][:, 0])


def test_wraparound_overwrites_the_oldest():
    buf = ReplayBuffer(capacity=5, max_humans=2, seed=0)
    buf.add_batch(**transitions(3, 2, start=0))
    buf.add_batch(**transitions(4, 2, start=3))  # ids 3..6; 5 and 6 wrap to slots 0 and 1
    assert len(buf) == 5 and buf.pos == 2
    np.testing.assert_array_equal(buf.data["robot"][:, 0], [5, 6, 2, 3, 4])
    buf.add_batch(**transitions(12, 2, start=100))  # more than the capacity at once
    assert len(buf) == 5
    assert sorted(buf.data["robot"][:, 0].tolist()) == [107, 108, 109, 110, 111]


def test_too_many_humans_is_an_error():
    buf = ReplayBuffer(capacity=5, max_humans=2, seed=0)
    with pytest.raises(ValueError, match="3 humans"):
        buf.add_batch(**transitions(1, 3))


def test_empty_buffer_cannot_be_sampled():
    with pytest.raises(ValueError, match="empty"):
        ReplayBuffer(capacity=5, max_humans=2).sample(4)


def test_state_round_trip_continues_identically():
    a = ReplayBuffer(capacity=50, max_humans=4, seed=7)
    a.add_batch(**transitions(30, 4))
    a.sample(8)
    saved = io.BytesIO()
    torch.save(a.state_dict(), saved)
    saved.seek(0)
    b = ReplayBuffer(capacity=50, max_humans=4, seed=123)
    b.load_state_dict(torch.load(saved, weights_only=True))
    for step in range(3):
        for buf in (a, b):
            buf.add_batch(**transitions(15, 4, start=1000 + 15 * step))
        sa, sb = a.sample(32), b.sample(32)
        for key in sa:
            torch.testing.assert_close(sa[key], sb[key])
    assert (a.pos, a.size) == (b.pos, b.size)


def test_load_rejects_a_different_shape():
    state = ReplayBuffer(capacity=10, max_humans=4).state_dict()
    with pytest.raises(ValueError, match="mismatch"):
        ReplayBuffer(capacity=10, max_humans=5).load_state_dict(state)
