"""Atomic file writes: a crash never leaves a half-written result or checkpoint behind."""

from __future__ import annotations

import json
import math
import os
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

_UMASK = os.umask(0)
os.umask(_UMASK)


def atomic_write(path: str | Path, write: Callable[[Any], None], mode: str = "w") -> None:
    """Write through ``write(file)`` into a temporary file beside ``path``, then rename it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp makes 0600 files; results are ordinary files
        with os.fdopen(fd, mode) as file:
            write(file)
            file.flush()
            os.fsync(file.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def json_safe(data: Any) -> Any:
    """Replace non-finite floats (nan, inf) by None so the file is strict JSON."""
    if isinstance(data, float):
        return data if math.isfinite(data) else None
    if isinstance(data, dict):
        return {key: json_safe(value) for key, value in data.items()}
    if isinstance(data, (list, tuple)):
        return [json_safe(value) for value in data]
    return data


def write_json(path: str | Path, data: Any) -> None:
    """Atomically write indented, strict JSON."""
    text = json.dumps(json_safe(data), indent=2, allow_nan=False)
    atomic_write(path, lambda f: f.write(text + "\n"))


def write_jsonl(path: str | Path, rows: Iterable[dict]) -> None:
    """Atomically write one JSON object per line."""
    lines = [json.dumps(json_safe(row), allow_nan=False) + "\n" for row in rows]
    atomic_write(path, lambda f: f.writelines(lines))


class OutputError(ValueError):
    """An output path that cannot or must not be written (found before any work is done)."""


def _check_creatable(path: Path) -> None:
    """Raise OutputError unless ``path`` (absent or a folder) can be made and written into."""
    existing = path.absolute()
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        raise OutputError(f"cannot create {path}: {existing} is a file, not a folder")
    try:
        fd, probe = tempfile.mkstemp(dir=existing, prefix=".crowdplan-probe.")
    except OSError as error:
        raise OutputError(f"cannot write to {path}: {existing}: {error.strerror}") from None
    os.close(fd)
    os.unlink(probe)


def check_output_folder(path: str | Path, files: Iterable[str], force: bool = False) -> Path:
    """Check, before any work, that ``files`` can be written into folder ``path``.

    Raises OutputError when ``path`` is a file, cannot be created or written, or already holds
    one of ``files`` (unless ``force``). Other files in the folder are left alone.
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise OutputError(f"{path} is a file; give a folder to write {', '.join(files)} into")
    present = [name for name in files if (path / name).exists()]
    if present and not force:
        raise OutputError(
            f"{path} already holds {', '.join(present)}; pass --force to replace "
            f"{'it' if len(present) == 1 else 'them'} or choose another folder"
        )
    _check_creatable(path)
    return path


def check_output_file(
    path: str | Path, force: bool = False, suffixes: tuple[str, ...] | None = None
) -> Path:
    """Check, before any work, that file ``path`` can be written (and has one of ``suffixes``).

    Raises OutputError when ``path`` is a folder, exists (unless ``force``), has another suffix,
    or its folder cannot be created or written.
    """
    path = Path(path)
    if suffixes is not None and path.suffix.lower() not in suffixes:
        raise OutputError(
            f"cannot write a {path.suffix or 'suffix-less'!r} file ({path}); "
            f"valid suffixes are {', '.join(suffixes)}"
        )
    if path.is_dir():
        raise OutputError(f"{path} is a folder; give a file name")
    if path.exists() and not force:
        raise OutputError(f"{path} exists; pass --force to replace it or choose another name")
    _check_creatable(path.parent)
    return path
