"""The blocks the master steps between plant steps. Each is a small class with

    name: str
    reset(trace) -> None   # bind to the trace's arrays, set initial state
    step(k) -> bool        # compute row k from rows <= k; False if an output is not finite

Data flows one way: reference, plant outputs -> sensor -> observer -> controller -> torque.
"""

from typing import Protocol

from ..trace import Trace


class Block(Protocol):
    name: str

    def reset(self, trace: Trace) -> None: ...

    def step(self, k: int) -> bool: ...
