"""``cosim sweep``: the spec from the command line, every point checked, the points run on Dask,
the results written and the tables printed, then the best and/or worst points re-run with
their recording (``--record``); or, with ``--dry-run``, what would be done."""

from __future__ import annotations

import json
import math
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from ..config import load_pipeline
from ..evaluate.reports import SWEEP_REPORTS
from ..progress import phase
from .checks import margin
from .execution import cluster_client, execute
from .files import write_results
from .spec import (
    SweepError,
    SweepSpec,
    assignments,
    check_spec,
    only_runs,
    parse_grid,
    parse_sample,
    points,
    validate,
)
from .tables import format_table, safety_by_value, safety_table

if TYPE_CHECKING:
    import argparse

    from ..outputs.run_folder import RunFolder


def record_points(spec: SweepSpec, rows: list[dict], which: list[str], out: Path,
                  progress: bool = False) -> list[str]:
    """Full run folders (recording, figures) of each run's best and/or worst point by
    :func:`margin`, re-run here: ``out/best_<run>_point<i>``, ``out/worst_<run>_point<i>``.
    A run with no completed row has nothing to record."""
    from ..runner import run

    ok = [r for r in rows if r["status"] == "ok" and not math.isnan(margin(r))]
    written = []
    for kind in which:
        for name in dict.fromkeys(r["run"] for r in ok):
            mine = [r for r in ok if r["run"] == name]
            row = (min if kind == "best" else max)(mine, key=margin)
            point = {k.removeprefix("set:"): json.loads(v) if isinstance(v, str) and
                     v.startswith("[") else v for k, v in row.items() if k.startswith("set:")}
            folder = out / f"{kind}_{name}_point{row['point']}"
            pipeline = only_runs(load_pipeline(spec.pipeline, assignments(spec, point),
                                               warn=None), [name])
            with phase(f"re-running {name}'s {kind} point ({row['point']}) with its "
                       "recording and figures", progress):
                run(pipeline, folder, progress=False, force=True)
            written.append(str(folder))
    return written


def _dry_run(spec: SweepSpec, all_points: list[dict], runs: list[str], out: Path,
             args: argparse.Namespace) -> int:
    """What the sweep would do, every point checked (as before a real sweep), nothing run."""
    from ..outputs.run_folder import would_refuse

    load = load_pipeline(spec.pipeline, spec.base, warn=None)
    steps = round(load.simulation.duration / load.simulation.step)
    where = args.scheduler or f"{args.workers or os.cpu_count() or 1} local Dask worker(s)"
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
    print("every point checked against the pipeline's schema; nothing was run")
    return 0


def _on_sigterm(signum: int, frame: object) -> None:
    raise KeyboardInterrupt("terminated (SIGTERM)")


def main(args: argparse.Namespace) -> int:
    """``cosim sweep`` (parsed arguments): returns the exit status. SIGTERM is handled like
    Ctrl-C in every phase: finished rows are written, the cluster ended, the lock released."""
    import signal

    previous = signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        return _main(args)
    finally:
        signal.signal(signal.SIGTERM, previous)


def _main(args: argparse.Namespace) -> int:
    from ..outputs.run_folder import RunFolder

    spec, record = _spec_of(args)
    check_spec(spec, args.max_points, args.workers, args.scheduler)
    out = Path(args.out)
    try:
        with phase("checking every point against the pipeline's schema", not args.quiet):
            all_points = points(spec)
            validate(spec, all_points)
    except KeyboardInterrupt as exc:
        raise SweepError(f"{str(exc) or 'interrupted (Ctrl-C)'} while checking the points; "
                         "nothing was run") from None
    runs = spec.runs or list(load_pipeline(spec.pipeline, spec.base, warn=None).runs)
    if args.dry_run:
        return _dry_run(spec, all_points, runs, out, args)
    folder = RunFolder.create(out, args.force)
    rows, interrupted = _run_on_dask(spec, all_points, runs, out, folder, args)
    _report(folder, spec, rows, interrupted, all_points, runs, out)
    if interrupted:
        print(f"cosim: interrupted; the {len(rows)} finished row(s) are kept in {out}",
              file=sys.stderr)
        return 2
    if record:
        _record(spec, rows, record, out, args)
    return 0


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
    return spec, record


def _run_on_dask(spec: SweepSpec, all_points: list[dict], runs: list[str], out: Path,
                 folder: RunFolder, args: argparse.Namespace) -> tuple[list[dict], bool]:
    """Every point on the cluster ``args`` asks for: (rows, interrupted). A cluster that
    cannot start is said in the folder's summary too, the folder released."""
    from tqdm import tqdm

    rows: list[dict] = []
    interrupted = False
    try:
        starting = (f"connecting to {args.scheduler}" if args.scheduler else
                    f"starting {args.workers or os.cpu_count() or 1} Dask worker process(es)")
        with phase(starting, not args.quiet):
            client, cluster = cluster_client(args.workers, args.scheduler)
        try:
            where = (args.scheduler
                     or f"a local cluster of {len(client.scheduler_info()['workers'])}")
            print(f"sweeping {len(all_points)} point(s) × {len(runs)} run(s) of "
                  f"{spec.pipeline} on {where} worker(s) -> {out}", file=sys.stderr)
            bar = tqdm(total=len(all_points), unit="point", file=sys.stderr,
                       disable=args.quiet or not sys.stderr.isatty())
            rows, interrupted = execute(spec, all_points, client, bar.update)
            bar.close()
        finally:
            client.close()
            if cluster is not None:
                cluster.close()
    except KeyboardInterrupt:  # while the cluster started or closed: what finished is kept
        interrupted = True
    except BaseException as exc:  # the cluster could not start: say so in the folder too
        try:
            folder.write_summary({"complete": False, "kind": "sweep", "error": str(exc)},
                                 final=True)
        finally:
            folder.release()
        raise
    return rows, interrupted


def _report(folder: RunFolder, spec: SweepSpec, rows: list[dict], interrupted: bool,
            all_points: list[dict], runs: list[str], out: Path) -> None:
    """The results files and the folder's summary (the folder released), then the tables
    printed."""
    table = safety_table(rows)
    failed = sum(r["status"] != "ok" for r in rows)
    try:
        write_results(folder, spec, rows, table, interrupted, len(all_points))
        folder.write_summary({"complete": not interrupted, "kind": "sweep",
                              "status_detail": "interrupted" if interrupted else "finished",
                              "points": len(all_points), "runs": runs, "rows": len(rows),
                              "failed_rows": failed}, final=True)
    finally:
        folder.release()
    print(format_table(table))
    for key, entries in safety_by_value(rows, spec).items():
        print(format_table(entries, key))
    for report in SWEEP_REPORTS.values():
        entries = report.table(rows)
        if entries:
            print(report.text(entries))
    print(f"{len(rows)} row(s) in {out / 'results.parquet'} and results.csv"
          + (f"; {failed} failed (see their error column)" if failed else ""))


def _record(spec: SweepSpec, rows: list[dict], record: list[str], out: Path,
            args: argparse.Namespace) -> None:
    """--record: each run's best and/or worst point re-run with its recording."""
    if not any(r["status"] == "ok" and not math.isnan(margin(r)) for r in rows):
        raise SweepError(f"--record {args.record}: no row completed, so there is no "
                         f"point to record; the {len(rows)} row(s) and their errors are "
                         f"in {out / 'results.csv'}")
    try:
        for path in record_points(spec, rows, record, out, not args.quiet):
            print(f"recorded: {path}")
    except KeyboardInterrupt as exc:
        raise SweepError(f"{str(exc) or 'interrupted (Ctrl-C)'} while recording; the sweep's "
                         f"results are complete in {out}") from None
