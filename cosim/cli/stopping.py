"""How a command stops on Ctrl-C or SIGTERM, and, in a run process under the supervisor,
how it tells the supervisor it heard the signal and ends with it."""

from __future__ import annotations

import os
import signal
from types import FrameType

from ..interrupts import hear

TERMINATED, INTERRUPTED = "terminated (SIGTERM)", "interrupted (Ctrl-C)"


class Terminated(KeyboardInterrupt):
    """SIGTERM, handled like Ctrl-C: what was computed is kept and summarised."""


def on_sigterm(signum: int, frame: FrameType | None) -> None:
    _acknowledge_to_supervisor()
    hear(TERMINATED)
    raise Terminated(TERMINATED)


def _on_sigint(signum: int, frame: FrameType | None) -> None:
    _acknowledge_to_supervisor()
    hear(INTERRUPTED)
    raise KeyboardInterrupt


_supervisor: list[int] = []  # in a supervised run process: the supervisor's pid


def _acknowledge_to_supervisor() -> None:
    """Tell the supervisor this process heard its signal (Python ran the handler, so it is
    not stuck in a plant's binary) and is ending: no need to kill it after the grace."""
    if _supervisor and os.getppid() == _supervisor[0]:
        os.kill(_supervisor[0], signal.SIGUSR1)


def follow_the_supervisor() -> None:
    """In the run process a supervisor started: Ctrl-C and SIGTERM are acknowledged to it,
    and the process ends with it."""
    _supervisor.append(os.getppid())
    signal.signal(signal.SIGINT, _on_sigint)
    _end_with_the_supervisor()


def _end_with_the_supervisor() -> None:
    """In the supervised run process: if the supervisor dies (SIGKILL, a closed terminal),
    end as on SIGTERM — what was computed is kept and summarised — rather than run on as an
    orphan. A daemon thread polls the parent once a second."""
    import threading

    parent = os.getppid()

    def watch() -> None:
        while os.getppid() == parent:
            threading.Event().wait(1.0)
        os.kill(os.getpid(), signal.SIGTERM)

    threading.Thread(target=watch, daemon=True, name="cosim-supervisor-watch").start()
