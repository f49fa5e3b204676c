"""Two-layer NN tracking controller, eqs. (21)–(26), in two variants:

- ``baseline`` (Lewis 1999): full state, ė = q̇_d − q̇ with the true q̇ from the plant,
  robust term v = −Kz(‖Ẑ‖_F + Z_B) r;
- ``proposed`` (Theorem 2): output feedback, ė̂ = q̇_d − x̂2 from the observer, and v_c of
  (27), whose scalar middle term multiplies r̂ (a smooth sign):

    v_c = −Kz(‖Ẑ‖_F + Z_Wc) r̂ − [κ(Z_Wc + C1/κ)²/4 + C0] r̂ / √(δ + ‖r̂‖²) − e
          − ψ_B² r̂ / (δ + ‖r̂‖²).

τ = Ŵᵀσ̂(V̂ᵀξ) + Kv r̂ − v, ξ = [1; e; ė; q_d; q̇_d; q̈_d], σ̂ = [1; σ(V̂ᵀξ)] (logistic),
σ̂' = [0; diag(σ(1 − σ))]. Weights follow (25)–(26) with σ̂' in (26) (as in Lewis; the
printed σ̂ does not make the dimensions agree), integrated by Euler at the master rate with
the κ‖r̂‖ decay terms implicit so that they never overshoot. Ŵ starts at zero; V̂ at zero or,
as Lewis does, at small seeded random values (``init``), so that hidden units differ.
"""

from __future__ import annotations

from typing import Annotated, Literal, NamedTuple

import numpy as np
from numba import njit
from pydantic import Field

from ..blocks.base import Block, BlockContext, Ports, kernel_args, register_block
from ..blocks.binding import master_step, parameter, reads, scratch, writes
from ..records import kernel_record
from ..schema import (
    GainVector,
    NonNegativeFloat,
    PipelineError,
    PositiveFloat,
    Section,
    Seed,
    per_joint_array,
)
from ..signals import Signal
from .sampled_loop import LinearGains, check_step


class ControllerParams(Section):
    """Kv [N·m·s/rad], Λ [1/s], F, G (scalars × I), κ, Kz, Z_B or Z_Wc, C0, C1, δ, ψ_B,
    hidden width. Vectors may be given per joint or as one scalar."""

    # the controller (a name): "proposed", the paper's output-feedback controller, or
    # "baseline", Lewis's full-state one
    variant: Literal["baseline", "proposed"] = "proposed"
    # gain Kv on the filtered error r̂ in (22), per joint or one for all, N·m·s/rad
    kv: GainVector = 20.0
    # gain Λ of the filtered error r̂ = ė + Λe, per joint or one for all, 1/s
    lam: GainVector = Field(5.0, alias="lambda")
    # learning rate F of the output weights Ŵ in (25), a scalar times I, N·m/rad
    f: PositiveFloat = 10.0
    # learning rate G of the hidden weights V̂ in (26), a scalar times I, mixed units
    g: PositiveFloat = 12.0
    # κ of the weights' decay κ‖r̂‖ in (25)–(26) and of (27)'s middle term, 1/(N·m)
    kappa: PositiveFloat = 0.1
    # gain Kz of the robust term v = −Kz(‖Ẑ‖_F + Z)r̂ in (27) (and Lewis's), mixed units
    # (s/rad with the weights' norm in N·m)
    kz: NonNegativeFloat = 5.0
    # bound Z_B on the ideal weights' norm ‖Z‖ in the baseline's robust term (Lewis), mixed
    # units
    z_b: NonNegativeFloat = 10.0
    # bound Z_Wc on the ideal weights' norm in the proposed controller's v_c of (27), mixed
    # units
    z_wc: NonNegativeFloat = 10.0
    # constant C0 of Lemma 1's bound on the NN's error w_c, in (27)'s middle term, N·m
    c0: NonNegativeFloat = 150.0
    # constant C1 of Lemma 1's bound on the NN's error w_c, ‖w_c‖ ≤ C0 + C1‖Z̃‖ + …, in
    # (27)'s middle term, mixed units
    c1: NonNegativeFloat = 0.1
    # δ in (27)'s denominators √(δ + ‖r̂‖²) and δ + ‖r̂‖²: near r̂ = 0 the last term is a
    # gain ψ_B²/δ, (rad/s)²
    delta: PositiveFloat = 1.0
    # ψ_B of (27)'s last term −ψ_B² r̂/(δ + ‖r̂‖²) (Remark 4), √(N·m·rad/s)
    psi_b: NonNegativeFloat = 20.0
    # width of the NN's hidden layer, dimensionless (a count)
    hidden: Annotated[int, Field(ge=1, le=200)] = 10
    # where ė comes from (a name): "auto", the true q̇ for the baseline (Lewis's full state)
    # and the observer's x̂2 for the proposed controller; "plant"; "observer";
    # "finite_difference", the backward difference of the measured position,
    # (y_k − y_k−1)/h, which amplifies sensor noise
    velocity: Literal["auto", "plant", "observer", "finite_difference"] = "auto"
    # the initial weights (a name): Ŵ starts at zero; V̂ at zero ("zero") or, as Lewis does,
    # uniform in ±init_scale, seeded ("random")
    init: Literal["zero", "random"] = "zero"
    # half-width of V̂'s random initial weights, mixed units
    init_scale: NonNegativeFloat = 0.1
    # seed of the random initial weights, dimensionless
    seed: Seed = 0
    # the units of the gains and the NN's output (a name): "torque", as the paper gives
    # them (kv in N·m·s/rad, the robust terms and f̂ in N·m); "inertia", accelerations
    # scaled by the inertia model's M̂(q): τ = M̂(q)(f̂ + Kv r̂ − v), kv in 1/s, the robust
    # terms and f̂ in rad/s², so that one set of gains gives every joint of any arm the same
    # bandwidth (cosim.paper.sampled_loop checks the step either way)
    scale: Literal["torque", "inertia"] = "torque"


class NnGains(NamedTuple):
    """The gains the controller publishes (constant ``nn_gains``) for Theorem 1's R and
    barriers: Λ per joint (1/s), and the scalar adaptation gains F and G of (25)–(26)."""

    Lambda: np.ndarray
    F: float
    G: float


@kernel_record
class ControllerArgs(NamedTuple):
    dt: master_step()  # s
    proposed: bool
    finite_difference: bool  # velocity = backward difference of position
    f: parameter()
    g: parameter()
    kappa: parameter()
    kz: parameter()
    z_w: float  # Z_B (baseline) or Z_Wc (proposed)
    c0: parameter()
    c1: parameter()
    delta: parameter()
    psi_b: parameter()
    hidden: parameter()
    lam: parameter()  # (n,)
    kv: parameter()  # (n,)
    inertia_scaled: bool  # τ = M̂(q)(f̂ + Kv r̂ − v): scale = "inertia"
    M_model: np.ndarray  # M̂ per row (steps, n, n); (1, n, n) zeros when not scaled
    state: np.ndarray  # Ŵ ((hidden+1) × n), V̂ ((1+5n) × hidden), flat
    position: reads(chosen_by="position")  # q (baseline) or q_meas (proposed)
    velocity: reads(chosen_by="velocity")  # q̇ (baseline) or x̂2 (proposed)
    q_d: reads()
    qdot_d: reads()
    qddot_d: reads()
    tau: writes()
    e: writes()
    edot: writes()
    r_hat: writes()
    nn_output: writes()
    v_c: writes()
    W_norm: writes()
    V_norm: writes()
    feedback_gain: writes()
    # scratch, so that a step allocates nothing
    xi: scratch("1 + 5 * n")  # ξ
    act: scratch("hidden")  # V̂ᵀξ
    sig_hat: scratch("hidden + 1")  # σ̂
    back: scratch("hidden")  # σ̂'ᵀŴr̂
    feedback: scratch("n")  # the feedback Kv r̂ − v
    scaled: scratch("n")  # an acceleration's torque M̂a


@njit(cache=True)
def _torques(mass, vector, scratch):
    """``vector`` (accelerations, n) replaced by M̂ times it (torques); returns the square of
    its new norm."""
    n = vector.shape[0]
    for i in range(n):
        scratch[i] = 0.0
        for j in range(n):
            scratch[i] += mass[i, j] * vector[j]
    square = 0.0
    for i in range(n):
        vector[i] = scratch[i]
        square += scratch[i] * scratch[i]
    return square


@njit(cache=True, inline="always")
def _errors(k, a, e, edot, r, xi):
    """e, ė and r̂ = ė + Λe at step k (ė from the velocity read, or from the positions'
    difference), and the NN's input ξ = [1; e; ė; q_d; q̇_d; q̈_d]; returns ‖r̂‖²."""
    n = a.position.shape[1]
    r_sq = 0.0
    for i in range(n):
        e[i] = a.q_d[k, i] - a.position[k, i]
        if not a.finite_difference:
            velocity = a.velocity[k, i]
        elif k > 0:
            velocity = (a.position[k, i] - a.position[k - 1, i]) / a.dt
        else:
            velocity = a.qdot_d[0, i]
        edot[i] = a.qdot_d[k, i] - velocity
        r[i] = edot[i] + a.lam[i] * e[i]
        r_sq += r[i] * r[i]
        # ξ = [1; e; ė; q_d; q̇_d; q̈_d]
        xi[1 + i] = e[i]
        xi[1 + n + i] = edot[i]
        xi[1 + 2 * n + i] = a.q_d[k, i]
        xi[1 + 3 * n + i] = a.qdot_d[k, i]
        xi[1 + 4 * n + i] = a.qddot_d[k, i]
    xi[0] = 1.0
    return r_sq


@njit(cache=True, inline="always")
def _learn(a, W, V, r, r_norm):
    """The weight laws (25)-(26) over [t_k, t_k+1), the κ‖r̂‖ decay implicit:
    Ŵ⁺ = (Ŵ + dt F (σ̂ − σ̂'V̂ᵀξ) r̂ᵀ) / (1 + dt κ F ‖r̂‖),
    V̂⁺ = (V̂ + dt G ξ (σ̂'ᵀŴr̂)ᵀ) / (1 + dt κ G ‖r̂‖)."""
    n, hidden = W.shape[1], a.hidden
    n_in = V.shape[0]
    sig_hat, act, xi, back = a.sig_hat, a.act, a.xi, a.back  # scratch, this step's
    dt_f = a.dt * a.f
    shrink_w = 1.0 + a.dt * a.kappa * a.f * r_norm
    for m in range(hidden + 1):
        if m == 0:
            row = 1.0  # σ̂'s bias entry, whose σ̂' row is 0
        else:
            s = sig_hat[m]
            row = s - s * (1.0 - s) * act[m - 1]
        for i in range(n):
            W[m, i] = (W[m, i] + dt_f * (row * r[i])) / shrink_w
    dt_g = a.dt * a.g
    shrink_v = 1.0 + a.dt * a.kappa * a.g * r_norm
    for m in range(n_in):
        for j in range(hidden):
            V[m, j] = (V[m, j] + dt_g * (xi[m] * back[j])) / shrink_v


@njit(cache=True)
def controller_step(k, a):
    """One step of the NN controller (21)–(27) in one body, which its speed needs: loops
    over scratch arrays rather than numpy expressions (at n = 2 and 10 hidden units the
    temporaries and BLAS calls cost more than the arithmetic)."""
    n = a.position.shape[1]
    hidden = a.hidden
    n_in = 1 + 5 * n
    W = a.state[0:(hidden + 1) * n].reshape((hidden + 1, n))
    V = a.state[(hidden + 1) * n:(hidden + 1) * n + n_in * hidden].reshape((n_in, hidden))
    xi, act, sig_hat, back = a.xi, a.act, a.sig_hat, a.back  # scratch
    e, edot, r = a.e[k], a.edot[k], a.r_hat[k]  # written here, then read

    r_sq = _errors(k, a, e, edot, r, xi)
    # V̂ᵀξ, σ̂ = [1; σ(V̂ᵀξ)], and ‖V̂‖² on the same pass over V̂
    v_sq = 0.0
    for j in range(hidden):
        act[j] = 0.0
    for m in range(n_in):
        for j in range(hidden):
            act[j] += V[m, j] * xi[m]
            v_sq += V[m, j] * V[m, j]
    sig_hat[0] = 1.0
    for j in range(hidden):
        sig_hat[1 + j] = 1.0 / (1.0 + np.exp(-act[j]))
    # f̂ = Ŵᵀσ̂ (21), ‖Ŵ‖², and Ŵr̂ for (26)'s σ̂'ᵀŴr̂, on one pass over Ŵ
    f_hat = a.nn_output[k]
    for i in range(n):
        f_hat[i] = 0.0
    w_sq = 0.0
    for m in range(hidden + 1):
        w_r = 0.0
        for i in range(n):
            f_hat[i] += W[m, i] * sig_hat[m]
            w_sq += W[m, i] * W[m, i]
            w_r += W[m, i] * r[i]
        if m > 0:
            s = sig_hat[m]
            back[m - 1] = s * (1.0 - s) * w_r  # σ̂'ᵀŴr̂, σ̂' = diag(σ(1 − σ)) below its 0 row
    w_norm = np.sqrt(w_sq)
    v_norm = np.sqrt(v_sq)
    z_norm = np.sqrt(w_norm**2 + v_norm**2)  # ‖Ẑ‖_F, Ẑ = diag(V̂, Ŵ)
    r_norm = np.sqrt(r_sq)
    # v = −Kz(‖Ẑ‖_F + Z)r̂, and for the proposed controller the rest of (27): the smooth sign
    # r̂/√(δ + ‖r̂‖²) times κ(Z_Wc + C1/κ)²/4 + C0, −e, and −ψ_B² r̂/(δ + ‖r̂‖²)
    robust = -a.kz * (z_norm + a.z_w)
    sign_gain = (a.kappa * (a.z_w + a.c1 / a.kappa) ** 2 / 4.0 + a.c0) / np.sqrt(a.delta + r_sq)
    psi_gain = a.psi_b**2 / (a.delta + r_sq)
    v = a.v_c[k]
    feedback_sq = 0.0
    finite = w_norm + v_norm
    for i in range(n):
        v[i] = robust * r[i]
        if a.proposed:
            v[i] = v[i] - sign_gain * r[i] - e[i] - psi_gain * r[i]
        feedback = a.kv[i] * r[i] - v[i]
        a.feedback[i] = feedback
        feedback_sq += feedback * feedback
        a.tau[k, i] = f_hat[i] + feedback
        finite += a.tau[k, i]
    if a.inertia_scaled:  # accelerations: τ, f̂, v and the feedback's gain as torques, M̂ a
        feedback_sq = _torques(a.M_model[k], a.feedback, a.scaled)
        for vector in (a.tau[k], f_hat, v):
            _torques(a.M_model[k], vector, a.scaled)
            finite += np.sum(vector)
    a.W_norm[k] = w_norm
    a.V_norm[k] = v_norm
    a.feedback_gain[k] = np.sqrt(feedback_sq) / r_norm if r_norm > 0.0 else 0.0

    _learn(a, W, V, r, r_norm)
    return np.isfinite(finite)


@register_block
class NnController(Block):
    kind = "controller"
    Params = ControllerParams
    kernel = controller_step
    # nn_gains: NnGains (Λ, F, G), for Theorem 1's R and barriers; velocity_source: where ė
    # comes from ("plant", "observer" or "finite_difference").
    PUBLISHES = {"nn_gains": NnGains, "velocity_source": str}

    def __init__(self, params: ControllerParams, context: BlockContext):
        super().__init__(params, context)
        velocity = params.velocity
        if velocity == "auto":
            velocity = "plant" if params.variant == "baseline" else "observer"
        if velocity == "plant" and "qdot" not in context.plant_outputs:
            n = context.links
            who = ("the full-state baseline" if params.variant == "baseline"
                   else 'controller.velocity = "plant"')
            raise PipelineError(
                f"run '{context.run}': {who} reads the true joint velocity, but "
                f"{context.plant_file} has no qdot mapping (no outputs qdot[1]..qdot[{n}]); map "
                "them with plant.variables.qdot = [...] or drop the run")
        self.velocity_source = velocity
        self.chatter: str | None = None  # what the step check says of the robust terms
        self.publishes = {"nn_gains": kernel_args(
            NnGains, Lambda=per_joint_array(params.lam, context.links),
            F=params.f, G=params.g), "velocity_source": velocity}
        # Full state reads the plant's true q, q̇; output feedback only the sensor (and the
        # observer, or its own difference quotient).
        self.position, self.velocity = {"plant": ("q", "qdot"),
                                        "observer": ("q_meas", "qdot_hat"),
                                        "finite_difference": ("q_meas", "q_meas")}[velocity]
        self.inputs = tuple(dict.fromkeys((self.position, self.velocity, "q_d", "qdot_d",
                                           "qddot_d")))
        if params.scale == "inertia":
            self.inputs += ("M_model",)
        self.outputs = {
            "tau": Signal("n", "N·m", "joint torque τ", "controller/tau"),
            "e": Signal("n", "rad", "tracking error e = q_d − q", "controller/e"),
            "edot": Signal("n", "rad/s", "error rate ė (ė̂ for the proposed controller)",
                           "controller/edot"),
            "r_hat": Signal("n", "rad/s", "filtered error r̂ = ė̂ + Λe", "controller/r_hat"),
            "nn_output": Signal("n", "N·m", "NN output f̂ = Ŵᵀσ̂(V̂ᵀξ)",
                                "controller/nn_output", "f_hat"),
            "v_c": Signal("n", "N·m", "robust term v (v_c of (27))", "controller/v_c"),
            "W_norm": Signal("1", "-", "output weights ‖Ŵc‖", "controller/W_norm", "‖Ŵc‖"),
            "V_norm": Signal("1", "-", "hidden weights ‖V̂c‖", "controller/V_norm", "‖V̂c‖"),
            # In the trace files and summarised (metrics.feedback_gain), not recorded: the
            # recording's 40 MB budget goes to the safety checks (the true error rate).
            "feedback_gain": Signal("1", "N·m·s/rad", "effective feedback gain on r̂: "
                                    "‖Kv r̂ − v‖ / ‖r̂‖", kept=True),
        }

    def initial_weights(self) -> np.ndarray:
        """Ŵ(0) = 0 and V̂(0), flat as the kernel's state holds them."""
        p, n = self.params, self.context.links
        n_in = 1 + 5 * n
        weights = np.zeros((p.hidden + 1) * n + n_in * p.hidden)
        if p.init == "random":  # Lewis: V̂(0) small and random, so hidden units differ
            rng = np.random.default_rng(p.seed)
            weights[(p.hidden + 1) * n:] = rng.uniform(-p.init_scale, p.init_scale,
                                                       n_in * p.hidden)
        return weights

    def linear_gains(self) -> LinearGains:
        """The feedback near r̂ = 0: Kv plus the robust term's Kz(‖Ẑ(0)‖ + Z) at the initial
        weights on r̂ = ė + Λe, and for the proposed controller (27)'s −e, which grow with
        the error; and, bounded, (27)'s smooth-sign and ψ_B terms at their largest gain,
        (κ(Z_Wc + C1/κ)²/4 + C0)/√δ and ψ_B²/δ (their torque is at most
        κ(Z_Wc + C1/κ)²/4 + C0 and ψ_B²/(2√δ): they cannot make the loop diverge, only
        chatter). The robust term's gain grows with ‖Ẑ‖ as the weights adapt, which a check
        before the run cannot foresee."""
        p, n = self.params, self.context.links
        proposed = p.variant == "proposed"
        z_w = p.z_wc if proposed else p.z_b
        velocity = (per_joint_array(p.kv, n)
                    + p.kz * (np.linalg.norm(self.initial_weights()) + z_w))
        lam = per_joint_array(p.lam, n)
        bounded = None
        if proposed:
            bounded = np.full(n, (p.kappa * (z_w + p.c1 / p.kappa) ** 2 / 4.0 + p.c0)
                              / np.sqrt(p.delta) + p.psi_b ** 2 / p.delta)
        return LinearGains(lam * velocity + (1.0 if proposed else 0.0), velocity,
                           inertia_scaled=p.scale == "inertia",
                           difference=self.velocity_source == "finite_difference",
                           bounded=bounded, bounded_lambda=lam)

    def check(self, published) -> None:
        self.chatter = check_step(self, published, self.linear_gains(), "controller.kv or kz",
                                  "controller.c0, psi_b, or raise delta")

    def headline(self) -> str | None:
        return f"the controller: {self.chatter}" if self.chatter else None

    def reset(self, ports: Ports) -> None:
        p, n = self.params, self.context.links
        inp = ports.inputs
        self.args = self.bind(
            ControllerArgs, ports, proposed=p.variant == "proposed",
            finite_difference=self.velocity_source == "finite_difference",
            z_w=p.z_b if p.variant == "baseline" else p.z_wc,
            inertia_scaled=p.scale == "inertia",
            M_model=inp["M_model"] if p.scale == "inertia" else np.zeros((1, n, n)),
            state=self.initial_weights())
