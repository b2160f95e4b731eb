"""Re-express a DSAC model's world-frame actions in the goal frame.

A model trained with the paper's world-frame actions (``action_frame: world``) in a scenario whose
goals all lie in one compass direction (circle_crossing: +y, heading index 4 of 16) chose, in
effect, headings relative to that direction. Permuting its 80 moving actions so that heading
index ``k`` of the goal frame takes the logits of world index ``k + 4`` gives a goal-frame policy
that is the same policy whenever the goal lies exactly along +y, and that rotates with the scene
(the features were already goal-relative). It is the natural starting point for training a
planner that works for goals in any direction:

    python -m crowdplan.algos.action_frames models/lsa-dsac-paper/model.pt /tmp/lsa-goal.pt
"""

from __future__ import annotations

import argparse
import copy
from pathlib import Path
from typing import Any

import torch

from crowdplan.models import MODEL_FORMAT, load_payload, resolve_model_path
from crowdplan.sim.actions import N_DIRECTIONS, N_SPEEDS
from crowdplan.training.checkpoint import torch_save_atomic


def goal_frame_permutation(goal_heading_index: int = 4) -> torch.Tensor:
    """Index i of the goal-frame action table -> index of the same motion in the world frame
    when the goal lies along world heading ``goal_heading_index * 2 pi / 16``."""
    moves = [
        1 + ((d + goal_heading_index) % N_DIRECTIONS) * N_SPEEDS + s
        for d in range(N_DIRECTIONS)
        for s in range(N_SPEEDS)
    ]
    return torch.tensor([0, *moves])


def world_to_goal_frame(payload: dict[str, Any], goal_heading_index: int = 4) -> dict[str, Any]:
    """A copy of a world-frame DSAC model file whose policy acts in the goal frame."""
    if payload.get("format") != MODEL_FORMAT:
        raise ValueError(f"only DSAC model files ({MODEL_FORMAT}) can be converted")
    if payload["world"].get("kinematics", "holonomic") != "holonomic":
        raise ValueError("unicycle actions are already relative to the robot's heading")
    if payload["world"].get("action_frame", "world") != "world":
        raise ValueError("the model already acts in the goal frame")
    converted = copy.deepcopy(payload)
    actor = converted["actor"]
    # the last layer of the policy head produces the logits
    weight = max((k for k in actor if k.startswith("head.") and k.endswith(".weight")), key=_layer)
    bias = weight.removesuffix("weight") + "bias"
    order = goal_frame_permutation(goal_heading_index)
    actor[weight] = actor[weight][order].clone()
    actor[bias] = actor[bias][order].clone()
    converted["world"] = {**payload["world"], "action_frame": "goal"}
    converted["info"] = {**payload["info"], "converted_from_world_frame": goal_heading_index}
    return converted


def _layer(key: str) -> int:
    return int(key.split(".")[-2])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("model", help="a world-frame DSAC model file or shipped name")
    parser.add_argument("out", help="the goal-frame model file to write")
    args = parser.parse_args(argv)
    source = resolve_model_path(args.model)
    torch_save_atomic(Path(args.out), world_to_goal_frame(load_payload(source)))
    print(f"wrote {args.out} (goal-frame actions, from {source})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
