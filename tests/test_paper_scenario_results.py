"""The paper's scenario gives its stored reference results, which numpy's arithmetic
(temporaries, BLAS's gemv, LAPACK's solve) computed; the kernels compute them in loops over
preallocated scratch, for speed.

``paper_scenario_reference.json`` holds both runs of pipelines/paper_two_link.toml (20 s at
1 kHz) as numpy's arithmetic computed them (the file's git log names the code): the plant's
q and q̇, the observer's x̂2, k0 of (8) and ‖Ŵo‖, the torque τ and the NN controller's ‖Ŵ‖
and ‖V̂‖, at 22 instants (0.1 s, 0.5 s, then every second) and as their peaks |·| over the
run (552 numbers).

The kernels do the same arithmetic, but sums that BLAS's gemv and LAPACK's solve do in their
own order (and with FMA) are done in index order, so results differ in the last bits at a
step and the closed loop carries those differences on. Tolerances:

- positions (q): 1e-9 rad; measured ≤ 4.2e-13 rad at the stored rows
  and peaks, ≤ 2.2e-12 rad over every row of the full traces;
- everything else: 1e-9 of the signal's scale (max(1, its peak over the run)), as
  tests/test_references.py's closed forms; measured ≤ 5.6e-12 of it at the stored rows and
  peaks; over every row ≤ 5e-11, except the baseline's ‖V̂‖ at 1.2e-10 after its hidden
  weights jump (0.48 → 1.19 in one step at t = 10.855 s), which amplifies a last-bit
  difference ~100×.

Last-bit differences stay far below these bounds; a change of a law does not: measured, the
observer at 9 sub-steps instead of 10 moves the proposed run's q by 5e-4 rad, and Kv = 20.0001
instead of 20 moves it by 2e-7 rad (the baseline's by 4e-2 rad).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import PAPER

from cosim.config import load_pipeline
from cosim.runner import run

REFERENCE = json.loads((Path(__file__).parent / "paper_scenario_reference.json").read_text())
POSITION_TOL = 1e-9  # rad
RTOL = 1e-9  # of the signal's scale


@pytest.fixture(scope="module")
def paper_traces():
    results = run(load_pipeline(PAPER), None, progress=False)
    return {name: result.trace for name, result in results.items()}


@pytest.mark.parametrize("name", ["baseline", "proposed"])
def test_the_paper_runs_equal_the_kernels_before_the_rewrite(paper_traces, name):
    trace = paper_traces[name]
    assert trace.rows_done == trace.steps + 1 == 20001
    rows = [int(round(t / trace.dt)) for t in REFERENCE["times"]]
    for key, expected in REFERENCE["runs"][name].items():
        values = trace[key]
        peak = np.asarray(expected["peak"])
        tolerance = POSITION_TOL if key == "q" else RTOL * max(1.0, float(peak.max()))
        for what, got, want in (("rows", values[rows], expected["rows"]),
                                ("peak", np.abs(values).max(axis=0), peak)):
            worst = float(np.max(np.abs(got - np.asarray(want))))
            assert worst <= tolerance, (name, key, what, worst, tolerance)
