"""``--set KEY=VALUE`` on the command line: dotted keys into a training config as ``config.yaml``
writes it (``dsac.lr``, ``world.humans``), each checked to exist, and YAML values.

``crowdplan sweep --set KEY=V1,V2,...`` expands a grid over several values;
``crowdplan train --set KEY=VALUE`` sets one value for one run. Both read keys and values here.
"""

from __future__ import annotations

from typing import Any

import yaml


def parse_assignments(assignments: list[str], base: dict[str, Any]) -> list[tuple[str, list[Any]]]:
    """``["dsac.lr=1e-4,3e-4", ...]`` -> ``[("dsac.lr", [0.0001, 0.0003]), ...]``.

    Every key must exist in ``base`` (a config as ``TrainConfig.to_dict`` gives it) and be given
    once. Values are YAML scalars or flow sequences, separated by commas outside brackets.
    """
    parsed: list[tuple[str, list[Any]]] = []
    for assignment in assignments:
        key, sep, text = assignment.partition("=")
        key = key.strip()
        if not sep or not key:
            raise ValueError(
                f"--set takes KEY=VALUE (e.g. dsac.lr=1e-4; sweeps: dsac.lr=1e-4,3e-4), "
                f"got {assignment!r}"
            )
        if key in (k for k, _ in parsed):
            raise ValueError(f"--set {key} is given twice; list all its values in one --set")
        lookup(base, key)
        items = [item.strip() for item in _split_values(text)]
        if not text.strip() or any(not item for item in items):
            raise ValueError(
                f"--set {key}: empty value in {text!r}; give a value "
                "(a sweep: V1,V2,..., none empty)"
            )
        try:
            values = [_parse_value(item) for item in items]
        except yaml.YAMLError as error:
            raise ValueError(f"--set {key}: a value is not valid YAML: {error}") from error
        parsed.append((key, values))
    return parsed


def lookup(data: dict[str, Any], key: str) -> Any:
    """The value at dotted ``key`` in ``data``; an unknown key names the valid ones."""
    node: Any = data
    for depth, part in enumerate(key.split(".")):
        if not isinstance(node, dict) or part not in node:
            if depth == 0 and "algo" in node:
                _refuse_other_algorithms_section(key, part, node["algo"])
            where = ".".join(key.split(".")[:depth]) or "the top level"
            valid = sorted(node) if isinstance(node, dict) else []
            raise ValueError(f"--set {key}: unknown key {part!r} in {where}; valid keys: {valid}")
        node = node[part]
    return node


def _refuse_other_algorithms_section(key: str, section: str, algo: str) -> None:
    """A key under another algorithm's section gets the config loader's answer, not a list."""
    from crowdplan.algos.registry import ALGORITHMS

    if section in ALGORITHMS:
        raise ValueError(
            f"--set {key}: {section!r} is the section of another algorithm; this config trains "
            f"{algo!r} (its keys: {algo}.*; set algo: {section} in the config to train that one)"
        )


def assign(data: dict[str, Any], key: str, value: Any) -> None:
    """Set dotted ``key`` of ``data`` (which must exist, see :func:`lookup`) to ``value``."""
    *parents, last = key.split(".")
    for part in parents:
        data = data[part]
    data[last] = value


def _split_values(text: str) -> list[str]:
    """Split at commas outside brackets, so that ``[64,64],[128,128]`` is two values."""
    values, depth, current = [], 0, ""
    for char in text:
        depth += char in "[{"
        depth -= char in "]}"
        if char == "," and depth == 0:
            values.append(current)
            current = ""
        else:
            current += char
    values.append(current)
    return values


def _parse_value(text: str) -> Any:
    """A number as Python reads it (YAML 1.1 takes ``1e-4`` for a string), else YAML."""
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return yaml.safe_load(text)
