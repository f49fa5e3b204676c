"""`cosim sweep`: a pipeline over a grid and/or random samples of keys, on Dask."""

from __future__ import annotations

import argparse
from pathlib import Path

from .common import UserError

# A sweep's rows are held in memory and its points validated one by one (~1 ms each): past
# 100,000 points a typo (a 1000-value grid on three keys is 10⁹) would exhaust the machine
# before saying a word. --max-points raises the limit for a sweep meant to be that large.
# (Here, not in cosim.sweep: importing that loads numba, 0.3 s on every `cosim --help`.)
MAX_SWEEP_POINTS = 100_000


def add_parser(commands: argparse._SubParsersAction) -> None:
    p = commands.add_parser(
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
    p.add_argument("--cluster", choices=["local", "slurm"], default="local",
                   help="where the workers run: local processes (default), or SLURM jobs "
                   "from dask-jobqueue's configuration (jobqueue.slurm in "
                   "~/.config/dask/jobqueue.yaml; --workers K jobs; --dry-run prints the job "
                   "script)")
    p.add_argument("--record", default=None, metavar="best,worst",
                   help="also write full run folders of each run's best and/or worst point")
    folder = p.add_mutually_exclusive_group()
    folder.add_argument("--out", type=Path, help="sweep folder")
    folder.add_argument("--resume", type=Path, metavar="DIR",
                        help="go on with the sweep started in DIR (the same command, --resume "
                        "DIR for --out DIR): run only the points DIR's results lack")
    p.add_argument("--force", action="store_true", help="replace what --out holds")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--dry-run", action="store_true",
                   help="check every point, the runs and --out; print what would run; run "
                   "nothing")
    p.add_argument("--max-points", type=int, default=MAX_SWEEP_POINTS, metavar="N",
                   help="refuse a sweep of more points than this before any work "
                   f"(default {MAX_SWEEP_POINTS:,})")
    p.set_defaults(func=handle)


def handle(args: argparse.Namespace) -> int:
    from ..outputs.run_folder import RunFolderError
    from ..sweep import SweepError, main

    if args.pipeline is None:
        swallowed = [r for r in args.runs or [] if r.endswith(".toml") or Path(r).is_file()]
        if swallowed:
            raise UserError(f"--runs took the pipeline {swallowed[0]} as a run name: give the "
                            "pipeline first (cosim sweep PIPELINE … --runs NAME …), or end the "
                            "run names with --")
        raise UserError("give the pipeline file, e.g. cosim sweep "
                        "pipelines/paper_two_link.toml --grid … --out …")
    if args.out is None and args.resume is None:
        raise UserError("give the sweep folder: --out DIR (a new sweep) or --resume DIR (go "
                        "on with one started there)")
    if args.cluster == "slurm" and args.scheduler:
        raise UserError(f"--cluster slurm starts its own scheduler; --scheduler "
                        f"{args.scheduler} names another: give one of them")
    if args.resume is not None and args.force:
        raise UserError(f"--resume {args.resume} keeps what the folder holds; --force would "
                        "replace it: give one of them")
    try:
        return main(args)
    except (SweepError, RunFolderError) as exc:
        raise UserError(str(exc)) from None
