"""The `cosim` command line. User mistakes end with one clear message and exit status 2."""

from __future__ import annotations

import argparse
import os
import re
import signal
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

# Nothing heavier at module level: `cosim run` first starts a supervisor process that only
# waits for the run's own process (_supervise), and plant_fmu and pydantic (cosim.schema)
# would add a quarter of a second to every run there. Each command imports what it needs.

# A sweep's rows are held in memory and its points validated one by one (~1 ms each): past
# 100,000 points a typo (a 1000-value grid on three keys is 10⁹) would exhaust the machine
# before saying a word. --max-points raises the limit for a sweep meant to be that large.
# (Here, not in cosim.sweep: importing that loads numba, 0.3 s on every `cosim --help`.)
MAX_SWEEP_POINTS = 100_000


class UserError(Exception):
    """A mistake in what the user asked for: printed as one line, no traceback."""


def _build_fmu(args: argparse.Namespace) -> None:
    from plant_fmu import MODELS, build_fmu

    output = Path(args.output) if args.output is not None else None
    if output is not None and (output.is_dir() or args.output.endswith(os.sep)):
        try:  # a folder (one ending in / is made): the FMU goes into it
            output.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise UserError(f"--output {args.output}: cannot make the folder: "
                            f"{exc.strerror or exc}") from None
        identifier = MODELS[args.model].MODEL_IDENTIFIER
        output = output / f"{identifier}{args.links}_fmi{args.fmi_version}.fmu"
    elif output is not None and output.suffix.lower() != ".fmu":
        raise UserError(f"--output {args.output}: an FMU's file name ends in .fmu (e.g. "
                        f"{output.with_suffix('.fmu')}); for a folder, end it with "
                        f"{os.sep} and the FMU is written into it; nothing was written")
    try:
        path = build_fmu(links=args.links, fmi_version=args.fmi_version, output=output,
                         model=args.model)
    except OSError as exc:
        raise UserError(f"--output {args.output}: cannot write the FMU there: "
                        f"{exc.strerror or exc}") from None
    except KeyboardInterrupt as exc:  # written to a temporary and renamed: nothing half-made
        raise UserError(f"{str(exc) or 'interrupted (Ctrl-C)'} while building the FMU; nothing "
                        "was written") from None
    print(path)


class Terminated(KeyboardInterrupt):
    """SIGTERM, handled like Ctrl-C: what was computed is kept and summarised."""


def _on_sigterm(signum, frame) -> None:
    _acknowledge_to_supervisor()
    raise Terminated("terminated (SIGTERM)")


def _on_sigint(signum, frame) -> None:
    _acknowledge_to_supervisor()
    raise KeyboardInterrupt


_supervisor: list[int] = []  # in a supervised run process: the supervisor's pid


def _acknowledge_to_supervisor() -> None:
    """Tell the supervisor this process heard its signal (Python ran the handler, so it is
    not stuck in a plant's binary) and is ending: no need to kill it after the grace."""
    if _supervisor and os.getppid() == _supervisor[0]:
        os.kill(_supervisor[0], signal.SIGUSR1)


def _check_viewer(spawn: bool, connect: str | None) -> None:
    """Before anything runs: a display for --spawn, a reachable viewer for --connect."""
    if spawn:
        from .outputs.viewer import has_display

        if not has_display():
            raise UserError("--spawn needs a display (DISPLAY and WAYLAND_DISPLAY are unset): "
                            "run without it and open the recording with `cosim view` where "
                            "there is one, or stream to a viewer with --connect URL; nothing "
                            "was run")
    if connect:
        from .outputs.viewer import check_reachable

        problem = check_reachable(connect)
        if problem:
            raise UserError(f"--connect {connect}: {problem}; nothing was run")


def _run(args: argparse.Namespace) -> None:
    from .config import load_pipeline
    from .engine import Diverged
    from .outputs.recording import RecordingError
    from .outputs.run_folder import RunFolderError
    from .runner import run

    pipeline = load_pipeline(args.pipeline, args.set)
    if args.runs:
        unknown = [name for name in args.runs if name not in pipeline.runs]
        if unknown:
            raise UserError(f"--run {unknown[0]}: {args.pipeline} has no such run; its runs "
                            f"are {', '.join(pipeline.runs)}; nothing was run")
        pipeline.runs = {name: pipeline.runs[name] for name in dict.fromkeys(args.runs)}
    if args.out is not None:
        out = args.out
    else:  # a new folder per run, runs/NAME/TIME, and runs/NAME/latest pointing to it
        from .outputs.run_folder import new_run_folder, point_latest

        try:
            out = new_run_folder(Path("runs") / pipeline.name, create=not args.dry_run)
        except RunFolderError as exc:
            raise UserError(str(exc)) from None
        if not args.dry_run:
            point_latest(out)
    if args.dry_run:
        from .outputs.run_folder import would_refuse
        from .plan import describe_plan

        print(describe_plan(pipeline, out, record=not args.no_recording))
        refusal = would_refuse(out, args.force)
        if refusal:  # the run itself would stop there: say so now
            raise UserError(f"{refusal} (--dry-run: the run would be refused here)")
        return
    _check_viewer(args.spawn, args.connect)
    from .jit_cache import announce_compiles, cache_is_cold

    if cache_is_cold():  # otherwise the terminal would sit silent while numba compiles
        print("compiling the numba kernels for this machine (the first run after installing "
              "or updating cosim without its set-up step, `cosim warm-up`, which `make venv` "
              "runs: ~30 s on 2 cores; cached for later runs)", file=sys.stderr)
    if not args.no_figures:  # they import matplotlib while the runs go
        from .outputs.figures import start_painters

        start_painters()
    print(f"running {pipeline.name}: {', '.join(pipeline.runs)} "
          f"({pipeline.simulation.duration:g} s at {1 / pipeline.simulation.step:g} Hz) -> {out}",
          file=sys.stderr)
    previous = signal.signal(signal.SIGTERM, _on_sigterm)

    def kept() -> str:  # the run folder is made once the plant is open
        if (out / "summary.json").is_file():
            return f"what was computed is kept in {out}; summary.json says what is incomplete"
        return "nothing was written (the run had not started)"

    try:
        # A kernel edited since the last run (or the warm-up) recompiles: each module's
        # kernels are named as they are done.
        with announce_compiles(sys.stderr):
            results = run(pipeline, out, record=not args.no_recording, spawn=args.spawn,
                          connect=args.connect, figures=not args.no_figures, force=args.force)
    except Diverged as exc:
        raise UserError(f"{exc}; {kept()}") from None
    except KeyboardInterrupt as exc:
        raise UserError(f"{str(exc) or 'interrupted (Ctrl-C)'}; {kept()}") from None
    except RecordingError as exc:
        raise UserError(f"{exc}; {kept()}") from None
    except RunFolderError as exc:  # "--out …" messages: the folder could not be used at all
        raise UserError(str(exc) if str(exc).startswith("--out") else f"{exc}; {kept()}") \
            from None
    finally:
        signal.signal(signal.SIGTERM, previous)
    _print_summary(results)
    print(f"run folder: {out}")
    if not args.no_recording:
        print(f"review: cosim view {out}   (or: rerun {out / 'recording.rrd'})")


def _sweep(args: argparse.Namespace) -> int:
    from .outputs.run_folder import RunFolderError
    from .sweep import SweepError, main

    if args.pipeline is None:
        swallowed = [r for r in args.runs or [] if r.endswith(".toml") or Path(r).is_file()]
        if swallowed:
            raise UserError(f"--runs took the pipeline {swallowed[0]} as a run name: give the "
                            "pipeline first (cosim sweep PIPELINE … --runs NAME …), or end the "
                            "run names with --")
        raise UserError("give the pipeline file, e.g. cosim sweep "
                        "pipelines/paper_two_link.toml --grid … --out …")
    try:
        return main(args)
    except (SweepError, RunFolderError) as exc:
        raise UserError(str(exc)) from None


def _warm_up(args: argparse.Namespace) -> None:
    from .warm import WarmUpError, default_pipelines, warm_up

    pipelines = args.pipelines or default_pipelines()
    if not pipelines:
        raise UserError("no pipeline to warm up: give one, e.g. cosim warm-up "
                        "pipelines/paper_two_link.toml")
    missing = [p for p in pipelines if not Path(p).is_file()]
    if missing:
        raise UserError(f"{missing[0]}: no such pipeline file; nothing was compiled")
    if args.workers is not None and not 1 <= args.workers <= 4 * (os.cpu_count() or 1):
        raise UserError(f"--workers {args.workers}: give 1 to {4 * (os.cpu_count() or 1)} "
                        "processes")
    try:
        warm_up([Path(p) for p in pipelines], args.workers)
    except WarmUpError as exc:
        raise UserError(str(exc)) from None


def _view(args: argparse.Namespace) -> None:
    from .outputs.viewer import ViewerError, recording_path, screenshot, view

    try:
        if args.size is not None and not args.screenshot:
            raise UserError(f"--size {args.size}: sizes the --screenshot PNG; a window opened "
                            "by `cosim view` is resized by hand")
        if args.screenshot:
            size = _window_size(args.size or "1600x1000")
            if args.screenshot.is_dir():
                raise UserError(f"--screenshot {args.screenshot}: is a folder; give the PNG "
                                f"file to write, e.g. {args.screenshot / 'recording.png'}")
            if args.screenshot.suffix.lower() != ".png":
                raise UserError(f"--screenshot {args.screenshot}: the screenshot is a PNG; "
                                f"give a name ending in .png, e.g. "
                                f"{args.screenshot.with_suffix('.png')}")
            folder = args.screenshot.resolve().parent
            if not folder.is_dir() or not os.access(folder, os.W_OK):
                raise UserError(f"--screenshot {args.screenshot}: cannot write there "
                                f"({folder} is not a writable folder)")
            print(screenshot(recording_path(args.run_dir), args.screenshot, size))
            return
        status = view(args.run_dir)
    except ViewerError as exc:
        raise UserError(str(exc)) from None
    if status:
        raise UserError(f"the Rerun viewer exited with status {status}")


def _window_size(size: str) -> str:
    """``WIDTHxHEIGHT`` in pixels, each 200 to 8000, or one message saying so."""
    match = re.fullmatch(r"(\d+)x(\d+)", size.strip())
    if not match or not all(200 <= int(v) <= 8000 for v in match.groups()):
        raise UserError(f"--size {size!r}: expected WIDTHxHEIGHT in pixels, each from 200 to "
                        "8000, e.g. 1600x1000")
    return f"{int(match[1])}x{int(match[2])}"


def _export(args: argparse.Namespace) -> None:
    from .outputs.export import ExportError, export

    try:
        paths = export(args.run_dir, args.format, args.runs, args.out, args.force)
    except ExportError as exc:
        raise UserError(str(exc)) from None
    for path in paths:
        print(path)


def _compare(args: argparse.Namespace) -> int:
    from .outputs.compare import CompareError, compare

    try:
        result = compare(args.a, args.b, args.runs)
    except CompareError as exc:
        raise UserError(str(exc)) from None
    print("\n".join(result.lines))
    return 1 if result.regressions else 0  # 1, not 2: the command worked; B regressed


def _params(args: argparse.Namespace) -> None:
    from .config import load_pipeline
    from .config.params import describe

    pipeline = load_pipeline(args.pipeline, args.set) if args.pipeline or args.set else None
    text = describe(pipeline, args.grep)
    if not text:
        raise UserError(f"--grep {args.grep}: no key, value or meaning contains it")
    print(text)


def _inspect(args: argparse.Namespace) -> int:
    from .config import load_pipeline
    from .plant.inspection import inspect_fmu
    from .plant.mapping import FmuError

    pipeline = load_pipeline(args.pipeline, args.set)
    mapping = pipeline.plant.variables.model_dump()
    try:
        info = inspect_fmu(args.fmu, mapping)
        print(info)
        if args.linearize:
            _print_linearization(args.fmu, info, dict(pipeline.plant.parameters))
    except FmuError as exc:
        raise UserError(str(exc)) from None
    return 0 if info.fits else 1  # the report says why; 1, not 2: the command itself worked


def _print_linearization(path: Path, info, parameters: dict[str, float]) -> None:
    import numpy as np

    from .plant.linearization import linearize_at_start

    inputs = info.mapping.tau if info.fits else None
    outputs = info.mapping.q + (info.mapping.qdot or []) if info.fits else None
    point = linearize_at_start(path, inputs, outputs, parameters)
    system = point.system
    np.set_printoptions(precision=5, suppress=False, linewidth=100)
    print("\nlinearised about the start state (t = 0 s, after initialisation):")
    print(f"  x0    = {point.x0}   ({', '.join(system.state_labels)})")
    print(f"  u0    = {point.u0}")
    print(f"  xdot0 = {point.xdot0}"
          + ("   (not an equilibrium: the model is the local tangent along the motion)"
             if np.linalg.norm(point.xdot0) > 1e-9 else "   (an equilibrium)"))
    print(system)
    print("poles (1/s):")
    for pole in system.poles():
        wn = abs(pole)
        zeta = -pole.real / wn if wn else float("nan")
        kind = "unstable" if pole.real > 0 else "stable" if pole.real < 0 else "marginal"
        print(f"  {pole.real:+.6g} {pole.imag:+.6g}j   |p| = {wn:.6g} rad/s, "
              f"damping {zeta:.3g}, {kind}")


def _print_summary(results) -> None:
    import shutil

    from .outputs.table import text_table

    width = max(60, min(100, shutil.get_terminal_size((100, 24)).columns))
    print(text_table({name: r.summary() for name, r in results.items()}, width))
    for name, r in results.items():
        m = r.metrics
        g = m.get("guarantee") or {}
        if g.get("feasible") is not None:  # a filtered run: what its guarantee covers
            covered = g["starts_inside"] and g["feasible"] and g["within_bounds"]
            exit_text = (f"left {g['first_exit']['set']} at {g['first_exit']['t']:.3f} s"
                         if g["first_exit"] else "kept every hard set")
            _wrapped(f"{name}: {exit_text}; guarantee "
                     + ("covers this run" if covered else "does not cover this run: "
                        + "; ".join([*(["started outside"] if not g["starts_inside"] else []),
                                     *([f"{g['infeasible_steps']} infeasible step(s)"]
                                       if not g["feasible"] else []), *g["outside"]]))
                     + (" — BROKEN" if g["broken"] else ""))
        lines = []
        if "peak_torque" in m:
            tau = ", ".join(f"{x:.1f}" for x in m["peak_torque"])
            gain = m.get("feedback_gain")
            lines.append(f"peak torque [{tau}] N·m" + (
                f"; effective gain on r̂ (median) {gain['median']:.1f} N·m·s/rad"
                if gain else ""))
        obs = m.get("observer_velocity_error_rms_after_1s")
        if obs:
            lines.append("observer velocity RMS error after 1 s "
                         f"[{', '.join(f'{x:.3f}' for x in obs)}] rad/s")
        if "barrier_condition" in m:
            condition = m["barrier_condition"]
            lines.append(f"min H {m['min_barrier_H']:.3g} (H1 {m['min_barrier_H1']:.3g}, "
                         f"H2 {m['min_barrier_H2']:.3g}); dH/dt + {condition['alpha']:g} H < 0 "
                         f"in {100 * (condition['fraction_failing'] or 0):.1f} % of steps")
        not_run = [n for n, said in r.evaluation.evaluators.items() if said != "ran"]
        if not_run:
            lines.append(f"not evaluated (inputs missing, see summary.json): "
                         f"{', '.join(not_run)}")
        sps = m["steps_per_second"]
        lines.append(f"{m['wall_time_s']:.2f} s wall, {sps or 0:,.0f} steps/s")
        _wrapped(f"{name}: {lines[0]}")
        for line in lines[1:]:
            _wrapped(line, indent=1)


def _wrapped(line: str, indent: int = 0) -> None:
    """A summary line within 100 columns, indented by ``indent`` levels, its continuations
    by one more."""
    import textwrap

    print(textwrap.fill(line, width=100, initial_indent="    " * indent,
                        subsequent_indent="    " * (indent + 1), break_long_words=False,
                        break_on_hyphens=False))


def _parser() -> argparse.ArgumentParser:
    from plant_fmu import DEFAULT_MODEL, MODELS

    MAX_LINKS = max(model.MAX_LINKS for model in MODELS.values())

    parser = argparse.ArgumentParser(
        prog="cosim",
        description="Co-simulate a robot-arm FMU with a safe adaptive output-feedback "
        "controller. SI units, angles in radians.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("build-fmu", help="build a built-in plant FMU (FMI 2.0 or 3.0)",
                       description="Compile a built-in plant model with the system C compiler "
                       "into an FMU with Co-Simulation and Model Exchange. Prints the FMU's "
                       "path.")
    p.add_argument("--model", default=DEFAULT_MODEL, choices=list(MODELS),
                   help=f"the plant model: the rigid n-link planar arm (planar_arm), or the "
                   f"arm with elastic joints, motors driving the links through springs "
                   f"(elastic_joints) (default {DEFAULT_MODEL})")
    p.add_argument("--links", type=int, default=2, choices=range(1, MAX_LINKS + 1),
                   metavar="N", help=f"number of links, 1 to {MAX_LINKS} (default 2)")
    p.add_argument("--fmi-version", type=int, default=2, choices=(2, 3),
                   help="FMI version (default 2)")
    p.add_argument("--output", default=None, metavar="FILE.fmu|FOLDER/",
                   help="where to write the FMU: a .fmu file, or a folder (an existing one, "
                   "or a name ending in /, made if missing) (default: the build cache)")
    p.set_defaults(func=_build_fmu)

    p = sub.add_parser("run", help="run a pipeline (TOML) and write its run folder",
                       description="Run every run of a pipeline through the co-simulation "
                       "master and write the run folder: summary.json, trace_<run>.npz, "
                       "recording.rrd (Rerun) and PNG figures. SI units, radians.")
    p.add_argument("pipeline", help="pipeline file, e.g. pipelines/paper_two_link.toml")
    p.add_argument("--out", type=Path, default=None,
                   help="run folder (default: a new runs/<pipeline name>/<YYYYmmdd-HHMMSS>, "
                   "with runs/<pipeline name>/latest pointing to it)")
    p.add_argument("--set", action="append", default=[], metavar="KEY.PATH=VALUE",
                   help="override a pipeline key with a TOML value, e.g. controller.kv=25 or "
                   "'plant.fmu=\"arm.fmu\"' (repeatable)")
    p.add_argument("--run", action="append", default=None, metavar="NAME", dest="runs",
                   help="run only this run of the pipeline (repeatable; default: all)")
    live = p.add_mutually_exclusive_group()
    live.add_argument("--spawn", action="store_true",
                      help="start a Rerun viewer that follows the runs live (needs a display)")
    live.add_argument("--connect", metavar="URL", default=None,
                      help="stream to a Rerun viewer already running at URL, e.g. "
                      "rerun+http://127.0.0.1:9876/proxy")
    p.add_argument("--no-recording", action="store_true",
                   help="do not write recording.rrd (summary, traces and figures only)")
    p.add_argument("--no-figures", action="store_true",
                   help="do not write the PNG figures (Figs. 2-5)")
    p.add_argument("--force", action="store_true",
                   help="replace what --out holds (an existing run folder is refused without)")
    p.add_argument("--dry-run", action="store_true",
                   help="check everything (pipeline, plant FMU, wiring, sizes), build the FMU, "
                   "print the resolved plan and the memory and disk it needs; run nothing")
    p.set_defaults(func=_run)

    p = sub.add_parser(
        "sweep", help="run a pipeline over a grid and/or random samples of keys, on Dask",
        description="Run a pipeline over the Cartesian product of --grid values and/or seeded "
        "random --sample draws of any key --set accepts, on a Dask cluster (local by default), "
        "and write one row per (point, run) to OUT/results.parquet and results.csv, with "
        "sweep.json and a safety-rate table. SI units, radians.")
    # optional to argparse only so that a pipeline swallowed by --runs gets its own message
    p.add_argument("pipeline", nargs="?", default=None, help="pipeline file")
    p.add_argument("--grid", action="append", default=[], metavar="KEY=V1,V2,...",
                   help="TOML values, lists too: controller.kv=20,40 or "
                   "'controller.kv=[20,30],[25,25]' (repeatable: the product)")
    p.add_argument("--sample", action="append", default=[],
                   metavar="KEY=uniform(a,b)|normal(m,s)|integers(a,b)",
                   help="a random draw per sample (repeatable)")
    p.add_argument("--samples", type=int, default=0, metavar="N",
                   help="random draws (per grid point, with --sample)")
    p.add_argument("--seed", type=int, default=0, help="seed of the draws (default 0)")
    p.add_argument("--runs", nargs="+", default=None, metavar="NAME",
                   help="the pipeline's runs to sweep (default all)")
    p.add_argument("--set", action="append", default=[], metavar="KEY.PATH=VALUE",
                   help="applied to every point")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=None, metavar="K",
                       help="local Dask worker processes (default: one per core)")
    where.add_argument("--scheduler", default=None, metavar="ADDRESS",
                       help="an existing Dask scheduler, e.g. tcp://127.0.0.1:8786")
    p.add_argument("--record", default=None, metavar="best,worst",
                   help="also write full run folders of each run's best and/or worst point")
    p.add_argument("--out", required=True, type=Path, help="sweep folder")
    p.add_argument("--force", action="store_true", help="replace what --out holds")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--dry-run", action="store_true",
                   help="check every point, the runs and --out; print what would run; run "
                   "nothing")
    p.add_argument("--max-points", type=int, default=MAX_SWEEP_POINTS, metavar="N",
                   help="refuse a sweep of more points than this before any work "
                   f"(default {MAX_SWEEP_POINTS:,})")
    p.set_defaults(func=_sweep)

    p = sub.add_parser("warm-up", help="compile the kernels and fused loops of pipelines and "
                       "build their FMUs now, so that their first run starts at once",
                       description="Fill the caches a run loads from: compile the numba "
                       "kernels and fused loops that the pipelines' runs step (in parallel, one "
                       "process per core), build their plant FMUs and matplotlib's font list. "
                       "`make venv` and `make test-venv` run it; a warm cache is recognised "
                       "in a fraction of a second. Caches: $NUMBA_CACHE_DIR (else "
                       "~/.cache/cosim/numba, a folder per kernel module and version of its "
                       "sources), $COSIM_ENGINE_CACHE, $COSIM_CACHE.")
    p.add_argument("pipelines", nargs="*", metavar="PIPELINE",
                   help="pipeline files (default: pipelines/paper_two_link.toml)")
    p.add_argument("--workers", type=int, default=None, metavar="K",
                   help="compile in K processes (default: one per core)")
    p.set_defaults(func=_warm_up)

    p = sub.add_parser("view", help="open a run folder's recording in the Rerun viewer",
                       description="Open RUN_DIR/recording.rrd in the Rerun viewer, with the "
                       "layout stored in it (the paper's Figs. 2-4 per run, barriers, observer "
                       "error, the arm). Without a display, says how to view it elsewhere.")
    p.add_argument("run_dir", metavar="RUN_DIR", help="a run folder, or an .rrd file")
    p.add_argument("--screenshot", metavar="PNG", type=Path, default=None,
                   help="instead of opening a window, render the layout headless (software "
                   "Vulkan: Debian's mesa-vulkan-drivers) and save it as PNG")
    p.add_argument("--size", metavar="WxH", default=None,
                   help="the screenshot's size in pixels (default 1600x1000); with more "
                   "than two runs each run has a tab of its own")
    p.set_defaults(func=_view)

    p = sub.add_parser("export", help="write a run folder's traces as Parquet, CSV or MAT, "
                       "with units", description="Write every signal of each run (and each "
                       "check's and barrier's value per row) to export_<run>.parquet, .csv or "
                       ".mat, with its unit and meaning: Parquet field metadata (unit, "
                       "description), a CSV header 'name (unit)' per column, a MAT struct of "
                       "arrays with 'units' and 'descriptions'. Per-joint signals are q[1], "
                       "q[2], ...; n×n ones M[1,1], M[1,2], ... (1-based). SI units, radians. "
                       "Prints the files written.")
    p.add_argument("run_dir", metavar="RUN_DIR", type=Path, help="a run folder")
    p.add_argument("--format", default="parquet", choices=("parquet", "csv", "mat"),
                   help="file format (default parquet)")
    p.add_argument("--run", action="append", default=None, metavar="NAME", dest="runs",
                   help="a run to export (repeatable; default: all)")
    p.add_argument("--out", type=Path, default=None,
                   help="folder for the files (default: RUN_DIR itself, where earlier exports "
                   "are replaced)")
    p.add_argument("--force", action="store_true",
                   help="replace files of the same name in --out")
    p.set_defaults(func=_export)

    p = sub.add_parser("compare", help="compare two run folders' checks and metrics; exit 1 "
                       "if a check that held in A fails in B", description="Print each run's "
                       "safety checks (worst value and verdict) and numeric metrics from two run "
                       "folders side by side with the difference B - A. Exit status 0 when "
                       "every check that held in A holds in B, 1 when one does not (each named: "
                       "a gate for a controller change), 2 on an error. SI units, radians.")
    p.add_argument("a", metavar="A", type=Path, help="the run folder to compare against")
    p.add_argument("b", metavar="B", type=Path, help="the run folder being checked")
    p.add_argument("--run", action="append", default=None, metavar="NAME", dest="runs",
                   help="compare only this run (repeatable; default: every run of either)")
    p.set_defaults(func=_compare)

    p = sub.add_parser("params", help="list every pipeline key: default, allowed values, "
                       "meaning", description="List every key a pipeline (and --set) accepts, "
                       "generated from the schema it is validated with: its default, the values "
                       "it takes, and its meaning with units (SI, radians). With PIPELINE, its "
                       "values instead, '*' marking those that differ from the defaults. "
                       "Block tables are also keys of each run (runs.NAME.controller.kv).")
    p.add_argument("pipeline", nargs="?", default=None, help="a pipeline file (optional)")
    p.add_argument("--set", action="append", default=[], metavar="KEY.PATH=VALUE",
                   help="override a key first, as `cosim run --set` (repeatable)")
    p.add_argument("--grep", default="", metavar="TEXT",
                   help="only the keys whose line contains TEXT, e.g. --grep observer")
    p.set_defaults(func=_params)

    p = sub.add_parser("inspect", help="show what an FMU offers and whether it fits the plant "
                       "interface", description="Print an FMU's FMI version, interfaces "
                       "(Co-Simulation, Model Exchange), platforms and variables by causality "
                       "with units, then whether it fits cosim's plant interface (tau inputs, "
                       "q outputs, optional qdot and M) under the given mapping, and if not, "
                       "every reason. Exit status 0 if it fits, 1 if not, 2 on an error.")
    p.add_argument("fmu", type=Path, metavar="FMU", help="the .fmu file")
    p.add_argument("--pipeline", default=None,
                   help="take plant.variables and plant.parameters from this pipeline")
    p.add_argument("--set", action="append", default=[], metavar="KEY.PATH=VALUE",
                   help="map the interface, e.g. 'plant.variables.q=[\"shoulder\",\"elbow\"]'"
                   " (repeatable)")
    p.add_argument("--linearize", action="store_true",
                   help="also linearise it about its start state from its Model Exchange "
                   "directional derivatives and print the state-space model and its poles "
                   "(inputs tau, outputs q and qdot when it fits, else all)")
    p.set_defaults(func=_inspect)
    return parser


SUPERVISED = "COSIM_SUPERVISED"


# Seconds the run process has to answer Ctrl-C or SIGTERM (its handler acknowledges at once
# when Python runs it) before it is killed: only a plant binary that never returns control
# (a foreign FMU blocking in doStep) keeps Python from running it.
STOP_GRACE_S = float(os.environ.get("COSIM_STOP_GRACE_S", "10"))


def _supervise(args: list[str]) -> int:
    """Run ``cosim run`` in a child process and wait: if it dies by a signal (a plant
    binary that crashes takes the process with it), say so and mark its summary. The child
    has its own process group, so Ctrl-C and SIGTERM reach it once, through here; if it does
    not acknowledge one within STOP_GRACE_S, it is killed (and its summary marked)."""
    import threading

    child = subprocess.Popen([sys.executable, "-m", "cosim.cli", *args],
                             env=dict(os.environ, **{SUPERVISED: "1"}), process_group=0)
    stopping: dict = {"timer": None, "acknowledged": False, "killed": None}

    def end_unanswered(name: str) -> None:
        if not stopping["acknowledged"] and child.poll() is None:
            stopping["killed"] = name
            child.kill()

    def forward(signum, frame) -> None:
        child.send_signal(signum)
        if stopping["timer"] is None:
            stopping["timer"] = threading.Timer(STOP_GRACE_S, end_unanswered,
                                                (signal.Signals(signum).name,))
            stopping["timer"].daemon = True
            stopping["timer"].start()

    def acknowledged(signum, frame) -> None:
        stopping["acknowledged"] = True

    signal.signal(signal.SIGUSR1, acknowledged)
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, forward)
    status = child.wait()
    if stopping["timer"] is not None:
        stopping["timer"].cancel()
    if status >= 0:
        return status
    name = signal.Signals(-status).name
    out, plant = _crashed_run(args)
    where = f" in {plant}" if plant else ""
    if stopping["killed"]:
        print(f"cosim: error: the run process did not answer {stopping['killed']} within "
              f"{STOP_GRACE_S:g} s (most likely blocked inside the plant FMU's doStep{where}) "
              f"and was killed; what was written before is kept in {out} (summary.json "
              "marked crashed)", file=sys.stderr)
        _mark_crashed(out, f"killed: the run process did not answer {stopping['killed']} "
                      f"within {STOP_GRACE_S:g} s{where}")
        return 2
    print(f"cosim: error: the run process was killed by {name}, most likely inside the "
          f"plant FMU's binary{where}; what was computed is kept in {out} (summary.json "
          "marked crashed)", file=sys.stderr)
    _mark_crashed(out, f"the run process was killed by {name}{where}")
    return 2


def _crashed_run(args: list[str]) -> tuple[Path, str]:
    """The run folder and plant of the run that crashed, from its arguments."""
    from .config import load_pipeline
    from .schema import PipelineError

    ns = _parser().parse_args(args)
    try:
        pipeline = load_pipeline(ns.pipeline, ns.set)
    except PipelineError:
        return Path(ns.out or "runs"), ""
    plant = Path(pipeline.plant.fmu).name if pipeline.plant.fmu else "the built-in plant"
    # without --out, the run made runs/NAME/TIME and pointed runs/NAME/latest at it
    return Path(ns.out or (Path("runs") / pipeline.name / "latest").resolve()), plant


def _mark_crashed(out: Path, reason: str) -> None:
    import json

    summary = out / "summary.json"
    try:
        data = json.loads(summary.read_text())
        data.update(complete=False, status="crashed", error=reason)
        tmp = out / ".summary.json.crashed"
        tmp.write_text(json.dumps(data, indent=2) + "\n")
        tmp.replace(summary)
    except (OSError, ValueError):
        pass


def _end_with_the_supervisor() -> None:
    """In the supervised run process: if the supervisor dies (SIGKILL, a closed terminal),
    end as on SIGTERM — what was computed is kept and summarised — rather than run on as an
    orphan. A daemon thread polls the parent once a second."""
    import threading

    parent = os.getppid()

    def watch() -> None:
        while os.getppid() == parent:
            threading.Event().wait(1.0)
        os.kill(os.getpid(), signal.SIGTERM)

    threading.Thread(target=watch, daemon=True, name="cosim-supervisor-watch").start()


def main(argv: Sequence[str] | None = None) -> int:
    if argv is None and sys.argv[1:2] == ["run"] and not os.environ.get(SUPERVISED) \
            and not {"-h", "--help", "--dry-run"} & set(sys.argv[2:]):
        return _supervise(sys.argv[1:])
    if argv is None and os.environ.get(SUPERVISED):
        _supervisor.append(os.getppid())
        signal.signal(signal.SIGINT, _on_sigint)
        _end_with_the_supervisor()
    from plant_fmu import BuildError

    from .schema import PipelineError

    args = _parser().parse_args(argv)
    # Every command ends on SIGTERM as on Ctrl-C (run and sweep keep what they computed).
    previous = signal.signal(signal.SIGTERM, _on_sigterm) if argv is None else None
    try:
        return args.func(args) or 0  # a command may return its own status (inspect: 1)
    except (UserError, BuildError, PipelineError) as exc:
        print(f"cosim: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:  # inspect, view: nothing of theirs to keep
        print(f"cosim: error: {str(exc) or 'interrupted (Ctrl-C)'}", file=sys.stderr)
        return 2
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":
    sys.exit(main())
