"""`cosim new`: a pipeline for a robot from its URDF (cosim/paper/scaffold.py), printed chain
first, written where --out says."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from .build_fmu import add_chain_options, fixed_joints
from .common import UserError


def add_parser(commands: argparse._SubParsersAction) -> None:
    p = commands.add_parser(
        "new", help="write a pipeline for a robot from its URDF that runs as it is",
        description="Read a robot's URDF, print its chain (joints, kinds, limits, friction, "
        "masses, the held joints and the tip) and write a pipeline for it: the robot named "
        "once, a start well inside its limits and a default motion about it, the paper's "
        "observer and NN controller with gains scaled to the arm's own inertia, the safety "
        "filter on its own limits, a PD + gravity baseline, and a payload range at the tip. "
        "`cosim run FILE.toml` then runs it as it is. SI units, radians.",
        epilog="Then: cosim run FILE.toml --dry-run (checks every key, the motion against "
        "every limit and the step against the gains), cosim run FILE.toml --out runs/NAME, "
        "cosim view runs/NAME.")
    add_chain_options(p, required=True)
    p.add_argument("--friction", default="auto", choices=("auto", "keep", "none"),
                   help="the URDF's <dynamics> friction in the plant and the nominal model: "
                   "auto (default) keeps it but on joints whose viscous friction damps faster "
                   "than a 1 ms step allows (said in the file), keep, or none")
    p.add_argument("--out", default=None, metavar="FILE.toml",
                   help="where to write the pipeline (default: NAME.toml in the working "
                   "folder, NAME the robot's)")
    p.add_argument("--force", action="store_true",
                   help="replace a file already at --out (otherwise refused, untouched)")
    p.set_defaults(func=handle)


def handle(args: argparse.Namespace) -> None:
    from plant_fmu.urdf import UrdfError, read_urdf, resolve_uri

    from ..paper.scaffold import chain_table, default_name, pipeline_text

    fixed = fixed_joints(args.fix)
    path = resolve_uri(args.urdf, Path.cwd())
    try:
        chain = read_urdf(path, base=args.base, tip=args.tip, fixed=fixed)
    except UrdfError as exc:
        raise UserError(f"--urdf {exc}; nothing was written") from None
    name = default_name(chain, args.urdf)
    out = Path(args.out) if args.out else Path(f"{name}.toml")
    if out.suffix != ".toml":
        raise UserError(f"--out {args.out}: a pipeline file's name ends in .toml (e.g. "
                        f"{out.with_suffix('.toml')}); nothing was written")
    if out.exists() and not args.force:
        raise UserError(f"--out {out}: a file is already there; give --force to replace it, "
                        "or another --out; nothing was written")
    # The URDF as the user named it: a package:// address as is, a path relative to the
    # pipeline file's folder (where a pipeline's paths are read from).
    urdf = args.urdf if "://" in args.urdf else _relative(path, out.parent)
    text = pipeline_text(chain, urdf, out.stem if args.out else name, base=args.base,
                         tip=args.tip, fixed=fixed, friction=args.friction)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise UserError(f"--out {out}: cannot write the pipeline there: "
                        f"{exc.strerror or exc}") from None
    print(chain_table(chain))
    print(f"wrote {out}: run it with\n  cosim run {out} --dry-run\n  cosim run {out} --out "
          f"runs/{out.stem}\n(the first run of an arm from a URDF on this machine compiles its "
          "kernels once, minutes on 2 cores, for every robot alike; `cosim warm-up "
          f"{out}` does it ahead)")


def _relative(path: Path, folder: Path) -> str:
    """``path`` relative to ``folder`` where it can be, else absolute."""
    try:
        return os.path.relpath(path.resolve(), folder.resolve())
    except ValueError:  # another drive
        return str(path.resolve())
