"""Running one ``crowdplan`` command: its exit status for each way it can end (docs/cli.md).

Exit status: 0 done, 1 failed while running (e.g. a disk error), 2 bad input (refused before any
work), 130 interrupted (Ctrl-C), 141 output pipe closed (``crowdplan eval | head``).
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable

EXIT_FAILED, EXIT_BAD_INPUT, EXIT_INTERRUPTED, EXIT_BROKEN_PIPE = 1, 2, 130, 141


def run_command(
    command: Callable[[argparse.Namespace], int], args: argparse.Namespace, prog: str
) -> int:
    """Run ``command(args)`` with one torch thread unless the command sets its own; an error is
    printed as ``prog: error: ...`` and becomes the exit status instead of a traceback."""
    try:
        import torch

        torch.set_num_threads(1)
        status = command(args)
        sys.stdout.flush()  # a closed pipe shows here, where it is handled, not at exit
        return status
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        _silence_stdout()
        return EXIT_BROKEN_PIPE
    except (ValueError, TypeError, FileNotFoundError) as error:
        print(f"{prog}: error: {error}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except OSError as error:
        print(f"{prog}: error: {error}", file=sys.stderr)
        return EXIT_FAILED


def _silence_stdout() -> None:
    """Point stdout at /dev/null so that flushing at exit cannot raise again on a closed pipe."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):  # stdout without a file descriptor (e.g. captured in tests)
        pass
