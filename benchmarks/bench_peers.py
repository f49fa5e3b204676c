"""cosim against peer tools on the same closed loop, in one process on one machine.

The plant is the paper's two-link arm (Lewis: a1 = a2 = 1 m, m1 = 0.8 kg, m2 = 2.3 kg,
g = 9.8 m/s², point masses at the link tips, angles from the horizontal, τ_d = 0.01 N·m per
joint, q(0) = 0.1 rad, q̇(0) = 10 rad/s), run for ``--duration`` s (default 20) at 1 kHz with
the torque held over each 1 ms step (zero-order hold). Two closed loops:

- **NN baseline**: Lewis's two-layer NN controller with the true state, the ``baseline`` run
  of pipelines/paper_two_link.toml (gains, hidden width, seeded random V̂(0) read from the
  pipeline), tracking the paper's sinusoids q_d = [20 sin 0.5t, 10 sin t] rad;
- **PD**: τ = Kp e + Kd ė + G(q), the ``pd_full_state`` run of pipelines/pd_control.toml.

The tools:

1. **cosim**, engine "fused": ``assemble_run`` + ``simulate`` as benchmarks/bench_cosim.py
   does, the loop's own wall time (assembly and JIT outside it). For the NN baseline twice:
   the same loop as the peers (``blocks = ["reference", "controller"]``, what the ratios use)
   and the pipeline's own chain, which also runs the sensor, the nominal M̂(q) and the
   observer that the baseline does not use for control. The PD run is the pipeline's chain
   as it is (sensor and nominal M̂(q) included: a little more work than the peers do).
2. **python-control** (``control.nlsys`` + ``control.interconnect`` +
   ``control.input_output_response``): the plant and the controller as two *discrete-time*
   nlsys with dt = 1 ms, interconnected by signal name; the plant's update integrates the
   arm over the 1 ms step by RK4 in ten 0.1 ms sub-steps with the torque held (what the FMU
   does), the NN controller's state is its weights (Ŵ, V̂) updated as cosim does, the
   reference enters as the exogenous input. A continuous plant cannot be interconnected with
   a discrete controller (one timebase per interconnect), and a continuous closed loop
   through solve_ivp would feed a linearly interpolated torque, not a held one: the
   discrete formulation is the faithful one. python-control is slow: ``--control-duration``
   (default: ``--duration``) runs it shorter, and its µs per step are scaled from that.
3. **FMPy's simulate_fmu** of the same FMU file, open loop (zero torque, no controller),
   1 ms communication step and output interval, recording the outputs cosim reads (q, q̇, M).
   Two figures: the whole call, and its cost per step beyond a 10-step call (instantiation
   and set-up taken out); the ratio uses the latter, the one kinder to FMPy.
4. **A plain Python loop**: the arm's closed-form equations in scalar ``math``
   (faster in CPython than 2×2 NumPy arrays), RK4 with 10 sub-steps per 1 ms, the NN's
   matrix products in NumPy. The same functions are python-control's plant and controllers,
   so the two differ only by the framework.

Each figure is the best of ``--repeat`` repetitions, interleaved so that a slow spell of the
shared machine hits every tool, after an untimed warm-up (numba compilation, FMU load). The
peers' traces are checked against cosim's: max |Δq1| over the run, for both loops (the NN
baseline's random V̂(0) is reproduced from the pipeline's seed, so it is comparable too).

Run: .venv/bin/python benchmarks/bench_peers.py [--duration 20] [--repeat 3]
     [--control-duration SECONDS]
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import control as ct
import numpy as np
from fmpy import extract, read_model_description, simulate_fmu

from cosim.assemble import assemble_run
from cosim.config import Pipeline, load_pipeline
from cosim.engine import simulate
from cosim.plant.fmu import Fmu
from cosim.plant_source import open_plant

ROOT = Path(__file__).resolve().parent.parent
PAPER = ROOT / "pipelines" / "paper_two_link.toml"
PD = ROOT / "pipelines" / "pd_control.toml"
H = 1e-3  # s, the master step (the torque's hold)
SUBSTEPS = 10  # RK4 sub-steps per master step: 0.1 ms, the FMU's rk4_step

# The paper's arm; checked against the FMU's parameters in arm_from_fmu.
A1 = A2 = 1.0  # m
M1, M2 = 0.8, 2.3  # kg
GRAV = 9.8  # m/s²
TAU_D = 0.01  # N·m on each joint
Q0, QDOT0 = 0.1, 10.0  # rad, rad/s (each joint)
# The FMU's parameter values the closed-form model below assumes.
EXPECTED = {"m[1]": M1, "m[2]": M2, "l[1]": A1, "l[2]": A2, "lc[1]": A1, "lc[2]": A2,
            "I[1]": 0.0, "I[2]": 0.0, "b[1]": 0.0, "b[2]": 0.0, "fc[1]": 0.0, "fc[2]": 0.0,
            "tau_d[1]": TAU_D, "tau_d[2]": TAU_D, "tau_d_amp[1]": 0.0, "tau_d_amp[2]": 0.0,
            "g": GRAV, "q0[1]": Q0, "q0[2]": Q0, "qdot0[1]": QDOT0, "qdot0[2]": QDOT0,
            "rk4_step": H / SUBSTEPS}
OUTPUTS = ["q[1]", "q[2]", "qdot[1]", "qdot[2]", "M[1,1]", "M[1,2]", "M[2,1]", "M[2,2]"]

State = tuple[float, float, float, float]  # q1, q2 (rad), q̇1, q̇2 (rad/s)
Law = Callable[[int, State], tuple[float, float]]  # step k, state -> τ (N·m)


# ---- the plant: the paper's arm in closed form ------------------------------------------

def arm_acceleration(q1: float, q2: float, w1: float, w2: float, t1: float, t2: float
                     ) -> tuple[float, float]:
    """q̈ = M(q)⁻¹ (τ − Vm q̇ − G(q) − τ_d), the 2×2 solve written out (Cramer)."""
    c2, s2 = math.cos(q2), math.sin(q2)
    c12 = math.cos(q1 + q2)
    m11 = (M1 + M2) * A1 * A1 + M2 * A2 * A2 + 2.0 * M2 * A1 * A2 * c2
    m12 = M2 * A2 * A2 + M2 * A1 * A2 * c2
    m22 = M2 * A2 * A2
    h = M2 * A1 * A2 * s2
    b1 = t1 + h * (2.0 * w1 * w2 + w2 * w2) \
        - (M1 + M2) * GRAV * A1 * math.cos(q1) - M2 * GRAV * A2 * c12 - TAU_D
    b2 = t2 - h * w1 * w1 - M2 * GRAV * A2 * c12 - TAU_D
    det = m11 * m22 - m12 * m12
    return (m22 * b1 - m12 * b2) / det, (m11 * b2 - m12 * b1) / det


def rk4_hold(x: State, t1: float, t2: float, h: float = H, substeps: int = SUBSTEPS) -> State:
    """The arm over one master step with τ held, classical RK4 in equal sub-steps (the FMU's
    scheme: rk4_step = 0.1 ms)."""
    # Python floats: arithmetic on NumPy scalars (rows of the reference, python-control's
    # x and u) would cost several times more and make the peers look slower than they are.
    q1, q2, w1, w2 = (float(v) for v in x)
    t1, t2 = float(t1), float(t2)
    dt = h / substeps
    for _ in range(substeps):
        a1, b1 = arm_acceleration(q1, q2, w1, w2, t1, t2)
        k1 = (w1, w2, a1, b1)
        y = (q1 + 0.5 * dt * k1[0], q2 + 0.5 * dt * k1[1], w1 + 0.5 * dt * a1,
             w2 + 0.5 * dt * b1)
        k2 = (y[2], y[3], *arm_acceleration(*y, t1, t2))
        y = (q1 + 0.5 * dt * k2[0], q2 + 0.5 * dt * k2[1], w1 + 0.5 * dt * k2[2],
             w2 + 0.5 * dt * k2[3])
        k3 = (y[2], y[3], *arm_acceleration(*y, t1, t2))
        y = (q1 + dt * k3[0], q2 + dt * k3[1], w1 + dt * k3[2], w2 + dt * k3[3])
        k4 = (y[2], y[3], *arm_acceleration(*y, t1, t2))
        q1 += dt / 6.0 * (k1[0] + 2.0 * k2[0] + 2.0 * k3[0] + k4[0])
        q2 += dt / 6.0 * (k1[1] + 2.0 * k2[1] + 2.0 * k3[1] + k4[1])
        w1 += dt / 6.0 * (k1[2] + 2.0 * k2[2] + 2.0 * k3[2] + k4[2])
        w2 += dt / 6.0 * (k1[3] + 2.0 * k2[3] + 2.0 * k3[3] + k4[3])
    return q1, q2, w1, w2


def gravity(q1: float, q2: float) -> tuple[float, float]:
    """G(q) of the paper's arm, N·m: the PD controller's compensation (nominal arm = plant)."""
    c12 = math.cos(q1 + q2)
    return (M1 + M2) * GRAV * A1 * math.cos(q1) + M2 * GRAV * A2 * c12, M2 * GRAV * A2 * c12


def check_fmu_parameters(md) -> None:
    """The FMU's defaults must be the arm the closed-form model above is, else the peers
    would not compute the same thing."""
    start = {v.name: float(v.start) for v in md.modelVariables if v.start is not None}
    wrong = {k: (start.get(k), v) for k, v in EXPECTED.items() if start.get(k) != v}
    if wrong:
        raise SystemExit(f"the FMU's parameters differ from the paper's arm: {wrong}")


# ---- the controllers, shared by the plain loop and python-control -------------------------

class Reference(NamedTuple):
    q_d: np.ndarray  # (rows, 2) rad
    qdot_d: np.ndarray  # rad/s
    qddot_d: np.ndarray  # rad/s²


def reference(pipeline: Pipeline, rows: int) -> Reference:
    """The pipeline's sinusoids q_d,i = offset_i + Σ_j a_ij sin(ω_ij t + φ_ij) at t_k = k h."""
    p = pipeline.reference
    a, w = np.array(p.amplitude), np.array(p.frequency)
    phase = np.array(p.phase) if p.phase is not None else np.zeros_like(a)
    arg = (np.arange(rows) * H)[:, None, None] * w[None] + phase[None]
    return Reference(np.array(p.offset)[None] + (a * np.sin(arg)).sum(-1),
                     (a * w * np.cos(arg)).sum(-1), -(a * w * w * np.sin(arg)).sum(-1))


class PdGains(NamedTuple):
    kp: tuple[float, float]  # N·m/rad
    kd: tuple[float, float]  # N·m·s/rad


def pd_gains(pipeline: Pipeline) -> PdGains:
    p = pipeline.runs["pd_full_state"].pd_controller
    if p.velocity != "plant" or not p.gravity_compensation:
        raise SystemExit("pd_full_state: expected the true velocity and gravity compensation")
    kp, kd = np.broadcast_to(p.kp, (2,)), np.broadcast_to(p.kd, (2,))
    return PdGains((float(kp[0]), float(kp[1])), (float(kd[0]), float(kd[1])))


def pd_torque(g: PdGains, x: State, q_d: np.ndarray, qdot_d: np.ndarray
              ) -> tuple[float, float]:
    """τ = Kp e + Kd ė + G(q), as cosim's pd_step."""
    g1, g2 = gravity(x[0], x[1])
    return (g.kp[0] * (q_d[0] - x[0]) + g.kd[0] * (qdot_d[0] - x[2]) + g1,
            g.kp[1] * (q_d[1] - x[1]) + g.kd[1] * (qdot_d[1] - x[3]) + g2)


class NnGains(NamedTuple):
    kv: np.ndarray  # (2,) N·m·s/rad
    lam: np.ndarray  # (2,) 1/s
    f: float
    g: float
    kappa: float
    kz: float
    z_b: float
    hidden: int


def nn_setup(pipeline: Pipeline) -> tuple[NnGains, np.ndarray, np.ndarray]:
    """The baseline's gains and initial weights Ŵ(0) = 0, V̂(0) drawn as cosim's controller
    block draws them (same generator, seed and layout), so the runs are comparable."""
    p = pipeline.runs["baseline"].controller
    if p.variant != "baseline" or p.velocity not in ("auto", "plant"):
        raise SystemExit("paper_two_link: the baseline run must be the full-state baseline")
    n, n_in = 2, 11
    gains = NnGains(np.broadcast_to(np.asarray(p.kv, float), (n,)).copy(),
                    np.broadcast_to(np.asarray(p.lam, float), (n,)).copy(),
                    p.f, p.g, p.kappa, p.kz, p.z_b, p.hidden)
    w0 = np.zeros((p.hidden + 1, n))
    v0 = np.zeros((n_in, p.hidden))
    if p.init == "random":
        v0[:] = np.random.default_rng(p.seed).uniform(-p.init_scale, p.init_scale,
                                                      n_in * p.hidden).reshape(n_in, p.hidden)
    return gains, w0, v0


class NnStep(NamedTuple):
    """What the weight update needs from the torque's evaluation."""

    tau: np.ndarray
    r: np.ndarray
    xi: np.ndarray
    act: np.ndarray
    sig_hat: np.ndarray


def nn_torque(g: NnGains, W: np.ndarray, V: np.ndarray, q: np.ndarray, qdot: np.ndarray,
              q_d: np.ndarray, qdot_d: np.ndarray, qddot_d: np.ndarray) -> NnStep:
    """τ = Ŵᵀσ̂(V̂ᵀξ) + Kv r − v, v = −Kz(‖Ẑ‖_F + Z_B) r (Lewis 1999), as cosim's
    controller_step with the baseline's options."""
    e = q_d - q
    edot = qdot_d - qdot
    r = edot + g.lam * e
    xi = np.concatenate(((1.0,), e, edot, q_d, qdot_d, qddot_d))
    act = V.T @ xi
    sig_hat = np.concatenate(((1.0,), 1.0 / (1.0 + np.exp(-act))))
    z_norm = math.sqrt(float(np.sum(W * W)) + float(np.sum(V * V)))
    v = -g.kz * (z_norm + g.z_b) * r
    return NnStep(W.T @ sig_hat + (g.kv * r - v), r, xi, act, sig_hat)


def nn_update(g: NnGains, W: np.ndarray, V: np.ndarray, s: NnStep
              ) -> tuple[np.ndarray, np.ndarray]:
    """(25)-(26) over one step, Euler with the κ‖r‖ decay implicit (cosim's choice)."""
    sig = s.sig_hat[1:]
    dsig = sig * (1.0 - sig)
    s_prime_a = np.concatenate(((0.0,), dsig * s.act))
    back = dsig * (W @ s.r)[1:]
    r_norm = math.sqrt(float(np.sum(s.r * s.r)))
    W_new = (W + H * g.f * np.outer(s.sig_hat - s_prime_a, s.r)) / (1.0 + H * g.kappa * g.f
                                                                    * r_norm)
    V_new = (V + H * g.g * np.outer(s.xi, back)) / (1.0 + H * g.kappa * g.g * r_norm)
    return W_new, V_new


# ---- tool 4: the plain Python loop -------------------------------------------------------

def plain_loop(law: Law, steps: int, x0: State = (Q0, Q0, QDOT0, QDOT0)
               ) -> tuple[float, np.ndarray]:
    """(s per step, q rows 0..steps): the master's order, row k = the plant at t_k, then τ_k
    held over [t_k, t_k + h]."""
    q = np.empty((steps + 1, 2))
    x = x0
    start = time.perf_counter()
    for k in range(steps + 1):
        q[k] = x[0], x[1]
        if k == steps:
            break
        t1, t2 = law(k, x)
        x = rk4_hold(x, t1, t2)
    return (time.perf_counter() - start) / steps, q


def pd_law(g: PdGains, ref: Reference) -> Law:
    def law(k: int, x: State) -> tuple[float, float]:
        return pd_torque(g, x, ref.q_d[k], ref.qdot_d[k])
    return law


def nn_law(g: NnGains, w0: np.ndarray, v0: np.ndarray, ref: Reference) -> Law:
    weights = [w0.copy(), v0.copy()]  # the controller's state, updated once per step

    def law(k: int, x: State) -> tuple[float, float]:
        W, V = weights
        s = nn_torque(g, W, V, np.array(x[:2]), np.array(x[2:]), ref.q_d[k], ref.qdot_d[k],
                      ref.qddot_d[k])
        weights[:] = nn_update(g, W, V, s)
        return float(s.tau[0]), float(s.tau[1])
    return law


# ---- tool 2: python-control --------------------------------------------------------------

REF_SIGNALS = ["q_d1", "q_d2", "qdot_d1", "qdot_d2", "qddot_d1", "qddot_d2"]
PLANT_SIGNALS = ["q1", "q2", "qdot1", "qdot2"]


def control_plant() -> ct.NonlinearIOSystem:
    """The arm as a discrete-time nlsys: x[k+1] = RK4 over 1 ms with τ[k] held; y = x."""
    def update(t: float, x: np.ndarray, u: np.ndarray, params: dict) -> np.ndarray:
        return np.array(rk4_hold((x[0], x[1], x[2], x[3]), u[0], u[1]))
    return ct.nlsys(update, None, inputs=["tau1", "tau2"], outputs=PLANT_SIGNALS,
                    states=PLANT_SIGNALS, dt=H, name="arm")


def control_pd(g: PdGains) -> ct.NonlinearIOSystem:
    """The PD law as a static discrete-time nlsys (no state)."""
    def output(t: float, x: np.ndarray, u: np.ndarray, params: dict) -> np.ndarray:
        return np.array(pd_torque(g, (u[0], u[1], u[2], u[3]), u[4:6], u[6:8]))
    return ct.nlsys(None, output, inputs=PLANT_SIGNALS + REF_SIGNALS[:4],
                    outputs=["tau1", "tau2"], dt=H, name="pd")


def control_nn(g: NnGains, n_w: int) -> ct.NonlinearIOSystem:
    """The NN controller as a discrete-time nlsys: state = [vec Ŵ, vec V̂] (row-major, as
    cosim's), output τ[k], update the weights."""
    shape_w, shape_v = (g.hidden + 1, 2), (11, g.hidden)

    def evaluate(x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, NnStep]:
        W, V = x[:n_w].reshape(shape_w), x[n_w:].reshape(shape_v)
        return W, V, nn_torque(g, W, V, u[0:2], u[2:4], u[4:6], u[6:8], u[8:10])

    def output(t: float, x: np.ndarray, u: np.ndarray, params: dict) -> np.ndarray:
        return evaluate(x, u)[2].tau

    def update(t: float, x: np.ndarray, u: np.ndarray, params: dict) -> np.ndarray:
        W, V, s = evaluate(x, u)
        W_new, V_new = nn_update(g, W, V, s)
        return np.concatenate((W_new.ravel(), V_new.ravel()))
    return ct.nlsys(update, output, inputs=PLANT_SIGNALS + REF_SIGNALS,
                    outputs=["tau1", "tau2"], states=n_w + 11 * g.hidden, dt=H, name="nn")


def control_loop(controller: ct.NonlinearIOSystem) -> ct.InterconnectedSystem:
    """Plant and controller connected by signal name; the reference signals the controller
    reads are the loop's inputs."""
    inputs = [name for name in REF_SIGNALS if name in controller.input_labels]
    return ct.interconnect([control_plant(), controller], inputs=inputs,
                           outputs=PLANT_SIGNALS + ["tau1", "tau2"], name="closed_loop")


def control_run(loop: ct.InterconnectedSystem, ref: Reference, x0: np.ndarray, steps: int
                ) -> tuple[float, np.ndarray]:
    """(s per step, q rows 0..steps) of input_output_response over steps + 1 samples."""
    T = np.arange(steps + 1) * H
    U = np.hstack((ref.q_d[:steps + 1], ref.qdot_d[:steps + 1], ref.qddot_d[:steps + 1])).T
    U = U[:loop.ninputs]  # REF_SIGNALS' order: the PD loop reads q_d and q̇_d only
    start = time.perf_counter()
    response = ct.input_output_response(loop, T, U, x0)
    wall = time.perf_counter() - start
    return wall / steps, np.asarray(response.outputs)[:2].T


# ---- tool 1: cosim; tool 3: FMPy ---------------------------------------------------------

def cosim_run(pipeline: Pipeline, run: str, plant: Fmu, steps: int
              ) -> tuple[float, np.ndarray]:
    """(s per step of the fused loop, as the master times it, q rows 0..steps)."""
    plan = assemble_run(pipeline, run, plant)
    trace = plan.new_trace(steps)
    wall = simulate(plant, plan, trace, engine="fused")
    return wall / steps, np.array(trace["q"])


def fmpy_run(unzipdir: str, md, steps: int) -> tuple[float, np.ndarray]:
    """(s of the whole simulate_fmu call, q rows 0..steps), open loop: τ = 0 throughout."""
    start = time.perf_counter()
    result = simulate_fmu(unzipdir, validate=False, stop_time=steps * H, step_size=H,
                          output_interval=H, fmi_type="CoSimulation", output=OUTPUTS,
                          model_description=md)
    wall = time.perf_counter() - start
    return wall, np.column_stack((result["q[1]"], result["q[2]"]))


def max_dq1(a: np.ndarray, b: np.ndarray) -> float:
    """max |Δq1| (rad) over the rows both traces have."""
    rows = min(len(a), len(b))
    return float(np.max(np.abs(a[:rows, 0] - b[:rows, 0])))


# ---- the benchmark -----------------------------------------------------------------------

def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=20.0, help="simulated seconds")
    parser.add_argument("--repeat", type=int, default=3, help="repetitions (best is kept)")
    parser.add_argument("--control-duration", type=float, default=None,
                        help="simulated seconds for python-control (default: --duration); "
                        "its µs per step are scaled from it")
    args = parser.parse_args()
    steps = int(round(args.duration / H))
    c_steps = int(round((args.control_duration or args.duration) / H))
    if c_steps > steps:
        raise SystemExit("--control-duration must not exceed --duration")
    over = [f"simulation.duration={args.duration}"]
    paper = load_pipeline(PAPER, over)
    # The peers' loop in cosim: the baseline's own blocks only (no sensor, M̂, observer).
    same = load_pipeline(PAPER, over + ['runs.baseline.blocks=["reference", "controller"]'])
    pd = load_pipeline(PD, over)
    if paper.plant != pd.plant or paper.plant.parameters:
        raise SystemExit("expected both pipelines on the built-in arm at its defaults")

    ref = reference(paper, steps + 1)
    if pd.reference != paper.reference:
        raise SystemExit("expected the same reference in both pipelines")
    pdg = pd_gains(pd)
    nng, w0, v0 = nn_setup(paper)
    x0_plant = np.array([Q0, Q0, QDOT0, QDOT0])
    x0_nn = np.concatenate((x0_plant, w0.ravel(), v0.ravel()))
    pd_loop, nn_loop = control_loop(control_pd(pdg)), control_loop(control_nn(nng, w0.size))

    plant = open_plant(paper)
    with tempfile.TemporaryDirectory() as tmp:
        md = read_model_description(plant.path)
        check_fmu_parameters(md)
        unzipdir = extract(plant.path, tmp)  # once: FMPy would unzip the archive every call
        variants: dict[str, Callable[[int], tuple[float, np.ndarray]]] = {
            "cosim_nn": lambda n: cosim_run(same, "baseline", plant, n),
            "cosim_nn_chain": lambda n: cosim_run(paper, "baseline", plant, n),
            "cosim_pd": lambda n: cosim_run(pd, "pd_full_state", plant, n),
            "plain_nn": lambda n: plain_loop(nn_law(nng, w0, v0, ref), n),
            "plain_pd": lambda n: plain_loop(pd_law(pdg, ref), n),
            "control_nn": lambda n: control_run(nn_loop, ref, x0_nn, min(n, c_steps)),
            "control_pd": lambda n: control_run(pd_loop, ref, x0_plant, min(n, c_steps)),
            "fmpy": lambda n: fmpy_run(unzipdir, md, n),
            "fmpy_short": lambda n: fmpy_run(unzipdir, md, 10),
        }
        try:
            for measure in variants.values():  # numba JIT, FMU loading: outside the timing
                measure(10)
            best = {name: float("inf") for name in variants}
            traces: dict[str, np.ndarray] = {}
            for _ in range(args.repeat):  # interleaved: a slow spell hits every tool
                for name, measure in variants.items():
                    value, traces[name] = measure(steps)
                    best[name] = min(best[name], value)
        finally:
            plant.close()
    # Open loop, untimed: the closed-form plant against what FMPy's run of the FMU computed.
    _, plain_open = plain_loop(lambda k, x: (0.0, 0.0), steps)

    us = {name: 1e6 * value for name, value in best.items()}
    fmpy_marginal = 1e6 * (best["fmpy"] - best["fmpy_short"]) / (steps - 10)
    fmpy_call = us["fmpy"] / steps
    print(f"two-link arm, {args.duration:g} s at 1 kHz ({steps} steps, τ held 1 ms, plant RK4 "
          f"at 0.1 ms), best of {args.repeat}, interleaved")
    if c_steps < steps:
        print(f"python-control over {c_steps * H:g} s ({c_steps} steps), per step scaled "
              "from that")
    print("                                                              us/step")
    rows = [
        ("NN baseline  cosim fused, same loop (reference + controller)", us["cosim_nn"]),
        ("             cosim fused, pipeline's chain (+sensor, M, obs.)", us["cosim_nn_chain"]),
        ("             plain Python/NumPy loop", us["plain_nn"]),
        ("             python-control (discrete nlsys, interconnect)", us["control_nn"]),
        ("PD + G(q)    cosim fused, pipeline's chain (+sensor, M)", us["cosim_pd"]),
        ("             plain Python/NumPy loop", us["plain_pd"]),
        ("             python-control (discrete nlsys, interconnect)", us["control_pd"]),
        ("open loop    FMPy simulate_fmu, per step beyond set-up", fmpy_marginal),
        ("             FMPy simulate_fmu, whole call / steps", fmpy_call),
    ]
    for label, value in rows:
        print(f"  {label:62s}{value:9.2f}")
    print("ratios (cosim / tool; < 1: cosim faster)          NN baseline        PD")
    for label, tool_nn, tool_pd in (("cosim / python-control", us["control_nn"],
                                     us["control_pd"]),
                                    ("cosim / simulate_fmu (open loop)", fmpy_marginal,
                                     fmpy_marginal),
                                    ("cosim / numpy loop", us["plain_nn"], us["plain_pd"])):
        nn, pdr = us["cosim_nn"] / tool_nn, us["cosim_pd"] / tool_pd
        print(f"  {label:34s}{nn:10.4f} ({1 / nn:6.1f}x){pdr:10.4f} ({1 / pdr:6.1f}x)")
    chain = us["cosim_nn_chain"]
    print(f"  NN baseline, pipeline's chain: / python-control {chain / us['control_nn']:.4f}, "
          f"/ simulate_fmu {chain / fmpy_marginal:.2f}")
    diff = {pair: max_dq1(traces[pair[0]], traces[pair[1]]) for pair in (
        ("cosim_pd", "plain_pd"), ("cosim_pd", "control_pd"), ("cosim_nn", "plain_nn"),
        ("cosim_nn", "control_nn"), ("cosim_nn", "cosim_nn_chain"))}
    print(f"agreement, max |q1 difference| (rad), over {args.duration:g} s "
          f"(python-control: {c_steps * H:g} s):")
    print(f"  PD loop      cosim vs numpy loop {diff['cosim_pd', 'plain_pd']:.2e}, "
          f"vs python-control {diff['cosim_pd', 'control_pd']:.2e}")
    print(f"  NN baseline  cosim vs numpy loop {diff['cosim_nn', 'plain_nn']:.2e}, "
          f"vs python-control {diff['cosim_nn', 'control_nn']:.2e}; cosim's two chains "
          f"{diff['cosim_nn', 'cosim_nn_chain']:.2e}")
    print(f"  open loop    FMPy simulate_fmu vs numpy loop "
          f"{max_dq1(traces['fmpy'], plain_open):.2e}")
    print(f"cosim_nn_us_per_step={us['cosim_nn']:.2f} cosim_pd_us_per_step={us['cosim_pd']:.2f} "
          f"python_control_nn_us_per_step={us['control_nn']:.1f} "
          f"simulate_fmu_us_per_step={fmpy_marginal:.2f} "
          f"cosim_nn/python_control={us['cosim_nn'] / us['control_nn']:.4f} "
          f"cosim_nn/simulate_fmu={us['cosim_nn'] / fmpy_marginal:.2f}")


if __name__ == "__main__":
    main()
