"""Simulated deployment: with no noise it reproduces ``crowdplan eval``; noise options work."""

from __future__ import annotations

import json

import pytest

pytest.importorskip("onnxruntime", reason="the onnx extra is not installed")

from crowdplan import evaluation  # noqa: E402
from crowdplan.cli import main  # noqa: E402
from crowdplan.deploy.export import export_model  # noqa: E402
from crowdplan.deploy.manifest import MANIFEST_FILE  # noqa: E402
from crowdplan.deploy.onnx_policy import OnnxPolicy  # noqa: E402
from crowdplan.deploy.simulate import SensorModel, run_deployment  # noqa: E402
from crowdplan.models import load_model_policy  # noqa: E402

CASES = evaluation.test_seeds(8)


@pytest.fixture(scope="module")
def exported_lsa(tmp_path_factory):
    """The shipped model exported once per test session (shared by the deploy test files)."""
    folder = tmp_path_factory.getbasetemp() / "export-lsa-dsac-paper"
    if not (folder / MANIFEST_FILE).is_file():
        export_model("lsa-dsac-paper", folder)
    return folder


def test_noise_free_deployment_reproduces_eval(exported_lsa):
    assert_deployment_reproduces_eval("lsa-dsac-paper", exported_lsa)


def test_noise_free_deployment_of_the_unicycle_model_reproduces_eval(tmp_path):
    export_model("lsa-dsac-unicycle", tmp_path / "export")
    assert_deployment_reproduces_eval("lsa-dsac-unicycle", tmp_path / "export")


def assert_deployment_reproduces_eval(model, export_folder):
    policy, world = load_model_policy(model)
    expected = evaluation.run_episodes(policy, world, CASES)
    records, stats = run_deployment(OnnxPolicy(export_folder), world, CASES)
    assert stats["safety_stop_share"] == 0.0
    for got, want in zip(records, expected, strict=True):
        assert (got.outcome, got.steps) == (want.outcome, want.steps)
        assert got.discounted_return == pytest.approx(want.discounted_return, abs=1e-9)
        assert got.path_length == pytest.approx(want.path_length, abs=1e-9)


def test_noise_is_seeded_and_latency_causes_initial_stops(exported_lsa):
    policy = OnnxPolicy(exported_lsa)
    world = load_model_policy("lsa-dsac-paper")[1]
    sensor = SensorModel(position_noise=0.05, drift=0.01, drop_rate=0.1, seed=3)
    first, _ = run_deployment(policy, world, CASES[:3], sensor)
    again, _ = run_deployment(policy, world, CASES[:3], sensor)
    assert [r.to_json() for r in first] == [r.to_json() for r in again]
    _, stats = run_deployment(policy, world, CASES[:3], SensorModel(latency=0.25))
    assert stats["safety_stop_share"] > 0  # no pose has arrived during the first period


def test_deploy_command_writes_eval_summary(exported_lsa, tmp_path, capsys):
    out = tmp_path / "dep"
    code = main(
        ["deploy", "--sim", "--model", str(exported_lsa), "--episodes", "3"]
        + ["--position-noise", "0.02", "--out", str(out)]
    )
    assert code == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["episodes"]["value"] == 3 and "success_rate" in summary
    assert summary["meta"]["deploy"]["sensor"]["position_noise"] == 0.02
    assert "safety stops" in capsys.readouterr().out
    assert main(["deploy", "--model", str(exported_lsa)]) == 2  # --sim is required
