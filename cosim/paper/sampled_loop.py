"""Whether a controller's sampled loop is stable at the pipeline's step, before the run.

The master samples the state at t_k and holds the controller's torque over the step (a
zero-order hold). A light joint with stiff gains makes that loop unstable at 1 kHz long
before the continuous-time law would be: the run then diverges within milliseconds. Near
the reference the loop is linear. With the tracking error x = (e, ė), e = q_d − q, and a
feedback

    τ_fb = G(q) (K_p e + K_v ė),   G = I (gains in torque units) or M̂(q) (``scale =
    "inertia"``: gains in acceleration units, scaled by the nominal model's inertia),

the plant ë = −M(q)⁻¹ τ_fb (q̈_d and the slow parts, the NN's adaptation and the bias
forces, enter as inputs, not as feedback) sampled exactly over a step h gives

    x⁺ = Φ x,  Φ = [[I − (h²/2) A K_p,  h I − (h²/2) A K_v],
                    [−h A K_p,          I − h A K_v      ]],  A = M(q)⁻¹ G(q),

and a velocity read as the measured position's backward difference adds the previous
error to the state. The loop is stable at q if Φ's spectral radius is below 1. The check
takes q along the reference (what the run visits) and the plant's inertia M at both ends of
the declared payload range (the light end is the stiff one); the controller's linear gains
are the feedback that grows with the error (each controller's ``linear_gains``: a bounded
term, the paper's smooth sign, cannot make the loop diverge). The observer's error dynamics
are its own (the separation of a linear observer and controller; its sub-steps keep it
stable), so the velocity is taken as known. SI units, radians.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from ..dynamics.model import RigidBodyModel, model_geometry, model_mass, own_scratch
from ..schema import PipelineError

CONFIGURATIONS = 64  # positions along the reference the check takes, with its start


@dataclass(frozen=True)
class LinearGains:
    """A controller's feedback near the reference: τ_fb = G(q)(K_p e + K_v ė), per joint,
    in N·m/rad and N·m·s/rad (1/s² and 1/s when ``inertia_scaled``: G = M̂(q)); its
    velocity the true one or the measured position's backward difference."""

    position: np.ndarray
    velocity: np.ndarray
    inertia_scaled: bool = False
    difference: bool = False  # ė from (y_k − y_k−1)/h
    # a bounded term's gain near the reference, on r̂ = ė + Λe, per joint (the paper's
    # smooth sign and ψ_B terms: at most a fixed torque, so they cannot make the loop
    # diverge, only chatter), with its Λ; none for a controller without one
    bounded: np.ndarray | None = None
    bounded_lambda: np.ndarray | None = None

    def with_bounded(self) -> LinearGains:
        """The small-signal feedback, the bounded term's gain added."""
        if self.bounded is None:
            return self
        return LinearGains(self.position + self.bounded_lambda * self.bounded,
                           self.velocity + self.bounded, self.inertia_scaled, self.difference)


@dataclass(frozen=True)
class Worst:
    """The least stable case of a check: Φ's spectral radius there, the configuration
    (rad), the plant's payload (kg), the joint that moves most in its least stable mode
    (0-based) and that joint's inertia there (kg·m², or kg for a prismatic joint)."""

    radius: float
    q: np.ndarray
    payload: float
    joint: int
    inertia: float


def closed_loop(mass: np.ndarray, gain_matrix: np.ndarray, gains: LinearGains,
                h: float) -> np.ndarray:
    """Φ of the sampled loop (module docstring) for the plant's inertia ``mass`` (n×n) and
    the feedback's ``gain_matrix`` G (n×n: I, or M̂(q)) at the step ``h`` (s)."""
    n = len(mass)
    a = np.linalg.solve(mass, gain_matrix)
    kp, kv = a * gains.position, a * gains.velocity  # A K_p, A K_v (K diagonal: columns)
    eye = np.eye(n)
    if not gains.difference:
        return np.block([[eye - 0.5 * h * h * kp, h * eye - 0.5 * h * h * kv],
                         [-h * kp, eye - h * kv]])
    # ė read as (e_k − e_k−1)/h (the reference's own rate cancels in the error): the state
    # (e_k, ė_k, e_k−1), the feedback K_p e_k + K_v (e_k − e_k−1)/h.
    feedback = kp + kv / h
    zero = np.zeros((n, n))
    return np.block([[eye - 0.5 * h * h * feedback, h * eye, 0.5 * h * kv],
                     [-h * feedback, eye, kv],
                     [eye, zero, zero]])


def spectral_radius(matrix: np.ndarray) -> float:
    return float(np.max(np.abs(np.linalg.eigvals(matrix))))


@dataclass(frozen=True)
class Cases:
    """What the check runs over: per case the plant's inertia M and the feedback's gain
    matrix G at one configuration and payload."""

    masses: list[np.ndarray]
    gain_matrices: list[np.ndarray]
    positions: list[np.ndarray]
    payloads: list[float]


def cases(model: RigidBodyModel, positions: Sequence[np.ndarray],
          payloads: Sequence[float], inertia_scaled: bool) -> Cases:
    """The plant's M(q) at each position and payload (the nominal model's bodies, the
    payload at its payload point), and G: M̂(q) (no payload: the controller's model) when
    ``inertia_scaled``, else I."""
    model = own_scratch(model)
    out: Cases = Cases([], [], [], [])
    for q in positions:
        q = np.asarray(q, float)
        n = len(q)
        model_geometry(model, q)
        nominal = np.zeros((n, n))
        model_mass(model, 1.0, 0.0, nominal)
        for payload in payloads:
            mass = np.zeros((n, n))
            model_mass(model, 1.0, float(payload), mass)
            out.masses.append(mass)
            out.gain_matrices.append(nominal if inertia_scaled else np.eye(n))
            out.positions.append(q)
            out.payloads.append(float(payload))
    return out


def worst_case(loop_cases: Cases, gains: LinearGains, h: float) -> Worst:
    """The case whose Φ has the largest spectral radius, and the joint its least stable
    mode moves most (the largest entry of that eigenvector's error part)."""
    radii = [spectral_radius(closed_loop(m, g, gains, h))
             for m, g in zip(loop_cases.masses, loop_cases.gain_matrices, strict=True)]
    i = int(np.argmax(radii))
    mass = loop_cases.masses[i]
    values, vectors = np.linalg.eig(closed_loop(mass, loop_cases.gain_matrices[i], gains, h))
    n = len(mass)
    mode = np.abs(vectors[:, int(np.argmax(np.abs(values)))])
    joint = int(np.argmax(mode[:n] + mode[n:2 * n]))
    return Worst(radii[i], loop_cases.positions[i], loop_cases.payloads[i], joint,
                 float(mass[joint, joint]))


def largest_stable_step(loop_cases: Cases, gains: LinearGains, h: float) -> float:
    """The largest step (s) at which every case is stable, bisected below ``h`` (an unstable
    step) to 1 % (zero when the loop is unstable at any step: a negative gain)."""
    stable = 0.0
    low = h
    for _ in range(60):  # down to a stable step first
        low *= 0.5
        if worst_case(loop_cases, gains, low).radius < 1.0:
            stable = low
            break
    else:
        return 0.0
    unstable = 2.0 * stable
    while unstable - stable > 0.01 * stable:
        middle = 0.5 * (stable + unstable)
        if worst_case(loop_cases, gains, middle).radius < 1.0:
            stable = middle
        else:
            unstable = middle
    return stable


def reference_positions(reference, duration: float,
                        count: int = CONFIGURATIONS) -> list[np.ndarray]:
    """``count`` positions of the reference's q_d over the run, its start among them."""
    times = np.linspace(0.0, duration, count)
    return list(reference.evaluate(times)[0])


def check_step(block, published: Mapping[str, object], gains: LinearGains,
               keys: str, bounded_keys: str = "") -> str | None:
    """Refuse (:class:`PipelineError`) a controller ``block`` whose sampled loop is unstable
    at the master step anywhere along the reference (the constant ``reference_trajectory``)
    for the nominal model's inertia (``nominal_model``) at either end of the declared
    payload range, naming the joint, its inertia and the largest stable step; ``keys``:
    the gains that set its feedback ("controller.kv or kz"). Where only its bounded terms
    (``gains.bounded``, set by ``bounded_keys``) make the small-signal loop unstable, the
    run goes on (they cannot make it diverge) and what it will do is returned, to be said
    as the run starts. Without the model or the reference: nothing to check (None)."""
    model = published.get("nominal_model")
    reference = published.get("reference_trajectory")
    if model is None or reference is None:
        return None
    context = block.context
    low, high = map(float, context.uncertainty.payload)
    loop = cases(model, reference_positions(reference, context.duration),
                 sorted({low, high}), gains.inertia_scaled)
    worst = worst_case(loop, gains, context.dt)
    if worst.radius >= 1.0:
        raise PipelineError(
            f"run '{context.run}': the {block.name}'s gains make its sampled loop unstable at "
            + _unstable(published, loop, gains, worst, context.dt)
            + f"; lower {keys} or the step{_scale_hint(block, gains)}")
    small = gains.with_bounded()
    worst = worst_case(loop, small, context.dt)
    if worst.radius < 1.0:
        return None
    return (f"its bounded robust terms ({bounded_keys}) at r̂ = 0 make its sampled loop "
            f"chatter about the reference at this step, "
            + _unstable(published, loop, small, worst, context.dt)
            + f"; they cannot make it diverge, but the chatter drives the NN's weights: "
            f"lower {bounded_keys} or the step{_scale_hint(block, gains)}")


def _unstable(published: Mapping[str, object], loop: Cases, gains: LinearGains,
              worst: Worst, dt: float) -> str:
    """Where a sampled loop is unstable and the step it needs, for a message."""
    largest = largest_stable_step(loop, gains, dt)
    chain = published.get("nominal_urdf")
    name = f" ('{chain.joints[worst.joint]}')" if chain is not None else ""
    prismatic = chain is not None and int(chain.kind[worst.joint]) == 1
    where = ", ".join(f"{x:.3g}" for x in worst.q)
    return (f"simulation.step = {dt * 1e3:g} ms (spectral radius {worst.radius:.3g} > 1): "
            f"joint {worst.joint + 1}{name}, inertia {worst.inertia:.3g} "
            f"{'kg' if prismatic else 'kg·m²'} at the reference's q = [{where}] rad with a "
            f"payload of {worst.payload:g} kg, is stable up to a step of "
            f"{largest * 1e3:.3g} ms")


def _scale_hint(block, gains: LinearGains) -> str:
    return ("" if gains.inertia_scaled else
            f", or give {block.kind}.scale = \"inertia\" (gains in accelerations, scaled by "
            "each joint's inertia)")


# The viscous friction the observer's certified bound can hold at a step: its velocity box
# must be confirmed by the acceleration bound it implies, dt·|M̂⁻¹ B̂| r ≤ ρ, which needs
# dt·Σ_l |(M̂⁻¹)_il| b̂_l < 1 per joint i (the friction's error is bounded there, not used as
# the damping it is); half of that, for the rest of the bound.
FRICTION_STEP_SHARE = 0.5


def check_friction_step(block, published: Mapping[str, object]) -> None:
    """Refuse (:class:`PipelineError`) a nominal viscous friction too stiff for the master
    step: dt·Σ_l |(M̂⁻¹)_il| (b̂_l + |Δb_l|) ≥ FRICTION_STEP_SHARE for a joint i at a
    configuration of the reference (the light end of the payload range), naming the joint,
    its friction and inertia, and the step it needs. Without the model or the reference:
    nothing to check."""
    from ..dynamics.model import Friction

    model = published.get("nominal_model")
    reference = published.get("reference_trajectory")
    friction = getattr(model, "friction", None)
    if reference is None or friction is None or not np.any(friction[Friction.DAMPING]
                                                           + friction[Friction.DAMPING_ERROR]):
        return
    context = block.context
    damping = friction[Friction.DAMPING] + friction[Friction.DAMPING_ERROR]
    loop = cases(model, reference_positions(reference, context.duration),
                 [float(context.uncertainty.payload[0])], False)
    worst, where = 0.0, (0, 0)
    for index, mass in enumerate(loop.masses):
        rates = np.abs(np.linalg.inv(mass)) @ damping  # 1/s per joint
        joint = int(np.argmax(rates))
        if rates[joint] > worst:
            worst, where = float(rates[joint]), (index, joint)
    if context.dt * worst < FRICTION_STEP_SHARE:
        return
    index, joint = where
    mass = loop.masses[index]
    chain = published.get("nominal_urdf")
    name = f" ('{chain.joints[joint]}')" if chain is not None else ""
    raise PipelineError(
        f"run '{context.run}': joint {joint + 1}{name}'s viscous friction (the nominal model's "
        f"b̂ = {friction[Friction.DAMPING, joint]:g} N·m·s/rad, the URDF's <dynamics damping> "
        f"unless inertia_model.b) against its inertia {mass[joint, joint]:.3g} kg·m² damps in "
        f"{1e3 / worst:.3g} ms, too fast for simulation.step = {context.dt * 1e3:g} ms: the "
        "observer's certified bound takes friction as a bounded error, which holds for a "
        f"step up to {FRICTION_STEP_SHARE / worst * 1e3:.3g} ms; shorten the step, or leave "
        "that joint's friction out of the plant (plant.parameters.b[i]) and the nominal "
        "model (inertia_model.b)")
