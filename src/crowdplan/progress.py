"""Progress of long jobs on stderr, readable in a terminal and in a log file.

On a terminal, a tqdm bar redrawn in place; otherwise (stderr redirected to a file or a pipe)
plain lines at most every ``log_every`` seconds and one at the end, so a log holds no carriage
returns. Nothing is shown for jobs shorter than ``delay`` seconds, or with ``quiet``.

Usage::

    with Progress(total=500, desc="eval", quiet=args.quiet) as progress:
        for batch in batches:
            ...
            progress.update(len(batch), success=0.98, reward=0.55)
"""

from __future__ import annotations

import sys
import time
from typing import TextIO


def _format_postfix(postfix: dict) -> str:
    return " ".join(
        f"{key}={value:.3f}" if isinstance(value, float) else f"{key}={value}"
        for key, value in postfix.items()
    )


class Progress:
    """A counter of ``total`` units (episodes by default) shown on ``stream`` (stderr).

    Args:
        total: number of units the job has.
        desc: label in front of the count, e.g. "eval" or "train".
        quiet: show nothing.
        unit: name of one unit, for the log lines.
        stream: where to write; a terminal gets a bar, anything else plain lines.
        delay: seconds before the first output (short jobs stay silent).
        log_every: seconds between two lines when ``stream`` is not a terminal.
        initial: units already done (a resumed job).
        bar: False writes plain lines even on a terminal.
    """

    def __init__(
        self,
        total: int,
        desc: str = "",
        quiet: bool = False,
        unit: str = "episode",
        stream: TextIO | None = None,
        delay: float = 1.0,
        log_every: float = 10.0,
        initial: int = 0,
        bar: bool = True,
    ) -> None:
        self.total, self.desc, self.unit = total, desc, unit
        self.count = initial
        self.postfix: dict = {}
        self._stream = stream if stream is not None else sys.stderr
        self._delay, self._log_every = delay, log_every
        self._start = time.monotonic()
        self._last_line: float | None = None
        self._logged_count = initial
        self._bar = None
        self._quiet = quiet
        if bar and not quiet and self._stream.isatty():
            from tqdm import tqdm

            self._bar = tqdm(
                total=total,
                desc=desc,
                unit=unit,
                file=self._stream,
                delay=delay,
                leave=True,
                initial=initial,
            )

    def update(self, n: int = 1, **postfix: float | int | str) -> None:
        """Add ``n`` finished units; ``postfix`` (e.g. ``success=0.98``) follows the count."""
        self.count += n
        self.postfix = postfix
        if self._quiet:
            return
        if self._bar is not None:
            if postfix:
                self._bar.set_postfix_str(_format_postfix(postfix), refresh=False)
            self._bar.update(n)
            return
        now = time.monotonic()
        if now - self._start < self._delay:
            return
        if self._last_line is None or now - self._last_line >= self._log_every:
            self._write_line(now)

    def write(self, line: str) -> None:
        """A message of its own line, without breaking the bar."""
        if self._quiet:
            return
        if self._bar is not None:
            self._bar.write(line, file=self._stream)
        else:
            self._stream.write(line + "\n")
            self._stream.flush()

    def close(self) -> None:
        """Finish the display: the bar stays as it is; a log gets a line with the final count."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None
        elif not self._quiet and self._last_line is not None and self._logged_count < self.count:
            self._write_line(time.monotonic())

    def _write_line(self, now: float) -> None:
        percent = 100.0 * self.count / self.total if self.total else 100.0
        line = f"{self.desc}: {self.count}/{self.total} {self.unit}s ({percent:.0f}%)"
        if self.postfix:
            line += ", " + _format_postfix(self.postfix)
        self._stream.write(f"{line}, {now - self._start:.1f} s\n")
        self._stream.flush()
        self._last_line, self._logged_count = now, self.count

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
