"""The filter as a block: its parameters, its signals, what it publishes it assumes, and
the arguments its step (:mod:`.step`) is given at reset; the same step with a qpsolvers
solver in Python."""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import Field

from ...blocks.base import Block, BlockContext, Ports, register_block
from ...declared import joint_boxes
from ...dynamics.model import own_scratch, payload_dim
from ...schema import FiniteFloat, PerJoint, PipelineError, PositiveFloat, Section, per_joint_array
from ...signals import Signal
from .assumptions import BACKUP, FILTER_ASSUMES, KEPT_CHECKS, VIABLE, FilterAssumptions
from .check import verified
from .groups import payload_corners
from .rows import cbf_rows
from .scratch import SET_UNITS, SETS, CbfArgs, CbfWork
from .step import beyond_authority, cbf_record, cbf_step, within_authority
from .steps import check_step_range

HardSet = Literal["position", "velocity"]
SoftSet = Literal["error", "error_rate"]


class CbfFilterParams(Section):
    # the physical sets guaranteed per joint, "position" and true "velocity", names
    hard: list[HardSet] = ["position", "velocity"]
    # the tracking sets kept per joint where the hard ones allow, weighted, "error" and
    # "error_rate", names
    soft: list[SoftSet] = ["error", "error_rate"]
    # the tracking sets kept as norms, weighted, names
    soft_norms: list[SoftSet] = ["error", "error_rate"]
    # p of the hard degree-2 (position) conditions (k1 = 2p, k0 = p²), 1/s. A model error D
    # (rad/s²) keeps the joint D/p² from its bound and the velocity error ε keeps it 2ε/p:
    # a fast p costs less tracking where the reference runs along a bound; p·step ≪ 1.
    position_rate: PositiveFloat = 30.0
    # p of the soft error rows (degree 2), 1/s. A slow p also caps how fast an error may
    # shrink (ḧ ≥ −2p ḣ − p² h on the far side of the set), which holds a fast tracking
    # controller back: the tracking rows are as fast as the controller they watch.
    tracking_rate: PositiveFloat = 100.0
    # k of degree-1 conditions, 1/s: under a model error D (rad/s²) a velocity set keeps a
    # margin D/k, so a fast rate costs little; k·step ≪ 1 for the 1 ms hold.
    velocity_rate: PositiveFloat = 100.0
    # the velocity the filter is given (a name): "observer", x̂2 with its bound ε, or
    # "plant", the true q̇
    velocity: Literal["observer", "plant"] = "observer"
    # the fraction of every bound kept for the sampled-data hold between steps (1 ms),
    # dimensionless
    bound_margin: Annotated[float, Field(ge=0, lt=1)] = 0.002
    # the actuators' limits |τ_i| ≤ τ_max,i, per joint or one for all (unset: none), N·m:
    # never exceeded, the backup's torque included
    torque_limit: PerJoint[PositiveFloat] | None = None
    # what the tracking (soft) rows may ask of a joint's torque (a name): "limit", up to
    # the torque limit; or "controller", no more than the controller itself has asked of
    # that joint so far in the run (its largest |τ_nom,i|): a joint's torque goes past the
    # controller's only where the hard sets ask it (their rows alone, up to what they ask;
    # the backup)
    tracking_torque: Literal["limit", "controller"] = "limit"
    # the torque the backup brakes with wherever that is verified to keep the hard sets,
    # per joint or one for all, N·m (unset: the torque limits; a joint without a limit
    # ignores it): the limits beyond it are a reserve the backup uses only where braking
    # within it is not verified, or where nothing is (not viable as seen). It bounds the
    # backup, not the torque verified (a torque the QP asks above it is applied where
    # verified)
    braking_torque: PerJoint[PositiveFloat] | None = None
    # the start-up policy: the most the backup brakes with before the filter's first
    # viable step (an output-feedback start whose velocity interval is still too wide for
    # any torque to be verified), per joint or one for all, N·m (unset: the torque limits;
    # a joint without a limit ignores it). Such a run is not covered before that step
    # whatever this is (guarantee.covered_from_s); it trades start-up torque against how
    # far an unverified start may drift
    startup_torque: PerJoint[PositiveFloat] | None = None
    # weight ρ_s of a soft row's squared violation against τ's: high, so that tracking gives
    # way only where it conflicts with a hard row (ρ_hard is 1e4 times more), dimensionless
    tracking_weight: PositiveFloat = 1e6
    # weight ρ_hard of a hard row's squared violation in the penalty form (then checked
    # exactly), dimensionless
    hard_weight: PositiveFloat = 1e10
    # how far the hard limits are lowered, N·m
    hard_tolerance: PositiveFloat = 1e-4
    # what makes the hard sets hold (a name): "verified", every torque checked against the
    # braking backup (applied only if the backup can still keep every hard set after it,
    # for every state and plant the declared uncertainty allows; else blended towards it),
    # or "least_violation", the QP's answer alone (its hard rows assume unbounded torque)
    backup: Literal["verified", "least_violation"] = "verified"
    # rate k_b of the braking backup q̈ = k_b (w − (v − q̇_s)), 1/s
    backup_rate: PositiveFloat = 50.0
    # speed w at which the backup steers a joint outside its position set back in, rad/s
    recovery_speed: PositiveFloat = 2.0
    # rate at which a set already left must be regained in the backup's check: the excess
    # allowed decays as e^{−rate·t}, 1/s
    recovery_rate: PositiveFloat = 1.0
    # step of the backup's rollout (its first step is the control step), s: rounded to a
    # whole number of control steps, at least one
    backup_step: PositiveFloat = 0.002
    # longest step of the backup's rollout, s: a step where no torque limit binds and no
    # joint can reach the band near its position bound where the backup steers it doubles
    # from backup_step up to this (rounded to whole control steps; at most backup_step: no
    # step grows)
    backup_step_max: PositiveFloat = 0.016
    # longest the backup may take to stop every joint, s
    backup_horizon: PositiveFloat = 1.0
    # boxes over which the payload's worst case is taken, at their corners, covering the
    # curve (s_1(Δm), s_2(Δm)): exact as it grows, conservative by a box's size,
    # dimensionless (a count)
    payload_grid: Annotated[int, Field(ge=1, le=32)] = 4
    # the disturbance torque τ_d of the filter's model, per joint or one for all (unset:
    # the observer's), N·m
    tau_d: PerJoint[FiniteFloat] | None = None
    # the QP solver (a name): "newton", the compiled semismooth Newton, or a qpsolvers
    # solver: daqp, osqp, clarabel, proxqp, quadprog
    solver: str = "newton"
    # Newton steps at most per control step, dimensionless (a count)
    iterations: Annotated[int, Field(ge=1, le=1000)] = 50
    # the Newton solver's stopping tolerance on the gradient, relative to ‖τ_nom‖,
    # dimensionless
    tolerance: PositiveFloat = 1e-12


def filter_signals() -> dict[str, Signal]:
    """What the filter writes: its torque, each set's barrier values and active flags, and
    what the run's classifier reads to judge the guarantee and its premises."""
    outputs: dict[str, Signal] = {"tau": Signal("n", "N·m", "filtered torque τ", "cbf_filter/tau")}
    for name in SETS:
        unit = SET_UNITS[name]
        outputs[f"cbf_{name}"] = Signal(
            "n", unit, f"{name} set: β − |x_i| − its uncertainty (≥ 0 inside for every "
            "state the declared bounds allow)", f"cbf_filter/h/{name}", f"h_{name}")
        outputs[f"cbf_{name}_active"] = Signal(
            "n", "-", f"{name} set: a constraint of joint i active (1)",
            f"cbf_filter/active/{name}", f"active_{name}")
        outputs[f"cbf_{name}_norm"] = Signal(
            "1", unit, f"{name} set as a norm: β − ‖x‖", f"cbf_filter/h/{name}_norm",
            f"h_{name}_norm")
        outputs[f"cbf_{name}_norm_active"] = Signal(
            "1", "-", f"{name} norm constraint active (1)",
            f"cbf_filter/active/{name}_norm", f"active_{name}_norm")
    outputs.update({
        "cbf_slack": Signal("1", "N·m", "largest slack of a soft (tracking) row",
                            "cbf_filter/slack"),
        "cbf_active": Signal("1", "-", "number of active constraints",
                             "cbf_filter/active_count"),
        "cbf_correction": Signal("1", "N·m", "‖τ − τ_nom‖", "cbf_filter/correction"),
        "cbf_infeasible": Signal("1", "-", "1 where no torque was verified (the state was "
                                 "not viable as the filter saw it): the backup acted",
                                 "cbf_filter/infeasible"),
        VIABLE: Signal("1", "-", "1 where a verified torque existed: the backup could "
                       "keep every hard set under the declared uncertainty",
                       "cbf_filter/viable"),
        BACKUP: Signal("1", "-", "share of the braking backup in the torque (0 … 1)",
                       "cbf_filter/backup"),
        "cbf_planned": Signal("1", "-", "1 where the filter followed the plan in force, "
                              "no torque verified afresh: the plan's tube holds the state "
                              "there", kept=True),
        "cbf_velocity_centre": Signal("n", "rad/s", "centre of the interval the filter "
                                      "holds the true q̇ in", kept=True),
        "cbf_velocity_spread": Signal("n", "rad/s", "half-width of the interval the "
                                      "filter holds the true q̇ in", kept=True),
        "cbf_rows_met": Signal("1", "-", "1 where the torque applied met every hard row of "
                               "the QP as given (its conditions; the backup's check is "
                               "apart)", "cbf_filter/rows_met"),
        **{f"cbf_tube_{quantity}{part}": Signal(
            "n", unit, f"{what} of the box the plan in force at the step before puts the "
            f"true {quantity} in at this step (NaN: no plan)", kept=True)
           for quantity, unit in (("position", "rad"), ("velocity", "rad/s"))
           for part, what in (("", "centre"), ("_spread", "half-width"))},
        **{f"cbf_acceleration_{end}": Signal(
            "n", "rad/s²", f"{end} end of the check's bound on the true q̈ over the step "
            "held from this row", kept=True) for end in ("low", "high")},
    })
    return outputs


def rollout_step(backup_step: float, dt: float) -> float:
    """``backup_step`` (s) rounded to a whole number of control steps ``dt``, at least one:
    the check's rollout steps a whole number of the holds it models (the backup is applied
    and held at the control step; holds.feedback_contraction counts them)."""
    holds = max(1, round(backup_step / dt))
    return backup_step if abs(backup_step - holds * dt) <= 1e-9 * dt else holds * dt


@register_block
class CbfFilter(Block):
    kind = "cbf_filter"
    Params = CbfFilterParams
    PUBLISHES = {FILTER_ASSUMES: FilterAssumptions}
    views = (("h", "CBF barrier values β − |x| (≥ 0 inside)"),
             ("correction", "‖τ − τ_nom‖ (N·m)"))

    def __init__(self, params: CbfFilterParams, context: BlockContext):
        super().__init__(params, context)
        observer = params.velocity == "observer"
        self.position = "q_meas" if observer else "q"
        self.velocity = "qdot_hat" if observer else "qdot"
        extra = ("qdot_hat_bound", "qdot_hat_drift", "qdot_envelope_centre") if observer \
            else ()
        self.inputs = (self.position, self.velocity, *extra, "q_s", "qdot_s", "q_d", "qdot_d",
                       "qddot_d", "M_model", "tau")
        self.requires = ("nominal_model", "inertia_is_plant",
                         *(("tau_d_model",) if params.tau_d is None else ()))
        self.outputs = filter_signals()
        boxes = joint_boxes(context.safety, context.links)
        if params.torque_limit is not None:
            limit = params.torque_limit
        else:  # the robot's effort limits where the safe sets are its own limits, else none
            limit = np.inf if boxes is None else boxes.effort
        limit = per_joint_array(limit, context.links)
        if boxes is not None and {"position", "velocity"} & set(params.soft_norms):
            raise PipelineError(
                f"run '{context.run}': cbf_filter.soft_norms names the position or velocity "
                "set, but safety.limits = \"urdf\" makes them per-joint boxes, which have "
                "no norm; drop them from cbf_filter.soft_norms")
        keeps = tuple(KEPT_CHECKS[name] for name in params.hard)
        self.publishes = {FILTER_ASSUMES: FilterAssumptions(
            self.position, self.velocity, limit, np.zeros(context.links), keeps)}
        self.backup_step = rollout_step(params.backup_step, context.dt)
        self.backup_step_max = max(self.backup_step,
                                   rollout_step(params.backup_step_max, context.dt))
        # a rollout step where a torque limit binds is one control step (check.verified)
        self.segments = int(np.ceil(params.backup_horizon / context.dt)) + 2
        if params.solver == "newton":
            self.kernel = cbf_step
        else:
            self._check_solver(params.solver)

    def check(self, published) -> None:
        check_step_range(self, published)

    @staticmethod
    def _check_solver(name: str) -> None:
        try:
            import qpsolvers
        except ImportError:
            raise PipelineError(f"cbf_filter.solver = {name!r} needs qpsolvers (pip install "
                                "'qpsolvers[daqp]'); or use solver = \"newton\"") from None
        if name not in qpsolvers.available_solvers:
            raise PipelineError(f"cbf_filter.solver = {name!r} is not an installed QP solver "
                                f"(installed: newton, {', '.join(qpsolvers.available_solvers)})")

    def reset(self, ports: Ports) -> None:
        for centre in ("q_s", "qdot_s"):
            values = ports.inputs[centre]
            moving = np.ptp(values, axis=0) if len(values) else np.zeros(1)
            if np.any(moving > 0.0):
                raise PipelineError(
                    f"run '{self.context.run}': the cbf_filter block needs constant safe-set "
                    f"centres, but {centre} moves (by up to {float(np.max(moving)):.3g}); use "
                    "reference.safe_case = \"midpoint\" or drop the filter")
        self.args = self._arguments(ports)
        published = self.publishes[FILTER_ASSUMES]
        self.publishes[FILTER_ASSUMES] = published._replace(
            tau_d=self.args.tau_d.copy(), check_bounds=self.args.viable_bounds.copy())

    def _arguments(self, ports: Ports) -> CbfArgs:
        """The step's arguments: the parameters, the declared bounds, the trace's arrays it
        reads and writes, and its scratch."""
        p, n = self.params, self.context.links
        safety, uncertainty = self.context.safety, self.context.uncertainty
        inp, const = ports.inputs, ports.constants
        model = const["nominal_model"]
        tau_d = const["tau_d_model"] if p.tau_d is None else p.tau_d
        bounds = np.array([safety.position_bound, safety.velocity_bound, safety.error_bound,
                           safety.error_rate_bound]) * (1.0 - p.bound_margin)
        boxes = joint_boxes(safety, n)
        if boxes is None:  # the paper's radii about the (constant) centres q_s, q̇_s
            joint_bounds = np.broadcast_to(bounds[:2, None], (2, n)).copy()
            centres = np.array([inp["q_s"][0], inp["qdot_s"][0]], float).reshape(2, n)
        else:  # the robot's own limits, per joint
            joint_bounds = np.array([boxes.position_half, boxes.velocity_half]) \
                * (1.0 - p.bound_margin)
            centres = np.array([boxes.position_centre, boxes.velocity_centre])
        dim = payload_dim(model)
        corners = (2**dim - 1) * p.payload_grid + 1 if any(uncertainty.payload) else 1
        rows = 2 * (2 * n * 2 * corners) + 2 * n * 2 + 4 + 2 * n
        steps = len(ports.trace.time)
        if p.velocity == "observer":
            velocity_bound, drift = inp["qdot_hat_bound"], inp["qdot_hat_drift"]
            envelope_centre = inp["qdot_envelope_centre"]
        else:
            velocity_bound, drift = np.zeros((steps, n)), np.full((steps, n), np.nan)
            envelope_centre = inp[self.velocity]
        payload_low, payload_high = map(float, uncertainty.payload)
        limit = self.publishes[FILTER_ASSUMES].torque_limit
        braking = within_limits(limit, p.braking_torque)
        return self.bind(
            CbfArgs, ports, sizes={"rows": rows},
            **{name: np.array([float(s in getattr(p, name)) for s in SETS])
               for name in ("hard", "soft", "soft_norms")},
            bounds=bounds, joint_bounds=joint_bounds,
            viable_bounds=joint_bounds * (1.0 - 0.5 * p.bound_margin) / (1.0 - p.bound_margin),
            centres=centres, k1=2.0 * p.position_rate, k0=p.position_rate**2,
            tracking_k1=2.0 * p.tracking_rate, tracking_k0=p.tracking_rate**2,
            braking_torque=braking,
            braking_reserve=bool(np.any(braking < limit)),
            startup_torque=within_limits(limit, p.startup_torque),
            torque_limited=bool(np.any(np.isfinite(limit))),
            verify=p.backup == "verified",
            tracking_authority=p.tracking_torque == "controller" and any(
                getattr(p, name) for name in ("soft", "soft_norms")),
            backup_step=self.backup_step, backup_step_max=self.backup_step_max,
            payload_low=payload_low, payload_high=payload_high,
            inertia_is_plant=bool(const["inertia_is_plant"]),
            model=own_scratch(model),
            tau_d=per_joint_array(tau_d, n),
            velocity_bound=velocity_bound, drift=drift, envelope_centre=envelope_centre,
            **{field: _per_set(ports.trace, f"cbf_{{}}{suffix}", shape)
               for field, suffix, shape in (("h_sets", "", (steps, n)),
                                            ("active_sets", "_active", (steps, n)),
                                            ("h_norms", "_norm", (steps,)),
                                            ("active_norms", "_norm_active", (steps,)))},
            work=self.bind(CbfWork, ports, sizes={
                "rows": rows, "d": dim, "corners": (2**dim - 1) * p.payload_grid + 1,
                "segments": self.segments},
                corner_index=payload_corners(p.payload_grid, dim)))

    def warm_parts(self) -> list[tuple[object, tuple]]:
        """The check (:func:`.check.verified`, a third of the step's compile with the
        backup it rolls out), with the types the policy calls it with."""
        if self.kernel is None:
            return []
        from numba import typeof, types

        vector = typeof(np.zeros(self.context.links))
        return [(verified, (types.int64, typeof(self.args), vector, vector, vector, vector,
                            types.boolean, types.int64, vector))]

    def step(self, k: int) -> bool:
        """With a qpsolvers solver (no kernel): the same rows, the hard ones as hard
        constraints and the soft ones with an explicit slack, solved in Python."""
        import qpsolvers

        a = self.args
        count = cbf_rows(k, a)
        G, h = a.rows[:count], a.limits[:count]
        hard = a.is_hard[:count] > 0
        soft = ~hard
        n, m = G.shape[1], int(soft.sum())
        # variables [τ, s]: ½‖τ − τ_nom‖² + ½ρ_s‖s‖²; G_h τ ≤ h_h; G_s τ − s ≤ h_s; s ≥ 0
        P = np.diag(np.concatenate([np.ones(n), a.weights[:count][soft]]))
        q = np.concatenate([-a.tau_nominal[k], np.zeros(m)])
        G_full = np.block([[G[hard], np.zeros((int(hard.sum()), m))],
                           [G[soft], -np.eye(m)], [np.zeros((m, n)), -np.eye(m)]])
        h_full = np.concatenate([h[hard] - a.hard_tolerance, h[soft], np.zeros(m)])
        x = qpsolvers.solve_qp(P, q, G_full, h_full, solver=self.params.solver)
        tau = a.tau_nominal[k].copy() if x is None else x[:n]
        if a.tracking_authority and beyond_authority(k, a, tau):
            alone = qpsolvers.solve_qp(np.eye(n), -a.tau_nominal[k], G[hard],
                                       h[hard] - a.hard_tolerance, solver=self.params.solver)
            if alone is not None:
                within_authority(a, tau, alone)
        return cbf_record(k, a, count, tau)


def within_limits(limit: np.ndarray, value: float | list[float] | None) -> np.ndarray:
    """Per joint, ``value`` (one for all, or per joint; None: the limit) but at most the
    joint's torque limit; a joint without a finite limit keeps it (a torque bounded below
    no limit leaves no reserve), N·m."""
    if value is None:
        return limit
    wanted = np.broadcast_to(np.asarray(value, float), limit.shape)
    return np.where(np.isfinite(limit), np.minimum(limit, wanted), limit)


def _per_set(trace, pattern: str, shape: tuple[int, ...]) -> np.ndarray:
    """One array (4, *shape) for the four sets' outputs named ``pattern.format(set)``, the
    kernel's to index by set; the trace's arrays become views of it."""
    stacked = np.full((len(SETS), *shape), np.nan)
    for i, name in enumerate(SETS):
        trace.arrays[pattern.format(name)] = stacked[i]
    return stacked
