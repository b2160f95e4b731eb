"""The DSAC networks file: actor, critic, target critic and temperature of a finished run, a few
MB instead of a checkpoint's replay buffer, to start another run from (``dsac.init_networks``).

    python -m crowdplan.algos.dsac_networks runs/<run>/checkpoint.pt results/train/<run>/networks.pt

``make publish`` writes it for every DSAC run.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Any

from crowdplan.config import to_dict

# crowdplan.training imports the algorithm registry, which imports this module: the checkpoint
# helpers are imported where they are used.
if TYPE_CHECKING:
    from crowdplan.training.config import TrainConfig

NETWORK_KEYS = ("actor", "critic", "critic_target", "log_alpha")
NETWORKS_FORMAT = "crowdplan-dsac-networks/1"


def networks_of(state: dict[str, Any], path: Path) -> dict[str, Any]:
    """The networks and temperature of a loaded checkpoint or networks file."""
    if state.get("format") == NETWORKS_FORMAT:
        return state["networks"]
    dsac = state["agent"].get("dsac") if isinstance(state.get("agent"), dict) else None
    if dsac is None:
        raise ValueError(f"{path} is not a DSAC training checkpoint")
    return {key: dsac[key] for key in NETWORK_KEYS}


def networks_payload(config: dict[str, Any], dsac_state: dict[str, Any]) -> dict[str, Any]:
    """A networks file's content: the run's config (plain data) and, of a DSAC state dict
    (:meth:`crowdplan.algos.dsac.DSAC.state_dict`), the networks and temperature."""
    networks = {key: dsac_state[key] for key in NETWORK_KEYS}
    return {"format": NETWORKS_FORMAT, "config": config, "networks": networks}


def save_networks(checkpoint: Path, out: Path) -> None:
    """Write the DSAC networks and temperature of a training checkpoint, with the run's config,
    to ``out``."""
    from crowdplan.training.checkpoint import read_checkpoint, torch_save_atomic

    state = read_checkpoint(checkpoint)
    torch_save_atomic(out, networks_payload(state["config"], networks_of(state, checkpoint)))


def initial_networks(config: TrainConfig) -> dict[str, Any]:
    """The networks of ``config.algo_config.init_networks``, checked against the run."""
    from crowdplan.training.checkpoint import read_checkpoint

    path = Path(config.algo_config.init_networks)
    if path.is_dir():
        path = path / "checkpoint.pt"
    if not path.is_file():
        raise FileNotFoundError(
            f"dsac.init_networks {path} does not exist: give a run's checkpoint.pt or a file "
            "written by python -m crowdplan.algos.dsac_networks"
        )
    state = read_checkpoint(path, also=(NETWORKS_FORMAT,))
    networks, saved = networks_of(state, path), state["config"]
    encoder = saved.get("encoder")
    if encoder != to_dict(config.encoder):
        raise ValueError(
            f"dsac.init_networks {path} has encoder {encoder}, the run {to_dict(config.encoder)}"
        )
    frame = saved.get("world", {}).get("action_frame", "world")
    if frame != config.world.action_frame:
        raise ValueError(
            f"dsac.init_networks {path} acts in the {frame} frame, the run in the "
            f"{config.world.action_frame} frame"
        )
    return networks


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("checkpoint", type=Path, help="a DSAC run's checkpoint.pt")
    parser.add_argument("out", type=Path, help="networks file to write")
    args = parser.parse_args(argv)
    if not args.checkpoint.is_file():
        parser.error(f"{args.checkpoint} does not exist: give a DSAC run folder's checkpoint.pt")
    try:
        save_networks(args.checkpoint, args.out)
    except (OSError, ValueError) as error:
        parser.error(str(error))
    print(f"{args.out}: networks of {args.checkpoint}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
