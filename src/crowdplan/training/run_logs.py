"""What a run folder records while training: CSV logs, TensorBoard scalars, meta.json, curves."""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

from crowdplan.analysis.plots import plot_training_curves
from crowdplan.io import atomic_write, write_json


class RunLogs:
    """Rows of ``episodes.csv``, ``validation.csv`` and ``updates.csv`` plus TensorBoard
    scalars in ``tb/``; :meth:`write` rewrites the CSV files atomically."""

    def __init__(self, run_dir: Path):
        self.run_dir = run_dir
        self.episodes: list[dict[str, Any]] = []
        self.validations: list[dict[str, Any]] = []
        self.updates: list[dict[str, Any]] = []
        self._tb = None

    def scalars(self, step: int, values: dict[str, float]) -> None:
        """Add TensorBoard scalars (``group/name -> value``) at ``step`` (episodes done)."""
        if self._tb is None:
            from torch.utils.tensorboard import SummaryWriter

            self._tb = SummaryWriter(str(self.run_dir / "tb"))
        for key, value in values.items():
            self._tb.add_scalar(key, value, step)

    def write(self, meta: dict[str, Any]) -> None:
        """The three CSV files, ``meta.json`` and ``curves.png``."""
        write_csv(self.run_dir / "episodes.csv", self.episodes)
        write_csv(self.run_dir / "validation.csv", self.validations)
        write_csv(self.run_dir / "updates.csv", self.updates)
        if self.episodes:
            plot_training_curves(self.run_dir)
        write_json(self.run_dir / "meta.json", meta)

    def close(self) -> None:
        if self._tb is not None:
            self._tb.close()
            self._tb = None

    def state(self) -> tuple[list, list, list]:
        return self.episodes, self.validations, self.updates

    def load_state(self, state: tuple[list, list, list]) -> None:
        self.episodes, self.validations, self.updates = state


def write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    """Rows as CSV, written atomically; columns in first-seen order (rows logged before a
    column existed leave it empty)."""
    if not rows:
        return
    fieldnames = list(dict.fromkeys(key for row in rows for key in row))

    def write(f):
        writer = csv.DictWriter(f, fieldnames=fieldnames)
        writer.writeheader()
        writer.writerows(rows)

    atomic_write(path, write)
