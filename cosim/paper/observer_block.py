"""The FLNN velocity observer as a block (:mod:`cosim.paper.observer`: its law and kernel):
its parameters, ports and what it publishes, and its kernel's record built at reset, with
the certified envelope behind ε(t) (:mod:`cosim.paper.envelope`). SI units, radians."""

from __future__ import annotations

import math
from typing import Annotated, Literal

import numpy as np
from pydantic import Field

from ..blocks.base import Block, BlockContext, Ports, register_block
from ..dynamics.model import own_scratch, payload_dim, planar_model
from ..schema import (
    FiniteFloat,
    NonNegativeFloat,
    PerJoint,
    PositiveFloat,
    Section,
    per_joint_array,
)
from ..signals import Signal
from .envelope import Envelope
from .inertia import InertiaModel, default_links
from .observer import ObserverArgs, basis_size, observer_step
from .sampled_loop import check_friction_step

LAWS = {"paper": 0, "error_driven": 1}
BASES = {"lagged": 0, "no_acceleration": 1}


class ObserverParams(Section):
    """Gains of (5)–(10) and (24); see the module docstring for ``law`` and ``basis``."""

    # gain kp of the output injection into the velocity estimate, x̂2 = ẑ2 + kp x̃1, 1/s
    kp: PositiveFloat = 100.0
    # gain kD of the output injection into the position estimate, x̂1' = x̂2 + kD x̃1, 1/s
    kd: PositiveFloat = 100.0
    # ν in the denominator of the gain k0 of (8), beside ‖x̃1‖²: the smaller, the larger k0
    # near x̃1 = 0, rad²
    nu: PositiveFloat = 5e-4
    # bound Z_Wo on the FLNN's ideal weights ‖Wo‖ (Assumption 4), in k0 of (8), mixed units
    z_wo: NonNegativeFloat = 10.0
    # bound ε_oM on the FLNN's approximation error, in k0 of (8), rad/s²
    eps_om: NonNegativeFloat = 1.0
    zeta_om: NonNegativeFloat = 1.0  # bound ζ_oM on the disturbance, in k0 of (8), rad/s²
    # learning rate Fo of the observer's weight law (24), a scalar times I, mixed units
    fo: PositiveFloat = 1.0
    # κo of the weight law: the value (24) draws Ŵo's entries to, or the factor of the
    # error-driven law's decay rate κo Fo ‖x̃1‖, mixed units
    kappa_o: NonNegativeFloat = 6.0
    # the weight law (a name): "paper", (24) as printed, or "error_driven", Kim & Lewis's
    law: Literal["paper", "error_driven"] = "error_driven"
    # the basis σo's acceleration q̂̈ (a name): "lagged", from the previous sub-step, or
    # "no_acceleration", dropped
    basis: Literal["lagged", "no_acceleration"] = "no_acceleration"
    # sub-steps of the observer's integration per master step, dimensionless (a count)
    substeps: Annotated[int, Field(ge=1, le=1000)] = 10
    # the disturbance torque τ_d that (7) assumes known, per joint or one for all, N·m
    tau_d: PerJoint[FiniteFloat] = 0.01
    # the initial velocity estimate x̂2(0): "desired", the reference's q̇_d(0), "zero", or
    # one value per joint, rad/s
    initial_velocity: Annotated[Literal["desired", "zero"] | list[FiniteFloat],
                                PerJoint.marker] = "desired"
    # longest window of the certified envelope's position-difference estimates of q̇ (ε(t),
    # cosim.paper.envelope), dimensionless (a count of steps)
    window: Annotated[int, Field(ge=1, le=10000)] = 16
    # cells of the declared payload range the envelope tracks apart, each dropped once the
    # measurements rule its payloads out (ε(t), cosim.paper.envelope), dimensionless (a count)
    payload_cells: Annotated[int, Field(ge=1, le=64)] = 4


@register_block
class FlnnObserver(Block):
    kind = "observer"
    Params = ObserverParams
    kernel = observer_step
    # tau_d_model: τ_d per joint (N·m), the disturbance (7) assumes; observer_gain: Fo of
    # (10), for H1 (28)
    PUBLISHES = {"tau_d_model": np.ndarray, "observer_gain": float}

    def __init__(self, params: ObserverParams, context: BlockContext):
        super().__init__(params, context)
        self.inputs = ("q_meas", "M_model", "q_d", "qdot_d")
        self.delayed = ("tau",)  # τ held over the previous step
        self.requires = ("nominal_model",)  # the certified envelope's model (ε(t))
        self.outputs = {
            "q_hat": Signal("n", "rad", "position estimate x̂1", "observer/q_hat",
                            estimates="q"),
            "qdot_hat": Signal("n", "rad/s", "velocity estimate x̂2", "observer/qdot_hat",
                               estimates="qdot"),
            "k0": Signal("1", "1/s²", "observer gain k0 of (8)", "observer/k0"),
            "W_o_norm": Signal("1", "-", "FLNN weight norm ‖Ŵo‖", "observer/W_norm", "‖Ŵo‖"),
            # For the safety filter and the evaluation; in the trace files, not recorded
            # (the recording shows ε(t) as the observer-error check's band).
            "qdot_hat_bound": Signal("n", "rad/s", "bound ε(t) on |q̇ − x̂2| per joint, from "
                                     "the declared uncertainty", kept=True),
            "qdot_hat_drift": Signal("n", "rad/s²", "dx̂2/dt − M̂⁻¹τ (its kp x̃2 term "
                                     "left out: unknown, |·| ≤ kp ε)", kept=True),
            # q̇ ∈ c ± (ε − |x̂2 − c|): the interval ε(t) is taken from, narrower than x̂2 ± ε
            # by 2|x̂2 − c| (the filter's backup check holds the velocity in it)
            "qdot_envelope_centre": Signal("n", "rad/s", "centre c of the certified velocity "
                                           "envelope (q̇ within ε − |x̂2 − c| of it)",
                                           kept=True),
        }
        self.publishes = {"tau_d_model": per_joint_array(params.tau_d, context.links),
                          "observer_gain": float(params.fo)}

    def check(self, published) -> None:
        check_friction_step(self, published)

    def reset(self, ports: Ports) -> None:
        p, n = self.params, self.context.links
        n_basis = basis_size(n, p.basis)
        if isinstance(p.initial_velocity, str):
            v0 = (ports.inputs["qdot_d"][0] if p.initial_velocity == "desired"
                  else np.zeros(n))
        else:
            v0 = np.asarray(p.initial_velocity, float)
        self.args = self.bind(
            ObserverArgs, ports, sizes={"n_basis": n_basis}, law=LAWS[p.law],
            basis=BASES[p.basis], eps_sum=p.eps_om + p.zeta_om, kp_kd=p.kp * p.kd,
            sqrt_basis=math.sqrt(n_basis), den_scale=2.0 * math.sqrt(p.kp * p.kd),
            n_basis=n_basis, initial_velocity=np.array(v0, float),
            env=self._envelope(ports, len(ports.inputs["q_meas"])))

    def _envelope(self, ports: Ports, steps: int) -> Envelope:
        """The envelope's constants (the nominal model the inertia model publishes, or the
        default chain when none is given, as in a unit test), state and scratch."""
        n, u = self.context.links, self.context.uncertainty
        model = ports.constants.get("nominal_model")
        if model is None:
            links = InertiaModel.chain_arrays(default_links(n))
            model = planar_model(**links, gravity=9.8)
        d = payload_dim(model)
        low, high = map(float, u.payload)
        cells = self.params.payload_cells if high > low else 1
        return self.bind(
            Envelope, ports, sizes={"P": cells, "steps": max(steps, 1), "d": d},
            model=own_scratch(model), payload_low=low, payload_high=high,
            cells=np.linspace(low, high, cells + 1), alive=np.ones(cells))
