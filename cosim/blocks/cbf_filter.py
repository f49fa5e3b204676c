"""An output-feedback CBF-QP safety filter: after any nominal controller, the torque closest
to the nominal one that keeps the paper's safe sets by construction (SPEC §7).

Every set is a deviation x with a bound β, relative degree 1 or 2 in the joint acceleration q̈:

    position    x = q − q_s     (2)      velocity    x = v − q̇_s   (1)
    error       x = q_d − q     (2)      error rate  x = q̇_d − v   (1)

with q the measured position and v the velocity estimate x̂2 (or the plant's q̇). Per joint
each side of |x_i| ≤ β is a linear barrier h = β ∓ x_i, and as a norm h = β² − ‖x‖²; the
conditions (an exponential CBF, critically damped, for degree 2)

    degree 2:  ḧ + 2p ḣ + p² h ≥ 0         degree 1:  ḣ + k h ≥ 0

are linear in q̈, and q̈ = M̂⁻¹(τ − b̂) with M̂ the inertia model and b̂ = C q̇ + G + τ_d of
the nominal chain at (q, v). The filter solves

    minimise ½‖τ − τ_nom‖² + ½ρ‖s‖²   subject to  G τ ≤ h + s  (and |τ_i| ≤ τ_max)

Robust margins: a degree-2 condition is tightened by 2p·ε for the velocity estimate's error
bound ε (it enters through ḣ), every condition by ‖row‖₁·a_m for an error a_m in the model's
acceleration (b̂'s error under a payload), and every bound by a fraction (for the
discrete-time step and sensor noise). The safe centres q_s, q̇_s are taken as constant
(Remark 1's case ii, the default).

Solvers: ``newton`` (default, compiled, so the filter runs in the fused loop): the slack
eliminated, ½‖τ − τ_nom‖² + ½ρ‖(Gτ − h)₊‖² is strictly convex and piecewise quadratic, and
semismooth Newton solves it exactly once the binding rows are found (a few iterations); its
Hessian I + ρG_AᵀG_A stays positive definite for opposing or conflicting rows, where a dual
method (Hildreth's, tried first) stalls. The slack s = (Gτ − h)₊ is logged; conflicting
sets are the defined fallback: the least-squares compromise the slack's weight gives. Any
other name is a solver of ``qpsolvers`` (``daqp``, ``osqp``, ``clarabel``, ``proxqp``,
``quadprog``) on the same QP with s explicit, called from Python each step.
"""

from __future__ import annotations

from typing import Annotated, Literal, NamedTuple

import numpy as np
from numba import njit
from pydantic import Field

from ..config.schema import FiniteFloat, NonNegativeFloat, PositiveFloat, Section
from ..signals import Signal
from .base import Block, BlockContext, Ports, register_block
from .inertia import default_links, planar_bias

SETS = ("position", "velocity", "error", "error_rate")
SetName = Literal["position", "velocity", "error", "error_rate"]
DEGREE = {"position": 2, "velocity": 1, "error": 2, "error_rate": 1}
# Per set, in SETS order: relative degree, and the sign of q̈ in x's top derivative
# (module constants: compiled in, not allocated each step).
DEGREES = np.array([DEGREE[s] for s in SETS])
SIGNS = np.array([1.0, 1.0, -1.0, -1.0])


class CbfFilterParams(Section):
    sets: list[SetName] = list(SETS)  # kept per joint
    norms: list[SetName] = ["error", "error_rate"]  # kept as norms too
    position_rate: PositiveFloat = 10.0  # p of degree-2 conditions (k1 = 2p, k0 = p²), 1/s
    velocity_rate: PositiveFloat = 20.0  # k of degree-1 conditions, 1/s
    velocity: Literal["observer", "plant"] = "observer"  # x̂2, or the plant's true q̇
    velocity_error_bound: NonNegativeFloat = 0.0  # ε of the robust margin, rad/s
    acceleration_margin: NonNegativeFloat = 0.0  # a_m: error of M̂⁻¹(τ − b̂), rad/s²
    bound_margin: Annotated[float, Field(ge=0, lt=1)] = 0.0  # keep within (1 − this)·β
    torque_limit: PositiveFloat | None = None  # |τ_i| ≤ this, N·m
    slack_weight: PositiveFloat = 1e6  # ρ
    bias: Literal["nominal", "none"] = "nominal"  # b̂ from the inertia model's chain, or 0
    gravity: FiniteFloat = 9.8  # m/s², of the nominal chain
    solver: str = "newton"  # or a qpsolvers solver: daqp, osqp, clarabel, proxqp, quadprog
    iterations: Annotated[int, Field(ge=1, le=1000)] = 50  # Newton steps at most
    tolerance: PositiveFloat = 1e-12  # on the gradient, relative to ‖τ_nom‖


class CbfArgs(NamedTuple):
    sets: np.ndarray  # (4,) 1 where the set is kept per joint, in SETS order
    norms: np.ndarray  # (4,) 1 where it is kept as a norm
    bounds: np.ndarray  # (4,) β per set, margin applied
    k1: float  # 2p
    k0: float  # p²
    k_velocity: float
    velocity_error: float  # ε
    acceleration_margin: float
    torque_limit: float  # inf: none
    rho: float
    iterations: int
    tolerance: float
    use_bias: bool
    gravity: float
    m: np.ndarray
    l: np.ndarray  # noqa: E741
    lc: np.ndarray
    inertia: np.ndarray
    tau_d: np.ndarray
    rows: np.ndarray  # scratch: (rows, n) G
    limits: np.ndarray  # scratch: (rows,) h
    kinds: np.ndarray  # (rows,) set index of each row (4 + set for norms, -1 torque)
    joints: np.ndarray  # (rows,) joint of each row (-1: a norm)
    multipliers: np.ndarray  # (rows,) λ = ρ·slack: nonzero where a row binds
    position: np.ndarray
    velocity: np.ndarray
    q_s: np.ndarray
    qdot_s: np.ndarray
    q_d: np.ndarray
    qdot_d: np.ndarray
    qddot_d: np.ndarray
    M_model: np.ndarray
    tau_nominal: np.ndarray
    tau: np.ndarray
    h_sets: np.ndarray  # (4, rows, n) h per set and joint: β − |x_i|
    active_sets: np.ndarray  # (4, rows, n)
    h_norms: np.ndarray  # (4, rows) β − ‖x‖
    active_norms: np.ndarray  # (4, rows)
    slack: np.ndarray
    active: np.ndarray
    correction: np.ndarray


@njit(cache=True)
def cbf_rows(k, a):
    """Fill ``a.rows`` (G) and ``a.limits`` (h) of G τ ≤ h for row k; returns how many and
    the nominal torque's acceleration model (M̂⁻¹, b̂) through ``a.rows``' first use."""
    n = a.position.shape[1]
    y, v = a.position[k], a.velocity[k]
    minv = np.linalg.inv(a.M_model[k])
    bias = np.zeros(n)
    if a.use_bias:
        planar_bias(y, v, a.m, a.l, a.lc, a.inertia, a.gravity, bias)
    bias += a.tau_d
    # deviation x, its rate ẋ (degree 2 only), and x's top derivative = sign·q̈ + offset
    x = np.empty((4, n))
    rate = np.empty((4, n))
    sign = SIGNS
    offset = np.zeros((4, n))
    x[0] = y - a.q_s[k]
    rate[0] = v
    x[1] = v - a.qdot_s[k]
    x[2] = a.q_d[k] - y
    rate[2] = a.qdot_d[k] - v
    offset[2] = a.qddot_d[k]
    x[3] = a.qdot_d[k] - v
    offset[3] = a.qddot_d[k]
    degree = DEGREES
    acc_row = np.zeros(n)  # one row on q̈: acc_row · q̈ ≤ bound
    count = 0
    for s in range(4):
        beta = a.bounds[s]
        for i in range(n):
            a.h_sets[s, k, i] = beta - abs(x[s, i])
            a.active_sets[s, k, i] = 0.0
        if a.sets[s]:
            for i in range(n):
                for side in (1.0, -1.0):  # h = β − side·x_i
                    h = beta - side * x[s, i]
                    acc_row[:] = 0.0
                    acc_row[i] = side * sign[s]
                    if degree[s] == 2:  # −side(sign q̈ + c) − side k1 ẋ + k0 h ≥ 0
                        bound = (-side * offset[s, i] - side * a.k1 * rate[s, i] + a.k0 * h
                                 - a.k1 * a.velocity_error)
                    else:  # −side(sign q̈ + c) + k h ≥ 0
                        bound = -side * offset[s, i] + a.k_velocity * h
                    bound -= a.acceleration_margin
                    a.rows[count] = acc_row @ minv
                    a.limits[count] = bound + a.rows[count] @ bias
                    a.kinds[count] = s
                    a.joints[count] = i
                    count += 1
        norm = np.sqrt(np.sum(x[s] ** 2))
        a.h_norms[s, k] = beta - norm
        a.active_norms[s, k] = 0.0
        if a.norms[s]:
            h = beta * beta - norm * norm
            acc_row[:] = 2.0 * sign[s] * x[s]  # −ḧ's q̈ part
            if degree[s] == 2:  # ḧ = −2‖ẋ‖² − 2xᵀ(sign q̈ + c), ḣ = −2xᵀẋ
                bound = (-2.0 * np.sum(rate[s] ** 2) - 2.0 * np.sum(x[s] * offset[s])
                         - 2.0 * a.k1 * np.sum(x[s] * rate[s]) + a.k0 * h
                         - 2.0 * a.k1 * norm * a.velocity_error)
            else:  # ḣ = −2xᵀ(sign q̈ + c)
                bound = -2.0 * np.sum(x[s] * offset[s]) + a.k_velocity * h
            bound -= a.acceleration_margin * np.sum(np.abs(acc_row))
            a.rows[count] = acc_row @ minv
            a.limits[count] = bound + a.rows[count] @ bias
            a.kinds[count] = 4 + s
            a.joints[count] = -1
            count += 1
    if np.isfinite(a.torque_limit):
        for i in range(n):
            for side in (1.0, -1.0):
                a.rows[count] = 0.0
                a.rows[count, i] = side
                a.limits[count] = a.torque_limit
                a.kinds[count] = -1
                a.joints[count] = i
                count += 1
    return count


@njit(cache=True)
def cbf_record(k, a, count, tau, multipliers, slack):
    """Write row k's outputs: the filtered torque, each constraint's activity, the slack."""
    a.tau[k] = tau
    active = 0
    for j in range(count):
        if multipliers[j] > 0.0:
            active += 1
            s = a.kinds[j]
            if 0 <= s < 4:
                a.active_sets[s, k, a.joints[j]] = 1.0
            elif s >= 4:
                a.active_norms[s - 4, k] = 1.0
    a.active[k] = active
    a.slack[k] = slack
    a.correction[k] = np.sqrt(np.sum((tau - a.tau_nominal[k]) ** 2))
    return np.isfinite(np.sum(tau))


@njit(cache=True)
def _penalty(tau, tau_nominal, G, h, rho):
    """½‖τ − τ_nom‖² + ½ρ‖(Gτ − h)₊‖²."""
    excess = np.maximum(G @ tau - h, 0.0)
    return 0.5 * np.sum((tau - tau_nominal) ** 2) + 0.5 * rho * np.sum(excess**2)


@njit(cache=True)
def solve_soft_qp(tau_nominal, G, h, rho, iterations, tolerance):
    """min ½‖τ − τ_nom‖² + ½ρ‖s‖² s.t. Gτ − s ≤ h, by semismooth Newton on the equivalent
    ½‖τ − τ_nom‖² + ½ρ‖(Gτ − h)₊‖²: strictly convex and piecewise quadratic, so with the
    rows violated at τ fixed, one linear solve (I + ρ G_Aᵀ G_A) is exact; repeated until the
    set of violated rows no longer changes, with a backtracking line search for safety.
    Returns (τ, iterations used)."""
    n, m = tau_nominal.shape[0], G.shape[0]
    tau = tau_nominal.copy()
    scale = 1.0 + np.sqrt(np.sum(tau_nominal**2))
    binding = np.zeros(m, np.bool_)
    full_step = False
    for it in range(iterations):
        excess = np.maximum(G @ tau - h, 0.0)
        now = excess > 0.0
        gradient = tau - tau_nominal + rho * (G.T @ excess)
        # Exact for this piece once a full Newton step kept the same binding rows (the
        # gradient itself only falls to rounding × ρ).
        if it > 0 and np.array_equal(now, binding) and full_step:
            return tau, it
        if np.sqrt(np.sum(gradient**2)) <= tolerance * scale:
            return tau, it
        binding = now
        hessian = np.eye(n)
        for j in range(m):
            if binding[j]:
                hessian += rho * np.outer(G[j], G[j])
        direction = -np.linalg.solve(hessian, gradient)
        value = _penalty(tau, tau_nominal, G, h, rho)
        slope = gradient @ direction
        step = 1.0
        while step > 1e-12:
            trial = tau + step * direction
            if _penalty(trial, tau_nominal, G, h, rho) <= value + 1e-4 * step * slope:
                break
            step *= 0.5
        full_step = step == 1.0
        tau = tau + step * direction
    return tau, iterations


@njit(cache=True)
def cbf_step(k, a):
    count = cbf_rows(k, a)
    G, h = a.rows[:count], a.limits[:count]
    tau, _ = solve_soft_qp(a.tau_nominal[k], G, h, a.rho, a.iterations, a.tolerance)
    excess = G @ tau - h
    multipliers = a.multipliers[:count]
    slack = 0.0
    for j in range(count):
        # at the optimum λ_j = ρ·(g_j τ − h_j)₊: a row is active where it binds
        multipliers[j] = a.rho * max(excess[j], 0.0)
        slack = max(slack, excess[j])
    return cbf_record(k, a, count, tau, multipliers, slack)


@register_block
class CbfFilter(Block):
    kind = "cbf_filter"
    Params = CbfFilterParams

    def __init__(self, params: CbfFilterParams, context: BlockContext):
        super().__init__(params, context)
        velocity = "qdot_hat" if params.velocity == "observer" else "qdot"
        position = "q_meas" if params.velocity == "observer" else "q"
        self.position, self.velocity = position, velocity
        self.inputs = (position, velocity, "q_s", "qdot_s", "q_d", "qdot_d", "qddot_d",
                       "M_model", "tau")
        self.outputs = {"tau": Signal("n", "N·m", "filtered torque τ", "cbf_filter/tau")}
        for name in SETS:
            self.outputs[f"cbf_{name}"] = Signal(
                "n", "SI", f"{name} set: β − |x_i| (≥ 0 inside)", f"cbf_filter/h/{name}",
                f"h_{name}")
            self.outputs[f"cbf_{name}_active"] = Signal(
                "n", "-", f"{name} set: a constraint of joint i active (1)",
                f"cbf_filter/active/{name}", f"active_{name}")
            self.outputs[f"cbf_{name}_norm"] = Signal(
                "1", "SI", f"{name} set as a norm: β − ‖x‖", f"cbf_filter/h/{name}_norm",
                f"h_{name}_norm")
            self.outputs[f"cbf_{name}_norm_active"] = Signal(
                "1", "-", f"{name} norm constraint active (1)",
                f"cbf_filter/active/{name}_norm", f"active_{name}_norm")
        self.outputs.update({
            "cbf_slack": Signal("1", "SI", "largest slack s = λ/ρ", "cbf_filter/slack"),
            "cbf_active": Signal("1", "-", "number of active constraints",
                                 "cbf_filter/active_count"),
            "cbf_correction": Signal("1", "N·m", "‖τ − τ_nom‖", "cbf_filter/correction"),
        })
        if params.solver == "newton":
            self.kernel = cbf_step
        else:
            self._check_solver(params.solver)

    @staticmethod
    def _check_solver(name: str) -> None:
        from ..config.schema import PipelineError

        try:
            import qpsolvers
        except ImportError:
            raise PipelineError(f"cbf_filter.solver = {name!r} needs qpsolvers (pip install "
                                "'qpsolvers[daqp]'); or use solver = \"newton\"") from None
        if name not in qpsolvers.available_solvers:
            raise PipelineError(f"cbf_filter.solver = {name!r} is not an installed QP solver "
                                f"(installed: newton, {', '.join(qpsolvers.available_solvers)})")

    def reset(self, ports: Ports) -> None:
        p, n = self.params, self.context.links
        tables, safety = self.context.tables, self.context.safety
        inertia = getattr(tables, "inertia_model", None)
        links = default_links(n)
        if inertia is not None:
            links = {key: getattr(inertia, key) or value for key, value in links.items()}
        observer = getattr(tables, "observer", None)
        tau_d = observer.tau_d if observer is not None else 0.0
        bounds = np.array([safety.position_bound, safety.velocity_bound, safety.error_bound,
                           safety.error_rate_bound]) * (1.0 - p.bound_margin)
        rows = 2 * n * len(SETS) + len(SETS) + 2 * n
        steps = len(ports.trace.time)
        inp, out = ports.inputs, ports.outputs
        self.args = CbfArgs(
            np.array([float(s in p.sets) for s in SETS]),
            np.array([float(s in p.norms) for s in SETS]), bounds,
            2.0 * p.position_rate, p.position_rate**2, p.velocity_rate, p.velocity_error_bound,
            p.acceleration_margin, p.torque_limit or np.inf, p.slack_weight, p.iterations,
            p.tolerance, p.bias == "nominal", p.gravity,
            *(np.asarray(links[key], float) for key in ("m", "l", "lc", "I")),
            np.broadcast_to(np.asarray(tau_d, float), (n,)).copy(),
            np.zeros((rows, n)), np.zeros(rows), np.zeros(rows, np.int64),
            np.zeros(rows, np.int64), np.zeros(rows),
            inp[self.position], inp[self.velocity], inp["q_s"], inp["qdot_s"], inp["q_d"],
            inp["qdot_d"], inp["qddot_d"], inp["M_model"], inp["tau"], out["tau"],
            *(_per_set(ports.trace, f"cbf_{{}}{suffix}", shape) for suffix, shape in
              (("", (steps, n)), ("_active", (steps, n)), ("_norm", (steps,)),
               ("_norm_active", (steps,)))),
            out["cbf_slack"], out["cbf_active"], out["cbf_correction"])

    def step(self, k: int) -> bool:
        """With a qpsolvers solver (no kernel): the same rows, solved in Python."""
        import qpsolvers

        a = self.args
        count = cbf_rows(k, a)
        G, h = a.rows[:count], a.limits[:count]
        n = G.shape[1]
        rho = a.rho
        # variables [τ, s]: ½‖τ − τ_nom‖² + ½ρ‖s‖², G τ − s ≤ h, s ≥ 0
        P = np.diag(np.concatenate([np.ones(n), np.full(count, rho)]))
        q = np.concatenate([-a.tau_nominal[k], np.zeros(count)])
        G_full = np.block([[G, -np.eye(count)], [np.zeros((count, n)), -np.eye(count)]])
        h_full = np.concatenate([h, np.zeros(count)])
        x = qpsolvers.solve_qp(P, q, G_full, h_full, solver=self.params.solver)
        if x is None:
            return False
        tau, slack = x[:n], x[n:]
        active = (G @ tau - slack >= h - 1e-7 * (1.0 + np.abs(h))).astype(float)
        return cbf_record(k, a, count, tau, active, float(np.max(slack, initial=0.0)))


def _per_set(trace, pattern: str, shape: tuple[int, ...]) -> np.ndarray:
    """One array (4, *shape) for the four sets' outputs named ``pattern.format(set)``, the
    kernel's to index by set; the trace's arrays become views of it."""
    stacked = np.full((len(SETS), *shape), np.nan)
    for i, name in enumerate(SETS):
        trace.arrays[pattern.format(name)] = stacked[i]
    return stacked
