"""`cosim build-fmu`: build a built-in plant FMU, or one from a URDF (FMI 2.0 or 3.0)."""

from __future__ import annotations

import argparse
import math
import os
import shutil
import zipfile
from pathlib import Path

from .common import UserError


def add_parser(commands: argparse._SubParsersAction) -> None:
    from plant_fmu import DEFAULT_MODEL, MODELS

    max_links = max(model.MAX_LINKS for model in MODELS.values())
    p = commands.add_parser(
        "build-fmu", help="build a plant FMU: a built-in model, or a robot's URDF (FMI 2.0 or "
        "3.0)",
        description="Compile a built-in plant model, or the spatial rigid-body chain of a "
        "URDF (--urdf), with the system C compiler into an FMU with Co-Simulation and Model "
        "Exchange. Prints the FMU's path.",
        epilog="A URDF's FMU has per joint the input tau[i] (N·m; N for a prismatic joint), "
        "the outputs q[i] (rad; m), qdot[i] (rad/s; m/s), M[i,j] and h[i] (its inertia "
        "matrix and bias forces), the parameters q0[i] and qdot0[i] (the start; q0's min/max "
        "the URDF's position limits), qdot_max[i] and tau_max[i] (its velocity and effort "
        "limits), b[i] and fc[i] (viscous and Coulomb friction) and payload (kg at the tip "
        "frame's origin); `cosim inspect FMU` lists them all. Built FMUs are cached in "
        "$COSIM_CACHE (default ~/.cache/cosim/fmus), by everything they are built from: "
        "--output copies from there.")
    p.add_argument("--model", default=None, choices=list(MODELS),
                   help="the plant model: the rigid n-link planar arm (planar_arm), the "
                   "arm with elastic joints, motors driving the links through springs "
                   "(elastic_joints), or the joints' drives, DC motors under current control "
                   "behind gears, a component of a system of FMUs (drives) "
                   f"(default {DEFAULT_MODEL})")
    p.add_argument("--links", "--joints", type=int, default=None,
                   choices=range(1, max_links + 1), metavar="N",
                   help=f"number of links (of joints, for the drives), 1 to {max_links} "
                   "(default 2)")
    urdf = p.add_argument_group(
        "a robot's URDF", "The chain from --base to --tip: revolute, continuous and prismatic "
        "joints move, fixed joints (and joints off that path, held at 0 or their nearest "
        "limit) are folded into their parent body. Meshes are not needed for the dynamics "
        "(the FMU ignores them) but must exist: the 3-D view draws them.")
    add_chain_options(urdf, required=False)
    p.add_argument("--fmi-version", type=int, default=2, choices=(2, 3),
                   help="FMI version (default 2)")
    p.add_argument("--output", default=None, metavar="FILE.fmu|FOLDER/",
                   help="where to write the FMU: a .fmu file, or a folder (an existing one, "
                   "or a name ending in /, made if missing) (default: the build cache)")
    p.add_argument("--force", action="store_true",
                   help="replace a different file already at the output path (an FMU built "
                   "the same way is left as it is either way)")
    p.set_defaults(func=handle)


def add_chain_options(group, required: bool) -> None:
    """--urdf, --base, --tip and --fix: a robot's chain, as `build-fmu` and `new` take it."""
    group.add_argument("--urdf", default=None, required=required, metavar="ROBOT.urdf",
                       help="the robot's URDF: a path, or package://PKG/... (found above the "
                       "file, in $ROS_PACKAGE_PATH, $AMENT_PREFIX_PATH or an installed "
                       "example-robot-data)")
    group.add_argument("--base", default=None, metavar="LINK",
                       help="the link the chain is fixed to (default: the URDF's root link)")
    group.add_argument("--tip", default=None, metavar="LINK",
                       help="the chain's last link, where the payload sits (default: from the "
                       "base, follow the one way on to a moving joint; stop where it forks)")
    group.add_argument("--fix", action="append", default=[], metavar="JOINT=VALUE",
                       help="hold a moving joint at VALUE (rad, or m for a prismatic joint), "
                       "folding it into its parent body (repeatable)")


def fixed_joints(items: list[str]) -> dict[str, float]:
    """``--fix JOINT=VALUE`` options as {joint: value}."""
    fixed: dict[str, float] = {}
    for item in items:
        name, sep, value = item.partition("=")
        name = name.strip()
        try:
            number = float(value)
        except ValueError:
            sep = ""
        if not sep or not name or not math.isfinite(number):
            raise UserError(f"--fix {item}: give JOINT=VALUE, the value a finite number in rad "
                            "(m for a prismatic joint), e.g. --fix panda_finger_joint1=0.02")
        if name in fixed:
            raise UserError(f"--fix {item}: joint '{name}' is already held at {fixed[name]} by "
                            "an earlier --fix; hold each joint once")
        fixed[name] = number
    return fixed


def _folder(args: argparse.Namespace) -> Path | None:
    """The folder --output names (made only once the FMU is built), or None for a file or
    the cache."""
    output = Path(args.output) if args.output is not None else None
    if output is not None and (output.is_dir() or args.output.endswith(os.sep)):
        if output.exists() and not output.is_dir():
            raise UserError(f"--output {args.output}: {output} is a file, not a folder; "
                            "nothing was written")
        return output
    if output is not None and output.suffix.lower() != ".fmu":
        raise UserError(f"--output {args.output}: an FMU's file name ends in .fmu (e.g. "
                        f"{output.with_suffix('.fmu')}); for a folder, end it with "
                        f"{os.sep} and the FMU is written into it; nothing was written")
    return None


def _build(args: argparse.Namespace) -> Path:
    """Build into the cache, then copy to --output: an error while building is the build's
    (the URDF, the compiler, the cache), one while writing the output is --output's."""
    from plant_fmu import DEFAULT_MODEL, MODELS, UrdfError, build_fmu, build_urdf_fmu
    from plant_fmu.urdf import resolve_uri

    folder = _folder(args)
    output = Path(args.output) if args.output is not None and folder is None else None
    if args.urdf is None:
        for option, given in (("--base", args.base), ("--tip", args.tip), ("--fix", args.fix)):
            if given:
                raise UserError(f"{option} chooses a part of a URDF: give --urdf ROBOT.urdf too")
        model, links = args.model or DEFAULT_MODEL, args.links or 2
        if folder is not None:
            identifier = MODELS[model].MODEL_IDENTIFIER
            output = folder / f"{identifier}{links}_fmi{args.fmi_version}.fmu"
        cached = build_fmu(links=links, fmi_version=args.fmi_version, model=model)
        return _write_output(output, cached, args)
    for option, given in (("--model", args.model), ("--links", args.links)):
        if given is not None:
            raise UserError(f"{option} is for the built-in planar models; --urdf builds the "
                            "robot the URDF describes (its joints are the URDF's): drop one")
    if not args.urdf.strip():  # (the working folder, resolved)
        raise UserError("--urdf '': an empty name; give the robot's URDF file")
    urdf = resolve_uri(args.urdf, Path.cwd())
    try:
        cached = build_urdf_fmu(urdf, base=args.base, tip=args.tip, fixed=fixed_joints(args.fix),
                                fmi_version=args.fmi_version)
    except UrdfError as exc:
        raise UserError(f"--urdf {exc}; nothing was written") from None
    if folder is not None:  # named as in the cache, without its digest
        output = folder / (cached.name.rsplit("_", 1)[0] + ".fmu")
    return _write_output(output, cached, args)


def _write_output(output: Path | None, cached: Path, args: argparse.Namespace) -> Path:
    """The cached FMU copied to ``output`` (its folder made if missing), unless a different
    file is there (:func:`_may_replace`); the cached FMU itself without --output."""
    from plant_fmu.build import write_atomically

    if output is None:
        return cached
    _may_replace(output, cached, args.force)
    above = next((folder for folder in output.parents if folder.exists()), None)
    if above is not None and not above.is_dir():
        raise UserError(f"--output {args.output}: cannot write the FMU there: {above} is a "
                        "file, not a folder; nothing was written")
    try:
        output.parent.mkdir(parents=True, exist_ok=True)
        write_atomically(output, lambda tmp: shutil.copyfile(cached, tmp))
    except OSError as exc:
        raise UserError(f"--output {args.output}: cannot write the FMU there: "
                        f"{exc.strerror or exc}; nothing was written") from None
    return output


def _entries(fmu: Path) -> list[tuple[str, int, int]] | None:
    """An FMU archive's entries (name, CRC-32, size), sorted; None for a file that is not
    a readable zip archive."""
    try:
        with zipfile.ZipFile(fmu) as archive:
            return sorted((i.filename, i.CRC, i.file_size) for i in archive.infolist())
    except (OSError, zipfile.BadZipFile):
        return None


def _may_replace(output: Path | None, built: Path, force: bool) -> None:
    """Refuse to replace a file at ``output`` that is not this very build (``built``, the
    cached FMU the output is a copy of) unless ``force``: another URDF or options, or a file
    cosim did not write."""
    if output is None or force or not output.exists():
        return
    if output.is_file() and _entries(output) == _entries(built):
        return  # the same build (its entries', not the archive's own dates): copied again
    raise UserError(f"--output {output}: a different file is already there (another build, "
                    "or a file cosim did not write); give --force to replace it, or another "
                    "--output; nothing was written")


def handle(args: argparse.Namespace) -> None:
    try:
        path = _build(args)
    except KeyboardInterrupt as exc:  # written to a temporary and renamed: nothing half-made
        raise UserError(f"{str(exc) or 'interrupted (Ctrl-C)'} while building the FMU; nothing "
                        "was written") from None
    print(path)
