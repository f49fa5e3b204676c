"""`cosim warm-up`: compile the kernels and build the FMUs of pipelines now."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from .common import UserError


def add_parser(commands: argparse._SubParsersAction) -> None:
    p = commands.add_parser(
        "warm-up", help="compile the kernels and fused loops of pipelines and build their FMUs "
        "now, so that their first run starts at once",
        description="Fill the caches a run loads from: compile the numba kernels and fused "
        "loops that the pipelines' runs step (in parallel, one process per core), build their "
        "plant FMUs and matplotlib's font list. `make demo` and `make test` run it; a "
        "warm cache is recognised in a fraction of a second. Caches: $NUMBA_CACHE_DIR (else "
        "~/.cache/cosim/numba, a folder per kernel module and version of its sources), "
        "$COSIM_ENGINE_CACHE, $COSIM_CACHE.")
    p.add_argument("pipelines", nargs="*", metavar="PIPELINE",
                   help="pipeline files (default: pipelines/paper_two_link.toml)")
    p.add_argument("--workers", type=int, default=None, metavar="K",
                   help="compile in K processes (default: one per core)")
    p.set_defaults(func=handle)


def handle(args: argparse.Namespace) -> None:
    from ..warm import WarmUpError, default_pipelines, warm_up

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
