"""`cosim export-ssp`: a pipeline's plant as an SSP 1.0 archive another SSP tool opens."""

from __future__ import annotations

import argparse
from pathlib import Path

from .common import UserError


def add_parser(commands: argparse._SubParsersAction) -> None:
    p = commands.add_parser(
        "export-ssp", help="write a pipeline's plant as an SSP 1.0 archive (a system of FMUs)",
        description="Write the plant of PIPELINE as an SSP 1.0 archive: SystemStructure.ssd "
        "(its components, the system's connectors, the connections, every connector with "
        "its kind, type and unit, the units by their SI base units), each component's "
        "parameter values as resources/<component>.ssv and its FMU as "
        "resources/<component>.fmu. A plant.system or plant.ssp is written as it runs "
        "(plant.parameters over its components' values); one FMU as a system of one "
        "component, 'arm', whose connectors are the plant's ports. A component's step "
        "multiple and a delayed connection, which SSP 1.0 has no element for, are kept as "
        "annotations (type org.cosim.ssp) other tools ignore. Prints the file written.")
    p.add_argument("pipeline", type=Path, metavar="PIPELINE", help="the pipeline file")
    p.add_argument("--set", action="append", default=[], metavar="KEY.PATH=VALUE",
                   help="override a pipeline key (repeatable)")
    p.add_argument("--output", type=Path, required=True, metavar="FILE.ssp",
                   help="the archive to write")
    p.add_argument("--force", action="store_true", help="replace a file already there")
    p.set_defaults(func=handle)


def handle(args: argparse.Namespace) -> None:
    from ..config import PipelineError, load_pipeline
    from ..plant.mapping import FmuError
    from ..plant.unpack import remove
    from ..plant_source import plant_system
    from ..system.export import export_ssp

    if args.output.suffix.lower() != ".ssp":
        raise UserError(f"--output {args.output}: an SSP archive's name ends in .ssp (e.g. "
                        f"{args.output.with_suffix('.ssp')}); nothing was written")
    if args.output.exists() and not args.force:
        raise UserError(f"--output {args.output}: already exists; pass --force to replace it; "
                        "nothing was written")
    pipeline = load_pipeline(args.pipeline, args.set)
    system_plant = pipeline.plant.system is not None or pipeline.plant.ssp is not None
    folder = None
    try:
        system, folder = plant_system(pipeline)
        path = export_ssp(system, args.output,
                          dict(pipeline.plant.parameters) if system_plant else None,
                          pipeline.simulation.duration)
    except (FmuError, PipelineError) as exc:
        raise UserError(f"{exc}; nothing was written") from None
    except OSError as exc:
        raise UserError(f"--output {args.output}: cannot write it ({exc.strerror or exc}); "
                        "nothing was written") from None
    finally:
        if folder is not None:
            remove(folder)
    print(path)
