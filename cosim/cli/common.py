"""What every command shares: the error a user's mistake ends with, and how it is printed."""

from __future__ import annotations

import sys


class UserError(Exception):
    """A mistake in what the user asked for: printed as one line, no traceback."""


def print_error(text: str) -> None:
    """``cosim: error: TEXT`` on stderr: how every command ends on a mistake (status 2)."""
    print(f"cosim: error: {text}", file=sys.stderr)
