"""The pipeline sections that blocks read through their :class:`~cosim.blocks.BlockContext`
(one typed interface, no other block's table): the safe set and the declared uncertainty.
They import nothing of the blocks, so blocks may import them. SI units, radians."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import Field, create_model, model_validator

from .schema import FileName, FiniteFloat, NonNegativeFloat, PipelineError, PositiveFloat, Section


class Safety(Section):
    """The safe sets every run is checked against. A package adds its own keys to this
    table with :func:`extend_safety` (the paper's barrier bounds); the pipeline's
    ``[safety]`` is then a :func:`safety_section`."""

    # radius α_max of the position set ‖x1 − q_s‖ ≤ α_max, per joint and as a norm, rad
    position_bound: PositiveFloat = 20.0
    # radius α_max of the velocity set ‖q̇ − q̇_s‖ ≤ α_max, per joint and as a norm, rad/s
    velocity_bound: PositiveFloat = 13.5
    error_bound: PositiveFloat = 1.0  # bound E1 of the tracking-error set ‖e‖ ≤ E1, rad
    error_rate_bound: PositiveFloat = 5.0  # bound E2 of the error-rate set ‖ė‖ ≤ E2, rad/s
    # where the per-joint position and velocity sets come from (a name): "radii", the
    # paper's |q_i − q_s,i| ≤ position_bound and |q̇_i − q̇_s,i| ≤ velocity_bound; "urdf",
    # the robot's own limits (``urdf``'s <limit>: lower + position_margin ≤ q_i ≤ upper −
    # position_margin, |q̇_i| ≤ velocity, |τ_i| ≤ effort), each overridable below
    limits: Literal["radii", "urdf"] = "radii"
    # the robot whose joint limits are the safe sets (limits = "urdf"), its chain from
    # ``urdf_base`` to ``urdf_tip`` as inertia_model.urdf reads it: a URDF file relative to
    # the pipeline file (to where cosim runs when given by --set) or package://…, a path
    urdf: FileName | None = None
    urdf_base: str | None = None  # the limits' URDF's base link (a name)
    urdf_tip: str | None = None  # the limits' URDF's tip link (a name)
    # joints of the limits' URDF held at a value (rad or m), as plant.urdf.fixed holds them:
    # not in the chain, so not among the safe sets
    urdf_fixed: dict[str, FiniteFloat] | None = None
    # the margin kept inside each URDF position limit (limits = "urdf"), rad (m: prismatic)
    position_margin: NonNegativeFloat = 0.0
    # per joint, instead of the URDF's: the position set's lower end (before the margin), rad
    position_lower: list[FiniteFloat] | None = None
    # per joint, instead of the URDF's: the position set's upper end (before the margin), rad
    position_upper: list[FiniteFloat] | None = None
    # per joint, instead of the URDF's: the velocity bound |q̇_i|, rad/s
    velocity_limit: list[PositiveFloat] | None = None
    # per joint, instead of the URDF's: the effort bound |τ_i|, N·m
    effort_limit: list[PositiveFloat] | None = None

    @model_validator(mode="after")
    def _limits_source(self) -> Safety:
        if self.urdf_fixed and (self.limits != "urdf" or self.urdf is None):
            raise ValueError("safety.urdf_fixed holds joints of safety.urdf, the limits' URDF: "
                             'give it with safety.limits = "urdf" and safety.urdf, or drop it')
        if self.limits == "urdf" and self.urdf is None and not (
                self.position_lower and self.position_upper and self.velocity_limit):
            raise ValueError('safety.limits = "urdf" needs safety.urdf (the robot\'s URDF, '
                             "a path or package://…), or position_lower, position_upper and "
                             "velocity_limit given per joint")
        return self


# Sections a package adds to [safety], in the order registered (extend_safety), and the
# [safety] built from them (one class per registry state).
_SAFETY_KEYS: list[type[Section]] = []
_SAFETY_SECTIONS: dict[tuple[type[Section], ...], type[Safety]] = {}


def extend_safety(keys: type[Section]) -> None:
    """Add the fields of ``keys`` (a :class:`~cosim.schema.Section`) to the pipeline's
    ``[safety]`` table: a package's own bounds on the sets it evaluates, declared in the
    package and read back with ``keys.model_validate`` of the run's safety (the paper's
    barrier bounds, cosim.paper.barrier_bounds). Call it when the package is imported;
    registering the same class twice adds it once."""
    if keys not in _SAFETY_KEYS:
        _SAFETY_KEYS.append(keys)


def safety_section() -> type[Safety]:
    """:class:`Safety` with the keys every package registered (:func:`extend_safety`)."""
    key = tuple(_SAFETY_KEYS)
    if not key:
        return Safety
    if key not in _SAFETY_SECTIONS:
        # the sets' keys first, then each package's in the order registered
        _SAFETY_SECTIONS[key] = create_model("Safety", __base__=(*reversed(key), Safety),
                                             __module__=__name__)
    return _SAFETY_SECTIONS[key]


class Uncertainty(Section):
    """What the safety filter's guarantee assumes, declared: its margins are computed from
    these, and the evaluation checks every run against them (a run outside them is
    classified as such, never counted as a failure of the filter).

    - ``payload``: the range [low, high] of mass added at the last link's centre of mass
      (its tip on the paper's arm), kg: the plant's m[n] lies in nominal + [low, high], so
      low > −m[n]; a URDF arm's payload is a point mass at its tip frame, low ≥ 0 (the
      inertia model refuses a range that allows a negative mass).
    - ``noise_bound``: bound on the sensor's error |q_meas − q| per joint, rad (Gaussian
      noise: take ~6σ).
    - ``initial_velocity_error``: bound on the observer's initial velocity error
      |q̇(0) − x̂2(0)| per joint, rad/s.
    - ``disturbance``: bound on the error of the disturbance model |τ_d − τ_d,model| per
      joint, N·m.
    - ``viscous_friction``: bound on the error of the nominal viscous friction
      |b_i − b̂_i| per joint (or one for all), N·m·s/rad: the true friction torque differs
      from the nominal model's (inertia_model.b, the URDF's <dynamics damping>) by at most
      that times |q̇_i|.
    - ``coulomb_friction``: bound on the error of the nominal Coulomb friction
      |fc_i − f̂c_i| per joint (or one for all), N·m (inertia_model.fc, the URDF's
      <dynamics friction>).
    - ``observer_residual_rate``: a bound J̄ on the rate of the observer's unmodelled
      acceleration, rad/s³, which the observer's bound ε(t) once rested on. No longer used
      by it: ε(t) is certified from the quantities above, the applied torque and the
      nominal chain (cosim/paper/envelope.py; docs/safety/filter.md, "How the margins follow
      from them"), since the closed loop broke any declared J̄. Kept so that pipelines that
      set it still load.
    """

    payload: Annotated[list[FiniteFloat], Field(min_length=2, max_length=2)] = [0.0, 0.0]
    noise_bound: NonNegativeFloat = 0.0
    initial_velocity_error: NonNegativeFloat = 0.0
    disturbance: NonNegativeFloat = 0.0
    viscous_friction: NonNegativeFloat | list[NonNegativeFloat] = 0.0
    coulomb_friction: NonNegativeFloat | list[NonNegativeFloat] = 0.0
    observer_residual_rate: NonNegativeFloat = 4.0e4

    @model_validator(mode="after")
    def _ordered(self) -> Uncertainty:
        low, high = self.payload
        if low > high:
            raise ValueError(f"uncertainty.payload = [{low:g}, {high:g}]: give [low, high] "
                             "with low ≤ high, kg")
        return self


@dataclass(frozen=True)
class JointBoxes:
    """The per-joint safe sets of the robot's own limits: |q_i − position_centre_i| ≤
    position_half_i (rad), |q̇_i − velocity_centre_i| ≤ velocity_half_i (rad/s) and
    |τ_i| ≤ effort_i (N·m; inf: none), each an (n,) array, and where they come from."""

    position_centre: np.ndarray
    position_half: np.ndarray
    velocity_centre: np.ndarray
    velocity_half: np.ndarray
    effort: np.ndarray
    source: str


@functools.lru_cache(maxsize=8)
def _urdf_limits(urdf: str, base: str | None, tip: str | None,
                 fixed: tuple[tuple[str, float], ...]) -> tuple:
    from plant_fmu.urdf import UrdfError, read_urdf, resolve_uri

    try:
        chain = read_urdf(resolve_uri(urdf, Path.cwd()), base=base, tip=tip,
                          fixed=dict(fixed), held_by="safety.urdf_fixed")
    except UrdfError as exc:
        raise PipelineError(f"safety.urdf: {exc}") from None
    return chain.joints, chain.lower, chain.upper, chain.velocity, chain.effort


def joint_boxes(safety: Safety, n: int) -> JointBoxes | None:
    """The robot's own limits as per-joint boxes (``safety.limits = "urdf"``), the URDF's
    overridden by the pipeline's per-joint values, a margin kept inside each position
    limit; None for the paper's radii. PipelineError naming the key when a joint has no
    finite position limit, a margin leaves no room, or a list has the wrong length."""
    if safety.limits != "urdf":
        return None
    source = (f"the pipeline's safety.position_lower/upper less safety.position_margin = "
              f"{safety.position_margin:g} rad, velocity_limit")
    lower = upper = velocity = effort = None
    if safety.urdf is not None:
        joints, lower, upper, velocity, effort = _urdf_limits(
            safety.urdf, safety.urdf_base, safety.urdf_tip,
            tuple(sorted((safety.urdf_fixed or {}).items())))
        if len(joints) != n:
            raise PipelineError(
                f"safety.urdf = {safety.urdf!r}: its chain has {len(joints)} moving joints "
                f"({', '.join(joints)}), the plant {n}: hold the joints the plant holds with "
                "safety.urdf_fixed = {JOINT = VALUE} (rad or m, as plant.urdf.fixed), or "
                "choose the chain with safety.urdf_base and safety.urdf_tip")
        source = (f"{safety.urdf}'s <limit>s, positions less safety.position_margin = "
                  f"{safety.position_margin:g} rad, overridden where the pipeline gives values")
    given = {"position_lower": lower, "position_upper": upper, "velocity_limit": velocity,
             "effort_limit": effort if effort is not None else np.full(n, np.inf)}
    values = {}
    for key, default in given.items():
        value = getattr(safety, key)
        if value is not None and len(value) != n:
            raise PipelineError(f"safety.{key}: {len(value)} values for {n} joints")
        values[key] = np.asarray(value if value is not None else default, float)
    lower = values["position_lower"] + safety.position_margin
    upper = values["position_upper"] - safety.position_margin
    if not np.all(np.isfinite(lower) & np.isfinite(upper)):
        bad = int(np.flatnonzero(~(np.isfinite(lower) & np.isfinite(upper)))[0]) + 1
        raise PipelineError(f"safety.limits = \"urdf\": joint {bad} has no finite position "
                            "limit (a continuous joint); give safety.position_lower and "
                            "position_upper, rad")
    if np.any(upper <= lower):
        bad = int(np.flatnonzero(upper <= lower)[0]) + 1
        raise PipelineError(f"safety.position_margin = {safety.position_margin:g} rad leaves "
                            f"joint {bad} no room between its position limits")
    if not np.all(np.isfinite(values["velocity_limit"])):
        bad = int(np.flatnonzero(~np.isfinite(values["velocity_limit"]))[0])
        name = f" ({joints[bad]}, <limit velocity> none or 0)" if safety.urdf is not None else ""
        raise PipelineError(f"safety.limits = \"urdf\": joint {bad + 1}{name} has no velocity "
                            "limit in the URDF; give safety.velocity_limit per joint, rad/s")
    return JointBoxes(0.5 * (lower + upper), 0.5 * (upper - lower), np.zeros(n),
                      values["velocity_limit"], values["effort_limit"], source)


__all__ = ["JointBoxes", "PositiveFloat", "Safety", "Uncertainty", "extend_safety", "joint_boxes",
           "safety_section"]
