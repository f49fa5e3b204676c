"""Run a pipeline: assemble it, run each run through the master while it is evaluated chunk
by chunk, and hand the evaluated result to the outputs (run folder, recording, figures).

A run that diverges or is interrupted keeps what was computed: its completed rows are
evaluated and written, and summary.json says ``"complete": false`` with the reason. A run
that diverges does not stop the others (:class:`RunsFailed` names each after all ran); an
interrupt does; a run that did not finish gets no figures.
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass, field
from pathlib import Path

from . import interface as io
from .assemble import RunPlan, Scenario, assemble, link_lengths
from .config import Pipeline, PipelineError
from .config.named_files import file_digests, named_files
from .engine import Diverged, simulate
from .evaluate import Evaluation
from .evaluate.parts import LOOP_METRIC_UNITS
from .outputs.figures import figure_files, write_figures
from .outputs.recording import Recorder, RunSpec, UrdfArm
from .outputs.recording.layout import check_views, derived_entities
from .outputs.run_folder import RunFolder, RunFolderError, jsonable
from .outputs.table import markdown_table
from .outputs.versions import package_versions
from .plant import PLANT_OUTPUTS
from .plant.mapping import FmuError
from .progress import percent, phase
from .signals import Trace


class RunsFailed(Diverged):
    """Runs that did not finish (each diverged, or its plant or a block failed), after every
    run of the pipeline was run: ``failed`` (their results, each with its ``error``) and
    ``results`` (every run's)."""

    def __init__(self, failed: list, results: dict):
        self.failed, self.results = failed, results
        first = failed[0].failure
        self.where, self.t = first.where, first.t
        RuntimeError.__init__(self, "; ".join(
            f"run '{r.name}': {r.error}" if len(failed) > 1 else str(r.error)
            for r in failed))


@dataclass
class RunResult:
    """One run's result, as :func:`run` returns it by run name.

    Attributes:
        name: the run's name (``[runs.NAME]``).
        trace: every signal of every completed row (:class:`cosim.signals.Trace`:
            ``trace["q"]`` an array (rows × joints), ``trace.time`` in s,
            ``trace.signals[name]`` its unit and meaning).
        evaluation: the evaluators' result: ``checks``, ``metrics``, ``safety`` (what
            summary.json holds), ``headlines`` and ``lines`` (what `cosim run` prints).
        complete: whether the run reached its end (False: it diverged, a block or the
            plant failed, or it was interrupted; ``error`` says which).
        error: why the run did not finish, or None.
        failure: the exception it ended with, or None.
        inertia_model: the model of the plant the run's blocks used (source, URDF, links).
        wall_time_s: the wall-clock time of its loop, s.
        blocks: what each block says of itself (its ``describe()``), by instance name.
        torque_asked: where the torque before a filter is in the trace (trace key, filter
            kind), or None without a filter.

    ``metrics`` and ``safety`` are the evaluation's; ``summary()`` is the run's entry of
    summary.json. SI units, radians.
    """

    name: str
    trace: Trace
    evaluation: Evaluation
    complete: bool
    error: str | None = None
    failure: BaseException | None = field(default=None, repr=False)
    inertia_model: dict = field(default_factory=dict)  # source and link parameters used
    wall_time_s: float = float("nan")
    blocks: dict = field(default_factory=dict)  # what each block says of itself (describe)
    torque_asked: tuple[str, str] | None = None  # (trace key, filter kind): see RunPlan

    @property
    def metrics(self) -> dict:
        return self.evaluation.metrics

    @property
    def safety(self) -> dict:
        return self.evaluation.safety

    def summary(self) -> dict:
        out = {"complete": self.complete, "inertia_model": self.inertia_model,
               "blocks": self.blocks, "metrics": self.metrics,
               "metric_units": {**self.evaluation.metric_units, **LOOP_METRIC_UNITS},
               "safety": self.safety, "evaluators": self.evaluation.evaluators}
        if self.error:
            out["error"] = self.error
        return out


def run(pipeline: Pipeline, out_dir: str | Path | None = None, progress: bool = True,
        record: bool = True, spawn: bool = False, connect: str | None = None,
        figures: bool = True, engine: str = "auto", force: bool = False,
        plant=None) -> dict[str, RunResult]:
    """Run every run of ``pipeline``; write the run folder if ``out_dir`` is given: summary,
    traces, ``recording.rrd`` (unless ``record`` is false) and PNG figures.

    A folder that holds files is refused unless ``force`` (which clears it first), and one
    another run is writing is refused. ``spawn`` starts a Rerun viewer that follows the runs
    live; ``connect`` streams to one already running at that URL. ``engine``: "auto" (the
    fused compiled loop where every block allows it), "fused" or "python". Raises
    :class:`Diverged`, ``KeyboardInterrupt`` or :class:`RunFolderError` after writing what
    was computed, with summary.json saying what is incomplete. ``plant``: an open
    :class:`~cosim.plant.fmu.Fmu` to re-use (it stays open).
    """
    scenario = assemble(pipeline, plant)
    plant_info = scenario.plant.info()
    if plant_info["unit_differences"]:  # a warning, not progress: said even when quiet
        print(f"cosim: warning: {plant_info['unit_differences']}", file=sys.stderr)
    results: dict[str, RunResult] = {}
    folder = recorder = None
    failure: BaseException | None = None
    try:
        named = file_digests(named_files(pipeline)) if out_dir else []
        folder = RunFolder.create(out_dir, force) if out_dir else None
        if folder is not None:  # what is to run, said before it runs (a crash keeps it)
            folder.named_files = named
            folder.write_summary(_summary(pipeline, results, plant_info), final=False)
        # The writer imports Rerun in its own process while the first run loads its blocks.
        arm = urdf_arm(pipeline) if folder is not None and record else None
        if folder is not None and record:
            recorder = _open_recorder(folder.path, scenario, spawn, connect, arm)
            recorder.set_properties(_properties(pipeline, plant_info))
        for name, plan in scenario.runs.items():
            result = _run_one(plan, scenario, plant_info, recorder, progress, engine, arm)
            results[name] = result
            if folder is not None:
                folder.write_trace(name, result.trace, result.evaluation)
                folder.write_summary(_summary(pipeline, results, plant_info), final=False)
            if not result.complete and not isinstance(result.failure, Diverged):
                failure = result.failure  # Ctrl-C: nothing more runs
                break
        # A run that diverged does not stop the others: each is run, then the failures said
        failed = [r for r in results.values() if isinstance(r.failure, Diverged)]
        if failed and failure is None:
            failure = RunsFailed(failed, results)
    except FmuError as exc:
        failure = PipelineError(str(exc))
    except BaseException as exc:  # Ctrl-C, SIGTERM, an OS error: still close and summarise
        failure = exc
    finally:
        scenario.close()
    if folder is None:
        if failure is not None:
            raise failure
        return results
    failure = _finish(folder, pipeline, results, plant_info, recorder, figures, failure,
                      progress)
    if failure is not None:
        raise failure
    return results


def _finish(folder: RunFolder, pipeline: Pipeline, results: dict, plant_info: dict,
            recorder: Recorder | None, figures: bool, failure: BaseException | None,
            progress: bool = False) -> BaseException | None:
    """The closing phases, each kept even if an earlier one failed or was interrupted:
    recording, figures, the final summary. Returns what to raise (the first failure)."""
    complete = failure is None and len(results) == len(pipeline.runs)
    reason = next((r.error for r in results.values() if r.error), "") or \
        (_describe(failure) if failure is not None else "")
    if recorder is not None:
        try:
            with phase("closing the recording", progress):
                recorder.close(complete, reason)
            folder.note("recording.rrd", True)
        except BaseException as exc:  # noqa: BLE001 (a second Ctrl-C, or the writer failed)
            folder.note("recording.rrd", False, _describe(exc))
            failure = failure or exc
    drawn = {n: r for n, r in results.items() if r.complete}  # a failed run has no figure
    if figures and drawn:
        try:
            with phase(f"drawing the figures ({len(figure_files())} PNG)", progress):
                write_figures(folder, {n: r.trace.time for n, r in drawn.items()},
                              {n: r.evaluation.checks for n, r in drawn.items()},
                              {n: r.trace["tau"] for n, r in drawn.items()},
                              {n: r.evaluation.barriers for n, r in drawn.items()},
                              {n: (r.trace[r.torque_asked[0]], r.torque_asked[1])
                               for n, r in drawn.items() if r.torque_asked})
        except BaseException as exc:  # noqa: BLE001
            for name in figure_files():
                if name not in folder.files:
                    folder.incomplete(name, _describe(exc))
            failure = failure or exc
    summary = _summary(pipeline, results, plant_info)
    summary["complete"] = summary["complete"] and failure is None
    summary["not_run"] = not_run(pipeline, results)
    if results:
        text = markdown_table(summary["runs"], f"{pipeline.name}: safety at a glance",
                              summary["not_run"])
        try:
            folder.write("summary.md", lambda tmp: tmp.write_text(text, encoding="utf-8"))
        except RunFolderError as exc:
            failure = failure or exc
    if failure is not None and not summary.get("error"):
        summary["error"] = _describe(failure)
    try:
        folder.write_summary(summary, final=True)
    except RunFolderError as exc:
        failure = exc if failure is None else RunFolderError(
            f"{_describe(failure)}; and {exc}")
    finally:
        folder.release()
    return failure


def not_run(pipeline: Pipeline, results: dict) -> list[str]:
    """The pipeline's runs without a result: those a failure left not run (after the one
    that failed, whose result is what it computed), or one stopped outside the loop."""
    return [name for name in pipeline.runs if name not in results]


def _describe(exc: BaseException) -> str:
    if isinstance(exc, KeyboardInterrupt):
        return str(exc) or "interrupted (Ctrl-C)"
    return str(exc) or type(exc).__name__


def _summary(pipeline: Pipeline, results: dict[str, RunResult], plant_info: dict) -> dict:
    complete = all(r.complete for r in results.values()) and len(results) == len(pipeline.runs)
    return {
        "complete": complete,
        "pipeline": pipeline.model_dump(by_alias=True),
        "plant": {"path": plant_info["file"], "model_name": plant_info["model_name"],
                  "fmi_version": plant_info["fmi_version"],
                  "guid": plant_info["instantiation_token"],
                  "variables": plant_info["variables"],
                  "parameters": plant_info["parameters"],
                  "unit_differences": plant_info["unit_differences"],
                  **({"system": plant_info["system"]} if "system" in plant_info else {})},
        "runs": {name: r.summary() for name, r in results.items()},
    }


def _run_one(plan: RunPlan, scenario: Scenario, plant_info: dict, recorder: Recorder | None,
             progress: bool, engine: str, arm: UrdfArm | None = None) -> RunResult:
    """One run through the master, evaluated and recorded chunk by chunk (one simulated
    second each); ``arm``: the plant's URDF, drawn in 3-D."""
    name, plant, sim = plan.name, scenario.plant, scenario.pipeline.simulation
    steps = scenario.steps
    if progress:
        for line in filter(None, (block.headline() for block in plan.blocks)):
            print(f"  {name}: {line}", file=sys.stderr)
    trace = plan.new_trace(steps)
    report = percent(name, steps) if progress else None
    entities = plan.entities()
    derived = derived_entities(plan.signals, _present(plan))
    recorded = sorted({key for key, _ in entities.values()} | {"q", "q_d"}
                      | {s for true, est, _ in derived.values() for s in (true, est)})
    evaluator = None

    def evaluate_rows() -> None:
        nonlocal evaluator
        first = evaluator is None
        if first:  # after the blocks' reset: the reference, and so every bound, is known
            evaluator = plan.evaluator(trace, {io.PLANT_PARAMETERS: plant_info["parameters"],
                                               io.PLANT_SYSTEM: plant_info.get("system"),
                                               io.UNCERTAINTY: plan.uncertainty})
        evaluator.update(trace.rows_done)
        if recorder is None:
            return
        if first:
            recorder.begin_run(RunSpec(
                name, plan.links, sim.step, sim.duration,
                {entity: (key, stem, plan.signals[key].width(plan.links))
                 for entity, (key, stem) in entities.items()},
                evaluator.bounds, link_lengths(plant_info, plan),
                tuple(n for n in evaluator.barrier_values if n != io.BARRIER_CONDITION), derived,
                {n: (declared.family, joint)
                 for n, (declared, joint) in evaluator.declared.items()}, arm))
        # Everything evaluated that the recorder has not been given (an interrupt between
        # the two leaves it for the next call).
        start, stop = recorder.sent[name], evaluator.upto
        recorder.send_rows(name, start, stop, {key: trace[key][start:stop] for key in recorded},
                           {n: v[start:stop] for n, v in evaluator.values.items()},
                           {n: v[start:stop] for n, v in evaluator.barrier_values.items()})

    def on_chunk(k: int) -> None:
        if report:
            report(k)
        evaluate_rows()

    error, wall, failure = None, float("nan"), None
    handed_over = recorder.handoff_seconds if recorder is not None else 0.0
    try:
        # Nothing to show or record as it goes (a sweep's point): the rows are evaluated
        # once, after the loop (each row's checks are its own, so the values are the same),
        # not a second at a time (~1 ms of Python a chunk, 20 % of the paper's 1 kHz loop).
        live = report is not None or recorder is not None
        wall = simulate(plant, plan, trace, progress=on_chunk if live else None,
                        progress_every=max(1, int(round(1.0 / sim.step))), engine=engine)
    except (Diverged, KeyboardInterrupt) as exc:
        error, failure = str(exc) or "interrupted (Ctrl-C)", exc
    finally:
        if report and sys.stderr.isatty():
            print(file=sys.stderr)
    evaluate_rows()
    handoff = recorder.handoff_seconds - handed_over if recorder is not None else None
    result = _result(plan, trace.completed(), evaluator.result(), steps, wall, handoff, error,
                     failure)
    if recorder is not None:
        recorder.end_run(name, result.summary())
    return result


def _result(plan: RunPlan, done: Trace, evaluation: Evaluation, steps: int, wall: float,
            handoff: float | None, error: str | None, failure: BaseException | None
            ) -> RunResult:
    """A finished run's result: its evaluation with the loop's timing among the metrics
    (``steps`` the run's, ``wall`` s; ``handoff``: the loop's share of writing the
    recording, s, if it was recorded)."""
    metrics = evaluation.metrics
    # The run's model of the plant: the block publishing it (summary.json says which
    # source and links it used).
    model = plan.publisher(io.PLANT_MODEL)
    metrics["wall_time_s"] = wall
    metrics["steps_per_second"] = steps / wall if wall == wall and wall > 0 else None
    metrics["simulated_time_s"] = float(done.time[-1]) if done.rows_done else 0.0
    if handoff is not None:
        metrics["recording_handoff_s"] = handoff
    return RunResult(plan.name, done, evaluation, error is None, error, failure,
                     model.describe() if model is not None else {}, wall,
                     {block.instance: block.describe() for block in plan.blocks
                      if block.describe()}, plan.torque_before_filter())


def urdf_arm(pipeline: Pipeline) -> UrdfArm | None:
    """The plant's URDF, its moving joints (q's columns) and the joints it holds, for the
    3-D view: a plant built from ``plant.urdf``; None for any other plant (drawn planar)."""
    urdf = getattr(pipeline.plant, "urdf", None)
    if urdf is None:
        return None
    from plant_fmu.urdf import read_urdf, resolve_uri

    path = resolve_uri(urdf.file, Path.cwd())
    chain = read_urdf(path, urdf.base, urdf.tip, dict(urdf.fixed))
    return UrdfArm(str(path), chain.joints, dict(chain.held))


def _open_recorder(out: Path, scenario: Scenario, spawn: bool, connect: str | None,
                   arm: UrdfArm | None = None) -> Recorder:
    pipeline, sim = scenario.pipeline, scenario.pipeline.simulation
    title = (f"{pipeline.name}: {' vs '.join(pipeline.runs)} "
             f"({sim.duration:g} s at {1 / sim.step:g} Hz)")
    views = {name: plan.views() for name, plan in scenario.runs.items()}
    errors = {name: [(entity, f"estimation error {true} − {estimate} "
                              f"({plan.signals[estimate].unit})")
                     for entity, (true, estimate, _) in derived_entities(
                         plan.signals, _present(plan)).items()]
              for name, plan in scenario.runs.items()}
    checks = {name: check_views(plan.declarations()) for name, plan in scenario.runs.items()}
    return Recorder(out / "recording.rrd", title, list(pipeline.runs), spawn=spawn,
                    connect=connect, views=views, error_views=errors, check_views=checks,
                    spatial=list(pipeline.runs) if arm is not None else [])


def _present(plan: RunPlan) -> frozenset[str]:
    """The run's signals that hold values: what its blocks produce and what the plant maps."""
    return frozenset(plan.signals) - (frozenset(PLANT_OUTPUTS) - plan.plant_outputs)


def _properties(pipeline: Pipeline, plant_info: dict) -> dict[str, dict]:
    resolved = json.dumps(jsonable(pipeline.model_dump(by_alias=True)))
    return {
        "pipeline": {"name": pipeline.name, "description": pipeline.description or "",
                     "resolved": resolved},
        "plant": {**{k: v for k, v in plant_info.items()
                     if k not in ("parameters", "variables", "system")},
                  **{k: json.dumps(plant_info[k]) for k in ("variables", "parameters", "system")
                     if k in plant_info}},
        "versions": package_versions(),
    }
