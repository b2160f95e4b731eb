"""DSAC's update captured in one CUDA graph: refused where it cannot be exact; on a GPU it
follows the eager update step for step (the GPU tests skip on machines without CUDA)."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch
from tiny_runs import TINY, flat_parameters, restored, train_tiny, without_clock

from crowdplan.algos.dsac import DSAC, DSACConfig
from crowdplan.nets.encoders import EncoderConfig
from crowdplan.training import load_config

needs_cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")


@pytest.mark.parametrize(
    "option",
    [
        {"parallel_update": True},
        {"target_entropy_anneal_updates": 100},
        {"clip_q_targets": True},
    ],
)
def test_options_a_fixed_graph_cannot_replay_are_refused(option):
    name = next(iter(option))
    with pytest.raises(ValueError, match=f"dsac.cuda_graph replays one fixed update.*dsac.{name}"):
        DSACConfig(cuda_graph=True, **option)


def test_cuda_graph_on_the_cpu_names_the_device_setting():
    with pytest.raises(ValueError, match="dsac.cuda_graph needs a CUDA device, not 'cpu'"):
        DSAC(DSACConfig(cuda_graph=True), EncoderConfig(name="lsa", max_humans=3))


def test_the_option_loads_from_yaml(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("name: g\ndevice: cuda\ndsac:\n  cuda_graph: true\n")
    assert load_config(path).algo_config.cuda_graph is True
    path.write_text("name: g\ndsac:\n  cuda_graph: true\n  parallel_update: true\n")
    with pytest.raises(ValueError, match="turn dsac.parallel_update off"):
        load_config(path)


def random_batch(
    batch: int, humans: int, seed: int, device: str, real: float = 1.0
) -> dict[str, torch.Tensor]:
    """A random replay batch; each human is real with probability ``real`` (below 1 the LSTM sees
    sequences of every length)."""
    g = torch.Generator().manual_seed(seed)
    mask = torch.rand(batch, humans, generator=g) < real
    next_mask = torch.rand(batch, humans, generator=g) < real
    cpu = {
        "robot": torch.randn(batch, 6, generator=g),
        "humans": torch.randn(batch, humans, 7, generator=g),
        "mask": mask,
        "action": torch.randint(0, 81, (batch,), generator=g),
        "reward": torch.randn(batch, generator=g) * 0.1,
        "next_robot": torch.randn(batch, 6, generator=g),
        "next_humans": torch.randn(batch, humans, 7, generator=g),
        "next_mask": next_mask,
        "done": (torch.rand(batch, generator=g) < 0.1).float(),
    }
    return {name: value.to(device) for name, value in cpu.items()}


@pytest.fixture
def exact_cuda():
    """Deterministic cuDNN and no TF32 for the test, restored after it."""
    # (torch's backend flags are properties that pytest's monkeypatch cannot restore)
    flags = [
        (torch.backends.cudnn, "deterministic", True),
        (torch.backends.cuda.matmul, "allow_tf32", False),
        (torch.backends.cudnn, "allow_tf32", False),
    ]
    saved = [getattr(owner, name) for owner, name, _ in flags]
    for owner, name, value in flags:
        setattr(owner, name, value)
    yield
    for (owner, name, _), value in zip(flags, saved, strict=True):
        setattr(owner, name, value)


@needs_cuda
@pytest.mark.parametrize("encoder", ["lsa", "rg", "sa"])
def test_graphed_updates_follow_the_eager_ones(encoder, exact_cuda):
    enc = EncoderConfig(name=encoder, max_humans=5)
    eager = DSAC(DSACConfig(batch_size=64, average_q=True), enc, device="cuda")
    graphed = DSAC(DSACConfig(batch_size=64, average_q=True, cuda_graph=True), enc, device="cuda")
    for step in range(12):  # 3 eager warm-up updates, the capture, then replays
        batch = random_batch(64, 5, seed=step, device="cuda")
        want, got = eager.update(batch), graphed.update(batch)
        for name in want:
            assert got[name] == pytest.approx(want[name], rel=1e-4, abs=1e-5), (step, name)
    assert graphed._graphed is not None and graphed._graphed.graph is not None
    for name, value in eager.actor.state_dict().items():
        torch.testing.assert_close(graphed.actor.state_dict()[name], value, rtol=1e-4, atol=1e-5)
    for name, value in eager.critic_target.state_dict().items():
        got = graphed.critic_target.state_dict()[name]
        torch.testing.assert_close(got, value, rtol=1e-4, atol=1e-5)


@needs_cuda
def test_padded_crowds_give_the_eager_update_under_the_graph(exact_cuda):
    """Under the graph the LSTM runs over the padded sequence and reads each row's last real
    step instead of packing by length: the same numbers up to rounding."""
    enc = EncoderConfig(name="lsa", max_humans=5)
    eager = DSAC(DSACConfig(batch_size=64), enc, device="cuda")
    graphed = DSAC(DSACConfig(batch_size=64, cuda_graph=True), enc, device="cuda")
    for step in range(4):  # the fourth is captured and replayed
        batch = random_batch(64, 5, seed=step, device="cuda", real=0.6)
        want, got = eager.update(batch), graphed.update(batch)
    assert graphed._graphed.graph is not None
    for name in want:
        assert got[name] == pytest.approx(want[name], rel=1e-4, abs=1e-5), name
    for step in range(4, 8):
        stats = graphed.update(random_batch(64, 5, seed=step, device="cuda", real=0.6))
        assert all(math.isfinite(v) for v in stats.values())


@needs_cuda
def test_the_graph_is_captured_after_the_actor_warmup():
    config = DSACConfig(batch_size=32, actor_warmup_updates=5, cuda_graph=True)
    agent = DSAC(config, EncoderConfig(name="lsa", max_humans=3), device="cuda")
    actor_before = [p.detach().clone() for p in agent.actor.parameters()]

    def actor_unchanged() -> bool:
        now = agent.actor.parameters()
        return all(torch.equal(a, b) for a, b in zip(actor_before, now, strict=True))

    for step in range(5):
        agent.update(random_batch(32, 3, seed=step, device="cuda"))
    assert agent._graphed.graph is None
    assert actor_unchanged()
    for step in range(5, 10):
        agent.update(random_batch(32, 3, seed=step, device="cuda"))
    assert agent._graphed.graph is not None
    assert not actor_unchanged()


@needs_cuda
def test_a_state_saved_by_an_eager_run_resumes_under_the_graph():
    enc = EncoderConfig(name="lsa", max_humans=3)
    eager = DSAC(DSACConfig(batch_size=32), enc, device="cuda")
    for step in range(3):
        eager.update(random_batch(32, 3, seed=step, device="cuda"))
    graphed = DSAC(DSACConfig(batch_size=32, cuda_graph=True), enc, device="cuda")
    graphed.load_state_dict(eager.state_dict())
    for step in range(3, 10):
        stats = graphed.update(random_batch(32, 3, seed=step, device="cuda"))
    assert graphed._graphed.graph is not None
    assert all(math.isfinite(v) for v in stats.values())
    assert graphed.n_updates == 10


GPU_TINY = {**TINY, "device": "cuda", "dsac": {**TINY["dsac"], "cuda_graph": True}}


@needs_cuda
def test_a_graphed_run_repeats_itself_and_resumes_exactly(tmp_path, exact_cuda):
    straight = train_tiny(GPU_TINY, tmp_path, "straight", episodes=6)
    again = train_tiny(GPU_TINY, tmp_path, "again", episodes=6)
    assert straight.agent.core._graphed.graph is not None
    actor = flat_parameters(straight.agent.core.actor)
    assert torch.equal(actor, flat_parameters(again.agent.core.actor))
    first = train_tiny(GPU_TINY, tmp_path, "resumed", episodes=3)
    resumed = restored(dataclasses.replace(first.config, episodes=6), tmp_path / "resumed")
    resumed.run()
    assert without_clock(resumed.episodes) == without_clock(straight.episodes)
