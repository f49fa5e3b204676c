"""PD control with gravity compensation, a classical baseline without an observer:

    τ = Kp e + Kd ė + Ĝ(q),  e = q_d − q,  ė = q̇_d − q̇,

with Ĝ(q) the nominal model's gravity torque (constant ``nominal_model``, published by the
inertia model: the planar chain or a URDF's spatial chain) at the position the controller
reads. Two velocity sources: the plant's true q̇ with its true q (``plant``, full state), or
the backward difference of the measured position (``finite_difference``, (y_k − y_k−1)/h,
which amplifies sensor noise). With
Kp, Kd > 0 and exact gravity the set-point error converges (Takegaki & Arimoto 1981); it
tracks a moving reference with an error that grows with its speed. SI units, radians.
"""

from __future__ import annotations

from typing import Literal, NamedTuple

import numpy as np
from numba import njit

from ..blocks.base import Block, BlockContext, Ports, register_block
from ..blocks.binding import master_step, parameter, reads, scratch, writes
from ..dynamics.model import (
    RigidBodyModel,
    model_bias,
    model_geometry,
    own_scratch,
    planar_model,
)
from ..records import kernel_record
from ..schema import GainVector, NonNegativeFloat, PerJoint, Section, per_joint_array
from ..signals import Signal
from .sampled_loop import LinearGains, check_step


class PdControllerParams(Section):
    """Kp [N·m/rad] and Kd [N·m·s/rad], per joint or one scalar for all; where ė comes from;
    whether the nominal model's gravity torque is added (needs an inertia_model block
    before this one)."""

    # proportional gain Kp on the position error e, per joint or one for all, N·m/rad
    kp: GainVector = 200.0
    # derivative gain Kd on the error rate ė, per joint or one for all, N·m·s/rad
    kd: PerJoint[NonNegativeFloat] = 40.0
    # where ė comes from (a name): "plant", the true q̇, or "finite_difference", the
    # measured position's backward difference
    velocity: Literal["plant", "finite_difference"] = "plant"
    # whether the nominal model's gravity torque Ĝ(q) is added to τ (a flag)
    gravity_compensation: bool = True
    # the units of the gains (a name): "torque", Kp in N·m/rad and Kd in N·m·s/rad;
    # "inertia", accelerations scaled by the inertia model's M̂(q): τ = M̂(q)(Kp e + Kd ė)
    # + Ĝ(q), Kp in 1/s² and Kd in 1/s, the same bandwidth on every joint of any arm
    scale: Literal["torque", "inertia"] = "torque"


@kernel_record
class PdArgs(NamedTuple):
    dt: master_step()  # s
    finite_difference: bool
    gravity_compensation: parameter()
    kp: parameter()  # (n,)
    kd: parameter()  # (n,)
    inertia_scaled: bool  # τ = M̂(q)(Kp e + Kd ė) + Ĝ: scale = "inertia"
    M_model: np.ndarray  # M̂ per row (steps, n, n); (1, n, n) zeros when not scaled
    acceleration: scratch("n")  # Kp e + Kd ė when scaled
    model: RigidBodyModel  # the nominal model, for Ĝ(q)
    gravity_torque: scratch("n")
    zero_velocity: scratch("n")  # Ĝ is the bias at q̇ = 0
    position: reads(chosen_by="position")  # q (plant) or q_meas (finite difference)
    velocity: reads(chosen_by="velocity")  # q̇ (plant); unused for the finite difference
    q_d: reads()
    qdot_d: reads()
    tau: writes()
    e: writes()
    edot: writes()


@njit(cache=True)
def pd_step(k, a):
    q = a.position[k]
    if a.finite_difference:
        velocity = (q - a.position[k - 1]) / a.dt if k > 0 else a.qdot_d[0]
    else:
        velocity = a.velocity[k]
    e = a.q_d[k] - q
    edot = a.qdot_d[k] - velocity
    a.e[k] = e
    a.edot[k] = edot
    if a.inertia_scaled:
        a.acceleration[:] = a.kp * e + a.kd * edot
        mass = a.M_model[k]
        for i in range(len(e)):
            a.tau[k, i] = 0.0
            for j in range(len(e)):
                a.tau[k, i] += mass[i, j] * a.acceleration[j]
    else:
        a.tau[k] = a.kp * e + a.kd * edot
    if a.gravity_compensation:
        model_geometry(a.model, q)
        model_bias(a.model, a.zero_velocity, 1.0, 0.0, 1.0, a.gravity_torque)
        a.tau[k] += a.gravity_torque
    return np.isfinite(np.sum(a.tau[k]))


@register_block
class PdController(Block):
    kind = "pd_controller"
    Params = PdControllerParams
    kernel = pd_step
    PUBLISHES = {"velocity_source": str}  # "plant" or "finite_difference"

    def __init__(self, params: PdControllerParams, context: BlockContext):
        super().__init__(params, context)
        self.position, self.velocity = (("q", "qdot") if params.velocity == "plant"
                                        else ("q_meas", "q_meas"))
        self.inputs = tuple(dict.fromkeys((self.position, self.velocity, "q_d", "qdot_d")))
        if params.scale == "inertia":
            self.inputs += ("M_model",)
        self.requires = ("nominal_model",) if params.gravity_compensation else ()
        self.outputs = {
            "tau": Signal("n", "N·m", "joint torque τ", "pd_controller/tau"),
            "e": Signal("n", "rad", "tracking error e = q_d − q", "pd_controller/e"),
            "edot": Signal("n", "rad/s", "error rate ė = q̇_d − q̇ (or its difference "
                           "estimate)", "pd_controller/edot"),
        }
        self.publishes = {"velocity_source": params.velocity}

    def linear_gains(self) -> LinearGains:
        """Kp and Kd: the whole feedback (Ĝ(q) is slow)."""
        p, n = self.params, self.context.links
        return LinearGains(per_joint_array(p.kp, n), per_joint_array(p.kd, n),
                           inertia_scaled=p.scale == "inertia",
                           difference=p.velocity == "finite_difference")

    def check(self, published) -> None:
        check_step(self, published, self.linear_gains(), "pd_controller.kp or kd")

    def reset(self, ports: Ports) -> None:
        p, n = self.params, self.context.links
        model = ports.constants.get("nominal_model")
        if model is None:  # no gravity compensation: the model is never read
            zeros = np.zeros(n)
            model = planar_model(zeros, zeros, zeros, zeros, 0.0)
        inp = ports.inputs
        self.args = self.bind(
            PdArgs, ports, finite_difference=p.velocity == "finite_difference",
            inertia_scaled=p.scale == "inertia",
            M_model=inp["M_model"] if p.scale == "inertia" else np.zeros((1, n, n)),
            model=own_scratch(model))
