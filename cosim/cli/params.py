"""`cosim params`: list every pipeline key: default, allowed values, meaning."""

from __future__ import annotations

import argparse

from .common import UserError


def add_parser(commands: argparse._SubParsersAction) -> None:
    p = commands.add_parser(
        "params", help="list every pipeline key: default, allowed values, meaning",
        description="List every key a pipeline (and --set) accepts, generated from the schema "
        "it is validated with: its default, the values it takes, and its meaning with units "
        "(SI, radians). With PIPELINE, its values instead, '*' marking those that differ from "
        "the defaults. Block tables are also keys of each run (runs.NAME.controller.kv).")
    p.add_argument("pipeline", nargs="?", default=None, help="a pipeline file (optional)")
    p.add_argument("--set", action="append", default=[], metavar="KEY.PATH=VALUE",
                   help="override a key first, as `cosim run --set` (repeatable)")
    p.add_argument("--grep", default="", metavar="TEXT",
                   help="only the keys whose line contains TEXT, e.g. --grep observer")
    p.set_defaults(func=handle)


def handle(args: argparse.Namespace) -> None:
    from ..config import load_pipeline
    from ..config.params import describe

    pipeline = load_pipeline(args.pipeline, args.set) if args.pipeline or args.set else None
    text = describe(pipeline, args.grep)
    if not text:
        raise UserError(f"--grep {args.grep}: no key, value or meaning contains it")
    print(text)
