"""The control steps the filter's check and the observer's certified bound support, checked
before the run: a step where their discretisation breaks is refused by name, with the range
that works.

Two things set the range (docs/safety/filter.md, "The steps it supports"):

- **The braking backup's hold.** Following its plan the filter applies the backup computed
  at each sample and held over the step h, and the check models the velocity's error under
  it as decaying by 1 − k_b h per hold (k_b = ``backup_rate``;
  holds.feedback_contraction). The held feedback v⁺ − w = (1 − k_b h)(v − w) overshoots
  its target for k_b h > 1 (deadbeat at 1): refused from k_b h ≥ 1. The check's rollout
  steps a whole number of holds (``backup_step`` rounded to a multiple of h, at least h).
- **The observer's certified bound ε(t)** (an output-feedback filter reads it). Each step
  the observer propagates its interval of q̇ with a bound on q̈ over the step, taken on an
  enclosure of q̇ that the bound itself must confirm, then narrows it by the position
  differences (cosim/paper/envelope.py). The velocity's uncertainty feeds back into that
  bound through b's velocity part and the viscous friction: per joint, the acceleration
  band's half-width grows by (G R)_i for an enclosure of half-widths R, with the nonnegative
  matrix G = |M(Δm)⁻¹ B(Δm, q̇)| + |M(Δm)⁻¹| diag(b̂ + |Δb|), B_lj = 2 Σ_k Γ_l,jk q̇_k the
  linear part of b(q̇ + δ) − b(q̇). The enclosure confirms only for an x = h ρ(G) < 1
  (ρ: the spectral radius), at R = (I − hG)⁻¹(r + …); the one-step position difference then
  gives the next half-width r' = 2n̄/h + ½ h G R + … = ½ x/(1 − x) r + …, so the error
  contracts step by step for x < 2/3 and grows past it (the paper's arm braking at 2 kN·m:
  ε stays ~0.5 rad/s at 3 ms, x = 0.56, and grows without bound at 4 ms, x = 0.74). The
  check asks x ≤ ½ (the error at least halved each step; the quadratic part and the
  enclosure's own widening take the rest), G at its largest over the states the sets allow:
  configurations along the reference, both ends of the declared payload range, every
  velocity in the velocity set (|(M⁻¹B)_ij| is convex in q̇, B linear: its largest at a
  corner, |Σ_k c_k A_ijk| + Σ_k r_k |A_ijk| for A = 2 M⁻¹Γ).

An observer whose bound does not contract runs soundly all the same (ε(t) grows, past a
point to infinity, and the filter then verifies nothing), but a filter resting on it is
useless: that is what is refused. SI units, radians.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from ...declared import joint_boxes
from ...dynamics.model import Friction, model_geometry, model_mass, own_scratch
from ...schema import PipelineError
from ..sampled_loop import CONFIGURATIONS, reference_positions
from .model import velocity_forms_into
from .scratch import POLAR_ROWS

# The largest h ρ(G) the observer's bound is asked to keep: its error at least halved each
# step (½ x/(1 − x) ≤ ½ at x = ½), against the 2/3 where it stops contracting.
ENVELOPE_SHARE = 0.5


def envelope_gain(model, positions, payloads, velocity_centre: np.ndarray,
                  velocity_half: np.ndarray, friction: np.ndarray | None
                  ) -> tuple[float, np.ndarray, float]:
    """The largest spectral radius of G (module docstring) over ``positions`` and
    ``payloads`` (kg at the model's payload point), every velocity within ``velocity_half``
    of ``velocity_centre`` (rad/s), 1/s; with the configuration and the payload it is
    largest at."""
    model = own_scratch(model)
    n = len(velocity_centre)
    damping = np.zeros(n) if friction is None \
        else friction[Friction.DAMPING] + friction[Friction.DAMPING_ERROR]
    polar = np.zeros((POLAR_ROWS, n))
    worst = (0.0, np.zeros(n), 0.0)
    for q in positions:
        q = np.asarray(q, float)
        bodies, point = np.zeros((n, n, n)), np.zeros((n, n, n))
        velocity_forms_into(model, q, 1.0, 0.0, polar, bodies)
        velocity_forms_into(model, q, 0.0, 1.0, polar, point)
        for payload in payloads:
            mass = np.zeros((n, n))
            model_geometry(model, q)
            model_mass(model, 1.0, float(payload), mass)
            inverse = np.linalg.inv(mass)
            slopes = 2.0 * np.einsum("il,ljk->ijk", inverse, bodies + payload * point)
            gain = (np.abs(slopes @ velocity_centre) + np.abs(slopes) @ velocity_half
                    + np.abs(inverse) * damping)
            radius = float(np.max(np.abs(np.linalg.eigvals(gain))))
            if radius > worst[0]:
                worst = (radius, q, float(payload))
    return worst


def check_step_range(block, published: Mapping[str, object]) -> None:
    """Refuse (:class:`PipelineError`) the filter ``block`` at a master step its check or
    the observer's bound it reads does not support (module docstring), naming the key, the
    value, why, and the steps that work. Without the model or the reference: the bound is
    not checked."""
    p, context = block.params, block.context
    dt = context.dt
    if p.backup == "verified" and p.backup_rate * dt >= 1.0:
        raise PipelineError(
            f"run '{context.run}': simulation.step = {dt * 1e3:g} ms is too long for the "
            f"filter's braking backup: held over a step h its feedback k_b h = "
            f"{p.backup_rate * dt:.3g} ≥ 1 overshoots the velocity it brakes to, which its "
            f"check does not model (cbf_filter.backup_rate = {p.backup_rate:g} 1/s); the "
            f"filter supports steps below {1e3 / p.backup_rate:.3g} ms at this backup_rate: "
            "shorten the step or lower cbf_filter.backup_rate")
    model = published.get("nominal_model")
    reference = published.get("reference_trajectory")
    if p.velocity != "observer" or model is None or reference is None:
        return
    boxes = joint_boxes(context.safety, context.links)
    if boxes is None:  # the paper's sets: |q̇ − q̇_s| ≤ α_v, q̇_s the reference's midpoint
        rates = reference.evaluate(np.linspace(0.0, context.duration, CONFIGURATIONS))[1]
        centre = 0.5 * (rates.max(axis=0) + rates.min(axis=0))
        half = np.full(context.links, context.safety.velocity_bound)
    else:
        centre, half = boxes.velocity_centre, boxes.velocity_half
    low, high = map(float, context.uncertainty.payload)
    radius, q, payload = envelope_gain(
        model, reference_positions(reference, context.duration), sorted({low, high}),
        centre, half, getattr(model, "friction", None))
    if dt * radius <= ENVELOPE_SHARE:
        return
    where = ", ".join(f"{x:.3g}" for x in q)
    raise PipelineError(
        f"run '{context.run}': simulation.step = {dt * 1e3:g} ms is too long for the "
        "observer's certified velocity bound ε(t), which the filter reads "
        "(cbf_filter.velocity = \"observer\"): within the velocity set the velocity's "
        f"uncertainty feeds the arm's acceleration bound back at up to {radius:.3g} 1/s "
        f"(b's velocity part and the viscous friction through M⁻¹, at q = [{where}] rad "
        f"with a payload of {payload:g} kg), and h·{radius:.3g} 1/s = {dt * radius:.3g} > "
        f"{ENVELOPE_SHARE:g} does not shrink the bound from step to step; the filter supports "
        f"simulation.step up to {ENVELOPE_SHARE / radius * 1e3:.3g} ms here: shorten the "
        "step, or give cbf_filter.velocity = \"plant\" (the true velocity)")
