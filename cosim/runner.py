"""Run a pipeline: build or open the plant, run each named run through the master, evaluate
safety and metrics, and write the run folder (summary.json, trace_<run>.npz).

A run that diverges or is interrupted keeps what was computed: its completed rows are
evaluated and written, and summary.json says ``"complete": false`` with the reason.
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from plant_fmu import build_fmu

from .blocks.controller import NnController
from .blocks.inertia import InertiaModel
from .blocks.observer import FlnnObserver
from .blocks.reference import SinusoidReference
from .blocks.sensor import PositionSensor
from .figures import write_figures
from .fmu import Fmu, FmuError
from .master import Diverged, simulate
from .pipeline import Pipeline, PipelineError, Run
from .recording import Recorder, RunSpec, package_versions
from .safety import Gains, SafeSet, check_signals, evaluate
from .trace import Trace


@dataclass
class RunResult:
    name: str
    trace: Trace
    metrics: dict
    safety: dict
    complete: bool
    error: str | None = None
    failure: BaseException | None = field(default=None, repr=False)
    inertia_model: dict = field(default_factory=dict)  # source and link parameters used

    def summary(self) -> dict:
        out = {"complete": self.complete, "inertia_model": self.inertia_model,
               "metrics": self.metrics, "safety": self.safety}
        if self.error:
            out["error"] = self.error
        return out


def plant_path(pipeline: Pipeline) -> Path:
    """The plant FMU file: the pipeline's ``plant.fmu``, or the built-in plant, built on
    demand and cached by its build options."""
    if pipeline.plant.fmu is not None:
        path = Path(pipeline.plant.fmu)
        if not path.is_file():
            raise PipelineError(f"plant.fmu: {path} does not exist")
        return path
    b = pipeline.plant.builtin
    return build_fmu(links=b.links, fmi_version=b.fmi_version)


def open_plant(pipeline: Pipeline) -> Fmu:
    """The pipeline's plant FMU, checked: file, Co-Simulation binary, ``plant.variables``
    and ``plant.parameters`` (:class:`PipelineError` naming the file and the variable)."""
    try:
        return Fmu(plant_path(pipeline), pipeline.plant.variables.model_dump(),
                   dict(pipeline.plant.parameters))
    except FmuError as exc:
        raise PipelineError(str(exc)) from None


def inertia_source(run: Run, plant: Fmu) -> str:
    """Resolve ``inertia_model.source``: "fmu" when the plant maps M (for "auto"), else
    "nominal"."""
    source = run.inertia_model.source
    return ("fmu" if plant.has_M else "nominal") if source == "auto" else source


def check_sizes(pipeline: Pipeline, plant: Fmu) -> None:
    """Everything sized per joint must have the plant's n entries, and each run must find
    the plant outputs it reads; else one :class:`PipelineError` naming the key."""
    n, file = plant.links, plant.path.name
    joints = f"the plant ({file}) has {n} joint{'s' * (n != 1)}"
    ref = pipeline.reference
    if len(ref.offset) != n:
        raise PipelineError(f"reference.offset has {len(ref.offset)} entries (one per joint, "
                            f"rad); {joints}")
    for name, run in pipeline.runs.items():
        sized = {"controller.kv": run.controller.kv, "controller.lambda": run.controller.lam,
                 "observer.tau_d": run.observer.tau_d,
                 "observer.initial_velocity": run.observer.initial_velocity,
                 **{f"inertia_model.{k}": getattr(run.inertia_model, k)
                    for k in ("m", "l", "lc", "I")}}
        for key, value in sized.items():
            if isinstance(value, list) and len(value) != n:
                raise PipelineError(f"{key} (run '{name}') has {len(value)} entries; {joints}")
        if run.controller.variant == "baseline" and not plant.has_qdot:
            raise PipelineError(
                f"run '{name}': the full-state baseline reads the true joint velocity, but "
                f"{file} has no qdot mapping (no outputs qdot[1]..qdot[{n}]); map them with "
                "plant.variables.qdot = [...] or drop the run")
        if run.inertia_model.source == "fmu" and not plant.has_M:
            raise PipelineError(
                f"inertia_model.source = \"fmu\" (run '{name}'), but {file} has no M mapping "
                f"(no outputs M[1,1]..M[{n},{n}]); map them with plant.variables.M = [...] "
                "(n×n, row-major) or use source = \"nominal\"")


def inertia_model(run: Run, plant: Fmu) -> InertiaModel:
    """The run's inertia model block (nominal links: the pipeline's, else the paper's arm)."""
    spec = run.inertia_model
    return InertiaModel(inertia_source(run, plant), spec.m, spec.l, spec.lc, spec.I)


def describe_inertia(model: InertiaModel, plant: Fmu) -> str:
    if model.source == "fmu":
        return f"from {plant.path.name}'s M outputs ({', '.join(plant.variables.M[:2])}, …)"
    links = model.nominal_links(plant.links)
    return (f"nominal (m = {links['m']} kg, l = {links['l']} m, lc = {links['lc']} m, "
            f"I = {links['I']} kg·m²) at the measured position"
            + ("" if plant.has_M else f"; {plant.path.name} maps no M outputs"))


def make_blocks(pipeline: Pipeline, run: Run, plant: Fmu) -> list:
    """reference, sensor, inertia model, observer, controller: the order data flows in."""
    ref = pipeline.reference
    amplitude = np.array(ref.amplitude, float)
    phase = np.array(ref.phase, float) if ref.phase is not None else np.zeros_like(amplitude)
    reference = SinusoidReference(np.array(ref.offset, float), amplitude,
                                  np.array(ref.frequency, float), phase, ref.safe_case)
    return [reference, PositionSensor(**run.sensor.model_dump()), inertia_model(run, plant),
            FlnnObserver(**run.observer.model_dump()),
            NnController(**run.controller.model_dump())]


def safe_set(pipeline: Pipeline) -> SafeSet:
    s = pipeline.safety
    return SafeSet(s.position_bound, s.velocity_bound, s.error_bound, s.error_rate_bound,
                   s.observer_error_bound, s.z_wo_tilde, s.z_wc_tilde, s.z_vc_tilde)


def gains(run: Run, links: int) -> Gains:
    lam = np.broadcast_to(np.asarray(run.controller.lam, float), (links,)).copy()
    return Gains(lam, run.controller.f, run.controller.g, run.observer.fo,
                 run.controller.variant == "proposed")


def _progress(name: str, total: int):
    tty = sys.stderr.isatty()
    marks = {int(total * f) for f in (0.25, 0.5, 0.75)}

    def report(k: int) -> None:
        if tty:
            print(f"\r  {name}: {100 * k / total:5.1f} %", end="", file=sys.stderr, flush=True)
        elif any(abs(k - m) < 1000 and k <= m for m in marks):
            print(f"  {name}: {100 * k / total:.0f} %", file=sys.stderr, flush=True)

    return report


def run(pipeline: Pipeline, out_dir: str | Path | None = None, progress: bool = True,
        record: bool = True, spawn: bool = False, connect: str | None = None,
        figures: bool = True) -> dict[str, RunResult]:
    """Run every run of ``pipeline``; write the run folder if ``out_dir`` is given: summary,
    traces, ``recording.rrd`` (unless ``record`` is false) and PNG figures.

    ``spawn`` starts a Rerun viewer that follows the runs live; ``connect`` streams to one
    already running at that URL. Raises :class:`Diverged` (or ``KeyboardInterrupt``) after
    writing what was computed, marked incomplete.
    """
    plant = open_plant(pipeline)
    try:
        check_sizes(pipeline, plant)
        plant.start(0.0)  # refuses bad parameters before anything is written
    except (PipelineError, FmuError) as exc:
        plant.close()
        raise PipelineError(str(exc)) from None
    links = plant.links
    sim = pipeline.simulation
    steps = int(round(sim.duration / sim.step))
    results: dict[str, RunResult] = {}
    out = Path(out_dir) if out_dir else None
    if out:
        out.mkdir(parents=True, exist_ok=True)
    # The writer imports Rerun in its own process while the first run compiles its blocks.
    recorder = _open_recorder(out, pipeline, spawn, connect) if out and record else None
    failure: BaseException | None = None
    try:
        plant_info = plant.describe()
        if recorder is not None:
            recorder.set_properties(_properties(pipeline, plant_info))
        for name, spec in pipeline.runs.items():
            result = _run_one(name, spec, pipeline, plant, steps,
                              _link_lengths(plant_info, spec, links), recorder, progress)
            results[name] = result
            if out:
                write_run_folder(out, pipeline, results, plant_info)
            if not result.complete:
                failure = result.failure
                break
    except FmuError as exc:
        raise PipelineError(str(exc)) from None
    finally:
        plant.close()
        complete = failure is None and len(results) == len(pipeline.runs)
        if recorder is not None:
            reason = next((r.error for r in results.values() if r.error), "")
            recorder.close(complete, reason)
        if out and figures and results:
            _write_figures(out, pipeline, results)
    if failure is not None:
        raise failure
    return results


def _run_one(name: str, spec: Run, pipeline: Pipeline, plant: Fmu, steps: int,
             link_lengths: np.ndarray, recorder: Recorder | None, progress: bool) -> RunResult:
    """One run through the master, recorded chunk by chunk (one simulated second each)."""
    sim = pipeline.simulation
    links = plant.links
    blocks = make_blocks(pipeline, spec, plant)
    model = next(b for b in blocks if isinstance(b, InertiaModel))
    if progress:
        print(f"  {name}: inertia model {describe_inertia(model, plant)}", file=sys.stderr)
    trace = Trace(links, steps, sim.step)
    safe, run_gains = safe_set(pipeline), gains(spec, links)
    report = _progress(name, steps) if progress else None
    if recorder is not None:
        recorder.begin_run(RunSpec(name, links, sim.step, sim.duration, safe, run_gains,
                                   link_lengths))

    def on_chunk(k: int) -> None:
        if report:
            report(k)
        if recorder is not None:
            recorder.send_rows(name, trace.arrays, trace.rows_done)

    error, wall, failure = None, float("nan"), None
    handed_over = recorder.handoff_seconds if recorder is not None else 0.0
    try:
        wall = simulate(plant, blocks, trace, progress=on_chunk,
                        progress_every=max(1, int(round(1.0 / sim.step))))
    except (Diverged, KeyboardInterrupt) as exc:
        error, failure = str(exc) or "interrupted (Ctrl-C)", exc
    finally:
        if report and sys.stderr.isatty():
            print(file=sys.stderr)
    done = trace.completed()
    metrics, safety = evaluate(done, safe, run_gains)
    metrics["wall_time_s"] = wall
    metrics["steps_per_second"] = steps / wall if wall == wall and wall > 0 else None
    metrics["simulated_time_s"] = float(done.time[-1]) if done.rows_done else 0.0
    if recorder is not None:  # the loop's share of writing the recording
        metrics["recording_handoff_s"] = recorder.handoff_seconds - handed_over
    result = RunResult(name, done, metrics, safety, error is None, error, failure,
                       {"source": "nominal", **model.nominal_links(links)}
                       if model.source == "nominal" else {"source": "fmu"})
    if recorder is not None:
        recorder.send_rows(name, trace.arrays, trace.rows_done)
        recorder.end_run(name, result.summary())
    return result


def _open_recorder(out: Path, pipeline: Pipeline, spawn: bool,
                   connect: str | None) -> Recorder:
    sim = pipeline.simulation
    title = (f"{pipeline.name}: {' vs '.join(pipeline.runs)} "
             f"({sim.duration:g} s at {1 / sim.step:g} Hz)")
    return Recorder(out / "recording.rrd", title, list(pipeline.runs), spawn=spawn,
                    connect=connect)


def _properties(pipeline: Pipeline, plant_info: dict) -> dict[str, dict]:
    resolved = json.dumps(_jsonable(pipeline.model_dump(by_alias=True)))
    return {
        "pipeline": {"name": pipeline.name, "description": pipeline.description or "",
                     "resolved": resolved},
        "plant": {**{k: v for k, v in plant_info.items() if k not in ("parameters", "variables")},
                  "variables": json.dumps(plant_info["variables"]),
                  "parameters": json.dumps(plant_info["parameters"])},
        "versions": package_versions(),
    }


def _link_lengths(plant_info: dict, run: Run, links: int) -> np.ndarray:
    """Link lengths for drawing the arm: the FMU's ``l[i]`` parameters, else the run's
    nominal model's (1 m each unless given)."""
    params = plant_info["parameters"]
    names = [f"l[{i}]" for i in range(1, links + 1)]
    if all(n in params for n in names):
        return np.array([params[n] for n in names])
    return np.array(run.inertia_model.l or [1.0] * links)


def _write_figures(out: Path, pipeline: Pipeline, results: dict[str, RunResult]) -> None:
    links = next(iter(results.values())).trace.links
    checks = {name: check_signals(r.trace, safe_set(pipeline), gains(pipeline.runs[name], links))
              for name, r in results.items()}
    write_figures(out, {n: r.trace.time for n, r in results.items()}, checks,
                  {n: r.trace["tau"] for n, r in results.items()})


def _jsonable(x):
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_jsonable(v) for v in x]
    if isinstance(x, float) and not np.isfinite(x):
        return None
    if isinstance(x, np.floating | np.integer):
        return _jsonable(x.item())
    return x


def write_run_folder(out: Path, pipeline: Pipeline, results: dict[str, RunResult],
                     plant_info: dict) -> None:
    """summary.json over the runs so far, and trace_<run>.npz (all signals, SI units) for the
    run just finished, the last of ``results``; the earlier runs' traces are on disk."""
    complete = all(r.complete for r in results.values()) and len(results) == len(pipeline.runs)
    summary = {
        "complete": complete,
        "pipeline": pipeline.model_dump(by_alias=True),
        "plant": {"path": plant_info["file"], "model_name": plant_info["model_name"],
                  "fmi_version": plant_info["fmi_version"],
                  "guid": plant_info["instantiation_token"],
                  "variables": plant_info["variables"],
                  "parameters": plant_info["parameters"]},
        "runs": {name: r.summary() for name, r in results.items()},
    }
    tmp = out / "summary.json.tmp"
    tmp.write_text(json.dumps(_jsonable(summary), indent=2) + "\n")
    tmp.replace(out / "summary.json")
    name, latest = next(reversed(results.items()))
    np.savez_compressed(out / f"trace_{name}.npz", time=latest.trace.time, **latest.trace.arrays)
