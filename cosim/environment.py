"""Settings a user gives cosim through the environment, read with one clear message for a
bad value (no Python traceback), using the standard library only: the supervisor of
`cosim run` reads them before anything heavy is imported."""

from __future__ import annotations

import os


def seconds_from_environment(variable: str, default: float) -> float:
    """A duration the user sets through the environment variable ``variable`` (seconds,
    > 0), else ``default``; ValueError naming the variable and what is valid otherwise."""
    text = os.environ.get(variable, "").strip()
    if not text:
        return default
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not (0 < value < float("inf")):
        raise ValueError(f"{variable}={text!r}: expected a number of seconds > 0 (default "
                         f"{default:g}); nothing was run")
    return value
