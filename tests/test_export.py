"""ONNX export: onnxruntime agrees with torch for every encoder and crowd size, and bad files or
mismatched manifests give clear errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

pytest.importorskip("onnxruntime", reason="the onnx extra is not installed")

from crowdplan.algos.dsac import DSAC, DSACConfig  # noqa: E402
from crowdplan.config import WorldConfig  # noqa: E402
from crowdplan.deploy.export import export_model, random_observations  # noqa: E402
from crowdplan.deploy.manifest import MANIFEST_FILE, load_manifest  # noqa: E402
from crowdplan.deploy.onnx_policy import OnnxPolicy  # noqa: E402
from crowdplan.features import robot_centric  # noqa: E402
from crowdplan.models import load_model_policy, model_payload  # noqa: E402
from crowdplan.nets.encoders import EncoderConfig  # noqa: E402

CROWDS = (0, 1, 5, 10, 20)
ENCODERS = {
    "raw": EncoderConfig(name="raw", max_humans=5),
    "rg": EncoderConfig(name="rg"),
    "rg-lstm-rob-obs": EncoderConfig(name="rg", rg_pooling="lstm(rob+obs)"),
    "aw": EncoderConfig(name="aw"),
    "sa": EncoderConfig(name="sa"),
    "lsa": EncoderConfig(name="lsa"),
}


def _model_file(tmp_path, encoder: EncoderConfig, world: WorldConfig | None = None):
    agent = DSAC(DSACConfig(), encoder, seed=1)
    path = tmp_path / "model.pt"
    torch.save(model_payload(agent.actor, encoder, DSACConfig(), world or WorldConfig(), {}), path)
    return path


@pytest.fixture(scope="module", params=sorted(ENCODERS))
def exported(request, tmp_path_factory):
    tmp = tmp_path_factory.mktemp(request.param)
    model = _model_file(tmp, ENCODERS[request.param])
    export_model(str(model), tmp / "export", max_humans=max(CROWDS))
    policy, _ = load_model_policy(str(model))
    return policy, OnnxPolicy(tmp / "export")


def _torch_outputs(policy, robot, humans, mask):
    feats = robot_centric(robot, humans, mask, policy.unicycle)
    with torch.no_grad():
        logits, attention = policy.actor(*(torch.from_numpy(x) for x in feats))
    return logits.numpy(), None if attention is None else attention.numpy()


def _assert_agree(onnx_policy, policy, robot, humans, mask):
    logits, attention = _torch_outputs(policy, robot, humans, mask)
    onnx_logits = onnx_policy.logits(robot, humans, mask)
    scale = np.maximum(1.0, np.abs(logits).max(axis=1, keepdims=True))
    assert np.abs(onnx_logits - logits).max(initial=0) <= 1e-5 * scale.max()
    assert np.all(np.abs(onnx_logits - logits) <= 1e-5 * scale)
    if attention is not None:
        np.testing.assert_allclose(
            onnx_policy.attention(robot, humans, mask), attention, rtol=0, atol=1e-5
        )
    return onnx_logits


@pytest.mark.parametrize("n", CROWDS)
def test_onnxruntime_agrees_with_torch(exported, n):
    policy, onnx_policy = exported
    rng = np.random.default_rng(n)
    padding = min(3, onnx_policy.max_humans - n)
    robot, humans, mask = random_observations(rng, 16, n, padding)
    logits = _assert_agree(onnx_policy, policy, robot, humans, mask)
    # the padded slots change nothing: the same crowd without them gives the same logits
    unpadded = _assert_agree(onnx_policy, policy, robot, humans[:, :n], mask[:, :n])
    np.testing.assert_allclose(logits, unpadded, rtol=0, atol=1e-4)
    # permuted humans (padding moved in between) still agree with torch
    perm = rng.permutation(humans.shape[1])
    _assert_agree(onnx_policy, policy, robot, humans[:, perm], mask[:, perm])


def test_shipped_model_export_has_attention_and_world_frame(exported_lsa):
    manifest, _ = load_manifest(exported_lsa)
    assert manifest.outputs == ("logits", "attention")
    assert manifest.action_frame == "world" and manifest.goal_heading == pytest.approx(np.pi / 2)
    assert len(manifest.action_table) == 81 and manifest.encoder == "lsa"
    assert manifest.feature_layout["human"][0] == "px_rel"


@pytest.fixture(scope="module")
def exported_lsa(tmp_path_factory):
    """The shipped model exported once per test session (shared by the deploy test files)."""
    folder = tmp_path_factory.getbasetemp() / "export-lsa-dsac-paper"
    if not (folder / MANIFEST_FILE).is_file():
        export_model("lsa-dsac-paper", folder)
    return folder


# ---------------------------------------------------------------------- bad input
def test_raw_encoder_has_no_attention(tmp_path):
    export_model(str(_model_file(tmp_path, ENCODERS["raw"])), tmp_path / "e", max_humans=5)
    policy = OnnxPolicy(tmp_path / "e")
    robot, humans, mask = random_observations(np.random.default_rng(0), 2, 3)
    assert policy.act(robot, humans, mask).scores is None
    with pytest.raises(ValueError, match="no attention"):
        policy.attention(robot, humans, mask)
    with pytest.raises(ValueError, match="at most 5"):
        policy.act(*random_observations(np.random.default_rng(0), 2, 6))


def test_foreign_or_tampered_files_are_refused(tmp_path, exported_lsa):
    with pytest.raises(FileNotFoundError, match="not a crowdplan export"):
        OnnxPolicy(tmp_path)
    (tmp_path / "other.onnx").write_bytes(b"\x08\x01")
    with pytest.raises(ValueError, match="not a crowdplan export"):
        OnnxPolicy(tmp_path / "other.onnx")
    copy = tmp_path / "copy"
    copy.mkdir()
    (copy / "policy.onnx").write_bytes((exported_lsa / "policy.onnx").read_bytes() + b"x")
    manifest = json.loads((exported_lsa / MANIFEST_FILE).read_text())
    (copy / MANIFEST_FILE).write_text(json.dumps(manifest))
    with pytest.raises(ValueError, match="SHA-256"):
        OnnxPolicy(copy)
    (copy / "policy.onnx").write_bytes((exported_lsa / "policy.onnx").read_bytes())
    manifest["action_table"][1][0] = 0.3
    (copy / MANIFEST_FILE).write_text(json.dumps(manifest))
    with pytest.raises(ValueError, match="action table"):
        OnnxPolicy(copy)
    (copy / MANIFEST_FILE).write_text(json.dumps({**manifest, "format": "other"}))
    with pytest.raises(ValueError, match="not a crowdplan ONNX manifest"):
        OnnxPolicy(copy)


def test_manifest_must_match_the_world(exported_lsa):
    manifest, _ = load_manifest(exported_lsa)
    manifest.check_world(WorldConfig(action_frame="world"))
    with pytest.raises(ValueError, match="kinematics"):
        manifest.check_world(WorldConfig(kinematics="unicycle"))
    with pytest.raises(ValueError, match="speed_sampling"):
        manifest.check_world(WorldConfig(speed_sampling="exponential"))


def test_manifest_from_before_other_algorithms_loads_as_dsac(tmp_path, exported_lsa):
    copy = tmp_path / "old"
    copy.mkdir()
    (copy / "policy.onnx").write_bytes((exported_lsa / "policy.onnx").read_bytes())
    manifest = json.loads((exported_lsa / MANIFEST_FILE).read_text())
    for key in ("algo", "network", "lookahead", "gamma_step"):
        manifest.pop(key)
    (copy / MANIFEST_FILE).write_text(json.dumps(manifest))
    policy = OnnxPolicy(copy)
    assert (policy.manifest.algo, policy.manifest.network) == ("dsac", "actor")
    assert policy.lookahead is None and policy.name == "lsa-dsac (onnx)"
