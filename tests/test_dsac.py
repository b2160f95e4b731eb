"""DSAC: learns a tiny MDP with a known soft-optimal solution; target, temperature, state."""

from __future__ import annotations

import copy
import io
import math
import warnings

import pytest
import torch

from crowdplan.algos.base import frozen_copy
from crowdplan.algos.dsac import DSAC, DSACConfig
from crowdplan.nets.encoders import ENCODER_NAMES, EncoderConfig

A = 81


@pytest.fixture(autouse=True, scope="module")
def _one_thread():
    """Library callers run torch on one thread; several threads are far slower for these nets."""
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


def chain_mdp() -> tuple[dict[str, torch.Tensor], torch.Tensor, torch.Tensor]:
    """Two-step chain s0 -> s1 -> end, every action enumerated once in each state.

    In s0 every action leads to s1 (not terminal) with reward r0(a); in s1 every action ends the
    episode (done = 1) with reward r1(a). The batch holds all 2 x 81 transitions.
    """
    s0 = torch.tensor([4.0, 1.0, 0.0, 0.3, 0.0, 0.0])
    s1 = torch.tensor([1.0, 1.0, 0.0, 0.3, 0.5, 0.0])
    humans = torch.tensor(
        [[1.0, 2.0, 0.0, -1.0, 0.3, 2.24, 0.6], [-2.0, 1.0, 1.0, 0.0, 0.3, 2.24, 0.6]]
    ).expand(2 * A, 2, 7)
    mask = torch.ones(2 * A, 2, dtype=torch.bool)
    r0 = torch.zeros(A)
    r0[7] = 0.3
    r1 = torch.zeros(A)
    r1[20], r1[40] = 1.0, 0.5
    actions = torch.arange(A)
    batch = {
        "robot": torch.cat([s0.expand(A, 6), s1.expand(A, 6)]),
        "humans": humans.clone(),
        "mask": mask,
        "action": torch.cat([actions, actions]),
        "reward": torch.cat([r0, r1]),
        "next_robot": s1.expand(2 * A, 6).clone(),  # s1's successor is irrelevant: done = 1
        "next_humans": humans.clone(),
        "next_mask": mask.clone(),
        "done": torch.cat([torch.zeros(A), torch.ones(A)]),
    }
    return batch, r0, r1


def states(batch: dict[str, torch.Tensor]) -> tuple[torch.Tensor, ...]:
    """(robot, humans, mask) of s0 and s1."""
    index = torch.tensor([0, A])
    return batch["robot"][index], batch["humans"][index], batch["mask"][index]


@pytest.mark.parametrize("encoder", ["lsa", "rg"])
def test_learns_the_soft_optimal_solution_of_a_two_step_chain(encoder):
    alpha, gamma = 0.2, 0.9
    cfg = DSACConfig(gamma=gamma, lr=3e-3, tau=0.05, init_alpha=alpha, autotune_alpha=False)
    agent = DSAC(cfg, EncoderConfig(name=encoder), seed=0)
    batch, r0, r1 = chain_mdp()
    for _ in range(220):
        agent.update(batch)

    # analytic soft solution: Q(s1, .) = r1, V(s1) = alpha logsumexp(r1 / alpha) (the value of
    # the policy softmax(Q / alpha)), Q(s0, .) = r0 + gamma V(s1): the bootstrap through s0's
    # non-terminal transitions and its absence after s1's terminal ones are both checked.
    v1 = alpha * torch.logsumexp(r1 / alpha, dim=0)
    q_s0, q_s1 = r0 + gamma * v1, r1
    with torch.no_grad():
        qf1, qf2 = agent.critic(*states(batch))
        logits, _ = agent.actor(*states(batch))
    for qf in (qf1, qf2):
        torch.testing.assert_close(qf[0], q_s0, atol=0.02, rtol=0)
        torch.testing.assert_close(qf[1], q_s1, atol=0.02, rtol=0)
    pi = torch.softmax(logits, dim=1)
    torch.testing.assert_close(pi[1], torch.softmax(q_s1 / alpha, dim=0), atol=0.02, rtol=0)
    actions, _ = agent.act(*states(batch), deterministic=True)
    assert actions.tolist() == [7, 20]


def small_batch(n: int = 16, humans: int = 3, seed: int = 0) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    mask = torch.rand(n, humans, generator=g) < 0.8
    return {
        "robot": torch.randn(n, 6, generator=g),
        "humans": torch.randn(n, humans, 7, generator=g),
        "mask": mask,
        "action": torch.randint(0, A, (n,), generator=g),
        "reward": torch.randn(n, generator=g),
        "next_robot": torch.randn(n, 6, generator=g),
        "next_humans": torch.randn(n, humans, 7, generator=g),
        "next_mask": mask.roll(1, dims=0),
        "done": (torch.rand(n, generator=g) < 0.3).float(),
        "behaviour_entropy": torch.rand(n, generator=g) * math.log(A),
    }


@pytest.mark.parametrize("share_encoder", [False, True])
@pytest.mark.parametrize("encoder", ENCODER_NAMES)
def test_update_runs_with_every_encoder(encoder, share_encoder):
    agent = DSAC(DSACConfig(share_encoder=share_encoder), EncoderConfig(name=encoder, max_humans=3))
    assert (agent.actor.encoder is agent.critic.encoder) == share_encoder
    assert agent.critic_target.encoder is not agent.critic.encoder
    before = [p.detach().clone() for p in agent.actor.parameters()]
    stats = agent.update(small_batch())
    assert set(stats) >= {"qf_loss", "actor_loss", "alpha_loss", "alpha", "entropy"}
    assert all(math.isfinite(v) for v in stats.values())
    changed = [not torch.equal(b, p) for b, p in zip(before, agent.actor.parameters(), strict=True)]
    assert any(changed)
    if share_encoder:  # the shared encoder belongs to the critic's parameter group only
        actor_group = next(g for g in agent.actor_optimizer.param_groups if g["name"] == "actor")
        encoder_ids = {id(p) for p in agent.critic.encoder.parameters()}
        assert not encoder_ids & {id(p) for p in actor_group["params"]}


@pytest.mark.parametrize("share_encoder", [False, True])
@pytest.mark.parametrize("encoder", ENCODER_NAMES)
def test_parallel_update_is_bitwise_identical(encoder, share_encoder):
    config = EncoderConfig(name=encoder, max_humans=3)
    serial = DSAC(DSACConfig(share_encoder=share_encoder), config, seed=5)
    parallel = DSAC(DSACConfig(share_encoder=share_encoder, parallel_update=True), config, seed=5)
    for step in range(4):
        batch = small_batch(seed=step)
        assert serial.update(batch) == parallel.update(batch)
    for net in ("actor", "critic", "critic_target"):
        for p, q in zip(
            getattr(serial, net).parameters(), getattr(parallel, net).parameters(), strict=True
        ):
            assert torch.equal(p, q)


def test_parallel_update_reports_errors_instead_of_hanging():
    agent = DSAC(DSACConfig(parallel_update=True), EncoderConfig(name="lsa", max_humans=3))
    batch = small_batch()
    batch["next_humans"] = batch["next_humans"][:, :, :5]  # wrong feature width
    with pytest.raises((RuntimeError, IndexError)):
        agent.update(batch)
    agent.update(small_batch())  # the worker thread is still usable


def test_target_critic_is_a_polyak_average():
    cfg = DSACConfig(tau=0.005)
    agent = DSAC(cfg, EncoderConfig(name="aw"))
    for target, online in zip(
        agent.critic_target.parameters(), agent.critic.parameters(), strict=True
    ):
        assert torch.equal(target, online)  # starts as an exact copy
    agent.update(small_batch(seed=1))  # make critic and target differ
    old_target = [p.detach().clone() for p in agent.critic_target.parameters()]
    agent.update(small_batch(seed=2))
    for old, target, online in zip(
        old_target, agent.critic_target.parameters(), agent.critic.parameters(), strict=True
    ):
        expected = (1 - cfg.tau) * old + cfg.tau * online.detach()
        torch.testing.assert_close(target, expected, atol=1e-7, rtol=1e-6)
    assert not all(
        torch.equal(t, o)
        for t, o in zip(agent.critic_target.parameters(), agent.critic.parameters(), strict=True)
    )


def test_frozen_copy_is_an_equal_detached_network():
    critic = DSAC(DSACConfig(), EncoderConfig(name="lsa", max_humans=3)).critic
    target = frozen_copy(critic)
    for p, q in zip(critic.parameters(), target.parameters(), strict=True):
        assert torch.equal(p, q) and p.data_ptr() != q.data_ptr() and not q.requires_grad


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_target_critic_lstm_runs_without_compacting_its_weights():
    agent = DSAC(DSACConfig(), EncoderConfig(name="lsa", max_humans=3), device="cuda")
    batch = {k: v.cuda() for k, v in small_batch().items()}
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message=".*single contiguous chunk of memory.*")
        agent.update(batch)


def test_temperature_moves_towards_the_target_entropy():
    batch = small_batch()
    # a fresh policy is close to uniform: entropy ~ log 81 > 0.98 log 81, so alpha goes down
    agent = DSAC(DSACConfig(), EncoderConfig(name="aw"))
    assert agent.target_entropy == pytest.approx(0.98 * math.log(81))
    assert agent.alpha == pytest.approx(0.2)
    for _ in range(5):
        stats = agent.update(batch)
        assert stats["entropy"] > agent.target_entropy
    assert agent.alpha < 0.2
    # a nearly deterministic policy: entropy ~ 0 < target, so alpha goes up
    agent = DSAC(DSACConfig(), EncoderConfig(name="aw"))
    with torch.no_grad():
        agent.actor.head.net[-1].bias[3] = 50.0
    stats = agent.update(batch)
    assert stats["entropy"] < agent.target_entropy
    assert agent.alpha > 0.2
    # autotune off: alpha stays put
    agent = DSAC(DSACConfig(autotune_alpha=False), EncoderConfig(name="aw"))
    agent.update(batch)
    assert agent.alpha == pytest.approx(0.2)


def test_act_deterministic_and_reproducible_sampling():
    agent = DSAC(DSACConfig(), EncoderConfig(name="lsa"))
    batch = small_batch()
    obs = (batch["robot"], batch["humans"], batch["mask"])
    greedy, attention = agent.act(*obs, deterministic=True)
    logits, _ = agent.actor(*obs)
    assert greedy.dtype == torch.int64 and greedy.shape == (16,)
    assert torch.equal(greedy, logits.argmax(dim=1))
    assert attention.shape == (16, 3)
    first, _ = agent.act(*obs, generator=torch.Generator().manual_seed(5))
    again, _ = agent.act(*obs, generator=torch.Generator().manual_seed(5))
    assert torch.equal(first, again)
    assert ((first >= 0) & (first < A)).all()
    sampled, entropy = agent.sample(*obs, generator=torch.Generator().manual_seed(5))
    assert torch.equal(sampled, first)  # the training loop's sampler draws what act() draws
    probs = torch.softmax(logits, dim=1)
    assert torch.allclose(entropy, -(probs * probs.log()).sum(dim=1), atol=1e-5)


def test_same_seed_same_agent_and_global_rng_untouched():
    torch.manual_seed(123)
    expected_next = torch.rand(1)
    torch.manual_seed(123)
    a = DSAC(DSACConfig(), EncoderConfig(name="sa"), seed=4)
    assert torch.equal(torch.rand(1), expected_next)  # initialisation used its own RNG
    b = DSAC(DSACConfig(), EncoderConfig(name="sa"), seed=4)
    for pa, pb in zip(a.actor.parameters(), b.actor.parameters(), strict=True):
        assert torch.equal(pa, pb)


def test_state_dict_round_trip_resumes_identically():
    batch = small_batch()
    a = DSAC(DSACConfig(), EncoderConfig(name="lsa"), seed=1)
    for _ in range(3):
        a.update(batch)
    saved = io.BytesIO()
    torch.save(a.state_dict(), saved)
    saved.seek(0)
    b = DSAC(DSACConfig(), EncoderConfig(name="lsa"), seed=2)
    b.load_state_dict(torch.load(saved, weights_only=True))
    obs = (batch["robot"], batch["humans"], batch["mask"])
    with torch.no_grad():
        for net in ("critic", "critic_target"):
            for qa, qb in zip(getattr(a, net)(*obs), getattr(b, net)(*obs), strict=True):
                assert torch.equal(qa, qb)
        assert torch.equal(a.actor(*obs)[0], b.actor(*obs)[0])
    assert a.alpha == b.alpha and a.n_updates == b.n_updates
    # the optimiser state came along too: the next updates are identical
    for _ in range(2):
        assert a.update(batch) == b.update(batch)
    for pa, pb in zip(a.critic.parameters(), b.critic.parameters(), strict=True):
        assert torch.equal(pa, pb)


def test_loads_checkpoints_of_one_joint_optimizer():
    """Checkpoints written when one Adam held the critic, actor and alpha groups still resume."""
    batch = small_batch()
    a = DSAC(DSACConfig(), EncoderConfig(name="lsa"), seed=1)
    for _ in range(3):
        a.update(batch)
    state = copy.deepcopy(a.state_dict())  # as from a file: no tensor shared with `a`
    critic_opt, actor_opt = state.pop("critic_optimizer"), state.pop("actor_optimizer")
    offset = len(critic_opt["param_groups"][0]["params"])  # the old ids ran on across groups
    state["optimizer"] = {
        "state": {
            **critic_opt["state"],
            **{i + offset: s for i, s in actor_opt["state"].items()},
        },
        "param_groups": critic_opt["param_groups"]
        + [{**g, "params": [i + offset for i in g["params"]]} for g in actor_opt["param_groups"]],
    }
    b = DSAC(DSACConfig(), EncoderConfig(name="lsa"), seed=2)
    b.load_state_dict(state)
    for _ in range(2):
        assert a.update(batch) == b.update(batch)
    for pa, pb in zip(a.actor.parameters(), b.actor.parameters(), strict=True):
        assert torch.equal(pa, pb)
