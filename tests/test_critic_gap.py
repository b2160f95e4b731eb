"""crowdplan.analysis.critic_gap: the critic-to-target distance read from a run's checkpoint."""

from __future__ import annotations

import pytest

from crowdplan.analysis import critic_gap
from crowdplan.training import Trainer
from crowdplan.training.config import config_from_dict
from tests.test_training import TINY


def _run(tmp_path, name, tau):
    config = config_from_dict({**TINY, "episodes": 3, "dsac": {"batch_size": 16, "tau": tau}})
    trainer = Trainer(config, tmp_path / name, progress=False)
    trainer.run()
    return tmp_path / name, len(trainer.episodes)


def test_gap_is_zero_when_the_target_copies_the_critic_and_positive_when_it_lags(tmp_path):
    run, episodes = _run(tmp_path, "copy", tau=1.0)
    copied = critic_gap.critic_gaps(run, samples=64)
    lagging = critic_gap.critic_gaps(_run(tmp_path, "lag", tau=0.005)[0], samples=64)
    assert copied["episodes"] == lagging["episodes"] == episodes
    assert copied["updates"] > 0 and copied["updates"] == lagging["updates"]
    assert len(copied["gaps"]) == 2 * 64  # both twins
    assert copied["gaps"].max() == 0.0
    assert lagging["gaps"].min() >= 0.0 and lagging["gaps"].max() > 0.0


def test_command_prints_one_row_per_run(tmp_path, capsys):
    run, episodes = _run(tmp_path, "lag", tau=0.005)
    critic_gap.main([str(run), "--samples", "32", "--clip", "0.01"])
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("| run | episodes | updates |") and "share > 0.01" in lines[0]
    assert len(lines) == 3 and lines[2].startswith(f"| {run} | {episodes} |")


def test_a_run_of_another_algorithm_is_refused(tmp_path):
    config = config_from_dict(
        {
            **{
                k: v
                for k, v in TINY.items()
                if k not in ("dsac", "random_steps", "learning_starts")
            },
            "algo": "a2c",
            "episodes": 2,
        }
    )
    Trainer(config, tmp_path / "a2c", progress=False).run()
    with pytest.raises(ValueError, match="'a2c' run; the critic gap is DSAC's"):
        critic_gap.critic_gaps(tmp_path / "a2c", samples=8)
