"""The stop signals this process has heard (SIGTERM, Ctrl-C), counted as their handlers run:
so that code calling into compiled code can tell an interrupt from a failure when the
interrupt surfaced there as another exception. Python raises a handler's exception at the
next bytecode, which may be inside numba's or a C extension's machinery around a call;
there it can be replaced by an ordinary exception, and a SIGTERM once reached `cosim run`
as "a block of the compiled loop raised" (a loaded make test)."""

from __future__ import annotations

_heard: list[str] = []


def hear(why: str) -> None:
    """Note a stop signal (a handler calls this before it raises): ``why`` in words,
    "terminated (SIGTERM)"."""
    _heard.append(why)


def heard() -> int:
    """How many stop signals this process has heard so far."""
    return len(_heard)


def heard_since(count: int) -> str | None:
    """What the first stop signal heard after :func:`heard` returned ``count`` was, or
    None."""
    return _heard[count] if len(_heard) > count else None
