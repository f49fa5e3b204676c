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
from .blocks.observer import FlnnObserver
from .blocks.reference import SinusoidReference
from .blocks.sensor import PositionSensor
from .fmu import Fmu, FmuError, PlantVariables
from .master import Diverged, simulate
from .pipeline import Pipeline, PipelineError, Run
from .safety import Gains, SafeSet, evaluate
from .trace import Trace


@dataclass
class RunResult:
    name: str
    trace: Trace
    metrics: dict
    safety: dict
    complete: bool
    error: str | None = None
    extra: dict = field(default_factory=dict)

    def summary(self) -> dict:
        out = {"complete": self.complete, "metrics": self.metrics, "safety": self.safety}
        if self.error:
            out["error"] = self.error
        return out


def plant_path(pipeline: Pipeline) -> Path:
    if pipeline.plant.fmu is not None:
        path = Path(pipeline.plant.fmu)
        if not path.is_file():
            raise PipelineError(f"plant.fmu: {path} does not exist")
        return path
    b = pipeline.plant.builtin
    return build_fmu(links=b.links, fmi_version=b.fmi_version)


def make_blocks(pipeline: Pipeline, run: Run, links: int) -> list:
    ref = pipeline.reference
    if len(ref.offset) != links:
        raise PipelineError(f"reference.offset has {len(ref.offset)} joints, the plant has "
                            f"{links}")
    amplitude = np.array(ref.amplitude, float)
    phase = np.array(ref.phase, float) if ref.phase is not None else np.zeros_like(amplitude)
    reference = SinusoidReference(np.array(ref.offset, float), amplitude,
                                  np.array(ref.frequency, float), phase, ref.safe_case)
    for section, key in [(run.controller, "kv"), (run.controller, "lam")]:
        value = getattr(section, key)
        if isinstance(value, list) and len(value) != links:
            raise PipelineError(f"controller.{'lambda' if key == 'lam' else key} has "
                                f"{len(value)} entries, the plant has {links} joints")
    return [reference, PositionSensor(**run.sensor.model_dump()),
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


def run(pipeline: Pipeline, out_dir: str | Path | None = None,
        progress: bool = True) -> dict[str, RunResult]:
    """Run every run of ``pipeline``; write the run folder if ``out_dir`` is given.

    Raises :class:`Diverged` (after writing what was computed) when a run diverges.
    """
    path = plant_path(pipeline)
    links = pipeline.plant.builtin.links if pipeline.plant.builtin else None
    variables = PlantVariables.default(links or _count_joints(path))
    links = len(variables.q)
    sim = pipeline.simulation
    steps = int(round(sim.duration / sim.step))
    results: dict[str, RunResult] = {}
    out = Path(out_dir) if out_dir else None
    if out:
        out.mkdir(parents=True, exist_ok=True)
    plant = Fmu(path, variables, dict(pipeline.plant.parameters))
    try:
        for name, spec in pipeline.runs.items():
            blocks = make_blocks(pipeline, spec, links)
            trace = Trace(links, steps, sim.step)
            report = _progress(name, steps) if progress else None
            error, wall = None, float("nan")
            try:
                wall = simulate(plant, blocks, trace, progress=report)
            except (Diverged, KeyboardInterrupt) as exc:
                error = str(exc) or "interrupted (Ctrl-C)"
                raise_after = exc
            else:
                raise_after = None
            finally:
                if report and sys.stderr.isatty():
                    print(file=sys.stderr)
            done = trace.completed()
            metrics, safety = evaluate(done, safe_set(pipeline), gains(spec, links))
            metrics["wall_time_s"] = wall
            metrics["steps_per_second"] = steps / wall if wall == wall and wall > 0 else None
            metrics["simulated_time_s"] = float(done.time[-1]) if done.rows_done else 0.0
            results[name] = RunResult(name, done, metrics, safety, error is None, error)
            if out:
                write_run_folder(out, pipeline, results, plant)
            if raise_after is not None:
                raise raise_after
    except FmuError as exc:
        raise PipelineError(str(exc)) from None
    finally:
        plant.close()
    return results


def _count_joints(path: Path) -> int:
    from fmpy import read_model_description

    names = {v.name for v in read_model_description(str(path)).modelVariables}
    n = 0
    while f"q[{n + 1}]" in names:
        n += 1
    if n == 0:
        raise PipelineError(f"{path}: no output named q[1]: not an arm FMU of this interface")
    return n


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
                     plant: Fmu) -> None:
    """summary.json plus one trace_<run>.npz per run (all signals, SI units)."""
    complete = all(r.complete for r in results.values()) and len(results) == len(pipeline.runs)
    md = plant.model_description
    summary = {
        "complete": complete,
        "pipeline": pipeline.model_dump(by_alias=True),
        "plant": {"path": str(plant.path), "model_name": md.modelName,
                  "fmi_version": md.fmiVersion, "guid": md.guid},
        "runs": {name: r.summary() for name, r in results.items()},
    }
    tmp = out / "summary.json.tmp"
    tmp.write_text(json.dumps(_jsonable(summary), indent=2) + "\n")
    tmp.replace(out / "summary.json")
    for name, r in results.items():
        np.savez_compressed(out / f"trace_{name}.npz", time=r.trace.time, **r.trace.arrays)
