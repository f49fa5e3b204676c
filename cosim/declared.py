"""The pipeline sections that blocks read through their :class:`~cosim.blocks.BlockContext`
(one typed interface, no other block's table): the safe set and the declared uncertainty.
They import nothing of the blocks, so blocks may import them. SI units, radians."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field, model_validator

from .schema import FiniteFloat, NonNegativeFloat, PositiveFloat, Section


class Safety(Section):
    position_bound: PositiveFloat = 20.0  # α_max of ‖x1 − q_s‖, rad
    velocity_bound: PositiveFloat = 13.5  # α_max of ‖q̇ − q̇_s‖, rad/s
    error_bound: PositiveFloat = 1.0  # E1, rad
    error_rate_bound: PositiveFloat = 5.0  # E2, rad/s
    observer_error_bound: PositiveFloat = 1.0  # ε_max of (16)
    z_wo_tilde: PositiveFloat = 20.0  # Z̃_Wo, bound of (17) used in H1
    z_wc_tilde: PositiveFloat = 50.0  # Z̃_Wc, bound of (18) used in H2
    z_vc_tilde: PositiveFloat = 50.0  # Z̃_Vc, bound of (18) used in H2
    # α of the barrier condition Ḣ + α·H ≥ 0 (class-K, linear), 1/s
    barrier_alpha: PositiveFloat = 1.0


class Uncertainty(Section):
    """What the safety filter's guarantee assumes, declared: its margins are computed from
    these, and the evaluation checks every run against them (a run outside them is
    classified as such, never counted as a failure of the filter).

    - ``payload``: the range of mass (kg) added at the last link's centre of mass (its tip
      on the paper's arm): the plant's m[n] lies in nominal + [low, high].
    - ``noise_bound``: |q_meas − q| per joint, rad (Gaussian noise: take ~6σ).
    - ``initial_velocity_error``: |q̇(0) − x̂2(0)| per joint, rad/s.
    - ``disturbance``: |τ_d − τ_d,model| per joint, N·m.
    - ``observer_residual_rate``: a bound on the rate of the observer's unmodelled
      acceleration (rad/s³); with the observer's gains it bounds the part of its velocity
      error that its measured position error does not explain (README, "margins").
    """

    payload: Annotated[list[FiniteFloat], Field(min_length=2, max_length=2)] = [0.0, 0.0]
    noise_bound: NonNegativeFloat = 0.0
    initial_velocity_error: NonNegativeFloat = 0.0
    disturbance: NonNegativeFloat = 0.0
    observer_residual_rate: NonNegativeFloat = 4.0e4

    @model_validator(mode="after")
    def _ordered(self) -> Uncertainty:
        low, high = self.payload
        if low > high:
            raise ValueError(f"uncertainty.payload = [{low:g}, {high:g}]: give [low, high] "
                             "with low ≤ high, kg")
        return self


__all__ = ["PositiveFloat", "Safety", "Uncertainty"]
