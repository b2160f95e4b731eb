"""DSAC stabilisation options: each does what it says, all are off by default, and the two-thread
update stays bitwise identical to the serial one with every option on."""

from __future__ import annotations

import math

import pytest
import torch
from torch import nn

from crowdplan.algos import dsac as dsac_module
from crowdplan.algos.base import frozen_copy
from crowdplan.algos.dsac import DSAC, DSACConfig
from crowdplan.nets.encoders import EncoderConfig
from crowdplan.nets.heads import QHead
from tests.test_dsac import small_batch

ENCODER = EncoderConfig(name="aw", max_humans=3)
ALL_ON = {
    "clip_q_targets": True,
    "alpha_min": 0.1,
    "alpha_lr": 1e-3,
    "policy_lr": 1e-4,
    "grad_clip_norm": 0.5,
    "critic_layer_norm": True,
    "target_entropy_start_scale": 0.9,
    "target_entropy_anneal_updates": 3,
    "average_q": True,
    "q_clip": 0.05,
    "entropy_penalty": 0.5,
    "anchor_weight": 0.1,
    "init_model": "lsa-dsac-paper",  # anchor_weight needs one; DSAC itself never reads it
}


@pytest.fixture(autouse=True, scope="module")
def _one_thread():
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


def test_every_option_is_off_by_default():
    config = DSACConfig()
    assert not config.clip_q_targets and not config.critic_layer_norm
    assert config.alpha_min == 0 and config.alpha_lr == 0 and config.grad_clip_norm == 0
    assert config.policy_lr == 0
    assert config.target_entropy_anneal_updates == 0
    assert not config.average_q and config.q_clip == 0 and config.entropy_penalty == 0
    assert config.anchor_weight == 0
    agent = DSAC(config, ENCODER)
    assert agent.anchor is None
    assert not any(isinstance(m, nn.LayerNorm) for m in agent.critic.modules())


def _targets_seen(monkeypatch, agent: DSAC, batch) -> torch.Tensor:
    """The soft targets y of one update (the second argument of the critic's MSE)."""
    seen = []
    original = dsac_module.F.mse_loss

    def spy(prediction, target, *args, **kwargs):
        seen.append(target.detach().clone())
        return original(prediction, target, *args, **kwargs)

    monkeypatch.setattr(dsac_module.F, "mse_loss", spy)
    agent.update(batch)
    monkeypatch.setattr(dsac_module.F, "mse_loss", original)
    return seen[0]


def test_q_targets_are_clipped_to_the_reachable_range(monkeypatch):
    batch = small_batch(seed=3)
    batch["reward"] = torch.linspace(-50.0, 50.0, len(batch["reward"]))
    free = _targets_seen(monkeypatch, DSAC(DSACConfig(), ENCODER), batch)
    assert free.min() < -2.5 and free.max() > 20.0  # far outside any return

    config = DSACConfig(clip_q_targets=True, return_min=-2.0, return_max=1.0)
    agent = DSAC(config, ENCODER)
    alpha = agent.alpha
    clipped = _targets_seen(monkeypatch, agent, batch)
    entropy_bonus = alpha * math.log(81) * 0.95 / 0.05
    assert clipped.min() == pytest.approx(-2.0)
    assert clipped.max() == pytest.approx(1.0 + entropy_bonus)
    inside = (free > -2.0) & (free < 1.0 + entropy_bonus)
    assert torch.equal(clipped[inside], free[inside])  # targets in range are untouched


@pytest.mark.parametrize("average_q", [False, True])
def test_soft_target_uses_the_minimum_or_the_mean_of_the_twin_critics(monkeypatch, average_q):
    batch = small_batch(seed=5)
    agent = DSAC(DSACConfig(average_q=average_q), ENCODER, seed=2)
    next_obs = (batch["next_robot"], batch["next_humans"], batch["next_mask"])
    with torch.no_grad():
        q1, q2 = agent.critic_target(*next_obs)
        log_pi = torch.log_softmax(agent.actor(*next_obs)[0], dim=1)
    twin = (q1 + q2) / 2 if average_q else torch.min(q1, q2)
    value = (log_pi.exp() * (twin - agent.alpha * log_pi)).sum(dim=1)
    expected = batch["reward"] + 0.95 * (1 - batch["done"]) * value
    seen = _targets_seen(monkeypatch, agent, batch)
    assert torch.allclose(seen, expected, atol=1e-5)
    if average_q:  # the mean is above the minimum wherever the twins disagree
        minimum = (log_pi.exp() * (torch.min(q1, q2) - agent.alpha * log_pi)).sum(dim=1)
        assert (value > minimum).all()


def test_q_clip_stops_the_gradient_of_a_critic_that_moved_past_the_clip():
    agent = DSAC(DSACConfig(q_clip=0.5), ENCODER)
    index = torch.zeros(2, 1, dtype=torch.long)
    old = torch.tensor([[1.0], [1.0]])
    target = torch.zeros(2)
    # moved 0.8 towards the target (past the clip) and 0.2 (inside it)
    for moved, expected_loss, gradient_flows in ((0.8, 0.5**2, False), (0.2, 0.8**2, True)):
        q_a = torch.full((2,), 1.0 - moved, requires_grad=True)
        loss = agent._clipped_loss(
            torch.nn.functional.mse_loss(q_a, target), q_a, old, index, target
        )
        loss.backward()
        assert loss.item() == pytest.approx(expected_loss)
        assert bool(q_a.grad.abs().sum() > 0) == gradient_flows


def test_q_clip_changes_the_update_once_critic_and_target_differ():
    batch = small_batch(seed=6)
    batch["reward"] = batch["reward"] * 30
    runs = []
    for q_clip in (0.0, 0.01):
        agent = DSAC(DSACConfig(q_clip=q_clip, lr=1e-2), ENCODER, seed=3)
        runs.append([agent.update(batch)["qf_loss"] for _ in range(3)])
    assert runs[0][0] == runs[1][0]  # critic == target at the start: nothing to clip
    assert runs[0][1:] != runs[1][1:]


def test_entropy_penalty_holds_the_policy_entropy_near_the_behaviour_entropy():
    batch = small_batch(seed=7)
    batch["behaviour_entropy"] = torch.zeros_like(batch["reward"])  # a deterministic behaviour
    entropies = {}
    for penalty in (0.0, 10.0):
        config = DSACConfig(entropy_penalty=penalty, lr=1e-3, autotune_alpha=False)
        agent = DSAC(config, ENCODER, seed=1)
        for _ in range(20):
            entropies[penalty] = agent.update(batch)["entropy"]
    assert entropies[10.0] < entropies[0.0] - 0.5


def test_entropy_penalty_is_zero_where_the_policy_kept_its_entropy():
    batch = small_batch(seed=8)
    plain = DSAC(DSACConfig(), ENCODER, seed=1)
    penalised = DSAC(DSACConfig(entropy_penalty=10.0), ENCODER, seed=1)
    obs = (batch["robot"], batch["humans"], batch["mask"])
    _, batch["behaviour_entropy"] = penalised.sample(*obs)
    assert plain.update(batch)["actor_loss"] == pytest.approx(
        penalised.update(batch)["actor_loss"], abs=1e-6
    )


def _anchored(weight: float) -> DSAC:
    config = DSACConfig(anchor_weight=weight, init_model="lsa-dsac-paper", lr=1e-3)
    agent = DSAC(config, ENCODER, seed=1)
    agent.anchor_to_actor()
    return agent


def test_anchor_adds_the_cross_entropy_to_the_initial_policy_to_the_policy_loss():
    batch = small_batch(seed=9)
    obs = (batch["robot"], batch["humans"], batch["mask"])
    plain, anchored = DSAC(DSACConfig(lr=1e-3), ENCODER, seed=1), _anchored(0.5)
    with torch.no_grad():  # the policy is still the anchor: the cross-entropy is its entropy
        log_pi = torch.log_softmax(anchored.actor(*obs)[0], dim=1)
        entropy = float(-(log_pi.exp() * log_pi).sum(dim=1).mean())
    assert anchored.update(batch)["actor_loss"] == pytest.approx(
        plain.update(batch)["actor_loss"] + 0.5 * entropy, abs=1e-5
    )


def test_anchor_holds_the_policy_near_the_initial_policy():
    batch = small_batch(seed=10)
    obs = (batch["robot"], batch["humans"], batch["mask"])
    drift = {}
    for weight in (0.0, 1.0):
        agent = _anchored(weight) if weight else DSAC(DSACConfig(lr=1e-3), ENCODER, seed=1)
        initial = frozen_copy(agent.actor)
        for _ in range(30):
            agent.update(batch)
        with torch.no_grad():
            p0 = torch.softmax(initial(*obs)[0], dim=1)
            log_p = torch.log_softmax(agent.actor(*obs)[0], dim=1)
            drift[weight] = float((p0 * (p0.log() - log_p)).sum(dim=1).mean())
    assert drift[1.0] < 0.5 * drift[0.0]


def test_anchor_needs_an_initial_policy():
    with pytest.raises(ValueError, match="set dsac.init_model too"):
        DSACConfig(anchor_weight=0.1)
    agent = DSAC(DSACConfig(anchor_weight=0.1, init_model="lsa-dsac-paper"), ENCODER)
    with pytest.raises(RuntimeError, match="anchor_to_actor"):
        agent.update(small_batch())


def test_alpha_never_goes_below_its_floor():
    # a fresh policy is near uniform, above the target entropy: alpha falls fast at this rate
    agent = DSAC(DSACConfig(alpha_min=0.15, alpha_lr=0.05), ENCODER)
    alphas = [agent.update(small_batch(seed=i)) and agent.alpha for i in range(20)]
    assert min(alphas) >= 0.15 * (1 - 1e-6)
    assert alphas[-1] == pytest.approx(0.15)
    free = DSAC(DSACConfig(alpha_lr=0.05), ENCODER)
    for i in range(20):
        free.update(small_batch(seed=i))
    assert free.alpha < 0.15


def test_temperature_has_its_own_learning_rate():
    # Adam's first step moves a parameter by its learning rate (up to eps)
    for alpha_lr, expected in ((0.0, 3e-4), (0.02, 0.02)):
        agent = DSAC(DSACConfig(alpha_lr=alpha_lr), ENCODER)
        before = float(agent.log_alpha.detach())
        agent.update(small_batch())
        assert abs(float(agent.log_alpha.detach()) - before) == pytest.approx(expected, rel=1e-3)
        groups = {g["name"]: g["lr"] for g in agent.actor_optimizer.param_groups}
        assert groups == {"actor": 3e-4, "alpha": expected}


def test_policy_has_its_own_learning_rate():
    for policy_lr, expected in ((0.0, 3e-4), (1e-4, 1e-4)):
        agent = DSAC(DSACConfig(policy_lr=policy_lr), ENCODER)
        before = [p.detach().clone() for p in agent.actor.parameters()]
        agent.update(small_batch())
        groups = {g["name"]: g["lr"] for g in agent.actor_optimizer.param_groups}
        assert groups == {"actor": expected, "alpha": 3e-4}
        # Adam's first step moves every parameter with a gradient by its learning rate (up to eps)
        steps = torch.cat(
            [
                (p.detach() - b).abs().flatten()
                for p, b in zip(agent.actor.parameters(), before, strict=True)
            ]
        )
        assert float(steps.max()) == pytest.approx(expected, rel=1e-3)
    critic_groups = {g["name"]: g["lr"] for g in agent.critic_optimizer.param_groups}
    assert critic_groups == {"critic": 3e-4}


def test_gradient_norms_are_clipped_before_each_step(monkeypatch):
    agent = DSAC(DSACConfig(grad_clip_norm=1e-3), ENCODER)
    norms: dict[str, float] = {}

    def recorder(name, params, step):
        def record(*args, **kwargs):
            grads = [p.grad for p in params if p.grad is not None]
            norms[name] = float(torch.linalg.vector_norm(torch.stack([g.norm() for g in grads])))
            return step(*args, **kwargs)

        return record

    critic_step = agent.critic_optimizer.step
    actor_step = agent.actor_optimizer.step
    actor_params = list(agent.actor.parameters())
    monkeypatch.setattr(
        agent.critic_optimizer, "step", recorder("critic", agent._critic_params, critic_step)
    )
    monkeypatch.setattr(agent.actor_optimizer, "step", recorder("actor", actor_params, actor_step))
    agent.update(small_batch())
    assert norms["critic"] == pytest.approx(1e-3, rel=1e-3)
    assert norms["actor"] == pytest.approx(1e-3, rel=1e-3)


def test_layer_norm_normalises_the_q_heads_hidden_features():
    head = QHead(56, 81, (128, 128), layer_norm=True)
    features = torch.randn(32, 56) * 100
    hidden = head.q1[:2](features)  # Linear -> LayerNorm
    torch.testing.assert_close(hidden.mean(dim=1), torch.zeros(32), atol=1e-5, rtol=0)
    torch.testing.assert_close(hidden.std(dim=1, unbiased=False), torch.ones(32), atol=1e-3, rtol=0)
    assert sum(isinstance(m, nn.LayerNorm) for m in head.modules()) == 4  # 2 per twin head
    q1, q2 = head(features)
    assert q1.shape == q2.shape == (32, 81)


def test_target_entropy_follows_a_linear_schedule():
    config = DSACConfig(
        target_entropy_start_scale=0.98,
        target_entropy_scale=0.5,
        target_entropy_anneal_updates=10,
    )
    agent = DSAC(config, ENCODER)
    scales = []
    for n in (0, 5, 10, 50):
        agent.n_updates = n
        scales.append(agent.target_entropy / math.log(81))
    assert scales == pytest.approx([0.98, 0.74, 0.5, 0.5])
    assert DSAC(DSACConfig(), ENCODER).target_entropy == pytest.approx(0.98 * math.log(81))


def test_an_absolute_target_entropy_overrides_the_scale_and_below_zero_only_lowers_alpha():
    # ALN-DSAC's setting: -162 with log alpha = 0. A deterministic policy (entropy ~ 0) is still
    # above the target, so even then the temperature falls.
    agent = DSAC(DSACConfig(target_entropy=-162.0, init_alpha=1.0), ENCODER)
    assert agent.target_entropy == -162.0
    with torch.no_grad():
        agent.actor.head.net[-1].bias[3] = 50.0
    batch = small_batch()
    alphas = [agent.alpha]
    for _ in range(3):
        stats = agent.update(batch)
        assert stats["entropy"] < 0.01
        alphas.append(agent.alpha)
    assert alphas == sorted(alphas, reverse=True) and alphas[-1] < 1.0


@pytest.mark.parametrize("share_encoder", [False, True])
def test_two_thread_update_is_bitwise_identical_with_every_option(share_encoder):
    serial = DSAC(DSACConfig(share_encoder=share_encoder, **ALL_ON), ENCODER, seed=4)
    parallel = DSAC(
        DSACConfig(share_encoder=share_encoder, parallel_update=True, **ALL_ON), ENCODER, seed=4
    )
    serial.anchor_to_actor()
    parallel.anchor_to_actor()
    for step in range(5):
        batch = small_batch(seed=step)
        batch["reward"] = batch["reward"] * 30  # some targets outside the range
        assert serial.update(batch) == parallel.update(batch)
    for net in ("actor", "critic", "critic_target"):
        for p, q in zip(
            getattr(serial, net).parameters(), getattr(parallel, net).parameters(), strict=True
        ):
            assert torch.equal(p, q)
    assert torch.equal(serial.log_alpha, parallel.log_alpha)


@pytest.mark.parametrize(
    ("changes", "fragment"),
    [
        ({"alpha_min": -0.1}, "dsac.alpha_min must be >= 0.0"),
        ({"grad_clip_norm": -1.0}, "dsac.grad_clip_norm must be >= 0.0"),
        ({"q_clip": -0.1}, "dsac.q_clip must be >= 0.0"),
        ({"entropy_penalty": -1.0}, "dsac.entropy_penalty must be >= 0.0"),
        ({"anchor_weight": -1.0}, "dsac.anchor_weight must be >= 0.0"),
        ({"target_entropy_anneal_updates": -5}, "dsac.target_entropy_anneal_updates must be"),
        ({"return_min": 2.0, "return_max": 1.0}, "dsac.return_min (2.0) must be below"),
    ],
)
def test_bad_option_values_are_refused(changes, fragment):
    with pytest.raises(ValueError) as error:
        DSACConfig(**changes)
    assert fragment in str(error.value)


def test_stable_preset_loads_with_every_option_on():
    from crowdplan.training import load_config

    params = load_config("configs/lsa_dsac_stable.yaml").algo_config
    assert params.clip_q_targets and params.critic_layer_norm
    assert params.alpha_min > 0 and params.alpha_lr > 0 and params.grad_clip_norm > 0
    assert params.target_entropy_anneal_updates > 0
