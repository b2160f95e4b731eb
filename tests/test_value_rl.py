"""Value-network baselines (CADRL, LSTM-RL, SARL): networks, value targets, determinism, resume,
the CLI, and bad input."""

import dataclasses
import json
import pickle
import re

import numpy as np
import pytest
import torch
import yaml
from tiny_runs import flat_parameters, restored, train_tiny, without_clock

from crowdplan import evaluation
from crowdplan.algos.value_rl import load_value_rl_payload
from crowdplan.cli import main
from crowdplan.config import WorldConfig
from crowdplan.models import load_model_policy, load_payload, resolve_model_path
from crowdplan.nets.encoders import masked_softmax
from crowdplan.nets.value import VALUE_NETWORKS, make_value_network
from crowdplan.sim.world import World
from crowdplan.training import Trainer, config_from_dict, load_config

TINY = {
    "name": "tiny_sarl",
    "algo": "value_rl",
    "episodes": 6,
    "num_envs": 2,
    "val_interval": 1000,
    "checkpoint_interval": 1000,
    "log_interval": 1000,
    "test_episodes": 0,
    "world": {"humans": 3, "time_limit": 4.0},
    "value_rl": {"il_episodes": 4, "il_epochs": 2, "train_batches": 4, "batch_size": 16},
}


def _states(batch=4, humans=3, seed=0):
    g = torch.Generator().manual_seed(seed)
    robot = torch.randn(batch, 6, generator=g)
    people = torch.randn(batch, humans, 7, generator=g)
    mask = torch.ones(batch, humans, dtype=torch.bool)
    return robot, people, mask


# ---------------------------------------------------------------------- networks
@pytest.mark.parametrize("name", VALUE_NETWORKS)
def test_networks_handle_no_humans_and_ignore_padding(name):
    torch.manual_seed(0)
    net = make_value_network(name)
    robot, humans, mask = _states()
    value, _ = net(robot, humans, mask)
    assert value.shape == (4,)
    padded = torch.cat([humans, torch.full((4, 2, 7), 1e6)], dim=1)
    padded_mask = torch.cat([mask, torch.zeros(4, 2, dtype=torch.bool)], dim=1)
    assert torch.allclose(net(robot, padded, padded_mask)[0], value, atol=1e-6)
    empty, _ = net(robot, humans[:, :0], mask[:, :0])
    assert empty.shape == (4,) and torch.isfinite(empty).all()
    all_padding, _ = net(robot, humans, torch.zeros_like(mask))
    assert torch.allclose(all_padding, empty, atol=1e-6)


def test_cadrl_takes_the_minimum_over_pairs():
    torch.manual_seed(0)
    net = make_value_network("cadrl")
    robot, humans, mask = _states(humans=4)
    value, _ = net(robot, humans, mask)
    pairs = torch.stack([net(robot, humans[:, i : i + 1], mask[:, i : i + 1])[0] for i in range(4)])
    assert torch.allclose(value, pairs.min(dim=0).values)


def test_sarl_is_the_formula_of_the_paper():
    """The regrouped forward pass equals SARL written out layer by layer."""
    torch.manual_seed(0)
    net = make_value_network("sarl")
    robot, humans, mask = _states(humans=5)
    mask[0, 3:] = False
    humans = humans.masked_fill(~mask.unsqueeze(-1), 0.0)
    pair = torch.cat([robot.unsqueeze(1).expand(-1, 5, -1), humans], dim=-1)
    e = net.f_e(pair)
    weights = mask.unsqueeze(-1).float()
    mean = (e * weights).sum(1, keepdim=True) / weights.sum(1, keepdim=True)
    scores = net.f_a(torch.cat([e, mean.expand_as(e)], dim=-1)).squeeze(-1)
    attention = masked_softmax(scores, mask)
    crowd = (attention.unsqueeze(-1) * net.f_h(e)).sum(dim=1)
    expected = net.value(torch.cat([robot, crowd], dim=1)).squeeze(-1)
    value, got_attention = net(robot, humans, mask)
    assert torch.allclose(value, expected, atol=1e-6)
    assert torch.allclose(got_attention, attention, atol=1e-6)
    assert torch.allclose(got_attention.sum(dim=1), torch.ones(4))


def test_unknown_network_is_refused():
    with pytest.raises(ValueError, match="unknown value network 'dqn'"):
        make_value_network("dqn")
    with pytest.raises(ValueError, match=r"value_rl.network must be one of \['cadrl'"):
        config_from_dict({**TINY, "value_rl": {"network": "dqn"}})


# ---------------------------------------------------------------------- value targets
def test_value_target_on_a_hand_made_chain(tmp_path):
    """s0 -(r=0)-> s1 -(r=1, goal)-> end, and s2 -(r=0.5, timeout)-> s1: with the discount
    g = 0.9^(dt v_pref) the values are V(s1) = 1, V(s0) = g and V(s2) = 0.5 + g (a truncation
    bootstraps)."""
    config = config_from_dict(
        {**TINY, "world": {"humans": 1}, "value_rl": {"network": "cadrl", "lr": 0.02}}
    )
    trainer = Trainer(config, tmp_path, progress=False)
    agent = trainer.agent
    robot = np.zeros((3, 6), dtype=np.float32)
    robot[:, 0] = [2.0, 1.0, 3.0]  # distance to goal tells the three states apart
    humans = np.zeros((3, 1, 7), dtype=np.float32)
    humans[:, 0, [0, 5]] = 5.0
    mask = np.ones((3, 1), dtype=bool)
    s1 = [1, 1, 1]
    agent.buffer.add_batch(
        robot,
        humans,
        mask,
        np.zeros(3, dtype=np.int64),
        np.array([0.0, 1.0, 0.5], dtype=np.float32),
        robot[s1],
        humans[s1],
        mask[s1],
        np.array([0.0, 1.0, 0.0], dtype=np.float32),
    )
    for episode in range(1, 61):
        agent.batch_credit = 50
        agent.update()
        agent.episodes_done(episode * config.algo_config.target_update_episodes)
    with torch.no_grad():
        values, _ = agent.net(*(torch.from_numpy(x) for x in (robot, humans, mask)))
    g = 0.9**0.25
    np.testing.assert_allclose(values.numpy(), [g, 1.0, 0.5 + g], atol=0.02)


def _cache_matches_the_target_network(agent) -> None:
    slots = np.arange(len(agent.buffer))
    after = agent.buffer.gather(slots, ("next_robot", "next_humans", "next_mask"))
    with torch.no_grad():
        values, _ = agent.target(after["next_robot"], after["next_humans"], after["next_mask"])
    np.testing.assert_allclose(agent.next_values[slots], values.numpy(), rtol=0, atol=1e-6)


def test_cached_target_values_follow_new_transitions_and_target_copies(tmp_path):
    agent = train_tiny(TINY, tmp_path, "run", episodes=4).agent
    agent.batch_credit = 1
    agent.update()
    _cache_matches_the_target_network(agent)
    # five new transitions (copies of stored ones with other rewards), then a target copy
    full = agent.buffer.gather(np.arange(len(agent.buffer)), tuple(agent.buffer.data))
    batch = [full[k][:5].numpy() for k in agent.buffer.data]
    batch[4] = batch[4] + 1.0
    agent.buffer.add_batch(*batch)
    agent.batch_credit = 1
    agent.update()
    _cache_matches_the_target_network(agent)
    agent.episodes_done(agent.episodes + agent.params.target_update_episodes)
    assert agent.values_stale
    agent.batch_credit = 1
    agent.update()
    _cache_matches_the_target_network(agent)


# ---------------------------------------------------------------------- runs


def _weights(trainer):
    return flat_parameters(trainer.agent.net)


def test_same_seed_twice_is_identical_and_another_seed_differs(tmp_path):
    a, b = train_tiny(TINY, tmp_path, "a"), train_tiny(TINY, tmp_path, "b")
    assert torch.equal(_weights(a), _weights(b))
    assert without_clock(a.episodes) == without_clock(b.episodes)
    assert a.agent.n_updates > 0
    c = train_tiny(TINY, tmp_path, "c", seed=1)
    assert not torch.equal(_weights(a), _weights(c))


def test_two_torch_threads_give_the_same_run_twice(tmp_path):
    # the SARL preset trains on two threads: batches large enough that kernels split their work
    config = {
        **TINY,
        "torch_threads": 2,
        "world": {"humans": 5, "time_limit": 4.0},
        "value_rl": {**TINY["value_rl"], "batch_size": 100},
    }
    try:
        a, b = train_tiny(config, tmp_path, "a"), train_tiny(config, tmp_path, "b")
    finally:
        torch.set_num_threads(1)
    assert json.loads((a.run_dir / "meta.json").read_text())["torch_threads"] == 2
    assert torch.equal(_weights(a), _weights(b))
    assert without_clock(a.episodes) == without_clock(b.episodes)


def test_resume_after_stop_continues_exactly(tmp_path):
    straight = train_tiny(TINY, tmp_path, "straight", episodes=6)
    # a run of 3 episodes ends with a checkpoint, as a kill would
    first = train_tiny(TINY, tmp_path, "resumed", episodes=3)
    resumed = restored(dataclasses.replace(first.config, episodes=6), tmp_path / "resumed")
    resumed.run()
    assert torch.equal(_weights(straight), _weights(resumed))
    assert torch.equal(
        torch.cat([p.flatten() for p in straight.agent.target.parameters()]),
        torch.cat([p.flatten() for p in resumed.agent.target.parameters()]),
    )
    assert without_clock(straight.episodes) == without_clock(resumed.episodes)


def test_no_demonstrations_starts_rl_from_scratch(tmp_path):
    config = config_from_dict({**TINY, "value_rl": {**TINY["value_rl"], "il_episodes": 0}})
    lines = []
    trainer = Trainer(config, tmp_path / "zero", progress=False)
    assert trainer.agent.pretrain(lines.append) is None
    assert "il_episodes is 0" in lines[0] and len(trainer.agent.buffer) == 0


# ---------------------------------------------------------------------- policies and files
def test_init_model_starts_rl_from_a_trained_network_and_refuses_what_does_not_fit(tmp_path):
    world = {**TINY["world"], "action_frame": "world", "humans": 6}
    warm = {
        **TINY,
        "world": world,
        "validate_at_start": True,
        "val_episodes": 2,
        "value_rl": {**TINY["value_rl"], "il_episodes": 0, "init_model": "sarl"},
    }
    trainer = Trainer(config_from_dict(warm), tmp_path / "warm", progress=False)
    shipped = load_payload(resolve_model_path("sarl"))["network"]
    for key, value in trainer.agent.net.state_dict().items():
        assert torch.equal(value, shipped[key]), key
    trainer.run()
    assert trainer.validations[0]["episode"] == 0 and trainer.agent.n_updates > 0
    refused = [
        ({"il_episodes": 4}, "set il_episodes: 0 to start from the model"),
        ({"network": "lstm_rl"}, "holds a 'sarl' value network, the run trains 'lstm_rl'"),
        ({"init_model": "lstm-a2c"}, "model file, not a value_rl model"),
    ]
    for change, fragment in refused:
        params = {**warm["value_rl"], **change}
        with pytest.raises(ValueError, match=re.escape(fragment)):
            Trainer(config_from_dict({**warm, "value_rl": params}), tmp_path / "no", progress=False)
    with pytest.raises(ValueError, match="acts in the world frame, the run in the goal frame"):
        goal_frame = {**warm, "world": TINY["world"]}
        Trainer(config_from_dict(goal_frame), tmp_path / "no", progress=False)
    assert not (tmp_path / "no").exists()


def test_cadrl_trained_with_one_human_evaluates_with_five(tmp_path):
    data = {**TINY, "world": {"humans": 1, "time_limit": 4.0}}
    data["value_rl"] = {**TINY["value_rl"], "network": "cadrl"}
    trainer = Trainer(config_from_dict(data), tmp_path / "cadrl", progress=False)
    trainer.save_model(tmp_path / "cadrl.pt", {})
    policy, trained = load_model_policy(str(tmp_path / "cadrl.pt"))
    assert trained.humans == 1 and policy.metadata["lookahead"] == "constant_velocity"
    records = evaluation.run_episodes(policy, trained.replace(humans=5), [1000, 1001])
    assert len(records) == 2


def test_oracle_policy_queries_the_evaluation_world(tmp_path):
    data = {**TINY, "value_rl": {**TINY["value_rl"], "lookahead": "oracle"}}
    trainer = Trainer(config_from_dict(data), tmp_path / "oracle", progress=False)
    policy = trainer.agent.policy("oracle")
    world = WorldConfig(humans=3, time_limit=2.0)
    with pytest.raises(ValueError, match="needs the world being played"):
        robot = np.array([[0.0, -4.0, 0.0, 0.0, 0.3, 0.0, 4.0, 1.0, 0.0]])
        policy.act(robot, np.zeros((1, 3, 5)), np.ones((1, 3), dtype=bool))
    records = evaluation.run_episodes(policy, world, [1000, 1001], record_traces=True)
    assert records[0].trace.scores.shape[1] == 3  # SARL's attention on every step


def test_a_model_of_another_algorithm_is_refused(tmp_path):
    dsac = {k: v for k, v in TINY.items() if k not in ("algo", "value_rl")}
    dsac_trainer = Trainer(
        config_from_dict({**dsac, "dsac": {"batch_size": 16}}), tmp_path / "d", progress=False
    )
    dsac_trainer.save_model(tmp_path / "dsac.pt", {})
    payload = load_payload(tmp_path / "dsac.pt")
    with pytest.raises(ValueError, match="not a value_rl model"):
        load_value_rl_payload(payload, tmp_path / "dsac.pt")


def test_a_dsac_section_in_a_value_rl_config_is_refused():
    with pytest.raises(ValueError, match=r"section\(s\) \['dsac'\] belong to another algorithm"):
        config_from_dict({**TINY, "dsac": {"batch_size": 16}})


def test_cli_train_eval_render(tmp_path, capsys):
    config = tmp_path / "tiny.yaml"
    data = {**TINY, "episodes": 2, "val_interval": 2, "val_episodes": 2, "test_episodes": 2}
    data["value_rl"] = {**TINY["value_rl"], "network": "lstm_rl"}
    config.write_text(yaml.safe_dump(data))
    run = tmp_path / "run"
    assert main(["train", "--config", str(config), "--out", str(run), "--no-progress"]) == 0
    summary = json.loads((run / "test" / "summary.json").read_text())
    assert summary["meta"]["lookahead"] == "constant_velocity"
    assert summary["meta"]["network"] == "lstm_rl"
    out = tmp_path / "eval"
    assert main(["eval", "--model", str(run), "--episodes", "2", "--out", str(out)]) == 0
    assert json.loads((out / "summary.json").read_text())["meta"]["algo"] == "value_rl"
    # a constant-velocity model evaluated with CrowdNav's oracle lookahead: the result says so
    argv = ["eval", "--model", str(run), "--episodes", "2", "--lookahead", "oracle"]
    assert main([*argv, "--out", str(tmp_path / "oracle")]) == 0
    oracle = json.loads((tmp_path / "oracle" / "summary.json").read_text())
    assert oracle["meta"]["lookahead"] == "oracle"
    assert "lookahead_precision" not in oracle["meta"]
    argv = ["eval", "--model", str(run), "--episodes", "2", "--lookahead-precision", "bfloat16"]
    assert main([*argv, "--out", str(tmp_path / "bf16")]) == 0
    bf16 = json.loads((tmp_path / "bf16" / "summary.json").read_text())
    assert bf16["meta"]["lookahead_precision"] == "bfloat16"
    assert "lookahead_compiled" not in bf16["meta"]
    argv = ["eval", "--model", str(run), "--episodes", "2", "--lookahead-compile"]
    assert main([*argv, "--out", str(tmp_path / "compiled")]) == 0
    compiled = json.loads((tmp_path / "compiled" / "summary.json").read_text())
    assert compiled["meta"]["lookahead_compiled"] is True
    eager = json.loads((out / "summary.json").read_text())
    assert compiled["success_rate"] == eager["success_rate"]
    png = tmp_path / "m.png"
    assert main(["render", "--model", str(run), "--case", "0", "--out", str(png)]) == 0
    assert png.stat().st_size > 0


@pytest.mark.parametrize(
    ("preset", "network", "humans"),
    [
        ("cadrl", "cadrl", 1),
        ("lstm_rl", "lstm_rl", 5),
        ("sarl", "sarl", 5),
        ("lstm_rl_h10", "lstm_rl", 10),
        ("sarl_h10", "sarl", 10),
    ],
)
def test_presets_load(preset, network, humans):
    config = load_config(f"configs/{preset}.yaml")
    assert config.algo == "value_rl" and config.algo_config.network == network
    assert config.world.humans == humans and config.algo_config.il_episodes == 3000


def test_a_compiled_value_policy_pickles_and_compiles_again():
    """Sharded evaluation sends the policy to worker processes: a compiled policy arrives
    compiled, and chooses the same actions."""
    policy, config = load_model_policy("cadrl")
    world = World(config, 3)
    world.reset(np.arange(3) + 1000)
    robot, humans, mask = world.observe()
    eager = policy.greedy(robot, humans, mask.astype(bool), world)
    policy.set_compiled(True)
    received = pickle.loads(pickle.dumps(policy))
    assert received.compiled and received.metadata["lookahead_compiled"] is True
    np.testing.assert_array_equal(received.greedy(robot, humans, mask.astype(bool), world), eager)
