"""The controller's inertia model M̂(q), which the observer's (7) needs (Assumption 3: M(q) is
known). Two sources, written to the trace's ``M_model`` for row k:

- ``fmu``: the plant's own ``M`` outputs at the true q (the FMU maps ``M``);
- ``nominal``: a planar serial chain with the pipeline's link parameters, evaluated at the
  measured position ``q_meas`` — all an output-feedback controller can know. A plant whose
  masses differ from these is how a model mismatch is studied.

The chain is the built-in plant's: link i of mass m_i, length l_i, centre of mass lc_i
along it and rotational inertia I_i; joint angles relative, link 1 from the horizontal.
With absolute angles θ_k = q_1 + … + q_k, joint origins o_i and centres of mass p_k,

    M_ij = Σ_{k ≥ max(i, j)} [ m_k (p_k − o_i)·(p_k − o_j) + I_k ],

since a rotation about joint i moves p_k by ẑ × (p_k − o_i) and (ẑ × a)·(ẑ × b) = a·b.
SI units, radians.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from plant_fmu.variables import PAPER_MASSES

from ..trace import Trace


def default_links(links: int) -> dict[str, list[float]]:
    """Nominal link parameters when the pipeline gives none: the paper's arm (SPEC §2),
    further links as the built-in plant's defaults (1 kg, 1 m, centre of mass at the tip,
    no rotational inertia)."""
    return {"m": [PAPER_MASSES[i] if i < len(PAPER_MASSES) else 1.0 for i in range(links)],
            "l": [1.0] * links, "lc": [1.0] * links, "I": [0.0] * links}


@njit(cache=True)
def planar_mass_matrix(q, m, l, lc, inertia, out):  # noqa: E741
    """M(q) of a planar serial chain into ``out`` (n×n)."""
    n = q.shape[0]
    ox = np.zeros(n)  # joint origins
    oy = np.zeros(n)
    px = np.empty(n)  # centres of mass
    py = np.empty(n)
    theta = 0.0
    x = 0.0
    y = 0.0
    for k in range(n):
        theta += q[k]
        c, s = np.cos(theta), np.sin(theta)
        ox[k], oy[k] = x, y
        px[k], py[k] = x + lc[k] * c, y + lc[k] * s
        x += l[k] * c
        y += l[k] * s
    for i in range(n):
        for j in range(i, n):
            total = 0.0
            for k in range(j, n):
                total += (m[k] * ((px[k] - ox[i]) * (px[k] - ox[j])
                                  + (py[k] - oy[i]) * (py[k] - oy[j])) + inertia[k])
            out[i, j] = total
            out[j, i] = total


@njit(cache=True)
def _nominal_step(k, position, m, l, lc, inertia, out):  # noqa: E741
    planar_mass_matrix(position[k], m, l, lc, inertia, out[k])


@dataclass
class InertiaModel:
    """``source``: "fmu" or "nominal" (the runner resolves the pipeline's "auto"); ``m``,
    ``l``, ``lc``, ``I``: the nominal chain's per-link kg, m, m, kg·m² (unset: the paper's
    arm, :func:`default_links`)."""

    source: str = "nominal"
    m: list[float] | None = None
    l: list[float] | None = None  # noqa: E741
    lc: list[float] | None = None
    I: list[float] | None = None  # noqa: E741
    name: str = "inertia model"

    def nominal_links(self, links: int) -> dict[str, list[float]]:
        """The nominal chain as used for ``links`` joints: given values, else the defaults."""
        return {key: getattr(self, key) or value
                for key, value in default_links(links).items()}

    def reset(self, trace: Trace) -> None:
        self._from_plant = self.source == "fmu"
        if self._from_plant:
            # M̂ is the plant's own M: the trace's M_model is that same array, so a step
            # has nothing to copy.
            trace.arrays["M_model"] = trace["M"]
            return
        links = self.nominal_links(trace.links)
        self._args = (trace["q_meas"],
                      *(np.asarray(links[key], float) for key in ("m", "l", "lc", "I")),
                      trace["M_model"])

    def step(self, k: int) -> bool:
        if not self._from_plant:
            _nominal_step(k, *self._args)
        return True  # a non-finite M̂ makes the observer's output non-finite: caught there
