"""Finding a URDF and the files it names, and reading its XML: ``package://`` and
``file://`` URIs resolved (:func:`resolve_uri`, :func:`package_dirs`), the XML parsed by
yourdfpy after the checks a hostile or mistaken file needs (no xacro, every number a
number, every mesh a mesh inside the URDF's package or folder: :mod:`plant_fmu.meshes`).
The chain itself is :mod:`plant_fmu.urdf`'s. A file refused raises :class:`UrdfError`,
naming the element at fault.
"""

from __future__ import annotations

import logging
import os
import sys
from pathlib import Path

import numpy as np

from .meshes import MeshRefused, check_mesh, urdf_home
from .named_file import not_a_file


class UrdfError(ValueError):
    """The URDF cannot be turned into a chain; the message names the element at fault."""


def package_dirs(package: str, near: Path | None = None) -> list[Path]:
    """Where ``package://<package>/`` may point: a folder of that name above ``near`` (a
    ROS workspace), in $ROS_PACKAGE_PATH, under $AMENT_PREFIX_PATH's share/, and under a
    Python environment's ``cmeel.prefix/share`` (how example-robot-data installs)."""
    return [p for p in _package_candidates(package, near) if p.is_dir() and p.name == package]


def _package_candidates(package: str, near: Path | None) -> list[Path]:
    candidates: list[Path] = []
    if near is not None:
        candidates += [p for p in Path(near).resolve().parents if p.name == package]
    for entry in os.environ.get("ROS_PACKAGE_PATH", "").split(os.pathsep):
        if entry:
            candidates += [Path(entry) / package, Path(entry)]
    for entry in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if entry:
            candidates.append(Path(entry) / "share" / package)
    for entry in sys.path:
        if entry:
            candidates.append(Path(entry) / "cmeel.prefix" / "share" / package)
    return candidates


def _package_not_found(package: str, rest: str, near: Path) -> str:
    """Why ``package://<package>/<rest>`` leads nowhere: where :func:`package_dirs` looked,
    and :func:`resolve_uri` after it."""
    ros, ament = (os.environ.get(name, "") for name in ("ROS_PACKAGE_PATH", "AMENT_PREFIX_PATH"))
    cmeel = dict.fromkeys(str(Path(entry) / "cmeel.prefix" / "share") for entry in sys.path
                          if entry and (Path(entry) / "cmeel.prefix" / "share").is_dir())
    return (f"package '{package}' was not found: no folder '{package}' above "
            f"{Path(near).resolve()}, in $ROS_PACKAGE_PATH ({ros or 'not set'}), in share/ "
            f"under $AMENT_PREFIX_PATH ({ament or 'not set'}) or in the Python environment's "
            f"cmeel.prefix/share ({', '.join(cmeel) or 'none on sys.path'}), and there is no "
            f"{Path(near) / rest}; install the package, or add the folder that holds it to "
            "$ROS_PACKAGE_PATH")


class _NotFound(type(Path())):
    """What :func:`resolve_uri` returns for a ``package://`` reference it cannot find: the
    missing path it returned before (the reference's path in the folder given), with
    ``uri`` and ``reason`` for the message that refuses it."""

    uri = ""
    reason = ""


def resolve_uri(uri: str, relative_to: Path) -> Path:
    """The file a URDF reference names: ``package://pkg/rest`` (see :func:`package_dirs`;
    else ``rest`` in ``relative_to``), ``file://path`` or a path relative to the folder
    ``relative_to``. The returned path may not exist (the caller says what was looked for;
    for a ``package://`` reference, :func:`_missing` says why)."""
    return _locate(uri, relative_to)[0]


def _locate(uri: str, relative_to: Path) -> tuple[Path, Path | None]:
    """:func:`resolve_uri`'s path, and the package folder it was found in (None: not
    found in a package)."""
    if uri.startswith("package://"):
        package, _, rest = uri[len("package://"):].partition("/")
        roots = package_dirs(package, near=relative_to)
        for root in roots:
            if (root / rest).exists():
                return root / rest, root
        if (Path(relative_to) / rest).exists():
            return Path(relative_to) / rest, None
        missing = _NotFound(Path(relative_to) / rest)
        missing.uri = uri
        if not package:  # "/" is then the package (a folder above everything named "")
            missing.reason = "the package name is empty (package://NAME/PATH)"
        elif roots:
            missing.reason = (f"no such file in package '{package}' (looked for "
                              f"{' and '.join(str(root / rest) for root in roots)})")
        else:
            missing.reason = _package_not_found(package, rest, relative_to)
        return missing, None
    if uri.startswith("file://"):
        uri = uri[len("file://"):]
    path = Path(uri).expanduser()
    return (path if path.is_absolute() else Path(relative_to) / path), None


def _missing(found: Path) -> str:
    """Why a reference that :func:`resolve_uri` resolved to ``found`` names no file."""
    return getattr(found, "reason", "") or f"no such file (looked for {found})"


def load_robot(path: Path):
    import yourdfpy
    from lxml import etree

    if not path.is_file():
        if isinstance(path, _NotFound) and path.reason:
            raise UrdfError(f"{path.uri}: {path.reason}")
        why = not_a_file(path)
        raise UrdfError(f"{path}: no such URDF file" if why == "does not exist" else
                        f"{path}: {why.replace(', not a file', ', not a URDF file')}")
    # The parser yourdfpy uses, first: yourdfpy would parse what it can of a file that is
    # not XML and fail later without saying where.
    try:
        root = etree.parse(str(path)).getroot()
    except etree.XMLSyntaxError as exc:
        line, column = exc.position
        reason = exc.msg.removesuffix(f", line {line}, column {column}")
        raise UrdfError(f"{path}: not well-formed XML at line {line}, column {column}: "
                        f"{reason}") from None
    except OSError as exc:
        raise UrdfError(f"{path}: cannot be read ({exc})") from None
    if etree.QName(root).localname != "robot":
        raise UrdfError(f"{path}: the XML's root element is <{etree.QName(root).localname}>, "
                        "not <robot>: not a URDF")
    _check_xacro(root, path)
    _check_numbers(root, path)
    # yourdfpy logs what it recovers from; our own checks below say what is wrong instead.
    logging.getLogger("yourdfpy").setLevel(logging.CRITICAL)
    try:
        with np.errstate(all="ignore"):  # an <origin> of inf: refused below, not warned of
            urdf = yourdfpy.URDF.load(str(path), build_scene_graph=False,
                                      build_collision_scene_graph=False, load_meshes=False,
                                      load_collision_meshes=False)
    except Exception as exc:  # lxml or yourdfpy: either way the file is not a URDF we read
        cause = (f"the attribute {exc} is missing" if isinstance(exc, KeyError)
                 else f"{type(exc).__name__}: {exc}")
        raise UrdfError(f"{path}: not a readable URDF ({cause}); a URDF is a <robot name> "
                        "whose every <link> and <joint> has its name, and every joint its "
                        "<parent link> and <child link>") from None
    if urdf.robot is None or not urdf.robot.links:
        raise UrdfError(f"{path}: no <robot> with <link> elements")
    return urdf.robot


XACRO = "http://www.ros.org/wiki/xacro"
# The attributes of URDF elements that hold numbers (each a list of them, space-separated),
# with their unit for messages, and those the URDF format requires of their element.
NUMBERS = {"mass": {"value": "kg"},
           "inertia": {name: "kg m^2" for name in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")},
           "origin": {"xyz": "m", "rpy": "rad"}, "axis": {"xyz": "a unit vector"},
           "limit": {"lower": "rad or m", "upper": "rad or m", "effort": "N m or N",
                     "velocity": "rad/s or m/s"},
           "dynamics": {"damping": "N m s/rad or N s/m", "friction": "N m or N"},
           "mimic": {"multiplier": "a ratio", "offset": "rad or m"},
           "box": {"size": "m"}, "cylinder": {"radius": "m", "length": "m"},
           "sphere": {"radius": "m"}, "mesh": {"scale": "a ratio"}, "color": {"rgba": "0 to 1"}}
REQUIRED = {"mass": ("value",), "inertia": tuple(NUMBERS["inertia"])}
VECTORS = frozenset({"xyz", "rpy", "size", "scale", "rgba"})  # several numbers each
OWNERS = ("link", "joint", "material")  # what a message names an element by


def _check_xacro(root, path: Path) -> None:
    """Refuse a xacro file (its <xacro:…> elements: macros, properties, includes): it is a
    program that makes a URDF, read here as the URDF it is not (a link its macro would make
    "undefined"). The namespace alone is no xacro: URDFs xacro made keep declaring it."""
    element = next((e for e in root.iter() if isinstance(e.tag, str)
                    and e.tag.startswith(f"{{{XACRO}}}")), None)
    if element is None:
        return
    what = f"<xacro:{element.tag.split('}')[1]}> at line {element.sourceline}"
    raise UrdfError(f"{path}: a xacro file ({what}), not a URDF: expand it first (ROS's "
                    f"xacro: xacro {path.name} > {path.name.split('.')[0]}.urdf) and give the "
                    "URDF it makes")


def _owner(element) -> str:
    """The link, joint or material an element belongs to, and the elements down to it:
    "link 'l1' <inertial><mass"."""
    tags, node = [], element
    while node is not None and node.tag not in OWNERS:
        tags.append(node.tag)
        node = node.getparent()
    inside = "".join(f"<{tag}>" for tag in reversed(tags[1:])) + f"<{tags[0]}"
    if node is None:
        return inside
    return f"{node.tag} '{node.get('name')}' {inside}"


def _check_numbers(root, path: Path) -> None:
    """Every attribute that holds numbers holds them, and a <mass> or <inertia> has its
    attributes: one message naming the element (yourdfpy's "could not convert string to
    float" named none; a <mass/> without a value was read as 0)."""
    for element in root.iter(*NUMBERS):
        where = f"{path}: {_owner(element)}"
        for name in REQUIRED.get(element.tag, ()):
            if element.get(name) is None:
                raise UrdfError(f"{where}>: no {name}='…': give "
                                + ("the link's mass in kg, e.g. <mass value='1.5'/>"
                                   if element.tag == "mass" else
                                   "all of ixx, ixy, ixz, iyy, iyz and izz (kg m^2)"))
        for name, unit in NUMBERS[element.tag].items():
            text = element.get(name)
            if text is None:
                continue
            try:
                for token in text.split() if name in VECTORS else [text]:
                    float(token)
            except ValueError:
                what = ("a xacro expression, not a number: expand the xacro first (ROS's "
                        "xacro makes the URDF)" if "$" in text else
                        f"not {'numbers' if name in VECTORS else 'a number'} ({unit})")
                raise UrdfError(f"{where} {name}='{text}'>: {what}") from None


def check_meshes(path: Path) -> None:
    """Refuse (:class:`UrdfError`) a URDF one of whose meshes the 3-D view must not read
    (:mod:`plant_fmu.meshes`): outside its package or folder, or not a mesh."""
    checked_meshes(load_robot(path), path)


def mesh_files(path: Path) -> list[Path]:
    """The mesh files a URDF names, each checked as :func:`check_meshes` checks it."""
    return checked_meshes(load_robot(path), path)


def checked_meshes(robot, path: Path) -> list[Path]:
    home = urdf_home(path)
    found_all = []
    for link in robot.links:
        for element, items in (("visual", link.visuals), ("collision", link.collisions)):
            for item in items:
                mesh = item.geometry.mesh if item.geometry is not None else None
                if mesh is None:
                    continue
                found, package = _locate(mesh.filename, path.parent)
                try:
                    if isinstance(found, _NotFound):
                        raise MeshRefused(_missing(found))
                    check_mesh(found, package or home)
                except MeshRefused as exc:
                    raise UrdfError(
                        f"{path}: link '{link.name}' <{element}><mesh filename="
                        f"'{mesh.filename}'>: {exc}. The FMU ignores meshes for its dynamics, "
                        "but the 3-D view draws them: fix the path, or remove the "
                        "<mesh>") from None
                found_all.append(found)
    return found_all
