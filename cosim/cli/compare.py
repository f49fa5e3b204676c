"""`cosim compare`: compare two run folders' checks and metrics (exit 1 on a regression)."""

from __future__ import annotations

import argparse
from pathlib import Path

from .common import UserError


def add_parser(commands: argparse._SubParsersAction) -> None:
    p = commands.add_parser(
        "compare", help="compare two run folders' checks and metrics; exit 1 if a check that "
        "held in A fails in B, or one violated in A got worse",
        description="Print each run's safety checks (worst value, its unit, and verdict) and "
        "the numeric metrics that differ, from two run folders side by side with the "
        "difference B - A. Each check's verdict is recomputed from its worst value and bound, "
        "and both from its values in the run's trace: a summary that disagrees is refused. "
        "A and B must compare like with like: plants of the same joints, the same duration "
        "and step, every compared run run to its end, the same bound for each check; "
        "otherwise nothing is judged and the difference is named (exit 2). Exit status 0 when "
        "every check that held in A holds in B and none violated in A got worse, 1 when one "
        "did, or a check of one side only is gone from B or violated in B (each named: a "
        "gate for a controller change), 2 on an error. SI units, radians.")
    p.add_argument("a", metavar="A", type=Path, help="the run folder to compare against")
    p.add_argument("b", metavar="B", type=Path, help="the run folder being checked")
    p.add_argument("--run", action="append", default=None, metavar="NAME", dest="runs",
                   help="compare only this run (repeatable; default: every run of either)")
    p.add_argument("--tolerance", type=float, default=0.0, metavar="FRACTION",
                   help="how much worse a check already violated in A may get in B before it "
                   "counts as a regression, as a fraction of its bound (default 0)")
    p.add_argument("--json", action="store_true",
                   help="print the comparison as JSON (every check and metric, both values, "
                   "the regressions) instead of the tables")
    p.set_defaults(func=handle)


def handle(args: argparse.Namespace) -> int:
    import math

    from ..outputs.compare import CompareError, compare

    if not (math.isfinite(args.tolerance) and args.tolerance >= 0):
        raise UserError(f"--tolerance {args.tolerance:g}: expected a fraction of each check's "
                        "bound ≥ 0, e.g. 0.01")
    try:
        result = compare(args.a, args.b, args.runs, args.tolerance)
    except CompareError as exc:
        raise UserError(str(exc)) from None
    if args.json:
        import json

        from ..outputs.run_folder import jsonable

        print(json.dumps(jsonable(result.document), indent=2, ensure_ascii=False))
    else:
        print("\n".join(result.lines))
    return 1 if result.regressions else 0  # 1, not 2: the command worked; B regressed
