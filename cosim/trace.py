"""The trace: every signal of every step, preallocated, written by the master and the blocks
and read afterwards by safety evaluation, metrics and logging.

Row k holds the values at t_k = k·h; the torque in row k is held over [t_k, t_k+1).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# Signal name -> shape per row, in terms of n (joints). "n×n" is stored as (n, n).
SIGNALS: dict[str, str] = {
    # reference
    "q_d": "n", "qdot_d": "n", "qddot_d": "n", "q_s": "n", "qdot_s": "n",
    # plant (ground truth from the FMU)
    "q": "n", "qdot": "n", "M": "nn",
    # sensor, and the controller's inertia model M̂(q) (the FMU's M or a nominal model)
    "q_meas": "n", "M_model": "nn",
    # observer
    "q_hat": "n", "qdot_hat": "n", "k0": "1", "W_o_norm": "1",
    # controller
    "tau": "n", "e": "n", "edot": "n", "r_hat": "n", "nn_output": "n", "v_c": "n",
    "W_norm": "1", "V_norm": "1",
}


@dataclass
class Trace:
    """Preallocated arrays, one per signal, ``steps + 1`` rows. NaN until written."""

    links: int
    steps: int
    dt: float
    arrays: dict[str, np.ndarray] = field(default_factory=dict)
    rows_done: int = 0  # rows 0 .. rows_done-1 are complete

    def __post_init__(self) -> None:
        n, rows = self.links, self.steps + 1
        shapes = {"n": (rows, n), "nn": (rows, n, n), "1": (rows,)}
        for name, kind in SIGNALS.items():
            self.arrays[name] = np.full(shapes[kind], np.nan)
        self.time = np.arange(rows) * self.dt

    def __getitem__(self, name: str) -> np.ndarray:
        return self.arrays[name]

    def completed(self) -> Trace:
        """A view holding only the rows that were completed."""
        k = self.rows_done
        view = Trace.__new__(Trace)
        view.links, view.steps, view.dt, view.rows_done = self.links, k - 1, self.dt, k
        view.arrays = {name: a[:k] for name, a in self.arrays.items()}
        view.time = self.time[:k]
        return view
