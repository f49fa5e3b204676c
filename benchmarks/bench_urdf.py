"""The URDF plant (``cosim build-fmu --urdf``) against what we did not write, with the figures
of issue 32:

1. M (CRBA), h (RNEA) and q̈ (ABA, with the URDF's friction and a 0.7 kg payload at the tip)
   at ``--states`` random states per arm (example-robot-data's UR5, UR10, Panda, Kinova,
   xArm7, Z1, SO-101 and our own test robot) against Pinocchio's: the largest relative error
   (|ours - theirs| / max |theirs|, per state). Figure: ≤ 1e-10. The FMU is called through
   FMPy's Model Exchange calls (set the states and τ, get M, h and the derivatives), the
   compiled model as any importer sees it.
2. The Panda's trajectory over 2 s (Co-Simulation, RK4 at the default 1e-4 s sub-step)
   against SciPy's DOP853 (rtol = atol = 1e-13) on Pinocchio's ABA: a free swing (τ = 0)
   with b = 0.1 N·m·s/rad, and with the URDF's own 0.003 N·m·s/rad (the wrist whips to
   ~74 rad/s), the latter also at 5e-5 s. Figure: ≤ 1e-6 rad.
3. MuJoCo (its own URDF compiler, on a mesh-free copy: it reads no .dae, and the inertias are
   the URDF's <inertial> either way) on the UR5: M, bias and q̈ at the same states.
4. Speed: the Panda FMU's cost per RK4 sub-step (one doStep of 0.1 s = 1000 sub-steps, so the
   FMI call is amortised) against Pinocchio's ABA called from Python (its C++ behind the
   binding, per call), timed in one run, best of ``--repeat``. Figure: ≤ 2×.

    .venv/bin/python benchmarks/bench_urdf.py [--states 1000] [--repeat 5]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pinocchio as pin

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
from fmu_helpers import FmuInstance  # noqa: E402
from urdf_helpers import (  # noqa: E402
    ARMS,
    OWN_ROBOT,
    ChainFmu,
    dynamics_errors,
    panda_swing,
    pinocchio_model,
    random_states,
    relative_error,
)

from plant_fmu import build_urdf_fmu, read_urdf  # noqa: E402

PAYLOAD = 0.7  # kg


def arm_errors(path, states: int, cache: Path) -> np.ndarray:
    """The FMU's M, h, q̈ against Pinocchio's at ``states`` random states, 0.7 kg at the
    tip (relative; urdf_helpers.dynamics_errors)."""
    return dynamics_errors(path, build_urdf_fmu(path, cache_dir=cache), read_urdf(path),
                           PAYLOAD, np.random.default_rng(0), states)


def trajectory_error(cache: Path, damping: float | None, rk4_step: float,
                     rk4_motion: float | None) -> tuple[float, float]:
    """Largest |q_FMU - q_solve_ivp| over 2 s (rad) and the fastest joint speed (rad/s)."""
    chain = read_urdf(ARMS["panda"])
    b = chain.damping if damping is None else np.full(chain.n, damping)
    trace, q, qdot = panda_swing(build_urdf_fmu(ARMS["panda"], fmi_version=3, cache_dir=cache),
                                 chain, b, rk4_step, rk4_motion)
    return float(np.abs(trace - q).max()), float(np.abs(qdot).max())


def mujoco_errors(states: int) -> np.ndarray | None:
    try:
        import mujoco
    except ImportError:
        print("mujoco: not installed (pip install mujoco); skipped")
        return None
    import yourdfpy

    path = ARMS["ur5"]
    urdf = yourdfpy.URDF.load(str(path), build_scene_graph=False, load_meshes=False)
    for link in urdf.robot.links:  # MuJoCo reads no .dae; the dynamics need no meshes
        link.visuals, link.collisions = [], []
    mj = mujoco.MjModel.from_xml_string(urdf.write_xml_string().decode())
    mj_data = mujoco.MjData(mj)
    chain = read_urdf(path)
    assert [mj.joint(i).name for i in range(mj.njnt)] == list(chain.joints)
    with tempfile.TemporaryDirectory(prefix="bench_urdf_") as tmp:
        plant = ChainFmu(build_urdf_fmu(path, cache_dir=tmp))
        worst = np.zeros(3)
        try:
            for q, qd, tau in zip(*random_states(chain, np.random.default_rng(1), states),
                                  strict=True):
                mj_data.qpos[:], mj_data.qvel[:], mj_data.qfrc_applied[:] = q, qd, tau
                mujoco.mj_forward(mj, mj_data)
                M = np.zeros((chain.n, chain.n))
                mujoco.mj_fullM(mj, mj_data, M)
                theirs = (M, mj_data.qfrc_bias.copy(), mj_data.qacc.copy())
                pairs = zip(plant.terms(q, qd, tau), theirs, strict=True)
                worst = np.maximum(worst, [relative_error(a, b) for a, b in pairs])
        finally:
            plant.free()
    return worst


def speed(cache: Path, repeat: int) -> tuple[float, float]:
    """µs per RK4 sub-step of the Panda FMU, µs per pin.aba call from Python."""
    path = ARMS["panda"]
    chain = read_urdf(path)
    model = pinocchio_model(path, chain)
    data = model.createData()
    q, qd, tau = (np.ascontiguousarray(a[0]) for a in
                  random_states(chain, np.random.default_rng(2), 1))
    # The FMU swings freely (τ = 0) with some damping, so that its motion stays bounded over
    # the 2 s x repeats it is stepped; the cost of a sub-step does not depend on the state.
    # Sub-steps of 1e-4 s throughout (rk4_motion off), so that a step of 0.1 s is 1000.
    damping = {f"b[{i + 1}]": 1.0 for i in range(chain.n)}
    plant = FmuInstance(build_urdf_fmu(path, fmi_version=2, cache_dir=cache), "CoSimulation",
                        {"rk4_step": 1e-4, "rk4_motion": 1e9, **damping})
    fmu_best = aba_best = np.inf
    calls, substeps, t = 20, 1000, 0.0
    try:
        for _ in range(repeat):  # interleaved, so that a slow spell hits both
            start = time.perf_counter()
            for _ in range(calls):
                plant.do_step(t, 0.1)
                t += 0.1
            fmu_best = min(fmu_best, (time.perf_counter() - start) / (calls * substeps))
            start = time.perf_counter()
            for _ in range(calls * substeps):
                pin.aba(model, data, q, qd, tau)
            aba_best = min(aba_best, (time.perf_counter() - start) / (calls * substeps))
    finally:
        plant.free()
    return fmu_best * 1e6, aba_best * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--states", type=int, default=1000)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench_urdf_") as tmp:
        cache = Path(tmp)
        print(f"1. M, h, q̈ against Pinocchio at {args.states} random states (relative)")
        overall = 0.0
        for name, path in {**ARMS, "own (slider_turret)": OWN_ROBOT}.items():
            worst = arm_errors(path, args.states, cache)
            overall = max(overall, worst.max())
            print(f"   {name:<20} n={read_urdf(path).n}  M {worst[0]:.1e}  h {worst[1]:.1e}  "
                  f"q̈ {worst[2]:.1e}")
        print(f"   largest: {overall:.1e} (figure ≤ 1e-10)")
        print("2. Panda over 2 s, RK4 in the FMU against solve_ivp (DOP853, 1e-13)")
        print("   (the defaults: rk4_step 1e-4 s, shorter where a joint would move more than "
              "rk4_motion = 4e-3 rad in one; 'off': rk4_motion 1e9)")
        for damping, step, motion in ((0.1, 1e-4, None), (None, 1e-4, None), (None, 1e-4, 1e9),
                                      (None, 5e-5, 1e9)):
            error, fastest = trajectory_error(cache, damping, step, motion)
            what = "b = 0.1 N·m·s/rad" if damping else "the URDF's b = 0.003 N·m·s/rad"
            limit = "default" if motion is None else "off"
            print(f"   {what:<31} rk4_step {step:g} s, rk4_motion {limit:<7}: {error:.1e} rad "
                  f"(fastest joint {fastest:.0f} rad/s; figure ≤ 1e-6)")
        print("3. MuJoCo on the UR5 (relative)")
        worst = mujoco_errors(args.states)
        if worst is not None:
            print(f"   M {worst[0]:.1e}  bias {worst[1]:.1e}  q̈ {worst[2]:.1e}")
        fmu_us, aba_us = speed(cache, args.repeat)
        print("4. Speed, Panda (7 joints)")
        print(f"   fmu_us_per_rk4_substep={fmu_us:.2f} pinocchio_aba_us_per_call={aba_us:.2f} "
              f"ratio={fmu_us / aba_us:.2f} (figure ≤ 2)")


if __name__ == "__main__":
    main()
