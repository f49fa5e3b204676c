"""A robust output-feedback CBF-QP safety filter: after any nominal controller, the torque
closest to the nominal one that keeps the *true* state in the physical sets, for every plant
and state the declared uncertainty allows (docs/safety/filter.md).

Sets, per joint i, each side of |x_i| ≤ β a barrier h = β − side·x_i:

    hard (physical, the true state)      position  x = q − q_s      degree 2
                                         velocity  x = q̇ − q̇_s     degree 1
    soft (tracking, weighted)            error     x = q_d − y      degree 2
                                         error rate x = q̇_d − v    degree 1

(and soft as norms, h = β² − ‖x‖²), with the conditions ḧ + 2p ḣ + p² h ≥ 0 (degree 2, an
exponential CBF, critically damped) and ḣ + k h ≥ 0 (degree 1).

What the filter knows: the measured y, the velocity v it is given (the observer's x̂2, or the
plant's q̇ for a full-state run), the observer's bound ε(t) on |q̇ − v| and the drift of x̂2,
the inertia model M̂, and the nominal model (``nominal_model``, published by the inertia
model: the planar chain or a URDF's spatial chain, cosim.dynamics) for
b̂ = C(y, v) v + G(y) + τ_d. The plant is q̈ = M⁻¹(τ − b − τ_d), and what is declared
(``[uncertainty]``) bounds the difference:

- |q − y| ≤ n̄ (noise bound) and |q̇ − v| ≤ ε(t): the hard rows take the worst case of
  each (p²·n̄, 2p·ε and k·ε), and a velocity row the worst case of the true barrier,
  max(h − ε, 0) (it is ≥ 0 until the set is first left);
- a payload Δm ∈ [low, high] at the model's payload point c (the planar chain's last
  centre of mass, d = 2; a URDF's tip frame, d = 3), Jacobian J (d×n):
  M = M̂ + Δm JᵀJ, b = b̂ + Δm Jᵀγ with γ = J̇q̇ − g. Then exactly
  q̈ = u − M̂⁻¹Jᵀ S (J u + γ), u = M̂⁻¹(τ − b̂), S = Δm (I + Δm K)⁻¹, K = J M̂⁻¹ Jᵀ;
  in K's eigenvectors S is diagonal with entries s_j(Δm) increasing in Δm, and a row is
  linear in (s_1 … s_d). Split the range in ``payload_grid`` intervals: on each,
  (s_1 … s_d) lies in the box of its end values, so the worst case is at a box corner:
  (2^d − 1)G + 1 linear rows in τ (3G + 1 in the plane), never optimistic, exact as G
  grows. (When M̂ is the plant's own M, only b
  differs: q̈ = u − Δm M̂⁻¹Jᵀγ, the worst case at one end of the range.)
- b̂'s own error from the velocity error: b's velocity part is a quadratic form vᵀΓ_l v, so
  Δb = B δ + (δᵀΓ_l δ)_l with B_lj = 2 Σ_k Γ_l,jk v_k (Γ of the nominal model plus the
  payload's); a row of joint i is tightened by Σ_j |(M̂⁻¹B)_ij| ε_j (its worst end of the
  payload range) + Σ_l |(M̂⁻¹)_il| (Σ_jk |Γ_l,jk| ε_j ε_k + d̄), d̄ the disturbance bound.

Solved as min ½‖τ − τ_nom‖² + ½ρ_s‖s‖² subject to G_hard τ ≤ h_hard and
G_soft τ ≤ h_soft + s (and |τ_i| ≤ τ_max,i, hard), every row scaled to unit norm (N·m). The
compiled semismooth Newton solves the penalty form with the hard rows at weight ρ_hard and
their limits lowered by ``hard_tolerance`` (each Newton step a least-squares solve in
square-root form, to ~1e-13 of τ; started from the rows that bound at the step before,
which is the answer at once at 99.9 % of the paper's steps). The hard rows are kept in
groups, a joint's side of a set with a row per payload corner (:func:`.groups.hard_groups`),
and enter the solve only where it needs them (cutting planes, :func:`.groups.add_cuts`): it
solves over the soft rows and the torque limits, then again with every corner row its
answer violates or comes within ``hard_tolerance`` of, until there is none; a row left out
is then met with the tolerance to spare, so the answer is the whole QP's minimiser (the
Panda's ~1000 hard rows a step are a handful in the solve). Where a hard row still slips
(tracking pulling hard against it), it re-solves with the soft weights 1e-3 and 1e-6 times,
then without the soft rows. The rows' answer is a proposal: the torque applied is decided by
the **backup's check** (:mod:`.check`): the answer (clipped to the torque limits; the
controller's torque where the answer does not meet the hard rows within the limits) if the
braking backup can still keep every hard set after it, for every state and plant the
declared uncertainty allows; else the largest verified blend towards the backup; else the
backup (``cbf_infeasible`` = 1, ``cbf_viable`` = 0: the state was not viable as seen). With
``braking_torque`` below the limits, the backup first brakes within it (the block's
``choose`` in ``policy``; docs/safety/filter.md, "How hard the backup brakes").
``cbf_rows_met`` says where the applied torque met the rows as given. Soft slack is reported
apart (``cbf_slack``): it says how much tracking gave way, never whether safety did.

Remaining assumptions (not covered by the margins): those of the backup's check (its
module docstring), and M̂, b̂ evaluated at y rather than q (first order in n̄). The safe
centres q_s, q̇_s must be constant (Remark 1, case ii): a moving centre is refused.

The package, in the order a step runs it: ``scratch`` (the work arrays and the step's
arguments), ``model`` (M̂, b̂, the bias error, the payload), ``rows`` (the QP's rows),
``solver`` (the semismooth Newton), ``step`` (the kernel: rows, solve, record),
``interval`` (the true velocity's interval), ``backup`` (the braking backup and its check),
``policy`` (the torque applied: verified, blended or the backup's), ``steps`` (the steps
it supports), ``assumptions`` (what the filter publishes it assumes), ``block`` (the block:
parameters, signals, arguments); the small linear algebra is :mod:`cosim.paper.linalg`,
shared with the observer.

What a step runs is compiled without numba's reference counting
(:func:`cosim.numba_compat.no_refcount_jit`): it allocates nothing (every array it works in
is made at reset, and the compiler refuses an allocation in such a function), and counting
the references to the arrays it passes around cost more than its arithmetic (numba counts
one per array each time a tuple of them is bound, and the filter's arguments hold ~70:
measured ~1000 counting call sites in the step, and a helper taking two of a's arrays 44 ns a
call against 4 ns without). The arguments ``a`` are a kernel record
(:mod:`cosim.records`), one pointer however many arrays it holds, so the functions that
take it are compiled as functions of their own (inlining them into the step took minutes
to compile); the small helpers called in loops, which take arrays, are inlined.
"""

from .block import CbfFilter, CbfFilterParams
from .model import acceleration_error_bound, velocity_forms
from .rows import cbf_rows
from .scratch import CbfArgs
from .solver import solve_soft_qp
from .step import cbf_step

__all__ = ["CbfArgs", "CbfFilter", "CbfFilterParams", "acceleration_error_bound", "cbf_rows",
           "cbf_step", "solve_soft_qp", "velocity_forms"]
