"""The `cosim` argument parser: a sub-parser per command, each defined in its command's
module next to its handler."""

from __future__ import annotations

import argparse

from . import (
    build_fmu,
    compare,
    export,
    export_ssp,
    inspect,
    new,
    params,
    run,
    sweep,
    view,
    warm_up,
)

# In the order `cosim --help` lists them. A command is a module whose add_parser(commands)
# adds its sub-parser, with its handler as ``func``.
COMMANDS = (new, build_fmu, run, sweep, warm_up, view, export, export_ssp, compare, params,
            inspect)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="cosim",
        description="Co-simulate a robot-arm FMU with a safe adaptive output-feedback "
        "controller. SI units, angles in radians.")
    parser.add_argument("--version", action="version", version=f"cosim {_version()}",
                        help="print cosim's version and exit")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for command in COMMANDS:
        command.add_parser(commands)
    return parser


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("cosim")
    except PackageNotFoundError:  # run from a source tree that was not installed
        return "(not installed)"
