"""D, the bound on the true q̈'s departure from the nominal model's that the check's tube
takes (:mod:`.check`): the bias error from the estimate's velocity error ε, the friction and
the disturbance (|M̂⁻¹(Δb + d)|, the hard rows' bound, see :mod:`.model`), at the rollout's
state, plus the payload's departure over the declared range (:func:`_payload_deviation`).
"""

from __future__ import annotations

from ...dynamics.model import model_payload
from ...numba_compat import no_refcount_jit
from ..linalg import dot
from .backup import rollout_payload
from .model import (
    friction_error_into,
    linear_error_bound_into,
    payload_structure,
    quadratic_error_into,
)
from .scratch import Matrix, PointRow, PointVector, Rollout, Square


@no_refcount_jit(cache=True)
def _payload_deviation(a, q_dot, acceleration, deviation, structure_taken):
    """D_i += the largest |q̈(Δm)_i − q̈(0)_i| over the payload range under the rollout's
    torque (the model's geometry at the rollout's state, its M̂⁻¹ in Matrix.ROLL_MINV and its q̈
    ``acceleration`` at the velocity ``q_dot``), Δm about the payload the rollout's model
    carries (:func:`rollout_payload`): from low − centre to high − centre.

    A point mass Δm at the payload point (Jacobian J, γ = J̇v − g) moves q̈ by
    −(M̂ + ΔmJᵀJ)⁻¹ΔmJᵀ(Jq̈(0) + γ) = −Σ_j α_j s_j(Δm) v_jᵀ(Jq̈(0) + γ), with
    K = JM̂⁻¹Jᵀ = Σ_j λ_j v_j v_jᵀ, α_j = v_jᵀJM̂⁻¹ and s_j = Δm/(1 + Δmλ_j) (Woodbury; the
    hard rows' structure, :func:`.model.payload_structure`). Linear in the s_j, which all
    increase with Δm: between two points of the payload grid the curve lies in their box,
    where a linear function's extremes are the sums of its terms' (each at one end). Not at
    the range's ends alone: the terms may cancel at both ends and not between (measured on
    the paper's arm braking near its bound: 0.75 rad/s² at the ends, 4.7 at Δm = 0.38 kg).
    Where M̂ is the plant's, the shift is −ΔmM̂⁻¹Jᵀγ: linear in Δm, largest at an end.

    ``structure_taken``: K's eigenvectors, the α_j and the s_j on the grid are in the work
    space already, taken at this configuration and M̂⁻¹ (they depend on nothing else): the
    D later in a step of several holds, at its start's configuration, after its start's D.
    On the Panda the structure is 0.57 of D's 1.35 µs."""
    if a.payload_low == 0.0 and a.payload_high == 0.0:
        return
    w = a.work
    minv = w.matrices[Matrix.ROLL_MINV]
    jac, gamma = w.point_rows[PointRow.JAC], w.point_vectors[PointVector.GAMMA]
    model_payload(a.model, q_dot, 1.0, jac, gamma)
    n, d = q_dot.shape[0], jac.shape[0]
    if a.inertia_is_plant:
        size = max(abs(a.payload_low), abs(a.payload_high))
        for i in range(n):
            shift = 0.0
            for col in range(n):
                for r in range(d):
                    shift += minv[i, col] * jac[r, col] * gamma[r]
            deviation[i] += size * abs(shift)
        return
    # γ + Jq̈(0) into γ: the point's acceleration the payload's force is proportional to
    for r in range(d):
        gamma[r] += dot(jac[r], acceleration)
    structure = w.point_vectors[PointVector.BETA]  # v_jᵀ(Jq̈(0) + γ), per eigenvector j
    if not structure_taken:
        centre = rollout_payload(a)  # the rollout's model carries it: Δm is taken about it
        payload_structure(a.payload_low - centre, a.payload_high - centre, minv, acceleration,
                          w.point_rows, w.point_vectors, w.squares, w.s_grid)
    vec = w.squares[Square.VEC]
    alpha, s_grid = w.point_rows[PointRow.ALPHA], w.s_grid
    grid = s_grid.shape[0] - 1
    for j in range(d):
        structure[j] = 0.0
        for r in range(d):
            structure[j] += vec[r, j] * gamma[r]
    for i in range(n):
        worst = 0.0
        for g in range(grid):  # the box between grid points g and g + 1: its extremes
            largest = least = 0.0
            for j in range(d):
                weight = -alpha[j, i] * structure[j]
                start, end = weight * s_grid[g, j], weight * s_grid[g + 1, j]
                largest += max(start, end)
                least += min(start, end)
            worst = max(worst, largest, -least)
        deviation[i] += worst


@no_refcount_jit(cache=True)
def fixed_deviation(a, spread):
    """D's part that a rollout with the velocity error ``spread`` keeps at every step, into
    Rollout.QUADRATIC (:func:`.model.quadratic_error_into`: Γ is the hard rows' for the whole
    rollout), so that :func:`deviation_bound` need not take it again."""
    w = a.work
    quadratic_error_into(spread, a.payload_low, a.payload_high, a.disturbance, w.forms[0],
                         w.forms[1], w.rollout[Rollout.QUADRATIC])


@no_refcount_jit(cache=True)
def deviation_bound(a, q_dot, spread, acceleration, deviation, structure_taken):
    """D at the rollout's state into ``deviation``: the bound on |M̂⁻¹(Δb + d)| for a
    velocity error up to ``spread`` (its fixed part taken by :func:`fixed_deviation`) at
    the velocity ``q_dot`` (b's velocity forms Γ as the hard rows took them at row k: the
    configuration's drift over the rollout is left out), plus the payload's
    (:func:`_payload_deviation`): the velocity's and the payload's departures add up (a
    payload's true q̈ also carries the velocity error's). ``structure_taken``: the payload's
    structure at this configuration is in the work space already (:func:`_payload_deviation`)."""
    w = a.work
    friction_error_into(a.model, q_dot, spread, w.rollout[Rollout.FRICTION])
    linear_error_bound_into(q_dot, spread, w.matrices[Matrix.ROLL_MINV], a.payload_low,
                            a.payload_high, w.forms[0], w.forms[1], w.linear,
                            w.rollout[Rollout.QUADRATIC], w.rollout[Rollout.FRICTION], deviation)
    _payload_deviation(a, q_dot, acceleration, deviation, structure_taken)
