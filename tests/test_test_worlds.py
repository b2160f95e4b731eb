"""The generalisation test worlds: every world runs through `crowdplan eval`."""

import json

from crowdplan.analysis.test_worlds import TEST_WORLDS, main


def test_every_world_evaluates_a_planner(tmp_path):
    assert main(["orca", "--out", str(tmp_path), "--episodes", "2"]) == 0
    for world in TEST_WORLDS:
        summary = json.loads((tmp_path / world / "orca" / "summary.json").read_text())
        assert summary["episodes"]["value"] == 2
    empty = json.loads((tmp_path / "empty" / "orca" / "summary.json").read_text())
    assert empty["meta"]["world"]["humans"] == 0
    replay = json.loads((tmp_path / "replay-heldout" / "orca" / "summary.json").read_text())
    assert replay["meta"]["world"]["replay_scenes"] == ["zara1", "zara2", "univ"]


def test_transfer_block_of_a_markdown_page(tmp_path):
    from crowdplan.analysis.markdown_fill import fill_markdown

    out = tmp_path / "worlds"
    assert main(["orca", "straight", "--out", str(out), "--episodes", "2"]) == 0
    page = tmp_path / "page.md"
    page.write_text(f"# t\n<!-- crowdplan report --transfer {out} -->\nold\n<!-- end report -->\n")
    assert fill_markdown(page) == 1
    text = page.read_text()
    assert "old" not in text
    assert "| planner | circle | circle-10 | circle-20 | circle-rotated | empty |" in text
    assert "| straight |" in text and "| orca |" in text
    # the time-to-goal table has the summary's mean of each planner in each world
    times = text.split("### Time to goal (s)")[1].split("###")[0]
    empty = json.loads((out / "empty" / "orca" / "summary.json").read_text())
    orca_row = next(line for line in times.splitlines() if line.startswith("| orca |"))
    assert f"{empty['time_to_goal']['value']:.2f}" in orca_row.split("|")[6]


def test_default_world_drops_the_training_mixture_but_keeps_the_action_interface():
    import argparse

    from crowdplan.algos.orca_planner import OrcaPlanner
    from crowdplan.config import WorldConfig
    from crowdplan.world_args import world_from_args

    trained = WorldConfig(humans=10, humans_min=0, social_force_fraction=0.3, action_frame="world")
    args = argparse.Namespace(
        command="eval", option=["goal_rotation=90"], scenario=None, humans=None, default_world=True
    )
    world = world_from_args(args, OrcaPlanner(), trained)
    assert world == WorldConfig(action_frame="world", goal_rotation=90.0)


def test_default_world_warns_in_one_line(capsys):
    from crowdplan.cli import main as crowdplan

    assert (
        crowdplan(["eval", "--model", "lsa-dsac", "--default-world", "--episodes", "1", "-q"]) == 0
    )
    warnings = [line for line in capsys.readouterr().err.splitlines() if "warning" in line]
    assert len(warnings) == 1 and "--default-world evaluates it in the paper's world" in warnings[0]


def test_model_files_are_named_after_their_folder_and_clashes_are_refused(tmp_path, capsys):
    import pytest

    from crowdplan.analysis.test_worlds import planner_label

    assert planner_label("results/train/run-s1/best_model.pt@shield=2.5") == "run-s1@shield=2.5"
    assert planner_label("models/sarl/model.pt") == "sarl"
    assert planner_label("results/train/run-s1") == "run-s1"
    assert planner_label("exported/other.pt") == "other.pt"
    assert planner_label("orca") == "orca"
    with pytest.raises(SystemExit):
        main(["a/best_model.pt", "a/final_model.pt", "--out", str(tmp_path), "--episodes", "1"])
    assert "would all write to <world>/a" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())
