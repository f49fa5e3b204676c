"""The figures of a plant that is a system of FMUs (issue 53; docs/systems.md), in one
process:

1. Ideal drives: pipelines/arm_with_drives.toml with every drive made ideal (N = kt = 1,
   i_max = 1e300 A, T = 0 s, J = 0 kg·m²) against pipelines/paper_safety.toml on the
   one-FMU arm: the largest |Δq| (rad) over every run and step.
2. A second master: pipelines/arm_with_drives.toml with its own drives, stepped every 2
   master steps, exported to SSP (`cosim export-ssp`), read back by FMPy's own SSP reader
   and stepped by a plain FMPy loop (:func:`plain_fmpy_loop`) with each run's commanded
   torque: the largest |Δq| (rad) against cosim's runs.
3. The system master's overhead: a step of the two-FMU system (drives and arm,
   ``SystemPlant.step``) against the two FMUs' own steps (each: set its inputs, doStep, get
   its outputs, through the raw FMI functions with prebuilt arguments, as cosim's one-FMU
   adapter steps), in interleaved blocks of 2000 steps so that a slow spell of the machine
   hits both; the median block of each, and their ratio.

The last line is

    ideal_max_dq_rad=A second_master_max_dq_rad=B system_us=C fmus_us=D ratio=C/D

Run: .venv/bin/python benchmarks/bench_systems.py [--duration 20] [--blocks 40]
"""

from __future__ import annotations

import argparse
import ctypes
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path

import numpy as np
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
from fmpy.fmi3 import FMU3Slave
from fmpy.ssp.ssd import read_ssd

from cosim.config import load_pipeline
from cosim.plant.lifecycle import open_instance
from cosim.plant_source import open_plant
from cosim.runner import run

ROOT = Path(__file__).resolve().parent.parent
SYSTEM = ROOT / "pipelines" / "arm_with_drives.toml"
ONE_FMU = ROOT / "pipelines" / "paper_safety.toml"
IDEAL = {"N": 1.0, "kt": 1.0, "i_max": 1e300, "T": 0.0, "J": 0.0}
BLOCK = 2000  # steps per timed block


def ideal_drives(duration: float) -> float:
    """Figure 1: the largest |Δq| between the arm behind ideal drives and the arm alone."""
    sets = [f"simulation.duration={duration}"]
    ideal = "plant.parameters={" + ", ".join(f'"drives.{key}[{i}]" = {value!r}'
                                             for key, value in IDEAL.items()
                                             for i in (1, 2)) + "}"
    behind = run(load_pipeline(SYSTEM, [*sets, ideal]), None, progress=False)
    alone = run(load_pipeline(ONE_FMU, sets), None, progress=False)
    return max(float(np.max(np.abs(behind[name].trace["q"] - alone[name].trace["q"])))
               for name in alone)


def started(ssd, folder: Path) -> tuple[dict, dict]:
    """Every component of an SSP read by FMPy, instantiated and initialised by FMPy with its
    parameter values: (FMPy slaves, value references) by component name."""
    fmus, vr = {}, {}
    for component in ssd.system.elements:
        path = str(folder / component.source)
        md = read_model_description(path)
        cls = FMU2Slave if md.fmiVersion.startswith("2") else FMU3Slave
        # unpacked into ``folder`` (FMPy's default, a temporary folder, is never removed)
        unpacked = extract(path, unzipdir=folder / f"{component.name}.unpacked")
        fmu = cls(guid=md.guid, unzipDirectory=unpacked, instanceName=component.name,
                  modelIdentifier=md.coSimulation.modelIdentifier)
        fmu.instantiate()
        refs = {v.name: v.valueReference for v in md.modelVariables}
        values = {p.name: float(p.value) for binding in component.parameterBindings
                  for parameters in binding.parameterValues for p in parameters.parameters}
        if md.fmiVersion.startswith("2"):
            fmu.setupExperiment(startTime=0.0)
            fmu.enterInitializationMode()
            fmu.setReal([refs[k] for k in values], list(values.values()))
        else:
            fmu.enterInitializationMode(startTime=0.0)
            fmu.setFloat64([refs[k] for k in values], list(values.values()))
        fmu.exitInitializationMode()
        fmus[component.name], vr[component.name] = fmu, refs
    return fmus, vr


def plain_fmpy_loop(ssp: Path, folder: Path, tau: np.ndarray, h: float,
                    multiple: int) -> np.ndarray:
    """The arm-with-drives system of ``ssp`` (components ``drives``, FMI 3, and ``arm``,
    FMI 2), read by FMPy's SSP reader and stepped by FMPy alone with the commanded torque
    ``tau`` (one row per step, N·m): at each step the drives (whose torque depends on their
    command within the instant) before the arm, the drives every ``multiple`` steps holding
    their command and torque between. The arm's joint angles, one row per step (rad)."""
    ssd = read_ssd(str(ssp))  # checks the file against SSP 1.0's schema
    with zipfile.ZipFile(ssp) as archive:
        archive.extractall(folder)
    fmus, vr = started(ssd, folder)
    arm, drives = fmus["arm"], fmus["drives"]
    given = [vr["drives"][n] for n in ("tau[1]", "tau[2]", "J_reflected[1]", "J_reflected[2]")]
    taken = [vr["arm"][n] for n in ("tau[1]", "tau[2]", "Jm[1]", "Jm[2]")]
    command = [vr["drives"]["tau_cmd[1]"], vr["drives"]["tau_cmd[2]"]]
    angles = [vr["arm"]["q[1]"], vr["arm"]["q[2]"]]
    steps = len(tau) - 1
    q = np.empty((steps + 1, 2))
    q[0] = arm.getReal(angles)
    out = drives.getFloat64(given)
    try:
        for k in range(steps):
            t = k * h
            if k % multiple == 0:
                drives.setFloat64(command, list(tau[k]))
                out = drives.getFloat64(given)
            arm.setReal(taken, list(out))
            if k % multiple == 0:
                drives.doStep(t, multiple * h)
            arm.doStep(t, h)
            if (k + 1) % multiple == 0:
                out = drives.getFloat64(given)
            q[k + 1] = arm.getReal(angles)
    finally:
        for fmu in fmus.values():
            fmu.terminate()
            fmu.freeInstance()
    return q


def second_master(duration: float) -> float:
    """Figure 2: the largest |Δq| between cosim's runs and a plain FMPy loop."""
    sets = [f"simulation.duration={duration}",
            "plant.system.components.drives.step_multiple=2"]
    with tempfile.TemporaryDirectory() as tmp:
        ssp = Path(tmp) / "arm_with_drives.ssp"
        subprocess.run([sys.executable, "-m", "cosim", "export-ssp", str(SYSTEM), "--output",
                        str(ssp), *(a for s in sets for a in ("--set", s))], check=True,
                       capture_output=True)
        results = run(load_pipeline(SYSTEM, sets), None, progress=False)
        worst = 0.0
        for name, result in results.items():
            q = plain_fmpy_loop(ssp, Path(tmp) / name, result.trace["tau"],
                                result.trace.dt, 2)
            worst = max(worst, float(np.max(np.abs(q - result.trace["q"]))))
    return worst


def own_steps(path: Path):
    """An FMU alone: instantiated, initialised, and a function stepping it ``n`` times
    (set every input, doStep, get every output) that returns its seconds."""
    md = read_model_description(str(path))
    fmi = open_instance(path, md, "CoSimulation", "alone")
    fmi.initialize(0.0, {})
    set_, do_step, get = fmi.raw_step_functions()
    inputs = [v.valueReference for v in md.modelVariables if v.causality == "input"]
    outputs = [v.valueReference for v in md.modelVariables if v.causality == "output"]
    vi, vo = (ctypes.c_uint32 * len(inputs))(*inputs), (ctypes.c_uint32 * len(outputs))(*outputs)
    given, read = np.zeros(len(inputs)), np.zeros(len(outputs))
    c = fmi.fmu.component
    extra = ((len(inputs),), (len(outputs),)) if md.fmiVersion.startswith("3") else ((), ())
    flags = np.zeros(4)
    tail = ((1,) if md.fmiVersion.startswith("2") else
            (True, *(flags.ctypes.data + 8 * i for i in range(4))))
    set_args = (c, vi, len(inputs), given.ctypes.data, *extra[0])
    get_args = (c, vo, len(outputs), read.ctypes.data, *extra[1])
    clock = {"t": 0.0}

    def steps(n: int, h: float = 1e-3) -> float:
        start = time.perf_counter()
        t = clock["t"]
        for _ in range(n):
            given[0] = 1.0
            set_(*set_args)
            do_step(c, t, h, *tail)
            get(*get_args)
            t += h
        clock["t"] = t
        return time.perf_counter() - start

    return fmi, steps


def overhead(blocks: int) -> tuple[float, float]:
    """Figure 3: µs per step of the system and of its two FMUs' own steps (medians)."""
    pipeline = load_pipeline(SYSTEM)
    plant = open_plant(pipeline)
    plant.start(0.0)
    files = {c: Path(i["file"]) for c, i in plant.info()["system"]["components"].items()}
    alone = [own_steps(files["arm"]), own_steps(files["drives"])]
    clock = {"t": 0.0}

    def system_steps(n: int, h: float = 1e-3) -> float:
        start = time.perf_counter()
        t = clock["t"]
        for _ in range(n):
            plant.tau[0] = 1.0
            plant.step(t, h)
            t += h
        clock["t"] = t
        return time.perf_counter() - start

    system, fmus = [], []
    try:
        for _ in range(blocks):
            system.append(system_steps(BLOCK) / BLOCK)
            fmus.append(sum(steps(BLOCK) for _, steps in alone) / BLOCK)
    finally:
        plant.close()
        for fmi, _ in alone:
            fmi.close()
    return float(np.median(system)) * 1e6, float(np.median(fmus)) * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=20.0, help="s per run")
    parser.add_argument("--blocks", type=int, default=40, help="timed blocks of each")
    args = parser.parse_args()
    ideal = ideal_drives(args.duration)
    print(f"1. ideal drives against the one-FMU arm, every run of paper_safety "
          f"({args.duration:g} s): largest |dq| = {ideal:.3g} rad")
    second = second_master(args.duration)
    print(f"2. a plain FMPy loop on the exported SSP (drives every 2 steps), every run "
          f"({args.duration:g} s): largest |dq| = {second:.3g} rad")
    system, fmus = overhead(args.blocks)
    print(f"3. a step of the two-FMU system {system:.2f} us, the two FMUs' own steps "
          f"{fmus:.2f} us: {system / fmus:.3f}x (median of {args.blocks} blocks of {BLOCK})")
    print(f"ideal_max_dq_rad={ideal:.3g} second_master_max_dq_rad={second:.3g} "
          f"system_us={system:.2f} fmus_us={fmus:.2f} ratio={system / fmus:.3f}")


if __name__ == "__main__":
    main()
