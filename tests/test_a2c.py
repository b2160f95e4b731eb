"""LSTM-A2C: return maths, the encoder, determinism, exact resume, CLI, bad input."""

import dataclasses
import json
import os
import re
import signal

import numpy as np
import pytest
import torch
import yaml
from tiny_runs import flat_parameters, restored, train_tiny

from crowdplan import evaluation
from crowdplan.algos.a2c import (
    A2C_MODEL_FORMAT,
    A2CAgent,
    A2CPolicy,
    advantages_and_returns,
    load_a2c_payload,
)
from crowdplan.algos.base import Transitions
from crowdplan.cli import main
from crowdplan.models import load_model_policy, resolve_model_path
from crowdplan.nets.lstm_rl import LSTMRLEncoder
from crowdplan.sim.env import CrowdNavVectorEnv
from crowdplan.training import Trainer, config_from_dict, load_config

TINY = {
    "name": "tiny_a2c",
    "algo": "a2c",
    "episodes": 6,
    "num_envs": 2,
    "val_interval": 1000,
    "val_episodes": 2,
    "checkpoint_interval": 1000,
    "log_interval": 1000,
    "test_episodes": 0,
    "world": {"humans": 3, "time_limit": 4.0},
    "a2c": {"n_steps": 7},  # does not divide the 16-step episodes: rollouts span episode ends
}


def _weights(trainer):
    return flat_parameters(trainer.agent.net)


# ------------------------------------------------------------------ maths
def test_n_step_returns_on_a_hand_made_rollout():
    # three envs, three steps, gamma 0.5; V(s'_t) = bootstrap[t]
    rewards = torch.tensor([[1.0, 1.0, 1.0, 1.0], [2.0, 2.0, 2.0, 2.0], [3.0, 3.0, 3.0, 3.0]])
    terminated = torch.tensor([[0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 1]], dtype=torch.bool)
    truncated = torch.tensor([[0, 0, 1, 0], [0, 0, 0, 0], [0, 0, 0, 1]], dtype=torch.bool)
    bootstrap = torch.tensor([[99.0, 99.0, 4.0, 99.0], [99.0] * 4, [10.0, 10.0, 10.0, 10.0]])
    values = torch.tensor([[0.5, -1.0, 2.0, 7.0], [1.5, 0.0, -3.0, 0.25], [9.0, 4.0, 1.0, 2.0]])
    advantages, returns = advantages_and_returns(
        rewards, values, terminated, truncated, bootstrap, gamma=0.5, lam=1.0
    )
    assert torch.allclose(advantages, returns - values)
    expected = torch.tensor(
        [
            # running on: 3 + 5 = 8, 2 + 4 = 6, 1 + 3 = 4
            # env 1 terminates at step 1: G_1 = 2, nothing of step 2 (a new episode) leaks in
            # env 2 is truncated at step 0: G_0 = 1 + 0.5 V(s'_0) = 1 + 2
            # env 3 is terminated and truncated at its last step: terminated wins, G_2 = 3
            [4.0, 2.0, 3.0, 1 + 0.5 * (2 + 0.5 * 3)],
            [6.0, 2.0, 6.0, 2 + 0.5 * 3],
            [8.0, 8.0, 8.0, 3.0],
        ]
    )
    assert torch.allclose(returns, expected)
    # lambda = 0: the one-step TD errors, the successor's value being V(s_{t+1}) inside an episode
    one_step, targets = advantages_and_returns(
        rewards, values, terminated, truncated, bootstrap, gamma=0.5, lam=0.0
    )
    successor = torch.tensor([[1.5, 0.0, 4.0, 0.25], [9.0, 0.0, 1.0, 2.0], [10.0] * 4])
    assert torch.allclose(one_step, rewards + 0.5 * (~terminated) * successor - values)
    assert torch.allclose(targets, one_step + values)


def test_gae_mixes_the_td_errors_and_stops_at_episode_ends():
    # one env, three steps, gamma 1, lambda 0.5; the episode ends (terminated) at step 1
    rewards = torch.tensor([[0.0], [1.0], [2.0]])
    values = torch.tensor([[1.0], [2.0], [3.0]])
    terminated = torch.tensor([[False], [True], [False]])
    truncated = torch.zeros(3, 1, dtype=torch.bool)
    bootstrap = torch.tensor([[0.0], [0.0], [5.0]])
    advantages, _ = advantages_and_returns(
        rewards, values, terminated, truncated, bootstrap, gamma=1.0, lam=0.5
    )
    # deltas: 0 + 2 - 1 = 1, 1 - 2 = -1, 2 + 5 - 3 = 4; A_0 = 1 + 0.5 * (-1), A_1 = -1, A_2 = 4
    assert torch.allclose(advantages, torch.tensor([[0.5], [-1.0], [4.0]]))


def test_normalised_advantages_change_the_step_and_are_part_of_the_run(tmp_path):
    plain = train_tiny(TINY, tmp_path, "plain", episodes=2)
    normalised = train_tiny(
        TINY,
        tmp_path,
        "normalised",
        episodes=2,
        algo_config=dataclasses.replace(
            config_from_dict(TINY).algo_config, normalize_advantages=True, gae_lambda=0.9
        ),
    )
    assert normalised.agent.n_updates == plain.agent.n_updates > 0
    assert not torch.equal(_weights(plain), _weights(normalised))
    assert torch.isfinite(_weights(normalised)).all()
    saved = torch.load(normalised.run_dir / "final_model.pt", weights_only=True)["a2c"]
    assert saved["normalize_advantages"] is True and saved["gae_lambda"] == 0.9


def _agent(**a2c):
    config = config_from_dict({**TINY, "a2c": {**TINY["a2c"], **a2c}})
    return A2CAgent(config, torch.device("cpu")), config


def test_update_bootstraps_on_truncation_and_last_step_only():
    agent, config = _agent(n_steps=2, gamma=0.5)
    env = CrowdNavVectorEnv(2, "circle_crossing", 3, time_limit=4.0)
    obs, _ = env.reset(seed=7)
    later, _ = env.reset(seed=8)  # any other states, as distinct successors
    rewards = [np.array([1.0, 2.0], np.float32), np.array([3.0, 4.0], np.float32)]
    # env 0: truncated at step 0, runs on at step 1; env 1: runs on, then terminates
    flags = [
        (np.array([False, False]), np.array([True, False])),
        (np.array([False, True]), np.array([False, False])),
    ]
    for reward, (terminated, truncated) in zip(rewards, flags, strict=True):
        actions = agent.act(obs, env.world)
        agent.observe(Transitions(obs, actions, reward, later, terminated, truncated))
    batch = {k: np.stack([s[k] for s in agent.rollout]) for k in agent.rollout[0]}
    t = {k: torch.from_numpy(v) for k, v in batch.items()}
    with torch.no_grad():
        v_next = agent.net.value(*(t[k][0] for k in ("next_robot", "next_humans", "next_mask")))
        v_now = agent.net.value(*(t[k].flatten(0, 1) for k in ("robot", "humans", "mask")))
    bootstrap = agent._bootstrap(t)
    # the two successors are the same states (``later``), so V(s'_t) is v_next for every step
    assert torch.allclose(bootstrap[:, 0], v_next[0].expand(2))
    assert bootstrap[0, 1] == 0.0 and bootstrap[1, 1] == 0.0  # runs on, then terminated
    _, returns = advantages_and_returns(
        t["reward"], v_now.view(2, 2), t["terminated"], t["truncated"], bootstrap, 0.5, 1.0
    )
    assert torch.allclose(returns[:, 0], torch.tensor([1 + 0.5 * v_next[0], 3 + 0.5 * v_next[0]]))
    assert torch.allclose(returns[:, 1], torch.tensor([2 + 0.5 * 4.0, 4.0]))
    # one gradient step, with the advantages G - V(s), clears the rollout
    stats = agent.update()
    assert stats is not None and agent.rollout == [] and agent.n_updates == 1
    advantages = returns.flatten() - v_now
    assert np.isfinite(stats["policy_loss"]) and advantages.abs().sum() > 0
    assert stats["value_loss"] == pytest.approx(0.5 * float(advantages.pow(2).mean()), rel=1e-5)


# ------------------------------------------------------------------ encoder
def test_encoder_orders_by_distance_and_ignores_padding():
    torch.manual_seed(0)
    encoder = LSTMRLEncoder()
    robot = torch.randn(2, 6)
    humans = torch.randn(2, 4, 7)
    humans[..., 5] = torch.rand(2, 4) * 5  # distances
    mask = torch.tensor([[True, True, True, False], [True, True, False, False]])
    out, scores = encoder(robot, humans, mask)
    assert out.shape == (2, 56) and scores is None and torch.equal(out[:, :6], robot)
    permuted = humans[:, [2, 0, 1, 3]]
    garbage = humans.clone()
    garbage[~mask] = float("nan")
    assert torch.allclose(encoder(robot, permuted, mask[:, [2, 0, 1, 3]])[0], out, atol=1e-6)
    assert torch.allclose(encoder(robot, garbage, mask)[0], out)
    none, _ = encoder(robot, humans[:, :0], mask[:, :0])  # N = 0
    assert torch.equal(none, torch.cat([robot, torch.zeros(2, 50)], dim=1))
    # the closest human is read last: it moves the output more than the farthest one
    base = humans[:1, :3].clone()
    base[0, :, 5] = torch.tensor([3.0, 1.0, 2.0])
    one = torch.ones(1, 3, dtype=torch.bool)
    ref = encoder(robot[:1], base, one)[0]
    moved = [base.clone(), base.clone()]
    moved[0][0, 1, :2] += 0.5  # closest
    moved[1][0, 0, :2] += 0.5  # farthest
    diffs = [(encoder(robot[:1], m, one)[0] - ref).abs().sum() for m in moved]
    assert diffs[0] > 0 and diffs[1] > 0


def test_trains_without_humans(tmp_path):
    config = config_from_dict({**TINY, "world": {"humans": 0, "time_limit": 4.0}})
    trainer = Trainer(dataclasses.replace(config, episodes=2), tmp_path / "n0", progress=False)
    trainer.run()
    assert trainer.agent.n_updates > 0 and torch.isfinite(_weights(trainer)).all()


def test_init_model_starts_from_a_trained_network_and_refuses_what_does_not_fit(tmp_path):
    world_frame = {**TINY["world"], "action_frame": "world"}
    ten = {**TINY, "world": {**world_frame, "humans": 10}, "a2c": {"init_model": "lstm-a2c"}}
    trainer = Trainer(config_from_dict(ten), tmp_path / "warm", progress=False)
    shipped = torch.load(resolve_model_path("lstm-a2c"), weights_only=True)["network"]
    for key, value in trainer.agent.net.state_dict().items():
        assert torch.equal(value, shipped[key]), key
    refused = [
        ({"world": TINY["world"]}, "acts in the world frame, the run in the goal frame"),
        ({"world": {**world_frame, "kinematics": "unicycle"}}, "drives a holonomic robot"),
        ({"a2c": {"init_model": "lstm-a2c", "lstm_hidden": 20}}, "do not match the run's a2c"),
        ({"a2c": {"init_model": "sarl"}}, "model file, not an LSTM-A2C model"),
    ]
    for change, fragment in refused:
        with pytest.raises(ValueError, match=re.escape(fragment)):
            Trainer(config_from_dict({**ten, **change}), tmp_path / "refused", progress=False)
    assert not (tmp_path / "refused").exists()


def test_validate_at_start_scores_the_starting_model_as_episode_0(tmp_path):
    world = {**TINY["world"], "action_frame": "world", "humans": 10}
    warm = {**TINY, "world": world, "a2c": {"init_model": "lstm-a2c"}, "validate_at_start": True}
    trainer = Trainer(config_from_dict(warm), tmp_path / "warm", progress=False)
    trainer.run()
    first = trainer.validations[0]
    assert (first["episode"], first["env_steps"]) == (0, 0)
    shipped, _ = load_model_policy("lstm-a2c")
    records = evaluation.run_episodes(
        shipped, trainer.config.validation_world(), evaluation.validation_seeds(2)
    )
    expected = evaluation.summarize(records)
    assert first["success_rate"] == expected["success_rate"]["value"]
    assert first["mean_reward"] == pytest.approx(expected["mean_reward"]["value"])
    # without the option the first validation comes after training, which it does not change
    cold = Trainer(
        config_from_dict({**warm, "validate_at_start": False}), tmp_path / "c", progress=False
    )
    cold.run()
    assert [row["episode"] for row in cold.validations] == [6]
    assert [row["episode"] for row in trainer.validations] == [0, 6]
    assert torch.equal(_weights(trainer), _weights(cold))


# ------------------------------------------------------------------ determinism and resume
def test_same_seed_twice_is_identical_and_another_seed_differs(tmp_path):
    a, b = train_tiny(TINY, tmp_path, "a"), train_tiny(TINY, tmp_path, "b")
    assert a.agent.n_updates > 0 and torch.equal(_weights(a), _weights(b))
    clock = "train_seconds"
    assert [{k: v for k, v in e.items() if k != clock} for e in a.episodes] == [
        {k: v for k, v in e.items() if k != clock} for e in b.episodes
    ]
    assert not torch.equal(_weights(a), _weights(train_tiny(TINY, tmp_path, "c", seed=1)))


LINEAR = {**TINY, "a2c": {**TINY["a2c"], "lr_schedule": "linear"}}


@pytest.mark.parametrize("data", [TINY, LINEAR], ids=["constant", "linear"])
def test_sigterm_mid_rollout_and_resume_is_exact(tmp_path, monkeypatch, data):
    straight = train_tiny(data, tmp_path, "straight", episodes=6)
    config = config_from_dict(data)
    killed = Trainer(config, tmp_path / "killed", progress=False)
    step, calls = killed._train_step, []

    def step_then_signal():
        step()
        calls.append(1)
        if len(calls) == 24:  # mid-episode (16 steps) and mid-rollout (7 steps)
            os.kill(os.getpid(), signal.SIGTERM)

    monkeypatch.setattr(killed, "_train_step", step_then_signal)
    assert killed.run() is False
    assert len(killed.agent.rollout) == 24 % 7
    resumed = restored(config, tmp_path / "killed")
    assert len(resumed.agent.rollout) == 24 % 7
    assert resumed.run() is True
    assert torch.equal(_weights(straight), _weights(resumed))
    assert resumed.agent.n_updates == straight.agent.n_updates
    assert [e["seed"] for e in straight.episodes] == [e["seed"] for e in resumed.episodes]


def test_linear_schedule_falls_to_zero_at_the_budget_and_changes_the_run(tmp_path):
    agent, config = _agent(lr_schedule="linear", lr=0.002)
    assert agent.learning_rate() == 0.002
    agent.episodes_done(config.episodes // 2)
    assert agent.learning_rate() == pytest.approx(0.001)
    agent.episodes_done(config.episodes)
    assert agent.learning_rate() == 0.0
    constant, _ = _agent(lr=0.002)
    constant.episodes_done(config.episodes)
    assert constant.learning_rate() == 0.002
    linear = train_tiny(LINEAR, tmp_path, "linear")
    assert linear.agent.optimizer.param_groups[0]["lr"] < config.algo_config.lr
    assert not torch.equal(_weights(linear), _weights(train_tiny(TINY, tmp_path, "constant")))


# ------------------------------------------------------------------ CLI and model files
def test_train_eval_render_from_the_command_line(tmp_path):
    data = {**TINY, "episodes": 4, "val_interval": 2, "val_episodes": 2, "test_episodes": 2}
    config = tmp_path / "tiny.yaml"
    config.write_text(yaml.safe_dump(data))
    run = tmp_path / "run"
    assert main(["train", "--config", str(config), "--out", str(run), "--no-progress"]) == 0
    assert json.loads((run / "test" / "summary.json").read_text())["success_rate"]["value"] >= 0
    resolved = yaml.safe_load((run / "config.yaml").read_text())
    assert resolved["algo"] == "a2c" and resolved["a2c"]["n_steps"] == 7
    assert (
        main(["eval", "--model", str(run), "--episodes", "2", "--out", str(tmp_path / "ev")]) == 0
    )
    picture = tmp_path / "case.png"
    assert main(["render", "--model", str(run), "--case", "0", "--out", str(picture)]) == 0
    assert picture.stat().st_size > 0
    policy, world = load_model_policy(str(run / "best_model.pt"))
    assert isinstance(policy, A2CPolicy) and world.humans == 3
    assert policy.metadata["algo"] == "a2c"


def test_shipped_presets_load():
    five, ten = load_config("configs/lstm_a2c.yaml"), load_config("configs/lstm_a2c_h10.yaml")
    assert five.algo == ten.algo == "a2c"
    assert (five.world.humans, ten.world.humans) == (5, 10)
    # the 10-human preset differs only by its entropy bonus (docs/baselines.md)
    assert ten.algo_config == dataclasses.replace(five.algo_config, entropy_coef=0.01)
    assert (ten.episodes, ten.val_interval) == (five.episodes, five.val_interval) == (40000, 100)
    # the warm start: the 5-human settings, from the shipped 5-human model, half the budget
    warm = load_config("configs/lstm_a2c_h10_warm.yaml")
    assert warm.algo_config == dataclasses.replace(five.algo_config, init_model="lstm-a2c")
    assert (warm.world, warm.episodes) == (ten.world, ten.episodes // 2)


# ------------------------------------------------------------------ bad input
@pytest.mark.parametrize(
    ("data", "fragment"),
    [
        ({**TINY, "dsac": {"batch_size": 16}}, "section(s) ['dsac'] belong to another algorithm"),
        ({**TINY, "a2c": {"n_steps": 0}}, "a2c.n_steps must be >= 1, got 0"),
        ({**TINY, "a2c": {"lr": "fast"}}, "a2c.lr must be a number, got 'fast'"),
        ({**TINY, "a2c": {"batch_size": 16}}, "unknown key(s) ['batch_size'] in a2c"),
        ({**TINY, "a2c": {"lr_schedule": "cosine"}}, "a2c.lr_schedule must be one of"),
        ({**TINY, "random_steps": 16}, "unknown key(s) ['random_steps'] in top level"),
        ({**TINY, "algo": "dsac"}, "section(s) ['a2c'] belong to another algorithm"),
    ],
)
def test_bad_config_is_explained(data, fragment):
    with pytest.raises(ValueError) as error:
        config_from_dict(data)
    assert fragment in str(error.value)


def test_model_of_another_algorithm_is_refused(tmp_path):
    a2c = train_tiny(TINY, tmp_path, "a2c", episodes=2)
    payload = torch.load(a2c.run_dir / "final_model.pt", weights_only=True)
    assert payload["format"] == A2C_MODEL_FORMAT
    with pytest.raises(ValueError, match="not an LSTM-A2C model"):
        load_a2c_payload({**payload, "format": "crowdplan-dsac-policy/1"}, tmp_path / "m.pt")
    future = tmp_path / "future.pt"
    torch.save({**payload, "format": "crowdplan-a2c-policy/9"}, future)
    with pytest.raises(ValueError, match=r"known formats: .*crowdplan-a2c-policy/1 \(a2c\)"):
        load_model_policy(str(future))
    wrong = tmp_path / "wrong.pt"
    torch.save({**payload, "a2c": {**payload["a2c"], "lstm_hidden": 20}}, wrong)
    with pytest.raises(ValueError, match="do not match its a2c settings"):
        load_model_policy(str(wrong))
    # an A2C run folder cannot be resumed as a DSAC run
    dsac = config_from_dict({**{k: v for k, v in TINY.items() if k != "a2c"}, "algo": "dsac"})
    with pytest.raises(ValueError, match="different config"):
        Trainer(dsac, a2c.run_dir, progress=False).restore(a2c.run_dir / "checkpoint.pt")
