"""ONNX export of the baselines: LSTM-A2C actors, DQN Q networks and the CADRL / LSTM-RL / SARL
value networks agree with torch; an exported value network chooses the torch lookahead's actions
through the runtime's numpy lookahead; bad value-network manifests and oracle models are refused."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

pytest.importorskip("onnxruntime", reason="the onnx extra is not installed")

from crowdplan import evaluation  # noqa: E402
from crowdplan.deploy.export import export_model, random_observations, verify_export  # noqa: E402
from crowdplan.deploy.manifest import MANIFEST_FILE, load_manifest  # noqa: E402
from crowdplan.deploy.onnx_policy import OnnxPolicy  # noqa: E402
from crowdplan.deploy.simulate import run_deployment  # noqa: E402
from crowdplan.features import robot_centric  # noqa: E402
from crowdplan.models import load_model_policy  # noqa: E402
from crowdplan.sim.actions import action_velocities  # noqa: E402
from crowdplan.sim.lookahead import action_values, one_step  # noqa: E402
from crowdplan.training import Trainer, config_from_dict  # noqa: E402

CROWDS = (0, 1, 5, 10, 20)
# name -> (training config changes, kind, outputs); world-frame and goal-frame actions both occur
MODELS = {
    "a2c": ({"algo": "a2c"}, "a2c-policy", ("logits",)),
    "dqn-rg": ({"algo": "dqn"}, "dqn-policy", ("q", "attention")),
    "dqn-lsa": ({"algo": "dqn", "encoder": {"name": "lsa"}}, "dqn-policy", ("q", "attention")),
    "cadrl": (
        {"algo": "value_rl", "value_rl": {"network": "cadrl"}, "world": {"action_frame": "world"}},
        "value-network",
        ("value",),
    ),
    "lstm_rl": (
        {"algo": "value_rl", "value_rl": {"network": "lstm_rl"}},
        "value-network",
        ("value",),
    ),
    "sarl": (
        {"algo": "value_rl", "value_rl": {"network": "sarl"}},
        "value-network",
        ("value", "attention"),
    ),
}
VALUE_NETWORKS = ("cadrl", "lstm_rl", "sarl")
# a few seconds of training, so that the networks are not at their initialisation
TRAINING = {
    "episodes": 2,
    "num_envs": 2,
    "val_interval": 1000,
    "val_episodes": 2,
    "checkpoint_interval": 1000,
    "log_interval": 1000,
    "test_episodes": 0,
    "a2c": {"n_steps": 5},
    "dqn": {"learning_starts": 16, "batch_size": 16},
    "value_rl": {"il_episodes": 2, "il_epochs": 1, "train_batches": 2, "batch_size": 16},
}


def _train(folder, name: str, **changes) -> str:
    """A model file of ``name`` trained for two tiny episodes."""
    options, _, _ = MODELS[name]
    algo = options["algo"]
    data = {
        "name": f"tiny-{name}",
        **{k: v for k, v in TRAINING.items() if not isinstance(v, dict)},
        **options,
        algo: {**TRAINING.get(algo, {}), **options.get(algo, {}), **changes},
        "world": {"humans": 3, "time_limit": 4.0, **options.get("world", {})},
    }
    trainer = Trainer(config_from_dict(data), folder / "run", progress=False)
    trainer.run()
    return str(folder / "run" / "final_model.pt")


@pytest.fixture(scope="module", params=sorted(MODELS))
def exported(request, tmp_path_factory):
    tmp = tmp_path_factory.mktemp(request.param)
    model = _train(tmp, request.param)
    export_model(model, tmp / "export", max_humans=max(CROWDS))
    policy, _ = load_model_policy(model)
    return request.param, model, policy, OnnxPolicy(tmp / "export"), tmp / "export"


def _torch_outputs(policy, robot, humans, mask) -> list[np.ndarray]:
    """The torch network's outputs (first: logits, Q values or values; then attention)."""
    feats = [
        torch.from_numpy(x)
        for x in robot_centric(robot, humans, mask, policy.kinematics == "unicycle")
    ]
    with torch.no_grad():
        if hasattr(policy, "q"):
            outputs = policy.q(*feats)
        elif hasattr(policy, "lookahead"):
            outputs = policy.net(*feats)
        else:
            outputs = (policy.net(*feats)[0],)
    return [x.numpy() for x in outputs if x is not None]


def _assert_agree(onnx_policy, policy, robot, humans, mask) -> np.ndarray:
    expected = _torch_outputs(policy, robot, humans, mask)
    got = onnx_policy.outputs(robot, humans, mask)
    assert len(got) == len(expected) == len(onnx_policy.manifest.outputs)
    scale = np.maximum(1.0, np.abs(expected[0]).max(axis=-1, keepdims=expected[0].ndim > 1))
    assert np.all(np.abs(got[0] - expected[0]) <= 1e-5 * scale)
    for g, e in zip(got[1:], expected[1:], strict=True):  # attention
        np.testing.assert_allclose(g, e, rtol=0, atol=1e-5)
    return got[0]


def test_manifest_records_algorithm_network_and_lookahead(exported):
    name, _, policy, _, folder = exported
    _, kind, outputs = MODELS[name]
    manifest, _ = load_manifest(folder)
    assert (manifest.kind, manifest.outputs) == (kind, outputs)
    assert manifest.algo == MODELS[name][0]["algo"]
    if kind == "value-network":
        assert manifest.network == name and manifest.lookahead == "constant_velocity"
        assert manifest.gamma_step == pytest.approx(policy.gamma_step)
        assert manifest.goal_heading is None  # the lookahead plans in the world frame
        if manifest.action_frame == "world":  # so its velocities are never turned
            robot, _, _ = random_observations(np.random.default_rng(0), 8, 0)
            actions = np.arange(8) * 10
            onnx_policy = OnnxPolicy(folder)
            vel, _ = onnx_policy.velocities(actions, robot, trip_heading=np.zeros(8))
            expected, _ = action_velocities(actions, robot, "holonomic", "world", "linear")
            np.testing.assert_allclose(vel, expected)
    else:
        assert manifest.lookahead is None and manifest.gamma_step is None
        assert manifest.network == ("q" if kind == "dqn-policy" else "actor")


@pytest.mark.parametrize("n", CROWDS)
def test_onnxruntime_agrees_with_torch(exported, n):
    _, _, policy, onnx_policy, _ = exported
    rng = np.random.default_rng(n)
    padding = min(3, onnx_policy.max_humans - n)
    robot, humans, mask = random_observations(rng, 16, n, padding)
    first = _assert_agree(onnx_policy, policy, robot, humans, mask)
    # padded slots change nothing, and permuted humans (padding in between) still agree
    unpadded = _assert_agree(onnx_policy, policy, robot, humans[:, :n], mask[:, :n])
    np.testing.assert_allclose(first, unpadded, rtol=0, atol=1e-4)
    perm = rng.permutation(humans.shape[1])
    _assert_agree(onnx_policy, policy, robot, humans[:, perm], mask[:, perm])


def test_verify_export_reports_every_crowd_size(exported):
    _, model, _, _, folder = exported
    differences = verify_export(model, folder, batch=8)
    assert sorted(differences) == list(CROWDS) and max(differences.values()) < 1e-4


@pytest.mark.parametrize("n", CROWDS)
def test_exported_policy_chooses_the_torch_policys_actions(exported, n):
    name, _, policy, onnx_policy, _ = exported
    padding = min(2, onnx_policy.max_humans - n)
    robot, humans, mask = random_observations(np.random.default_rng(100 + n), 64, n, padding)
    got = onnx_policy.act(robot, humans, mask)
    want = policy.act(robot, humans, mask)
    np.testing.assert_array_equal(got.actions, want.actions)
    if want.scores is None:
        assert got.scores is None
    else:
        np.testing.assert_allclose(got.scores, want.scores, rtol=0, atol=1e-5)
    if name in VALUE_NETWORKS:  # the lookahead's action values, not only their argmax
        expected = action_values(
            one_step(robot, humans, mask, policy.world), policy.net, policy.gamma_step
        ).numpy()
        np.testing.assert_allclose(
            onnx_policy.logits(robot, humans, mask), expected, rtol=0, atol=1e-5
        )


def test_deployed_value_network_reproduces_eval(tmp_path):
    """The runtime's closed loop (poses in, commands out) gives the torch policy's episodes."""
    model = _train(tmp_path, "sarl")
    export_model(model, tmp_path / "export", max_humans=5)
    policy, world = load_model_policy(model)
    cases = evaluation.test_seeds(3)
    expected = evaluation.run_episodes(policy, world, cases)
    records, stats = run_deployment(OnnxPolicy(tmp_path / "export"), world, cases)
    assert stats["safety_stop_share"] == 0.0
    for got, want in zip(records, expected, strict=True):
        assert (got.outcome, got.steps) == (want.outcome, want.steps)
        assert got.path_length == pytest.approx(want.path_length, abs=1e-9)


# ---------------------------------------------------------------------- bad input
def test_oracle_lookahead_model_is_refused(tmp_path):
    model = _train(tmp_path, "cadrl", lookahead="oracle")
    with pytest.raises(ValueError, match="no simulator"):
        export_model(model, tmp_path / "export")
    assert not (tmp_path / "export" / MANIFEST_FILE).exists()


@pytest.fixture(scope="module")
def value_export(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("value-export")
    export_model(_train(tmp, "lstm_rl"), tmp / "export", max_humans=5)
    return tmp / "export"


@pytest.mark.parametrize(
    "change, message",
    [
        ({"lookahead": None}, "needs lookahead"),
        ({"lookahead": None, "gamma_step": None}, "needs lookahead and gamma_step"),
        ({"gamma_step": 1.5}, "gamma_step must lie in"),
        ({"gamma_step": "0.9"}, "gamma_step must lie in"),
        ({"lookahead": "oracle"}, "no simulator"),
        ({"lookahead": "psychic"}, "unknown lookahead"),
        ({"goal_heading": 1.57}, "no goal_heading"),
        ({"outputs": ["logits"]}, "first output is 'value'"),
        ({"kind": "q-table"}, "unknown kind"),
    ],
)
def test_bad_value_network_manifest_is_refused(value_export, tmp_path, change, message):
    folder = tmp_path / "copy"
    folder.mkdir()
    (folder / "policy.onnx").write_bytes((value_export / "policy.onnx").read_bytes())
    manifest = json.loads((value_export / MANIFEST_FILE).read_text())
    for key in change:
        manifest.pop(key)
    manifest = {**manifest, **{k: v for k, v in change.items() if v is not None}}
    (folder / MANIFEST_FILE).write_text(json.dumps(manifest))
    with pytest.raises(ValueError, match=message):
        OnnxPolicy(folder)


def test_value_network_asked_for_attention_or_too_many_humans(value_export):
    policy = OnnxPolicy(value_export)
    robot, humans, mask = random_observations(np.random.default_rng(0), 2, 3)
    assert policy.act(robot, humans, mask).scores is None
    with pytest.raises(ValueError, match="no attention"):
        policy.attention(robot, humans, mask)
    with pytest.raises(ValueError, match="at most 5"):
        policy.act(*random_observations(np.random.default_rng(0), 2, 6))
