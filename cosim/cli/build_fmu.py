"""`cosim build-fmu`: build a built-in plant FMU (FMI 2.0 or 3.0)."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from .common import UserError


def add_parser(commands: argparse._SubParsersAction) -> None:
    from plant_fmu import DEFAULT_MODEL, MODELS

    max_links = max(model.MAX_LINKS for model in MODELS.values())
    p = commands.add_parser(
        "build-fmu", help="build a built-in plant FMU (FMI 2.0 or 3.0)",
        description="Compile a built-in plant model with the system C compiler into an FMU "
        "with Co-Simulation and Model Exchange. Prints the FMU's path.")
    p.add_argument("--model", default=DEFAULT_MODEL, choices=list(MODELS),
                   help=f"the plant model: the rigid n-link planar arm (planar_arm), or the "
                   f"arm with elastic joints, motors driving the links through springs "
                   f"(elastic_joints) (default {DEFAULT_MODEL})")
    p.add_argument("--links", type=int, default=2, choices=range(1, max_links + 1),
                   metavar="N", help=f"number of links, 1 to {max_links} (default 2)")
    p.add_argument("--fmi-version", type=int, default=2, choices=(2, 3),
                   help="FMI version (default 2)")
    p.add_argument("--output", default=None, metavar="FILE.fmu|FOLDER/",
                   help="where to write the FMU: a .fmu file, or a folder (an existing one, "
                   "or a name ending in /, made if missing) (default: the build cache)")
    p.set_defaults(func=handle)


def handle(args: argparse.Namespace) -> None:
    from plant_fmu import MODELS, build_fmu

    output = Path(args.output) if args.output is not None else None
    if output is not None and (output.is_dir() or args.output.endswith(os.sep)):
        try:  # a folder (one ending in / is made): the FMU goes into it
            output.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise UserError(f"--output {args.output}: cannot make the folder: "
                            f"{exc.strerror or exc}") from None
        identifier = MODELS[args.model].MODEL_IDENTIFIER
        output = output / f"{identifier}{args.links}_fmi{args.fmi_version}.fmu"
    elif output is not None and output.suffix.lower() != ".fmu":
        raise UserError(f"--output {args.output}: an FMU's file name ends in .fmu (e.g. "
                        f"{output.with_suffix('.fmu')}); for a folder, end it with "
                        f"{os.sep} and the FMU is written into it; nothing was written")
    try:
        path = build_fmu(links=args.links, fmi_version=args.fmi_version, output=output,
                         model=args.model)
    except OSError as exc:
        raise UserError(f"--output {args.output}: cannot write the FMU there: "
                        f"{exc.strerror or exc}") from None
    except KeyboardInterrupt as exc:  # written to a temporary and renamed: nothing half-made
        raise UserError(f"{str(exc) or 'interrupted (Ctrl-C)'} while building the FMU; nothing "
                        "was written") from None
    print(path)
