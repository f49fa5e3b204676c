"""The filter's work arrays and arguments: what a step reads and writes, made once at reset
(a step allocates nothing), and the names of their rows."""

from __future__ import annotations

from enum import auto
from typing import NamedTuple

import numpy as np

from ...blocks.binding import (
    master_step,
    parameter,
    published,
    reads,
    scratch,
    uncertainty,
    writes,
)
from ...dynamics.model import RigidBodyModel
from ...records import Rows, kernel_record
from .assumptions import BACKUP, FILTER_ASSUMES, VIABLE

SETS = ("position", "velocity", "error", "error_rate")
SET_UNITS = {"position": "rad", "velocity": "rad/s", "error": "rad", "error_rate": "rad/s"}

# The filter's scratch, made once at reset (a step allocates nothing), is a few arrays with
# named rows: each array's rows are a Rows class (cosim.records), numbered by their
# order, whose count its shape names. Both records are kernel records (cosim.records):
# compiled code takes each as one pointer, however many arrays it holds.


class Polar(Rows):
    """Rows of CbfWork.polar (n each)."""

    E = auto()  # the polarisation's velocity
    PLUS = auto()  # its biases


POLAR_ROWS = len(Polar)  # for the kernels that make their own (len of a class: Python's)


class Solver(Rows):
    """Rows of CbfWork.solver and .backup_solver (n each)."""

    TAU = auto()  # the iterate (then the answer)
    TRIAL = auto()  # the line search's point
    GRADIENT = auto()
    DIRECTION = auto()  # the step
    ROTATED = auto()  # a row being rotated into R


class Vector(Rows):
    """Rows of CbfWork.vectors (n each)."""

    BIAS = auto()  # b̂ at (y, v)
    MOVED_BIAS = auto()  # b̂ at a predicted state
    BASE = auto()  # M̂⁻¹b̂ at (y, v)
    BASE_END = auto()  # … at the hold's end
    BASE_MID = auto()  # … and at its midpoint
    ACCELERATION = auto()  # the nominal model's q̈ under the held torque
    Y_END = auto()  # the state predicted at the hold's end
    V_END = auto()
    Y_MID = auto()  # … and at its midpoint
    V_MID = auto()
    DRIFT = auto()  # dv/dt − M̂⁻¹τ
    ROW = auto()  # a row before its scaling
    QUADRATIC = auto()  # the bias error's quadratic part
    ROWS_ERROR = auto()  # … and its bound on |M̂⁻¹(Δb + d)|
    PLANT_SHIFT = auto()  # M̂⁻¹Jᵀγ when M̂ is the plant's
    # per joint, the most a hard row's g·τ reaches within the torque limits, and the most
    # its payload corners lower its limit (groups.py, _reach)
    REACH = auto()
    ROOM = auto()
    FRICTION = auto()  # the friction's error per joint at (y, v)
    X = auto()  # each set's x, SETS order: this row and the three below
    X_VELOCITY = auto()
    X_ERROR = auto()
    X_ERROR_RATE = auto()


class Matrix(Rows):
    """Of CbfWork.matrices (n×n each)."""

    NOMINAL_NOW = auto()  # the nominal model's M at y
    NOMINAL = auto()  # … and at a predicted position
    SHIFTED = auto()  # M̂ moved there
    MINV = auto()  # M̂⁻¹ at y
    MINV_END = auto()  # … at the hold's end
    MINV_MID = auto()  # … and at its midpoint
    LU = auto()  # elimination scratch
    FACTOR = auto()  # R
    # the backup's rollout (cosim.paper.cbf_filter.check): M at its state, M⁻¹, scratch, R
    ROLL_MASS = auto()
    ROLL_MINV = auto()
    ROLL_LU = auto()
    BACKUP_FACTOR = auto()


class Rollout(Rows):
    """Rows of CbfWork.rollout (n each)."""

    Q = auto()  # the rollout's state
    V = auto()
    DQ = auto()  # the tube's half-widths δq, δv
    DV = auto()
    TAU = auto()  # its torque
    ACC = auto()  # nominal q̈
    BIAS = auto()  # b̂
    DEV = auto()  # the bound D on q̈'s departure
    LIMIT_Q = auto()  # what each set allows
    LIMIT_V = auto()
    TARGET = auto()  # the backup's target velocities
    SCRATCH = auto()
    CANDIDATE = auto()  # a blend of the QP's torque and the backup's
    # the true velocity's interval at this step (its centre and half-width), and the one
    # predicted for the next step
    CENTRE = auto()
    HALF = auto()
    NEXT_LOW = auto()
    NEXT_HIGH = auto()
    WEIGHT = auto()  # the backup's √weight per joint
    # D's part that is fixed over a rollout (the bias error's quadratic part and the
    # disturbance, per row of b)
    QUADRATIC = auto()
    FRICTION = auto()  # the friction's error per joint at the rollout's state
    WIDEN = auto()  # the tube's widening per step (TUBE_SAFETY D)
    # the box the plan predicts for the true state at the next step (position centre and
    # half-width, velocity centre and half-width)
    BOX_Q = auto()
    BOX_Q_HALF = auto()
    BOX_V = auto()
    BOX_V_HALF = auto()
    ACC_LOW = auto()  # the check's bound on the true q̈ over the held step, its low end
    ACC_HIGH = auto()  # … and its high end
    # the held step's start (q, q̇, q̈) while the check looks at its predicted end
    HELD_Q = auto()
    HELD_V = auto()
    HELD_ACC = auto()
    HOLD_ACC = auto()  # the rollout's q̈ over its step's first hold (.holds.held_average)
    # the last check's candidate step: its torque, start (q, q̇ and its half-width) and the
    # hull of q̈ it took, the interval's prediction for that torque (.holds.held_drift)
    CHECKED_TAU = auto()
    CHECKED_Q = auto()
    CHECKED_V = auto()
    CHECKED_HALF = auto()
    CHECKED_LOW = auto()
    CHECKED_HIGH = auto()


class Flag(Rows):
    """Of CbfWork.flags (one each; a row of their own: an arm of one joint has a rollout row
    of one)."""

    CONSISTENT = auto()  # 1 where the velocity's intervals met at this step
    PLAN = auto()  # the backup policy of the last torque verified
    # 1 where that torque was verified with the backup within the torque limits, 0 within
    # braking_torque
    PLAN_RESERVE = auto()
    GROUPS = auto()  # the number of hard row groups at this step
    # the tube's buffers (CbfWork.tube): the one a check writes its rollout into, the one
    # that holds the rollout of the last torque verified, the step it was verified at
    TUBE_TRIAL = auto()
    PLAN_TUBE = auto()
    PLAN_STEP = auto()
    VIABLE_ONCE = auto()  # 1 from the run's first viable step on (before it: start-up)
    CHECKED_ROW = auto()  # k + 1 for the row whose check kept its candidate's hull, else 0


class Tube(Rows):
    """Of CbfWork.tube[buffer, segment] (n each): a rollout's segment, kept so that the plan
    it verified can say where it puts the true state later (the tube measured along the
    run). CbfWork.tube_steps[buffer, segment] holds the segment's length, s (0 past the
    rollout's last segment)."""

    Q = auto()  # the nominal state at its start
    V = auto()
    DQ = auto()  # the tube's half-widths there
    DV = auto()
    ACC_FIRST = auto()  # its nominal q̈ over its first hold
    WIDEN = auto()  # the tube's widening (TUBE_SAFETY D)
    FEEDBACK = auto()  # the share of δv the backup's feedback removes over it


# The hard rows in groups (cosim.paper.cbf_filter.rows): a joint's side of a hard set, now or
# at the hold's end, one row per payload corner c, g_c = g_0 + Σ_j s_cj u_j with the limit
# h_c = h_0 + Σ_j s_cj o_j (unscaled). CbfWork.group_added flags the corners already among
# the QP's rows.


class GroupValue(Rows):
    """Of CbfWork.group_values (one each)."""

    H_ZERO = auto()  # h_0
    NORM_BOUND = auto()  # a bound on every ‖g_c‖
    OFFSETS = auto()  # o_1 … o_d: this row and the d − 1 after it


class GroupLabel(Rows):
    """Of CbfWork.group_labels (one each)."""

    SET = auto()
    JOINT = auto()
    PHASE = auto()  # 0 now, 1 at the hold's end: the row of CbfWork.s_phase its s_cj are in
    CORNERS = auto()  # the number of corners


class Authority(Rows):
    """Of CbfWork.authority (n each), tracking_torque = "controller"."""

    PEAK = auto()  # the largest |τ_nom,i| so far
    # the QP's answer with the tracking rows while the hard rows' alone is solved
    ANSWER = auto()


# The payload's structure, its point of d coordinates (the model's dim: 2 in the plane, 3 in
# space).


class PointRow(Rows):
    """Of CbfWork.point_rows (d×n each)."""

    JAC = auto()  # J of its point
    JM = auto()  # J M̂⁻¹
    ALPHA = auto()  # α


class PointVector(Rows):
    """Of CbfWork.point_vectors (d each)."""

    GAMMA = auto()  # γ = J̇v − g
    JB = auto()  # J M̂⁻¹b̂
    LAM = auto()  # K's eigenvalues (ascending)
    BETA = auto()  # β


class Square(Rows):
    """Of CbfWork.squares (d×d each)."""

    KMAT = auto()  # K = J M̂⁻¹ Jᵀ
    VEC = auto()  # its eigenvectors (columns)
    EIGEN = auto()  # the eigensolver's scratch


@kernel_record
class CbfWork(NamedTuple):
    """The filter's scratch: n joints, at most ``rows`` rows, the payload's point of d
    coordinates, ``corners`` = (2^d − 1) payload_grid + 1 box corners, rollouts of at most
    ``segments`` segments."""

    polar: scratch("Polar, n")
    solver: scratch("Solver, n")
    vectors: scratch("Vector, n")
    matrices: scratch("Matrix, n, n")
    # Γ of the nominal model, of a unit payload (zero without a payload range)
    forms: scratch("2, n, n, n")
    linear: scratch("2, n, n")  # B at each end of the payload range
    point_rows: scratch("PointRow, d, n")
    point_vectors: scratch("PointVector, d")
    squares: scratch("Square, d, d")
    s_grid: scratch("payload_grid + 1, d")  # s_j(Δm) at Δm = low … high
    corner_index: np.ndarray  # (corners, d) the grid points of each box corner
    per_row: scratch("2, rows")  # the limits and the weights the QP is solved with
    binding: scratch("rows", bool)  # the rows violated at the solver's iterate
    rollout: scratch("Rollout, n")
    flags: scratch("Flag")
    # tracking_torque = "controller": the largest |τ_nom,i| so far and the QP's answer
    # with the tracking rows while the hard rows' alone is solved, PEAK, ANSWER
    authority: scratch("Authority, n")
    # the backup's torque as a small QP in q̈ (cosim.paper.cbf_filter.backup): its rows,
    # their limits and weights, its solver's vectors and the rows bound at its iterate
    backup_rows: scratch("2 * n, n")
    backup_limits: scratch("2, 2 * n")
    backup_solver: scratch("Solver, n")
    backup_binding: scratch("2 * n", bool)
    # the hard rows' groups, at most 8n (2 phases, 2 sets, n joints, 2 sides): g_0, u_1 …
    # u_d; GroupValue (the last row: scratch); GroupLabel; the corners among the QP's rows;
    # s_j(Δm) on the grid now and at the hold's end
    group_rows: scratch("8 * n, 1 + d, n")
    group_values: scratch("8 * n + 1, GroupValue.OFFSETS + d")
    group_labels: scratch("8 * n, GroupLabel", int)
    group_added: scratch("8 * n, corners", bool)
    s_phase: scratch("2, payload_grid + 1, d")
    # two rollouts (the trial a check writes, the plan last verified), segment by segment:
    # Tube, their lengths and the velocity error ε each was checked with
    tube: scratch("2, segments, Tube, n")
    tube_steps: scratch("2, segments")
    tube_eps: scratch("2, n")


@kernel_record
class CbfArgs(NamedTuple):
    hard: np.ndarray  # (4,) 1 where the set is a hard per-joint set, SETS order
    soft: np.ndarray  # (4,) 1 where it is a soft per-joint set
    soft_norms: np.ndarray  # (4,) 1 where it is a soft norm set
    bounds: np.ndarray  # (4,) β per set, bound_margin applied (position, velocity: norms)
    # (2, n) per joint, position and velocity: the hard sets' half-widths β_i (bound_margin
    # applied), the check's (half of it applied) and their centres (q_s, q̇_s, or the
    # middle of the robot's own limits)
    joint_bounds: np.ndarray
    viable_bounds: np.ndarray
    centres: np.ndarray
    k1: float  # 2p
    k0: float  # p²
    tracking_k1: float  # 2p of the soft error rows
    tracking_k0: float  # p²
    k_velocity: parameter("velocity_rate")
    dt: master_step()  # the hold, s
    torque_limit: published(FILTER_ASSUMES)  # (n,) |τ_i| ≤ this, N·m (inf: none)
    rho_soft: parameter("tracking_weight")
    rho_hard: parameter("hard_weight")
    hard_tolerance: parameter()
    verify: bool  # check every torque against the braking backup (else: the QP's answer)
    # the tracking rows may ask no joint for more torque than the controller has (its
    # largest |τ_nom,i| so far): tracking_torque = "controller"
    tracking_authority: bool
    # (n,) the torques the backup brakes with where that is verified (braking_torque, at
    # most the torque limits); braking_reserve: whether it is below them somewhere
    braking_torque: np.ndarray
    braking_reserve: bool
    # (n,) the most the backup brakes with before the run's first viable step
    # (startup_torque, at most the torque limits)
    startup_torque: np.ndarray
    torque_limited: bool  # whether some joint's torque limit is finite
    backup_rate: parameter()  # k_b, 1/s
    recovery_speed: parameter()  # rad/s
    recovery_rate: parameter()  # 1/s
    backup_step: float  # s
    backup_step_max: float  # s, at least backup_step
    backup_horizon: parameter()  # s
    payload_grid: parameter()
    iterations: parameter()
    tolerance: parameter()
    noise_bound: uncertainty()  # n̄, rad
    payload_low: float  # kg
    payload_high: float
    disturbance: uncertainty()  # d̄, N·m
    inertia_is_plant: bool
    model: RigidBodyModel  # the nominal model (inertia_model's nominal_model)
    tau_d: np.ndarray
    rows: scratch("rows, n")  # G, unit rows
    limits: scratch("rows")  # h
    weights: scratch("rows")  # ρ of each row
    is_hard: scratch("rows")  # 1 for hard rows
    kinds: scratch("rows", int)  # set index of each row (4 + set for norms, -1 torque)
    joints: scratch("rows", int)  # joint of each row (-1: a norm)
    backup: scratch("n")  # the backup's torque at this step
    position: reads(chosen_by="position")  # q_meas (observer) or q, rad
    velocity: reads(chosen_by="velocity")  # x̂2 (observer) or q̇, rad/s
    velocity_bound: np.ndarray  # ε per row and joint (zeros for the plant's q̇)
    # the centre c of the certified interval ε is taken from: q̇ ∈ c ± (ε − |v − c|)
    # (the plant's q̇ itself where the filter reads it)
    envelope_centre: np.ndarray
    drift: np.ndarray  # dv/dt − M̂⁻¹τ per row and joint (NaN: use the nominal model)
    q_s: reads()
    qdot_s: reads()
    q_d: reads()
    qdot_d: reads()
    qddot_d: reads()
    M_model: reads()
    tau_nominal: reads("tau")
    tau: writes()
    h_sets: np.ndarray  # (4, rows, n) robust h per set and joint
    active_sets: np.ndarray  # (4, rows, n)
    h_norms: np.ndarray  # (4, rows) β − ‖x‖
    active_norms: np.ndarray  # (4, rows)
    slack: writes("cbf_slack")
    active: writes("cbf_active")
    correction: writes("cbf_correction")
    infeasible: writes("cbf_infeasible")
    viable: writes(VIABLE)  # 1 where a verified torque existed
    # 1 where the step followed the plan in force, no torque verified afresh: its tube must
    # hold the true state there (the guarantee's premise, cosim/paper/premises.py)
    planned: writes("cbf_planned")
    backup_share: writes(BACKUP)  # the share of the backup in the torque, 0 … 1
    rows_met: writes("cbf_rows_met")  # 1 where the torque applied met every hard row as given
    velocity_centre: writes("cbf_velocity_centre")  # the true velocity's interval: centre
    velocity_spread: writes("cbf_velocity_spread")  # and half-width
    # (rows, n) the box the plan in force at the step before puts the true state in at this
    # row (its position's centre and half-width, its velocity's; NaN: no plan, the step
    # before was not viable), and the check's bound on the true q̈ over the step held from
    # this row (its low and high ends)
    tube_position: writes("cbf_tube_position")
    tube_position_spread: writes("cbf_tube_position_spread")
    tube_velocity: writes("cbf_tube_velocity")
    tube_velocity_spread: writes("cbf_tube_velocity_spread")
    acceleration_low: writes("cbf_acceleration_low")
    acceleration_high: writes("cbf_acceleration_high")
    work: CbfWork

