"""`cosim export`: write a run folder's traces as Parquet, CSV or MAT, with units."""

from __future__ import annotations

import argparse
from pathlib import Path

from .common import UserError


def add_parser(commands: argparse._SubParsersAction) -> None:
    p = commands.add_parser(
        "export", help="write a run folder's traces as Parquet, CSV or MAT, with units",
        description="Write every signal of each run (and each check's and barrier's value per "
        "row) to export_<run>.parquet, .csv or .mat, with its unit and meaning: Parquet field "
        "metadata (unit, description), a CSV header 'name (unit)' per column, a MAT struct of "
        "arrays with 'units' and 'descriptions'. Per-joint signals are q[1], q[2], ...; n×n "
        "ones M[1,1], M[1,2], ... (1-based). SI units, radians. Prints the files written.")
    p.add_argument("run_dir", metavar="RUN_DIR", type=Path, help="a run folder")
    from ..outputs.formats import EXPORT_FORMATS

    p.add_argument("--format", default="parquet", choices=tuple(EXPORT_FORMATS),
                   help="file format (default parquet)")
    p.add_argument("--run", action="append", default=None, metavar="NAME", dest="runs",
                   help="a run to export (repeatable; default: all)")
    p.add_argument("--out", type=Path, default=None,
                   help="folder for the files (default: RUN_DIR itself, where earlier exports "
                   "are replaced)")
    p.add_argument("--force", action="store_true",
                   help="replace files of the same name in --out")
    p.set_defaults(func=handle)


def handle(args: argparse.Namespace) -> None:
    from ..outputs.export import ExportError, export

    try:
        paths = export(args.run_dir, args.format, args.runs, args.out, args.force)
    except ExportError as exc:
        raise UserError(str(exc)) from None
    for path in paths:
        print(path)
