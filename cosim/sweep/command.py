"""``cosim sweep``: the spec from the command line, every point checked, the points run on Dask,
the results written and the tables printed, then the best and/or worst points re-run with
their recording (``--record``); or, with ``--dry-run``, what would be done."""

from __future__ import annotations

import contextlib
import json
import math
import os
import signal
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

from plant_fmu.named_file import read_text

from ..config import PipelineError, load_pipeline
from ..config.params import key_units
from ..evaluate.reports import SWEEP_REPORTS
from ..progress import phase
from .checks import margin
from .cluster import check_versions, close_cluster, cluster_client, quiet_dask, slurm_cluster
from .execution import execute, stranded_after
from .files import write_results, write_spec
from .journal import JOURNAL, Journal, Rows, check_journal, read_table
from .resume import check_same, identity, stored_identity
from .spec import (
    SweepError,
    SweepSpec,
    assignments,
    check_spec,
    only_runs,
    parse_grid,
    parse_sample,
    point_label,
    points,
    validate,
)
from .tables import format_table, safety_by_value, safety_table

if TYPE_CHECKING:
    import argparse

    from ..outputs.run_folder import RunFolder


def record_points(spec: SweepSpec, rows: Rows | list[dict], which: list[str], out: Path,
                  all_points: list[dict], progress: bool = False) -> list[str]:
    """Full run folders (recording, figures) of each run's best and/or worst point by
    :func:`margin`, re-run here with the point's own values: ``out/best_<run>_point<i>``,
    ``out/worst_<run>_point<i>``; returns, for each, its folder and what the point is. A
    run with no completed row has nothing to record. A re-run that fails is
    :class:`SweepError` naming the point and what its folder kept."""
    from ..engine import Diverged
    from ..outputs.run_folder import RunFolderError
    from ..runner import run

    ok = [r for r in rows if r["status"] == "ok" and not math.isnan(margin(r))]
    written = []
    for kind in which:
        for name in dict.fromkeys(r["run"] for r in ok):
            mine = [r for r in ok if r["run"] == name]
            row = (min if kind == "best" else max)(mine, key=margin)
            index = row["point"]
            point = all_points[index]
            folder = out / f"{kind}_{name}_point{index}"
            what = (f"{name}'s {kind} point {index}: {point_label(point)}; its worst check "
                    f"{margin(row):.3f} of its bound")
            pipeline = only_runs(load_pipeline(spec.pipeline, assignments(spec, point),
                                               warn=None), [name])
            try:
                with phase(f"re-running {name}'s {kind} point ({index}) with its "
                           "recording and figures", progress):
                    run(pipeline, folder, progress=False, force=True)
            except (Diverged, PipelineError, RunFolderError) as exc:
                raise SweepError(f"--record: re-running {what} failed: {exc}; what it kept "
                                 f"is in {folder} (the sweep's own results are complete in "
                                 f"{out})") from None
            written.append(f"{folder} ({what})")
    return written


def _dry_run(spec: SweepSpec, all_points: list[dict], runs: list[str], out: Path,
             args: argparse.Namespace) -> int:
    """What the sweep would do, every point checked (as before a real sweep), nothing run."""
    from ..outputs.folder_owner import would_refuse

    load = load_pipeline(spec.pipeline, spec.base, warn=None)
    steps = round(load.simulation.duration / load.simulation.step)
    where = (f"{args.workers or 1} SLURM job(s) of one worker" if args.cluster == "slurm"
             else args.scheduler
             or f"{args.workers or os.cpu_count() or 1} local Dask worker(s)")
    print(f"sweep of {spec.pipeline}: {len(all_points):,} point(s) × {len(runs)} run(s) "
          f"({', '.join(runs)}) = {len(all_points) * len(runs):,} row(s), "
          f"{load.simulation.duration:g} s simulated each ({steps:,} steps), on {where}")
    for axis in spec.grid:
        print(f"  grid   {axis.key} = {', '.join(json.dumps(v) for v in axis.values)}")
    for axis in spec.samples:
        name, *bounds = axis.distribution
        shown = ", ".join(str(int(b)) if float(b).is_integer() else f"{b:g}" for b in bounds)
        print(f"  sample {axis.key} = {name}({shown}), "
              f"{spec.count} draw(s) per grid point, seed {spec.seed}")
    for assignment in spec.base:
        print(f"  set    {assignment}")
    print(f"results -> {out} (results.parquet, results.csv, sweep.json, sweep_safety.png)"
          + (f"; then --record {args.record}" if args.record else ""))
    refusal = would_refuse(out, args.force)
    if refusal:
        raise SweepError(f"{refusal} (--dry-run: the sweep would be refused here)")
    if args.cluster == "slurm":
        cluster = slurm_cluster()
        try:
            print("each SLURM job's script (sbatch):")
            print(cluster.job_script().strip())
        finally:
            close_cluster(None, cluster)
    print("every point checked against the pipeline's schema; nothing was run")
    return 0


def _on_sigterm(signum: int, frame: object) -> None:
    raise KeyboardInterrupt("terminated (SIGTERM)")


@contextlib.contextmanager
def deferred_signals() -> Iterator[None]:
    """Ctrl-C and SIGTERM held while the block runs, acted on as it ends."""
    held = {signal.SIGINT, signal.SIGTERM}
    signal.pthread_sigmask(signal.SIG_BLOCK, held)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, held)


def main(args: argparse.Namespace) -> int:
    """``cosim sweep`` (parsed arguments): returns the exit status. SIGTERM is handled like
    Ctrl-C in every phase: finished rows are written, the cluster ended, the lock released."""
    previous = signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        return _main(args)
    finally:
        signal.signal(signal.SIGTERM, previous)


def _main(args: argparse.Namespace) -> int:
    spec, record = _spec_of(args)
    slurm = args.cluster == "slurm"  # --workers: jobs, not this machine's processes
    check_spec(spec, args.max_points, None if slurm else args.workers, args.scheduler)
    if slurm and args.workers is not None and args.workers < 1:
        raise SweepError(f"--workers {args.workers}: give 1 or more SLURM jobs")
    out = Path(args.resume or args.out)
    try:
        with phase("checking every point against the pipeline's schema", not args.quiet):
            all_points = points(spec)
            files = validate(spec, all_points)
    except KeyboardInterrupt as exc:
        raise SweepError(f"{str(exc) or 'interrupted (Ctrl-C)'} while checking the points; "
                         "nothing was run") from None
    pipeline = load_pipeline(spec.pipeline, spec.base, warn=None)
    runs = spec.runs or list(pipeline.runs)
    if args.dry_run:
        return _dry_run(spec, all_points, runs, out, args)
    start = identity(spec, len(all_points), files)
    folder, done = _open_folder(out, start, args, all_points, runs)
    todo = [i for i in range(len(all_points)) if i not in done]
    if done:
        print(f"resuming {out}: {len(done)} of {len(all_points)} point(s) already there; "
              f"running the other {len(todo)}", file=sys.stderr)
    interrupted = _run_on_dask(spec, all_points, todo, runs, out, folder, args)
    try:
        rows = _report(folder, spec, interrupted, all_points, runs, out, start,
                       key_units(pipeline, spec.keys))
    except KeyboardInterrupt as exc:
        raise SweepError(f"{str(exc) or 'interrupted (Ctrl-C)'} while writing the results; "
                         f"every finished row is kept in {out / JOURNAL}: the same command "
                         f"with --resume {out} writes them") from None
    if interrupted:
        resume = f"resume: the same command with --resume {out}"
        print(f"cosim: interrupted before any point finished; no results were written ({resume})"
              if not len(rows) else
              f"cosim: interrupted; the {len(rows)} finished row(s) are kept in {out}"
              + (f" ({resume})" if len(rows) < len(all_points) * len(runs) else ""),
              file=sys.stderr)
        return 2
    if record:  # (which says so itself when no row completed)
        _record(spec, rows, record, out, all_points, args)
    if len(rows) and all(status != "ok" for status in rows.column("status")):
        first = rows[0]
        raise SweepError(f"every row failed ({len(rows)} of {len(rows)}; the first, point "
                         f"{first['point']} run {first['run']}: {first.get('error') or '?'}); "
                         f"each row's error is in {out / 'results.csv'}")
    return 0


def _open_folder(out: Path, start: dict, args: argparse.Namespace, all_points: list[dict],
                 runs: list[str]) -> tuple[RunFolder, set[int]]:
    """The sweep folder, with sweep.json (what the sweep is) and the journal of rows listed
    in its summary from the start (so a killed sweep's folder is cosim's to --force or
    --resume), and the points it already holds (resumed: only if it is the same sweep and
    its journal holds rows of this sweep only; nothing is written otherwise)."""
    from ..outputs.run_folder import RunFolder

    done: set[int] = set()
    if args.resume:
        check_same(out, stored_identity(out), start)
        folder = RunFolder.create(out, keep=True, option="--resume")
        try:
            done, repeats = check_journal(out / JOURNAL, all_points, runs)
        except SweepError as exc:
            folder.release()
            raise SweepError(f"--resume {out}: {exc}") from None
        for repeat in repeats:
            print(f"cosim: warning: {out / JOURNAL}: {repeat}", file=sys.stderr)
        previous = _previous_files(out)
        folder.files.update({k: v for k, v in previous.items() if k == JOURNAL})
    else:
        folder = RunFolder.create(out, args.force)
    try:
        write_spec(folder, {**start, "status": "running"})
        (out / JOURNAL).touch()
        folder.files[JOURNAL] = {"complete": False, "reason": "the sweep is running"}
        folder.write_summary({"complete": False, "kind": "sweep",
                              "status_detail": "running", "points": start["points"]},
                             final=False)
    except BaseException:
        folder.release()
        raise
    return folder, done


def _previous_files(out: Path) -> dict:
    try:
        return json.loads(read_text(out / "summary.json")).get("files") or {}
    except (OSError, ValueError, AttributeError):
        return {}


def _spec_of(args: argparse.Namespace) -> tuple[SweepSpec, list[str]]:
    """The sweep's spec and what --record asks for (best, worst), from the command line."""
    spec = SweepSpec(args.pipeline, [parse_grid(g) for g in args.grid],
                     [parse_sample(s) for s in args.sample], args.samples, args.seed,
                     args.runs or None, list(args.set))
    if spec.samples and spec.count < 1:
        raise SweepError("--sample needs --samples N (N ≥ 1 random draws)")
    if spec.count and not spec.samples:
        raise SweepError("--samples needs at least one --sample KEY=distribution(a,b)")
    record = [w.strip() for w in (args.record or "").split(",") if w.strip()]
    if set(record) - {"best", "worst"}:
        raise SweepError(f"--record {args.record!r}: expected best, worst or best,worst")
    stranded_after()  # a bad COSIM_SWEEP_STRANDED_S, said before anything is made
    return spec, record


def _run_on_dask(spec: SweepSpec, all_points: list[dict], todo: list[int], runs: list[str],
                 out: Path, folder: RunFolder, args: argparse.Namespace) -> bool:
    """The points ``todo`` on the cluster ``args`` asks for, their rows appended to the
    journal as they finish: whether it was interrupted. A cluster that cannot start, or a
    scheduler lost mid-sweep, is said in the folder's summary too, the folder released (the
    rows written so far kept)."""
    from tqdm import tqdm

    journal = Journal(out / JOURNAL)
    interrupted = False
    # a local cluster's workers come back by nothing but its nannies: how long to wait for
    # none (checked, with the options, before anything is made: _spec)
    stranded = stranded_after() if args.scheduler is None and args.cluster != "slurm" else None
    try:
        client = cluster = None
        try:
            if todo:
                starting = (f"connecting to {args.scheduler}" if args.scheduler else
                            f"submitting {args.workers or 1} SLURM job(s)"
                            if args.cluster == "slurm" else
                            f"starting {args.workers or os.cpu_count() or 1} Dask worker "
                            "process(es)")
                # Ctrl-C or SIGTERM while the cluster starts is acted on once it has (a
                # second or two): a cluster half started could not be closed.
                with phase(starting, not args.quiet), quiet_dask(), deferred_signals():
                    client, cluster = cluster_client(args.workers, args.scheduler,
                                                     args.cluster)
                check_versions(client, args.scheduler)
                where = (args.scheduler
                         or f"a local cluster of {len(client.scheduler_info()['workers'])}")
                print(f"sweeping {len(todo)} point(s) × {len(runs)} run(s) of "
                      f"{spec.pipeline} on {where} worker(s) -> {out}", file=sys.stderr)
                bar = tqdm(total=len(todo), unit="point", file=sys.stderr,
                           disable=args.quiet or not sys.stderr.isatty())
                _, interrupted = execute(spec, all_points, client, bar.update,
                                         sink=journal.add, indices=todo,
                                         stranded_after=stranded)
                bar.close()
        finally:
            with deferred_signals():
                close_cluster(client, cluster)
    except KeyboardInterrupt:  # while the cluster started or closed: what finished is kept
        interrupted = True
    except BaseException as exc:  # no cluster, or the scheduler lost: said in the folder too
        message = _lost(exc, args.scheduler, journal.rows, out)
        try:
            folder.note(JOURNAL, False, message)
            folder.write_summary({"complete": False, "kind": "sweep", "error": message,
                                  "rows": journal.rows}, final=True)
        finally:
            folder.release()
            journal.close()
        if isinstance(exc, SweepError) or message == str(exc):
            raise
        raise SweepError(message) from None
    journal.close()
    return interrupted


def _lost(exc: BaseException, scheduler: str | None, rows: int, out: Path) -> str:
    """What to say of a cluster failure: a lost scheduler by name, with the rows kept."""
    if isinstance(exc, SweepError):
        return str(exc)
    name = type(exc).__name__
    if isinstance(exc, OSError | TimeoutError) or "Comm" in name or "Closed" in name \
            or "Cancelled" in name:
        where = f"--scheduler {scheduler}" if scheduler else "the Dask cluster"
        return (f"{where}: the scheduler stopped answering mid-sweep ({name}); every row "
                f"finished before is kept in {out / JOURNAL} ({rows} this time): start it "
                f"again and go on with the same command and --resume {out}")
    return str(exc) or name


def _report(folder: RunFolder, spec: SweepSpec, interrupted: bool, all_points: list[dict],
            runs: list[str], out: Path, start: dict, set_units: dict[str, str]) -> Rows:
    """The results files from the journal and the folder's summary (the folder released),
    then the tables printed; returns the rows. A sweep stopped before its first row writes
    no results files and says so."""
    rows = Rows(read_table(out / JOURNAL))
    failed = sum(s != "ok" for s in rows.column("status")) if len(rows) else 0
    table = safety_table(rows)
    try:
        folder.note(JOURNAL, True)
        if len(rows):
            write_results(folder, spec, rows, table, interrupted, start, set_units)
        folder.write_summary({"complete": not interrupted, "kind": "sweep",
                              "status_detail": ("interrupted" if interrupted and len(rows)
                                                else "interrupted before any point finished"
                                                if interrupted else "finished"),
                              "points": len(all_points), "runs": runs, "rows": len(rows),
                              "failed_rows": failed}, final=True)
    finally:
        folder.release()
    if not len(rows):
        return rows
    print(format_table(table))
    for key, entries in safety_by_value(rows, spec).items():
        print(format_table(entries, key))
    for report in SWEEP_REPORTS.values():
        entries = report.table(rows)
        if entries:
            print(report.text(entries))
    print(f"{len(rows)} row(s) in {out / 'results.parquet'} and results.csv"
          + (f"; {failed} failed (see their error column)" if failed else ""))
    return rows


def _record(spec: SweepSpec, rows: Rows, record: list[str], out: Path,
            all_points: list[dict], args: argparse.Namespace) -> None:
    """--record: each run's best and/or worst point re-run with its recording."""
    if not any(r["status"] == "ok" and not math.isnan(margin(r)) for r in rows):
        raise SweepError(f"--record {args.record}: no row completed, so there is no "
                         f"point to record; the {len(rows)} row(s) and their errors are "
                         f"in {out / 'results.csv'}")
    try:
        for written in record_points(spec, rows, record, out, all_points, not args.quiet):
            print(f"recorded: {written}")
    except KeyboardInterrupt as exc:
        raise SweepError(f"{str(exc) or 'interrupted (Ctrl-C)'} while recording; the sweep's "
                         f"results are complete in {out}") from None
