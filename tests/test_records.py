"""Trajectory records (crowdplan eval --record): round trip; bad input named by file and line."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from crowdplan.algos.orca_planner import OrcaPlanner
from crowdplan.cli import main
from crowdplan.config import WorldConfig
from crowdplan.evaluation import run_episodes
from crowdplan.evaluation_records import (
    RecordError,
    load_recorded,
    read_records,
    write_records,
)

WORLD = WorldConfig(humans=2, time_limit=6.0)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """A result folder written by the CLI: 4 test cases of ORCA with --record."""
    out = tmp_path_factory.mktemp("rec") / "orca"
    argv = ["eval", "--policy", "orca", "--humans", "2", "--episodes", "4", "-q", "--record"]
    assert main([*argv, "--out", str(out)]) == 0
    return out


def _copy(recorded, tmp_path):
    folder = tmp_path / "copy"
    shutil.copytree(recorded, folder)
    return folder


def test_records_round_trip_the_run(tmp_path):
    runs = run_episodes(OrcaPlanner(), WORLD, [1000, 1001, 1002], record_traces=True)
    records = read_records(write_records(tmp_path / "r.npz", runs))
    assert len(records) == 3 and list(records.seeds) == [1000, 1001, 1002]
    for k, run in enumerate(runs):
        trace = records.trace(k)
        assert len(trace.robot_vel) == run.steps and records.outcomes[k] == run.outcome
        np.testing.assert_allclose(trace.robot_pos, run.trace.robot_pos, atol=1e-5)
        np.testing.assert_allclose(trace.human_pos, run.trace.human_pos, atol=1e-5)
        np.testing.assert_allclose(trace.human_vel, run.trace.human_vel, atol=2e-3)
        np.testing.assert_allclose(trace.d_min, run.trace.d_min, atol=1e-5)
        np.testing.assert_allclose(trace.actions, run.trace.actions, atol=1e-5)
    assert not records.has_scores  # ORCA has no attention


def test_cli_folder_loads_and_scores_of_a_model_are_kept(recorded, tmp_path):
    run = load_recorded(recorded)
    assert len(run.episodes) == len(run.records) == 4 and run.name == "orca"
    out = tmp_path / "lsa"
    argv = ["eval", "--model", "lsa-dsac", "--default-world", "--episodes", "2", "-q", "--record"]
    assert main([*argv, "--out", str(out)]) == 0
    model = load_recorded(out)
    scores = model.records.trace(0).scores
    assert model.records.has_scores and scores.shape == (model.episodes[0].steps, 5)
    np.testing.assert_allclose(scores.sum(axis=1), 1.0, atol=1e-2)  # attention is a softmax


def test_record_needs_out(capsys):
    assert main(["eval", "--policy", "orca", "--episodes", "1", "--record", "-q"]) == 2
    assert "--record needs --out" in capsys.readouterr().err


def test_folder_without_records_is_named(recorded, tmp_path):
    folder = _copy(recorded, tmp_path)
    (folder / "records.npz").unlink()
    with pytest.raises(RecordError, match=r"copy: no records.npz .*--record --out"):
        load_recorded(folder)


def test_record_file_of_another_version(recorded, tmp_path):
    folder = _copy(recorded, tmp_path)
    with np.load(folder / "records.npz") as data:
        arrays = {k: data[k] for k in data.files}
    arrays["format"] = np.array("crowdplan-records/0")
    np.savez_compressed(folder / "records.npz", **arrays)
    with pytest.raises(RecordError, match=r"records.npz: record format 'crowdplan-records/0'"):
        load_recorded(folder)


def test_cut_short_and_broken_record_files(recorded, tmp_path):
    folder = _copy(recorded, tmp_path)
    with np.load(folder / "records.npz") as data:
        arrays = {k: data[k] for k in data.files}
    arrays["d_min"] = arrays["d_min"][:-3]
    np.savez_compressed(folder / "records.npz", **arrays)
    with pytest.raises(RecordError, match=r"records.npz: array d_min has \d+ rows"):
        read_records(folder / "records.npz")
    (folder / "records.npz").write_bytes(b"not a zip")
    with pytest.raises(RecordError, match=r"records.npz: not a record file"):
        read_records(folder / "records.npz")


def test_missing_episode_is_named(recorded, tmp_path):
    folder = _copy(recorded, tmp_path)
    lines = (folder / "episodes.jsonl").read_text().splitlines(keepends=True)
    (folder / "episodes.jsonl").write_text("".join(lines[:-1]))
    summary = json.loads((folder / "summary.json").read_text())
    for key in list(summary):
        if key != "meta":
            summary.pop(key)  # a summary with no metrics to disagree
    (folder / "summary.json").write_text(json.dumps(summary))
    with pytest.raises(RecordError, match=r"episodes.jsonl has 3 episodes, records.npz has 4"):
        load_recorded(folder)


def test_bad_episode_line_and_disagreeing_episode(recorded, tmp_path):
    folder = _copy(recorded, tmp_path)
    lines = (folder / "episodes.jsonl").read_text().splitlines(keepends=True)
    row = json.loads(lines[2])
    row.pop("steps")
    (folder / "episodes.jsonl").write_text("".join([*lines[:2], json.dumps(row) + "\n"]))
    with pytest.raises(RecordError, match=r"episodes.jsonl, line 3: field 'steps' is missing"):
        load_recorded(folder)
    rows = [json.loads(line) for line in lines]
    rows[0], rows[1] = rows[1], rows[0]  # same episodes and summary, another order
    (folder / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    with pytest.raises(RecordError, match=r"episode 1 \(seed 1001\).*records.npz has seed 1000"):
        load_recorded(folder)


def test_summary_that_disagrees_with_its_episodes(recorded, tmp_path):
    folder = _copy(recorded, tmp_path)
    summary = json.loads((folder / "summary.json").read_text())
    summary["success_rate"]["value"] = 0.123
    (folder / "summary.json").write_text(json.dumps(summary))
    with pytest.raises(RecordError, match=r"summary.json: success_rate is 0.123, its episodes"):
        load_recorded(folder)


def test_failed_write_leaves_nothing(tmp_path):
    runs = run_episodes(OrcaPlanner(), WORLD, [1000])
    with pytest.raises(ValueError, match="needs its trace"):
        write_records(tmp_path / "r.npz", runs)
    assert list(tmp_path.iterdir()) == []
