"""The velocity the measured positions prove (step 3 of :mod:`cosim.paper.envelope`): q̇(t_k)
from the position differences over the last N = 1 … ``window`` steps, within the
measurements' noise and the bounds on q̈ the envelope proved over each step. SI units,
radians."""

from __future__ import annotations

import numpy as np

from ..numba_compat import no_refcount_jit


@no_refcount_jit(cache=True)
def envelope_windows(k, dt, noise, window, y, acc, interval):
    """Intersect q̇(t_k) ∈ ``interval`` with the estimates from the position differences over
    the last N = 1 … ``window`` steps: q̇(t_k) = (q(t_k) − q(t_k−N))/T + (1/T)∫(s − t_k−N)q̈ ds,
    T = N dt, the measurements within ±``noise`` (±2 noise/T) and q̈ within acc[j] (lo, hi)
    over step j, whose weight ∫(s − t_k−N) ds over the step is dt²(j − k + N + ½). False
    when no q̇ fits every estimate (then the interval is the hull of the crossing ends)."""
    n = y.shape[1]
    consistent = True
    for i in range(n):
        sum_lo, sum_hi, moment_lo, moment_hi = 0.0, 0.0, 0.0, 0.0
        lo, hi = interval[0, i], interval[1, i]
        for length in range(1, min(k, window) + 1):
            j = k - length
            if not (np.isfinite(acc[j, 0, i]) and np.isfinite(acc[j, 1, i])):
                break  # a step whose q̈ no bound held: no window over it says anything
            sum_lo += acc[j, 0, i]
            sum_hi += acc[j, 1, i]
            moment_lo += (j - k + 0.5) * acc[j, 0, i]
            moment_hi += (j - k + 0.5) * acc[j, 1, i]
            span = length * dt
            base = (y[k, i] - y[j, i]) / span
            spread = 2.0 * noise / span
            lo = max(lo, base - spread + (moment_lo + length * sum_lo) * dt / length)
            hi = min(hi, base + spread + (moment_hi + length * sum_hi) * dt / length)
        if lo > hi:  # no q̇ fits: outside what is assumed; the hull of the two, never less
            lo, hi = hi, lo
            consistent = False
        interval[0, i], interval[1, i] = lo, hi
    return consistent
