"""`cosim compare`: compare two run folders' checks and metrics (exit 1 on a regression)."""

from __future__ import annotations

import argparse
from pathlib import Path

from .common import UserError


def add_parser(commands: argparse._SubParsersAction) -> None:
    p = commands.add_parser(
        "compare", help="compare two run folders' checks and metrics; exit 1 if a check that "
        "held in A fails in B",
        description="Print each run's safety checks (worst value and verdict) and numeric "
        "metrics from two run folders side by side with the difference B - A. Exit status 0 "
        "when every check that held in A holds in B, 1 when one does not (each named: a gate "
        "for a controller change), 2 on an error. SI units, radians.")
    p.add_argument("a", metavar="A", type=Path, help="the run folder to compare against")
    p.add_argument("b", metavar="B", type=Path, help="the run folder being checked")
    p.add_argument("--run", action="append", default=None, metavar="NAME", dest="runs",
                   help="compare only this run (repeatable; default: every run of either)")
    p.set_defaults(func=handle)


def handle(args: argparse.Namespace) -> int:
    from ..outputs.compare import CompareError, compare

    try:
        result = compare(args.a, args.b, args.runs)
    except CompareError as exc:
        raise UserError(str(exc)) from None
    print("\n".join(result.lines))
    return 1 if result.regressions else 0  # 1, not 2: the command worked; B regressed
