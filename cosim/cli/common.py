"""What every command shares: the error a user's mistake ends with, and how it is printed."""

from __future__ import annotations

import os
import sys


class UserError(Exception):
    """A mistake in what the user asked for: printed as one line, no traceback."""


def print_error(text: str) -> None:
    """``cosim: error: TEXT`` on stderr: how every command ends on a mistake (status 2)."""
    print(f"cosim: error: {text}", file=sys.stderr)


class StdoutReaderGone:
    """sys.stdout for a command whose reader may stop early (``cosim params | head``): the
    output ends there, the command does not (no BrokenPipeError traceback; its own exit
    status, e.g. compare's 1 on a regression, stands)."""

    def __init__(self, stream):
        self._stream = stream

    def write(self, text: str) -> int:
        try:
            return self._stream.write(text)
        except BrokenPipeError:
            self._discard()
            return len(text)

    def flush(self) -> None:
        try:
            self._stream.flush()
        except BrokenPipeError:
            self._discard()

    def _discard(self) -> None:
        """What is still to be written goes nowhere (the reader is gone)."""
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, self._stream.fileno())
        os.close(devnull)

    def __getattr__(self, name: str):
        return getattr(self._stream, name)
