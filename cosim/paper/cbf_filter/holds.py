"""How the check's rollout steps over the holds the filter applies (:mod:`.check`): the
filter re-evaluates its torque at every control step dt and holds it, so a rollout step of
h = m dt is m holds. A held torque (the candidate's, or the backup's where a torque limit
binds) is one hold whose q̈ drifts as the state moves (:func:`held_drift`). A free
backup's q̈ falls by (1 − c) at each hold, c = min(k_b dt, 1): its average over the step
(:func:`held_average`), its position the holds' own (:func:`held_position`), its velocity
inside the step (:func:`held_travel`), the feedback's share of the tube it removes
(:func:`feedback_contraction`) and D later in the step (:func:`later_deviation`). Where no
joint's target moves, its steps grow (:func:`may_grow`). docs/safety/filter.md, "The
check" and "Steps that grow"."""

from __future__ import annotations

import numpy as np

from ...dynamics.model import model_bias, model_friction
from ...numba_compat import no_refcount_jit
from .backup import HOLD, nominal_acceleration, rollout_payload
from .deviation import deviation_bound
from .scratch import Flag, Matrix, Rollout

# The tube's D is taken this many times: its linear model of the backup's feedback (each
# free joint pulled to its target at k_b, the torque recomputed from the true state) is first
# order; braked apart on the closed-form arm with 1 kg at the tip from the edge of the
# velocity's interval, D alone let joint 1 pass its bound by 0.015 rad
# (tests/test_viability.py), 1.5 D keeps it inside. An empirical factor, stated as such.
TUBE_SAFETY = 1.5
# rad/s: a velocity set's centre this small is a 0 (filtered) to the rollout's steps
TINY_CENTRE = 1e-6


@no_refcount_jit(cache=True)
def feedback_contraction(rate, h, dt):
    """f: the share of the true velocity's departure u from the rollout's that the backup's
    feedback removes over a rollout step of h. The filter applies the backup at the control
    step dt and holds it, so per hold u ← (1 − c) u − c e + ∫Δ with c = min(k_b dt, 1), and
    over the h/dt holds of a rollout step (``backup_step`` is a whole number of control
    steps) (1 − c)^(h/dt) of u remains. Within a step, the share after s is at least
    f s/h (1 − (1 − c)^j is concave in j), as :func:`.check.plan_box` takes it. The first-order
    k_b h claimed more than the holds give: 0.4 against 0.36 at k_b = 200 1/s, h = 2 dt =
    2 ms (docs/safety/filter.md, "The check")."""
    holds = max(1, round(h / dt))
    held = min(rate * dt, 1.0)
    if holds == 1:
        return held
    return 1.0 - (1.0 - held) ** holds


@no_refcount_jit(cache=True, inline="always")
def held_share(a, s):
    """A free joint's departure over a step of several holds, the backup's feedback removing
    the share c = min(k_b dt, 1) of the velocity's departure u at each hold: with
    u_{j+1} = (1 − c) u_j − c e_j + ∫Δ, |e| ≤ ε, |Δ| ≤ W, and inside hold j (the feedback
    held) u(τ) = u_j − (cτ/dt)(u_j + e_j) + ∫_0^τ Δ, after t = j dt + τ

        |u| ≤ ε + A (δv − ε) + G W,  A = (1 − c)^j (1 − cτ/dt),
        G = dt Σ_{k<j} (1 − c)^k (1 − cτ/dt) + τ

    Returns (A, ∫_0^s A, G, ∫_0^s G): the position's departure grows by
    ε s + (δv − ε) ∫A + W ∫G. The step's δv h + ½ W h² and W h left out that the feedback
    contracts the departure within the step: at 16 holds and 50 1/s, ∫A = 0.68 h,
    ∫G = 0.79 ½ h², G = 0.70 h."""
    c = min(a.backup_rate * a.dt, 1.0)
    holds = int(np.floor(s / a.dt + 1e-9))
    remains, integral, gathered, gathered_integral = 1.0, 0.0, 0.0, 0.0
    for _ in range(holds):
        integral += a.dt * remains * (1.0 - 0.5 * c)
        gathered_integral += a.dt * gathered * (1.0 - 0.5 * c) + 0.5 * a.dt * a.dt
        remains *= 1.0 - c
        gathered = gathered * (1.0 - c) + a.dt
    rest = s - holds * a.dt
    kept = 1.0 - c * rest / a.dt
    integral += remains * rest * (1.0 - 0.5 * c * rest / a.dt)
    gathered_integral += gathered * rest * (1.0 - 0.5 * c * rest / a.dt) + 0.5 * rest * rest
    return remains * kept, integral, gathered * kept + rest, gathered_integral


@no_refcount_jit(cache=True)
def held_end(k, a, tau, limit, spread):
    """A held step's predicted end: the rollout's row state (Rollout.Q, Rollout.V) moved by
    dt under its q̈ (Rollout.ACC), and there the nominal q̈ under τ held (Rollout.ACC) and D
    for the velocity error ``spread`` (Rollout.DEV). The true q̈ over the step lies in the
    hull of q̈ ± 1.5 D at the step's start and at this end (:func:`held_drift`,
    :func:`.interval.predict_interval`)."""
    r = a.work.rollout
    q, vel, acc = r[Rollout.Q], r[Rollout.V], r[Rollout.ACC]
    for i in range(q.shape[0]):
        q[i] += a.dt * vel[i] + 0.5 * a.dt * a.dt * acc[i]
        vel[i] += a.dt * acc[i]
    nominal_acceleration(k, a, tau, False, 0, limit)
    deviation_bound(a, vel, spread, acc, r[Rollout.DEV], False)


@no_refcount_jit(cache=True)
def held_drift(k, a, first, limit, eps, widen, keep):
    """Take q̈'s drift over a held step (``first`` held for dt) into the tube: the true q̈
    over the step lies in the hull of q̈ ± ``widen`` at the step's start (1.5 D there, per
    joint) and q̈ ± 1.5 D at its predicted end (the premise :func:`.interval.predict_interval`
    takes too). The rollout's q̈ (the tube's centre over the step) becomes the hull's
    middle and ``widen`` its half-width; q and q̇ are the start's again on return. (The
    start's q̈ as the centre, widened to max(1.5 D, |q̈(end) − q̈| + 1.5 D(end)), is as sound
    and wider by up to half the drift.) With ``keep`` (the check's candidate step), the hull
    is kept with its start and torque (Rollout.CHECKED_TAU …, Flag.CHECKED_ROW): it is the
    bound on q̈ the velocity's interval is predicted with for that torque from that state
    (:func:`.interval.predict_interval`, which then need not take it again)."""
    r = a.work.rollout
    q, vel, acc, deviation = r[Rollout.Q], r[Rollout.V], r[Rollout.ACC], r[Rollout.DEV]
    held_q, held_v, held_acc = r[Rollout.HELD_Q], r[Rollout.HELD_V], r[Rollout.HELD_ACC]
    n = q.shape[0]
    for i in range(n):
        held_q[i], held_v[i], held_acc[i] = q[i], vel[i], acc[i]
    held_end(k, a, first, limit, eps)
    for i in range(n):
        # the hull of q̈ ± W at the start and q̈ ± W at the end: its middle and half-width
        low = min(held_acc[i] - widen[i], acc[i] - TUBE_SAFETY * deviation[i])
        high = max(held_acc[i] + widen[i], acc[i] + TUBE_SAFETY * deviation[i])
        widen[i] = 0.5 * (high - low)
        q[i], vel[i], acc[i] = held_q[i], held_v[i], 0.5 * (low + high)
        if keep:
            r[Rollout.CHECKED_LOW, i], r[Rollout.CHECKED_HIGH, i] = low, high
            r[Rollout.CHECKED_TAU, i], r[Rollout.CHECKED_Q, i] = first[i], q[i]
            r[Rollout.CHECKED_V, i], r[Rollout.CHECKED_HALF, i] = vel[i], eps[i]
    if keep:
        a.work.flags[Flag.CHECKED_ROW] = k + 1


@no_refcount_jit(cache=True, inline="always")
def held_average(a, h, contraction):
    """The rollout's q̈ over a step of h = m dt, m > 1 holds of a backup no torque limit
    binds: its q̈ at each hold, averaged (into Rollout.ACC; the first hold's into
    Rollout.HOLD_ACC).
    The filter re-evaluates the backup at every control step dt and holds it, so over the
    step its q̈ = k_b (w − (v − q̇_s)) falls as it acts: (1 − c)^k q̈_0 at hold k,
    c = min(k_b dt, 1). Taken at the first hold's q̈ for the whole step, the rollout braked
    faster than the filter does, by c dt |q̈_0| m (m − 1)/2 in velocity after a step to first
    order: 0.2 dt |q̈_0| at 200 1/s and m = 2, up to 0.24 rad/s along a rollout
    (docs/safety/filter.md, "The check"). With the average, Σ_k (1 − c)^k / m = f / (m c),
    the rollout's velocity after the step is the holds'. Its position is the holds' own
    (:func:`held_position`), and inside the step the plan's box takes the holds' own
    velocities (:func:`held_travel`). A step where a limit binds is one hold
    (:func:`.check.verified`).
    ``contraction``: the step's f (:func:`feedback_contraction`)."""
    r = a.work.rollout
    acc, first = r[Rollout.ACC], r[Rollout.HOLD_ACC]
    c = min(a.backup_rate * a.dt, 1.0)
    share = 1.0
    if c > 0.0:
        share = contraction / (max(1, round(h / a.dt)) * c)
    for i in range(acc.shape[0]):
        first[i] = acc[i]
        acc[i] *= share


@no_refcount_jit(cache=True, inline="always")
def held_travel(a, h, s):
    """The velocity a step of h moves by after s, per unit of its first hold's q̈: s where
    the step is one hold (its q̈ constant), else the holds' Σ_{k<J} (1 − c)^k dt (J = s/dt,
    c = k_b dt: :func:`held_average`) and the next hold's share of the rest."""
    c = min(a.backup_rate * a.dt, 1.0)
    if h <= a.dt * (1.0 + 1e-9) or c <= 0.0:
        return s
    holds = np.floor(s / a.dt + 1e-9)
    remains = (1.0 - c) ** holds
    return a.dt * (1.0 - remains) / c + (s - holds * a.dt) * remains


@no_refcount_jit(cache=True, inline="always")
def held_position(a, h, s):
    """The position a step of h moves by after s beyond s times its start's velocity, per
    unit of its first hold's q̈: ½ s² where the step is one hold (its q̈ constant), else
    the holds' own sum, their q̈ falling by (1 − c) at each (:func:`held_average`). The
    holds' average q̈ held over the step put the position ahead of theirs in the direction
    of motion, by c dt² |q̈_0| m (m² − 1)/12 to first order: 0.011 rad (0.0078 exactly)
    from 13 rad/s over a step of 16 holds at 50 1/s."""
    c = min(a.backup_rate * a.dt, 1.0)
    if h <= a.dt * (1.0 + 1e-9) or c <= 0.0:
        return 0.5 * s * s
    holds = int(np.floor(s / a.dt + 1e-9))
    position = travel = 0.0  # per unit of q̈_0: so far, and the velocity gained so far
    share = 1.0  # (1 − c)^j: hold j's q̈ per unit of the first's
    for _ in range(holds):
        position += a.dt * travel + 0.5 * a.dt * a.dt * share
        travel += a.dt * share
        share *= 1.0 - c
    rest = s - holds * a.dt
    return position + rest * travel + 0.5 * rest * rest * share


@no_refcount_jit(cache=True, inline="always")
def may_grow(a, h):
    """Whether a free backup's step may take h (longer than ``backup_step``): its target
    stays w = 0 over it for every joint, as the rollout holds it. No joint is steered
    (Rollout.TARGET 0), and none can reach the band within HOLD of its position bound
    where the backup steers it, at its speed, which only falls over a free step (towards
    q̇_s, on the same side of 0: else the velocity crosses 0 and the position turns, by
    up to |q̇_s| h, left to the room ``bound_margin`` leaves between the check's points
    only where |q̇_s| ≤ TINY_CENTRE, a filtered 0). Then every joint's velocity and q̈
    fall by the same factor at each hold, and its position moves one way."""
    r = a.work.rollout
    if a.backup_rate * a.dt >= 1.0:
        return False
    for i in range(r.shape[1]):
        speed, centre = r[Rollout.V, i], a.centres[1, i]
        if r[Rollout.TARGET, i] != 0.0 or (speed * centre < 0.0 and abs(centre) > TINY_CENTRE):
            return False
        reach = abs(r[Rollout.Q, i] - a.centres[0, i]) + a.noise_bound \
            + (abs(speed - centre) + abs(centre)) * h
        if a.hard[0] and reach > a.viable_bounds[0, i] - HOLD:
            return False
    return True


@no_refcount_jit(cache=True, inline="always")
def free_at_end(a, h, limit):
    """Whether the backup's torque at a grown step's end, M̂ q̈ + b̂ at the nominal velocity
    and q̈ there (the start's configuration, Rollout.HELD_V, Rollout.HELD_ACC, b̂ into
    Rollout.HELD_Q), is within ``limit`` as at its start (:func:`may_grow`'s step is free
    only if a limit binds at neither end; between them the torque moves with the falling q̈
    and the bias, taken at its ends as D is). Call with the rollout's model at the step's
    start (:func:`.backup.nominal_acceleration`); its geometry is left there."""
    r = a.work.rollout
    vel, first = r[Rollout.V], r[Rollout.ACC]
    end_v, end_acc, bias = r[Rollout.HELD_V], r[Rollout.HELD_ACC], r[Rollout.HELD_Q]
    remains = (1.0 - min(a.backup_rate * a.dt, 1.0)) ** max(1, round(h / a.dt))
    travel = held_travel(a, h, h)
    for i in range(vel.shape[0]):
        end_v[i] = vel[i] + travel * first[i]
        end_acc[i] = first[i] * remains
    mass = a.work.matrices[Matrix.ROLL_MASS]
    centre = rollout_payload(a)
    model_bias(a.model, end_v, 1.0, centre, 1.0, bias)
    model_friction(a.model, end_v, bias)
    for i in range(vel.shape[0]):
        torque = bias[i] + a.tau_d[i]
        for j in range(vel.shape[0]):
            torque += mass[i, j] * end_acc[j]
        if abs(torque) >= limit[i] * (1.0 - 1e-9):
            return False
    return True


@no_refcount_jit(cache=True, inline="always")
def later_deviation(a, h, eps, widen):
    """Over a free step of several holds, D later in it too: the tube's widening the largest
    of 1.5 D at the step's start, at the end of its first hold and at its end, each at the
    nominal velocity there under the q̈ of the hold that reaches it (Rollout.HELD_V,
    Rollout.HELD_ACC), the start's configuration. Along the step every joint's velocity
    departs from q̇_s + w by the same falling factor: the bias error's part linear in it is
    largest at an end; the friction's and the payload's need not be (docs/safety/filter.md,
    "Steps that grow"): D at the start alone was up to 26 times short in a grown step and
    4.3 times at a 2 ms step's end, at the ends alone 1.11 times
    (benchmarks/check_rollout.py --premise)."""
    r = a.work.rollout
    vel, first = r[Rollout.V], r[Rollout.HOLD_ACC]
    later_v, later_acc, deviation = r[Rollout.HELD_V], r[Rollout.HELD_ACC], r[Rollout.DEV]
    c = min(a.backup_rate * a.dt, 1.0)
    holds = max(1, round(h / a.dt))
    for reached in (1, holds):  # the first hold's end, the step's end
        travel = held_travel(a, h, reached * a.dt)
        for i in range(vel.shape[0]):
            later_v[i] = vel[i] + travel * first[i]
            later_acc[i] = first[i] * (1.0 - c) ** (reached - 1)
        # the payload's structure is the start's D's: the same configuration and M̂⁻¹
        deviation_bound(a, later_v, eps, later_acc, deviation, True)
        for i in range(vel.shape[0]):
            widen[i] = max(widen[i], TUBE_SAFETY * deviation[i])
