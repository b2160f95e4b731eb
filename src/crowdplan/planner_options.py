"""Set the planner options stored in a model file (today: the safety shield's horizon).

    python -m crowdplan.planner_options models/lsa-dsac/model.pt --shield 2.5

The options live in the model file's ``planner`` entry, next to the weights they do not change;
``crowdplan eval``, ``render`` and ``export`` apply them unless told otherwise (``--shield 0``).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from crowdplan.models import load_payload, resolve_model_path
from crowdplan.sim.shield import Shield
from crowdplan.training.checkpoint import torch_save_atomic


def with_shield(payload: dict[str, Any], horizon: float) -> dict[str, Any]:
    """A copy of a model payload whose planner uses a shield of ``horizon`` s (0: none)."""
    planner = dict(payload.get("planner", {}))
    if horizon:
        planner["shield_horizon"] = Shield(horizon).horizon
    else:
        planner.pop("shield_horizon", None)
    return {**payload, "planner": planner}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("model", help="model file (or shipped name) to change in place")
    parser.add_argument(
        "--shield", type=float, required=True, metavar="SECONDS", help="shield horizon; 0: none"
    )
    args = parser.parse_args(argv)
    path = resolve_model_path(args.model)
    torch_save_atomic(Path(path), with_shield(load_payload(path), args.shield))
    print(f"{path}: shield horizon {args.shield or 'none'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
