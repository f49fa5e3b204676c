"""`cosim run`: run a pipeline and write its run folder."""

from __future__ import annotations

import argparse
import io
import json
import signal
import sys
from pathlib import Path

from .common import UserError
from .stopping import on_sigterm
from .summary import print_summary


def add_parser(commands: argparse._SubParsersAction) -> None:
    p = commands.add_parser(
        "run", help="run a pipeline (TOML) and write its run folder",
        description="Run every run of a pipeline through the co-simulation master and write "
        "the run folder: summary.json, trace_<run>.npz, recording.rrd (Rerun) and PNG "
        "figures. SI units, radians.",
        epilog="Every pipeline key can be set with --set: e.g. simulation.duration=2 (s), "
        "simulation.step=0.001 (s), cbf_filter.torque_limit=1000 (N·m); `cosim params "
        "PIPELINE` lists them with their values and units. Exit status: 0 when every run "
        "finished, whatever its verdict (limits kept or LEFT, tracking kept or left: the "
        "table, summary.json); 2 for a mistake in the input, refused before anything runs "
        "(the step is checked against the controllers' gains), or a run that did not "
        "finish (a plant fault, a diverging state: the other runs still run, the table is "
        "printed, then the failure named; Ctrl-C: what was computed is kept, and the runs "
        "not run are named).")
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
    p.add_argument("--quiet", action="store_true",
                   help="print no progress on stderr (errors, warnings and the final "
                   "summary still)")
    p.add_argument("--dry-run", action="store_true",
                   help="check everything (pipeline, plant FMU, wiring, sizes), build the FMU, "
                   "print the resolved plan and the memory and disk it needs; run nothing")
    p.set_defaults(func=handle)


def handle(args: argparse.Namespace) -> None:
    from ..config import load_pipeline
    from ..run_note import tell_supervisor

    pipeline = load_pipeline(args.pipeline, args.set)
    if args.runs:
        unknown = [name for name in args.runs if name not in pipeline.runs]
        if unknown:
            raise UserError(f"--run {unknown[0]}: {args.pipeline} has no such run; its runs "
                            f"are {', '.join(pipeline.runs)}; nothing was run")
        pipeline.runs = {name: pipeline.runs[name] for name in dict.fromkeys(args.runs)}
    if args.dry_run:
        _print_plan(pipeline, args.out or _run_folder(pipeline.name, create=False), args)
        return
    _check_viewer(args.spawn, args.connect)
    _check_caches()
    out = args.out or _run_folder(pipeline.name)
    source = pipeline.plant
    plant = (Path(source.fmu).name if source.fmu else Path(source.ssp).name if source.ssp else
             f"the system {source.system.name}" if source.system else
             Path(source.urdf.file).name if source.urdf else "the built-in plant")
    tell_supervisor(out=str(out), plant=plant, named="1" if args.out is None else None)
    try:
        _run(pipeline, out, args)
    finally:
        if args.out is None:
            _settle_named_folder(out)


def _run(pipeline, out: Path, args: argparse.Namespace) -> None:
    from ..engine import Diverged
    from ..jit_cache import announce_compiles, cache_is_cold
    from ..outputs.recording import RecordingError
    from ..outputs.run_folder import RunFolderError
    from ..runner import run

    say = (lambda text: None) if args.quiet else (lambda text: print(text, file=sys.stderr))
    if cache_is_cold():  # otherwise the terminal would sit silent while numba compiles
        say("compiling the numba kernels for this machine (the first run after installing "
            "or updating cosim without its set-up step, `cosim warm-up`, which `make demo` "
            "and `make test` run: ~30 s on 2 cores one kernel after another; cached for "
            "later runs)")
    if not args.no_figures:  # they import matplotlib while the runs go
        from ..outputs.figures import start_painters

        start_painters()
    overrides = f" with {', '.join(args.set)}" if args.set else ""
    say(f"running {pipeline.name}{overrides}: {', '.join(pipeline.runs)} "
        f"({pipeline.simulation.duration:g} s at {1 / pipeline.simulation.step:g} Hz) -> {out}")
    previous = signal.signal(signal.SIGTERM, on_sigterm)

    def kept() -> str:  # the run folder is made once the plant is open
        if not (out / "summary.json").is_file():
            return "nothing was written (the run had not started)"
        text = f"what was computed is kept in {out}; summary.json says what is incomplete"
        try:
            left = json.loads((out / "summary.json").read_text()).get("not_run") or []
        except (OSError, ValueError):
            left = []
        if left:
            text += (f"; not run: {', '.join(left)} (run "
                     f"{'it' if len(left) == 1 else 'them'} with "
                     f"{' '.join(f'--run {name}' for name in left)})")
        return text

    try:
        # A kernel edited since the last run (or the warm-up) recompiles: each module's
        # kernels are named as they are done.
        with announce_compiles(io.StringIO() if args.quiet else sys.stderr):
            results = run(pipeline, out, progress=not args.quiet,
                          record=not args.no_recording, spawn=args.spawn,
                          connect=args.connect, figures=not args.no_figures, force=args.force)
    except Diverged as exc:
        results = getattr(exc, "results", None)  # every run ran: the table, then the failure
        if results:
            print_summary(results)
        raise UserError(f"{exc}; {kept()}") from None
    except KeyboardInterrupt as exc:
        raise UserError(f"{str(exc) or 'interrupted (Ctrl-C)'}; {kept()}") from None
    except RecordingError as exc:
        raise UserError(f"{exc}; {kept()}") from None
    except MemoryError:  # a limit the memory check could not see
        raise UserError("ran out of memory (an allocation failed); shorten "
                        "simulation.duration or lengthen simulation.step, or run fewer runs "
                        f"with --run; {kept()}") from None
    except RunFolderError as exc:  # "--out …" messages: the folder could not be used at all
        raise UserError(str(exc) if str(exc).startswith("--out") else f"{exc}; {kept()}") \
            from None
    finally:
        signal.signal(signal.SIGTERM, previous)
    print_summary(results)
    print(f"run folder: {out}")
    if not args.no_recording:
        print(f"review: cosim view {out}   (or: rerun {out / 'recording.rrd'})")


def _run_folder(name: str, create: bool = True) -> Path:
    """A new folder per run, runs/NAME/TIME (``create=False``: only named, for --dry-run)."""
    from ..outputs.run_folder import RunFolderError, new_run_folder

    try:
        return new_run_folder(Path("runs") / name, create=create)
    except RunFolderError as exc:
        raise UserError(str(exc)) from None


def _settle_named_folder(out: Path) -> None:
    """After a run in a folder cosim named: runs/NAME/latest → it once it holds a run
    (complete or not); a run refused before writing anything (a missing FMU, too little
    memory) leaves no empty folder behind, and latest where it was."""
    from ..outputs.run_folder import point_latest

    if (out / "summary.json").is_file():
        left = point_latest(out)
        if left is not None:
            print(f"cosim: warning: {left}", file=sys.stderr)
        return
    try:
        out.rmdir()  # only if empty: it is ours, made a moment ago
    except OSError:
        pass


def _print_plan(pipeline, out: Path, args: argparse.Namespace) -> None:
    """--dry-run: the resolved plan, and a refusal the run itself would meet."""
    from ..outputs.folder_owner import would_refuse
    from ..plan import describe_plan

    print(describe_plan(pipeline, out, record=not args.no_recording))
    refusal = would_refuse(out, args.force)
    if refusal:  # the run itself would stop there: say so now
        raise UserError(f"{refusal} (--dry-run: the run would be refused here)")


def _check_caches() -> None:
    """Before anything runs: the caches a run writes. numba compiles without its cache
    (every run, slowly: said); the fused loops' and the FMUs' are needed."""
    from ..warm import unwritable_caches

    for variable, folder, why in unwritable_caches():
        if variable == "NUMBA_CACHE_DIR":
            print(f"cosim: warning: the numba cache folder {folder} cannot be written ({why}): "
                  "every run compiles its kernels again; set NUMBA_CACHE_DIR to a writable "
                  "folder", file=sys.stderr)
            continue
        raise UserError(f"the cache folder {folder} cannot be written ({why}); set {variable} "
                        "to a writable folder; nothing was run")


def _check_viewer(spawn: bool, connect: str | None) -> None:
    """Before anything runs: a display for --spawn, a reachable viewer for --connect."""
    if spawn:
        from ..outputs.viewer import has_display

        if not has_display():
            raise UserError("--spawn needs a display (DISPLAY and WAYLAND_DISPLAY are unset): "
                            "run without it and open the recording with `cosim view` where "
                            "there is one, or stream to a viewer with --connect URL; nothing "
                            "was run")
    if connect:
        from ..outputs.viewer import check_reachable

        problem = check_reachable(connect)
        if problem:
            raise UserError(f"--connect {connect}: {problem}; nothing was run")
