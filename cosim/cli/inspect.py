"""`cosim inspect`: what an FMU offers, whether it fits the plant interface, and on request
its linearisation about the start state; or what a system of FMUs (an SSP archive) is made
of."""

from __future__ import annotations

import argparse
from pathlib import Path

from .common import UserError


def add_parser(commands: argparse._SubParsersAction) -> None:
    p = commands.add_parser(
        "inspect", help="show what an FMU (or a system of FMUs) offers and whether it fits "
        "the plant interface",
        description="Print an FMU's FMI version, interfaces (Co-Simulation, Model Exchange), "
        "platforms and variables by causality with units, then whether it fits cosim's plant "
        "interface (tau inputs, q outputs, optional qdot and M) under the given mapping, and "
        "if not, every reason. For an SSP archive (a system of FMUs): its components, its own "
        "connectors, the connections and what passes on in what order at each step, then "
        "whether its connectors fit the plant interface. Exit status 0 if it fits, 1 if not, "
        "2 on an error (a system that cannot run: an unknown connector, mismatched units, an "
        "algebraic loop).")
    p.add_argument("fmu", type=Path, metavar="FMU|SSP", help="the .fmu file, or a system's .ssp")
    p.add_argument("--pipeline", default=None,
                   help="take plant.variables and plant.parameters from this pipeline")
    p.add_argument("--set", action="append", default=[], metavar="KEY.PATH=VALUE",
                   help="map the interface, e.g. 'plant.variables.q=[\"shoulder\",\"elbow\"]'"
                   " (repeatable)")
    p.add_argument("--linearize", action="store_true",
                   help="also linearise it about its start state from its Model Exchange "
                   "directional derivatives and print the state-space model and its poles "
                   "(inputs tau, outputs q and qdot when it fits, else all)")
    p.set_defaults(func=handle)


def handle(args: argparse.Namespace) -> int:
    from ..config import load_pipeline
    from ..plant.inspection import inspect_fmu
    from ..plant.mapping import FmuError

    pipeline = load_pipeline(args.pipeline, args.set)
    mapping = pipeline.plant.variables.model_dump()
    if args.fmu.suffix.lower() == ".ssp":
        return _inspect_system(args, mapping, dict(pipeline.plant.parameters))
    try:
        info = inspect_fmu(args.fmu, mapping)
        print(info)
        if args.linearize:
            _print_linearization(args.fmu, info, dict(pipeline.plant.parameters))
    except FmuError as exc:
        raise UserError(str(exc)) from None
    return 0 if info.fits else 1  # the report says why; 1, not 2: the command itself worked


def _inspect_system(args: argparse.Namespace, mapping: dict, parameters: dict) -> int:
    from ..plant.mapping import FmuError
    from ..plant.unpack import remove
    from ..system.inspection import describe_system
    from ..system.ssp import read_ssp

    if args.linearize:
        raise UserError(f"--linearize: {args.fmu} is a system of FMUs; linearise one FMU of "
                        "it (its resources/ folder holds them)")
    try:
        system, folder = read_ssp(args.fmu)
    except FmuError as exc:
        raise UserError(str(exc)) from None
    try:
        report, fits = describe_system(system, mapping, parameters)
    except FmuError as exc:
        raise UserError(f"{args.fmu}: {exc}") from None
    finally:
        remove(folder)
    print(report)
    return 0 if fits else 1


def _print_linearization(path: Path, info, parameters: dict[str, float]) -> None:
    import numpy as np

    from ..plant.linearization import linearize_at_start

    inputs = info.mapping.tau if info.fits else None
    outputs = info.mapping.q + (info.mapping.qdot or []) if info.fits else None
    point = linearize_at_start(path, inputs, outputs, parameters)
    system = point.system
    np.set_printoptions(precision=5, suppress=False, linewidth=100)
    print("\nlinearised about the start state (t = 0 s, after initialisation):")
    print(f"  x0    = {point.x0}   ({', '.join(system.state_labels)})")
    print(f"  u0    = {point.u0}")
    print(f"  xdot0 = {point.xdot0}"
          + ("   (not an equilibrium: the model is the local tangent along the motion)"
             if np.linalg.norm(point.xdot0) > 1e-9 else "   (an equilibrium)"))
    print(system)
    print("poles (1/s):")
    for pole in system.poles():
        wn = abs(pole)
        zeta = -pole.real / wn if wn else float("nan")
        kind = "unstable" if pole.real > 0 else "stable" if pole.real < 0 else "marginal"
        print(f"  {pole.real:+.6g} {pole.imag:+.6g}j   |p| = {wn:.6g} rad/s, "
              f"damping {zeta:.3g}, {kind}")
