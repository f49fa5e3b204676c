"""The `cosim` command line. User mistakes end with one clear message and exit status 2."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from plant_fmu import MAX_LINKS, BuildError, build_fmu


class UserError(Exception):
    """A mistake in what the user asked for: printed as one line, no traceback."""


def _build_fmu(args: argparse.Namespace) -> None:
    path = build_fmu(links=args.links, fmi_version=args.fmi_version, output=args.output)
    print(path)


def _simulate_plant(args: argparse.Namespace) -> None:
    from fmpy import simulate_fmu

    fmu = Path(args.fmu)
    if not fmu.is_file():
        raise UserError(f"{fmu}: no such FMU file")
    result = simulate_fmu(str(fmu), stop_time=args.stop_time, output_interval=args.step)
    names = [n for n in result.dtype.names if n.startswith(("q[", "qdot[")) or n == "energy"]
    print("open-loop, zero torque (rad, rad/s, J)")
    print("  ".join(f"{n:>10}" for n in ["time", *names]))
    stride = max(1, len(result) // 10)
    for row in result[::stride]:
        print("  ".join(f"{row[n]:10.4f}" for n in ["time", *names]))


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="cosim",
        description="Co-simulate a robot-arm FMU with a safe adaptive output-feedback "
        "controller. SI units, angles in radians.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("build-fmu", help="build the n-link planar arm FMU (FMI 2.0 or 3.0)",
                       description="Compile the built-in plant with the system C compiler into "
                       "an FMU with Co-Simulation and Model Exchange. Prints the FMU's path.")
    p.add_argument("--links", type=int, default=2, choices=range(1, MAX_LINKS + 1),
                   metavar="N", help=f"number of links, 1 to {MAX_LINKS} (default 2)")
    p.add_argument("--fmi-version", type=int, default=2, choices=(2, 3),
                   help="FMI version (default 2)")
    p.add_argument("--output", type=Path, default=None,
                   help="where to write the FMU (default: the build cache)")
    p.set_defaults(func=_build_fmu)

    p = sub.add_parser("simulate-plant", help="simulate a plant FMU open-loop with FMPy",
                       description="Simulate an FMU with zero input torque and print its joint "
                       "angles (rad), velocities (rad/s) and energy (J).")
    p.add_argument("fmu", help="the FMU file")
    p.add_argument("--stop-time", type=float, default=2.0, help="seconds (default 2)")
    p.add_argument("--step", type=float, default=1e-3, help="output interval, s (default 1e-3)")
    p.set_defaults(func=_simulate_plant)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        args.func(args)
    except (UserError, BuildError) as exc:
        print(f"cosim: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
