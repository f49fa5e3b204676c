"""Progress on stderr for the long parts of a command: a run's percentage, and a phase that
may take seconds (closing the recording, drawing figures, starting Dask workers) announced
before it starts and timed when it ends, so that a quiet terminal never looks hung."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager


def percent(name: str, total: int) -> Callable[[int], None]:
    """``report(k)``: ``name``'s share done after k of ``total`` steps; in place on a
    terminal, at 25, 50 and 75 % otherwise (a log file gets three lines, not thousands)."""
    tty = sys.stderr.isatty()
    marks = {int(total * f) for f in (0.25, 0.5, 0.75)}

    def report(k: int) -> None:
        if tty:
            print(f"\r  {name}: {100 * k / total:5.1f} %", end="", file=sys.stderr, flush=True)
        elif any(abs(k - m) < 1000 and k <= m for m in marks):
            print(f"  {name}: {100 * k / total:.0f} %", file=sys.stderr, flush=True)

    return report


@contextmanager
def phase(label: str, enabled: bool = True) -> Iterator[None]:
    """``  label … 1.2 s`` on stderr: the label before the work, its wall time after (also
    when it fails, so the message that follows starts on its own line)."""
    if not enabled:
        yield
        return
    print(f"  {label} …", end="", file=sys.stderr, flush=True)
    began = time.monotonic()
    try:
        yield
    finally:
        print(f" {time.monotonic() - began:.1f} s", file=sys.stderr, flush=True)
