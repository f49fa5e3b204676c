"""Read a URDF into the table of a spatial rigid-body chain (:class:`Chain`), the one input
of the spatial-chain FMU (``plant_fmu/models/spatial_chain``) and of the blocks that model it.

The XML is parsed by yourdfpy (without meshes); this module only turns its links and joints
into the chain from a base link to a tip link:

* every revolute, continuous or prismatic joint on the path from base to tip moves, unless
  ``fixed`` holds it at a value;
* fixed joints, held joints and every joint off that path (a gripper's fingers, say: held at
  0, or at the nearest limit if 0 is outside them) are folded into the body they hang from:
  their links' masses, centres of mass and inertias are lumped into it;
* meshes are not needed for the dynamics and are ignored by the FMU; they must exist all the
  same, since the 3-D view draws them (:func:`resolve_uri` finds them), and be meshes inside
  the URDF's package or folder, since the recording copies them (:mod:`plant_fmu.meshes`).

A URDF the plant cannot honestly simulate is refused with :class:`UrdfError`, one message
naming the element at fault. Units are the URDF's: SI, radians.
"""

from __future__ import annotations

import logging
import os
import sys
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .meshes import MeshRefused, check_mesh, urdf_home
from .named_file import not_a_file

GRAVITY = np.array([0.0, 0.0, -9.81])  # m/s^2 along the base's -z
MOVING_TYPES = ("revolute", "continuous", "prismatic")
SUPPORTED_TYPES = (*MOVING_TYPES, "fixed")
REVOLUTE, PRISMATIC = 0, 1  # Chain.kind
# A moving joint's numbers: element, attribute, what it is, units (revolute, prismatic).
JOINT_NUMBERS = (("limit", "lower", "lower limit", ("rad", "m")),
                 ("limit", "upper", "upper limit", ("rad", "m")),
                 ("limit", "velocity", "velocity limit", ("rad/s", "m/s")),
                 ("limit", "effort", "effort limit", ("N m", "N")),
                 ("dynamics", "damping", "damping", ("N m s/rad", "N s/m")),
                 ("dynamics", "friction", "friction", ("N m", "N")))


class UrdfError(ValueError):
    """The URDF cannot be turned into a chain; the message names the element at fault."""


@dataclass(frozen=True, eq=False)
class Chain:
    """A chain of moving joints from a base link to a tip link, fixed joints folded in.

    Body ``i`` is the child link of moving joint ``i``; its frame is that joint's frame
    (URDF puts the child link's frame at the joint). ``n`` arrays are indexed by joint.
    """

    name: str  # the robot's name from <robot name=...>
    joints: tuple[str, ...]  # moving joints' URDF names, parents before children
    links: tuple[str, ...]  # the child link of each moving joint
    kind: np.ndarray  # (n,) int: 0 revolute (incl. continuous), 1 prismatic
    continuous: np.ndarray  # (n,) bool: a continuous joint (no position limits)
    parent: np.ndarray  # (n,) int: the parent moving joint's body, -1 the base
    placement: np.ndarray  # (n,4,4): parent body frame -> this joint's frame at q = 0
    axis: np.ndarray  # (n,3): unit axis in the joint frame
    mass: np.ndarray  # (n,) kg, each body with its folded links
    com: np.ndarray  # (n,3) m, centre of mass in the body frame
    inertia: np.ndarray  # (n,3,3) kg m^2 about the centre of mass, body-frame axes
    damping: np.ndarray  # (n,) N m s/rad or N s/m, <dynamics damping>
    friction: np.ndarray  # (n,) N m or N, Coulomb, <dynamics friction>
    lower: np.ndarray  # (n,) rad or m (-inf for continuous or none given)
    upper: np.ndarray  # (n,) rad or m (+inf for continuous or none given)
    velocity: np.ndarray  # (n,) rad/s or m/s, <limit velocity> (inf if none or 0)
    effort: np.ndarray  # (n,) N m or N, <limit effort> (inf if none or 0)
    tip: np.ndarray  # (4,4): the tip link's frame in the last body's frame
    gravity: np.ndarray = field(default_factory=lambda: GRAVITY.copy())  # (3,) base frame
    base_link: str = ""  # the link the chain is fixed to
    tip_link: str = ""  # the link whose frame is ``tip``
    held: tuple[tuple[str, float], ...] = ()  # joints folded at a value (rad or m), sorted

    @property
    def n(self) -> int:
        """The number of moving joints."""
        return len(self.joints)


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


def _load(path: Path):
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
    _check_meshes(_load(path), path)


def mesh_files(path: Path) -> list[Path]:
    """The mesh files a URDF names, each checked as :func:`check_meshes` checks it."""
    return _check_meshes(_load(path), path)


def _check_meshes(robot, path: Path) -> list[Path]:
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


def _tree(robot, path: Path) -> tuple[dict, dict]:
    """parent_joint[link] and child_joints[link] (in file order), checked to be a tree."""
    for kind, elements in (("link", robot.links), ("joint", robot.joints)):
        for name, count in Counter(element.name for element in elements).items():
            if count > 1:
                raise UrdfError(f"{path}: {kind} '{name}' is defined "
                                f"{'twice' if count == 2 else f'{count} times'}: each "
                                f"<{kind}> needs a name of its own")
    links = {link.name for link in robot.links}
    parent_joint: dict = {}
    child_joints: dict = {name: [] for name in links}
    for joint in robot.joints:
        for role in ("parent", "child"):
            if getattr(joint, role) not in links:
                raise UrdfError(f"{path}: joint '{joint.name}' names {role} link "
                                f"'{getattr(joint, role)}', which no <link> defines")
        if joint.child in parent_joint:
            raise UrdfError(
                f"{path}: link '{joint.child}' is the child of joints "
                f"'{parent_joint[joint.child].name}' and '{joint.name}': a loop; a URDF "
                "is a tree (each link has at most one parent joint)")
        parent_joint[joint.child] = joint
        child_joints[joint.parent].append(joint)
    if len(parent_joint) == len(links):
        raise UrdfError(f"{path}: every link has a parent joint, so the joints form a loop; "
                        "a URDF is a tree with one root link")
    return parent_joint, child_joints


def _root(robot, parent_joint: dict, path: Path) -> str:
    roots = [link.name for link in robot.links if link.name not in parent_joint]
    if len(roots) > 1:
        raise UrdfError(f"{path}: links {roots} have no parent joint: a URDF has one root "
                        "link (or give --base)")
    return roots[0]


def _path(base: str, tip: str | None, parent_joint: dict, child_joints: dict,
          path: Path) -> list:
    """The joints from base to tip. Without a tip: from the base, follow the one child joint
    that moves or leads to a moving joint; past the last moving joint, follow fixed joints
    while a link has just one; stop where the way forks."""
    if tip is None:
        # the joints that move or lead to one, children before parents (not recursive: a
        # URDF may hang thousands of fixed links one below the other)
        leading: set[str] = set()
        for joint in reversed(_subtree(base, child_joints)):
            if joint.type != "fixed" or any(j.name in leading for j in child_joints[joint.child]):
                leading.add(joint.name)
        joints, link = [], base
        while True:
            ahead = [j for j in child_joints[link] if j.name in leading]
            if len(ahead) > 1 or (not ahead and len(child_joints[link]) != 1):
                return joints
            joints.append(ahead[0] if ahead else child_joints[link][0])
            link = joints[-1].child
    if tip not in child_joints:
        raise UrdfError(f"{path}: tip link '{tip}' is not a <link> of the URDF; links: "
                        f"{sorted(child_joints)}")
    joints, link = [], tip
    while link != base:
        if link not in parent_joint:
            raise UrdfError(f"{path}: tip link '{tip}' is not below base link '{base}'")
        joints.append(parent_joint[link])
        link = parent_joint[link].parent
    return joints[::-1]


def _subtree(base: str, child_joints: dict) -> list:
    """Every joint below ``base``, parents before children."""
    order, stack = [], list(reversed(child_joints[base]))
    while stack:
        joint = stack.pop()
        order.append(joint)
        stack.extend(reversed(child_joints[joint.child]))
    return order


def _limits(joint) -> tuple[float, float, float, float]:
    """lower, upper, velocity, effort; a missing or zero velocity or effort limit is none
    given (some URDFs write 0 for it): inf."""
    limit = joint.limit
    lower = -np.inf if limit is None or limit.lower is None else float(limit.lower)
    upper = np.inf if limit is None or limit.upper is None else float(limit.upper)
    if joint.type == "continuous":
        lower, upper = -np.inf, np.inf
    velocity = float(limit.velocity) if limit is not None and limit.velocity else np.inf
    effort = float(limit.effort) if limit is not None and limit.effort else np.inf
    return lower, upper, velocity, effort


def _motion(joint, value: float, path: Path) -> np.ndarray:
    """The joint's motion at ``value`` (rad or m) as a 4x4 transform."""
    transform = np.eye(4)
    if joint.type == "fixed" or value == 0.0:
        return transform
    axis = _unit_axis(joint, path)
    if joint.type == "prismatic":
        transform[:3, 3] = axis * value
    else:
        k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        transform[:3, :3] = np.eye(3) + np.sin(value) * k + (1 - np.cos(value)) * k @ k
    return transform


def _unit_axis(joint, path: Path) -> np.ndarray:
    axis = np.array([1.0, 0.0, 0.0]) if joint.axis is None else np.asarray(joint.axis, float)
    norm = np.linalg.norm(axis)
    if axis.shape != (3,) or not np.isfinite(norm) or norm == 0.0:
        raise UrdfError(f"{path}: joint '{joint.name}' <axis xyz='"
                        f"{' '.join(f'{x:g}' for x in axis.ravel())}'>: the axis must be a "
                        "non-zero vector of three finite numbers")
    return axis / norm


def _origin(element) -> np.ndarray:
    return np.eye(4) if element.origin is None else np.asarray(element.origin, float)


def _check_origin(element, name: str, path: Path) -> None:
    """``element``'s <origin> (a 4x4 transform once yourdfpy has read it), ``name`` in the
    message, is finite."""
    if not np.all(np.isfinite(_origin(element))):
        raise UrdfError(f"{path}: {name}: its xyz (m) and rpy (rad) must be finite numbers")


def _check_joint(joint, path: Path) -> None:
    """A joint below the base: a type the plant supports, a finite <origin>; if it moves,
    a finite non-zero <axis>, finite <limit>s with lower <= upper (a continuous joint's
    position limits are ignored), velocity, effort, damping and friction >= 0.

    lower == upper is accepted: held (off the chain, or by --fix), the joint is held there;
    on the chain it is q0's one valid value (the plant bounds q0 alone), and URDFs write
    0 and 0 for no limits (the spec's default; example-robot-data's double pendulum)."""
    if joint.type not in SUPPORTED_TYPES:
        raise UrdfError(f"{path}: joint '{joint.name}' has type '{joint.type}': the plant "
                        f"supports {', '.join(SUPPORTED_TYPES)} joints")
    _check_origin(joint, f"joint '{joint.name}' <origin>", path)
    if joint.type == "fixed":
        return
    _unit_axis(joint, path)
    unit = int(joint.type == "prismatic")
    for element, attribute, what, units in JOINT_NUMBERS:
        value = getattr(getattr(joint, element), attribute, None)
        if value is None or (element == "limit" and attribute in ("lower", "upper") and
                             joint.type == "continuous"):
            continue
        bound = "" if attribute in ("lower", "upper") else " >= 0"
        if not np.isfinite(float(value)) or (bound and float(value) < 0):
            raise UrdfError(f"{path}: joint '{joint.name}' <{element} {attribute}="
                            f"'{float(value):g}'>: the {what} must be a finite number{bound} "
                            f"({units[unit]})")
    lower, upper, _, _ = _limits(joint)
    if lower > upper:
        raise UrdfError(f"{path}: joint '{joint.name}' <limit lower='{lower:g}' upper="
                        f"'{upper:g}'>: lower must be <= upper ({('rad', 'm')[unit]}); no "
                        "position lies within these limits")


def _check_inertial(link, carried_by, path: Path) -> None:
    """A link's <inertial>: required, with a finite positive mass, a finite <origin> and a
    finite positive semi-definite inertia, where a moving joint carries the link
    (``carried_by``); elsewhere (massless frames such as a flange) it may be absent or
    massless, but never negative."""
    inertial = link.inertial
    if inertial is None or inertial.mass is None:
        if carried_by is not None:
            raise UrdfError(f"{path}: link '{link.name}' has no <inertial> (with <mass>), but "
                            f"moving joint '{carried_by}' carries it: give its mass, centre "
                            "of mass and inertia")
        return
    mass = float(inertial.mass)
    if not np.isfinite(mass) or mass < 0 or (carried_by is not None and mass == 0):
        raise UrdfError(f"{path}: link '{link.name}' <inertial><mass value='{mass:g}'>: a "
                        "mass must be a finite " +
                        ("positive number" if carried_by is not None else "number >= 0") +
                        " (kg)" +
                        (f": moving joint '{carried_by}' carries it" if mass == 0 else ""))
    if mass and not LIGHTEST <= mass <= HEAVIEST:
        raise UrdfError(f"{path}: link '{link.name}' <inertial><mass value='{mass:g}'>: "
                        f"outside {LIGHTEST:g} to {HEAVIEST:g} kg, the masses the plant "
                        "simulates (double precision makes nothing of the dynamics beyond "
                        "them); a massless frame has mass 0")
    _check_origin(inertial, f"link '{link.name}' <inertial><origin>", path)
    if inertial.inertia is None:
        if not mass:
            return
        raise UrdfError(f"{path}: link '{link.name}' <inertial> has no <inertia>: give ixx, "
                        "ixy, ixz, iyy, iyz and izz (kg m^2) about its centre of mass")
    inertia = np.asarray(inertial.inertia, float)
    if not np.all(np.isfinite(inertia)):
        raise UrdfError(f"{path}: link '{link.name}' <inertial><inertia>: ixx, ixy, ixz, "
                        "iyy, iyz and izz must be finite numbers (kg m^2)")
    if np.abs(inertia).max() > HEAVIEST:
        raise UrdfError(f"{path}: link '{link.name}' <inertial><inertia>: ixx, ixy, ixz, "
                        f"iyy, iyz and izz must be at most {HEAVIEST:g} kg m^2, what the plant "
                        "simulates")
    moments = np.linalg.eigvalsh(inertia)
    if moments.min() < -1e-12 * max(1.0, np.abs(inertia).max()):
        raise UrdfError(f"{path}: link '{link.name}' <inertial><inertia>: the inertia tensor "
                        "(kg m^2) must be symmetric positive semi-definite")
    if carried_by is not None and moments[0] + moments[1] < moments[2] * (1 - 1e-6):
        _warn_once(f"{path}: link '{link.name}' <inertial><inertia>: its principal moments "
                   f"{', '.join(f'{m:.6g}' for m in moments)} kg m^2 break the triangle "
                   "inequality (the two smaller sum to less than the largest): no rigid body "
                   "has this inertia; simulated as given")


# The masses (kg) and inertias (kg m^2, their largest entry) a link may have: far beyond any
# robot's links either way (example-robot-data's lightest frame is 1e-9 kg), yet far from
# where the dynamics' products leave double precision (a mass of 1e300 or 1e-300 kg).
LIGHTEST, HEAVIEST = 1e-12, 1e12
_warned: set[str] = set()


def _warn_once(text: str) -> None:
    """A warning on stderr, once per process (the URDF is read by the build, the nominal
    model, the limits and the 3-D view alike)."""
    if text not in _warned:
        _warned.add(text)
        print(f"cosim: warning: {text}", file=sys.stderr)


def _lumped(parts: list[tuple[float, np.ndarray, np.ndarray]]):
    """Mass, centre of mass and inertia about it of rigidly joined parts, each given as
    (mass, centre of mass, inertia about its centre of mass) in one frame."""
    mass = sum(m for m, _, _ in parts)
    if mass == 0.0:
        return 0.0, np.zeros(3), np.zeros((3, 3))
    com = sum(m * c for m, c, _ in parts) / mass
    inertia = np.zeros((3, 3))
    for m, c, i in parts:
        d = c - com
        inertia += i + m * (d @ d * np.eye(3) - np.outer(d, d))  # parallel axis
    return mass, com, inertia


def _held(held_by: str, name: str, value: float | str | None = None) -> str:
    """A held joint as the caller's option or key gives it: ``--fix NAME=VALUE`` on the
    command line, ``inertia_model.fixed.NAME = VALUE`` in a pipeline."""
    if held_by.startswith("--"):
        return f"{held_by} {name}" + ("" if value is None else f"={value}")
    return f"{held_by}.{name}" + ("" if value is None else f" = {value}")


def read_urdf(path: str | os.PathLike, base: str | None = None, tip: str | None = None,
              fixed: dict[str, float] | None = None, held_by: str = "--fix") -> Chain:
    """The chain of ``path`` from link ``base`` (default: the root link) to link ``tip``
    (default: from the base, the one way on to a moving joint, stopping where the arm forks;
    see ``_path``), with the joints in ``fixed`` held at their value (rad or m); ``held_by``
    names how the caller holds them, for messages (an option, or a pipeline key). Raises
    :class:`UrdfError`."""
    path = path if isinstance(path, Path) else Path(path)  # resolve_uri's _NotFound kept
    robot = _load(path)
    fixed = dict(fixed or {})
    parent_joint, child_joints = _tree(robot, path)
    if base is None:
        base = _root(robot, parent_joint, path)
    elif base not in child_joints:
        raise UrdfError(f"{path}: base link '{base}' is not a <link> of the URDF; links: "
                        f"{sorted(child_joints)}")
    subtree = _subtree(base, child_joints)
    for joint in subtree:
        _check_joint(joint, path)
    _check_meshes(robot, path)
    by_name = {joint.name: joint for joint in subtree}
    for name, value in fixed.items():
        if name not in by_name or by_name[name].type == "fixed":
            raise UrdfError(f"{path}: {_held(held_by, name)}: not a moving joint below base link "
                            f"'{base}'; moving joints: "
                            f"{[j.name for j in subtree if j.type != 'fixed']}")
        if not np.isfinite(value):
            raise UrdfError(f"{path}: {_held(held_by, name, value)}: the value is not a finite "
                            "number; give the angle in rad (m for a prismatic joint)")
        lower, upper, _, _ = _limits(by_name[name])
        if not lower <= value <= upper:
            raise UrdfError(f"{path}: {_held(held_by, name, value)}: outside the joint's limits "
                            f"[{lower}, {upper}] (rad or m)")
    chain_path = _path(base, tip, parent_joint, child_joints, path)
    on_path = {joint.name for joint in chain_path}
    tip_link = chain_path[-1].child if chain_path else base

    # Walk the subtree: each link's body (-1 the base) and its frame in that body's frame.
    body_of, frame_in_body = {base: -1}, {base: np.eye(4)}
    moving, placements, held = [], [], {}
    for joint in subtree:
        body, frame = body_of[joint.parent], frame_in_body[joint.parent] @ _origin(joint)
        if joint.type != "fixed" and joint.name in on_path and joint.name not in fixed:
            if joint.mimic is not None:
                raise UrdfError(f"{path}: joint '{joint.name}' mimics '{joint.mimic.joint}': "
                                "a mimic joint on the chain is not supported; hold it with "
                                f"{_held(held_by, joint.name, 'VALUE')}")
            moving.append((joint, body))
            placements.append(frame)
            body_of[joint.child], frame_in_body[joint.child] = len(moving) - 1, np.eye(4)
            continue
        if joint.type != "fixed":
            lower, upper, _, _ = _limits(joint)
            held[joint.name] = fixed.get(joint.name, float(np.clip(0.0, lower, upper)))
        body_of[joint.child] = body
        frame_in_body[joint.child] = frame @ _motion(joint, held.get(joint.name, 0.0), path)
    if not moving:
        raise UrdfError(f"{path}: no revolute, continuous or prismatic joint moves between "
                        f"base link '{base}' and tip link '{tip_link}'")

    carried_by = {j.child: j.name for j, _ in moving}
    links_by_name = {link.name: link for link in robot.links}
    parts: list[list] = [[] for _ in moving]
    for link_name, body in body_of.items():
        link = links_by_name[link_name]
        _check_inertial(link, carried_by.get(link_name), path)
        if body < 0 or link.inertial is None or not link.inertial.mass:
            continue
        to_body = frame_in_body[link_name] @ _origin(link.inertial)
        rotation = to_body[:3, :3]
        parts[body].append((float(link.inertial.mass), to_body[:3, 3],
                            rotation @ np.asarray(link.inertial.inertia, float) @ rotation.T))
    lumped = [_lumped(p) for p in parts]
    limits = np.array([_limits(j) for j, _ in moving]).reshape(-1, 4)

    def dynamics(attribute: str) -> np.ndarray:
        values = [getattr(j.dynamics, attribute, None) if j.dynamics else None for j, _ in moving]
        return np.array([float(v) if v is not None else 0.0 for v in values])

    return Chain(
        name=robot.name or path.stem,
        joints=tuple(j.name for j, _ in moving),
        links=tuple(j.child for j, _ in moving),
        kind=np.array([PRISMATIC if j.type == "prismatic" else REVOLUTE for j, _ in moving]),
        continuous=np.array([j.type == "continuous" for j, _ in moving]),
        parent=np.array([body for _, body in moving]),
        placement=np.array(placements),
        axis=np.array([_unit_axis(j, path) for j, _ in moving]),
        mass=np.array([m for m, _, _ in lumped]),
        com=np.array([c for _, c, _ in lumped]),
        inertia=np.array([i for _, _, i in lumped]),
        damping=dynamics("damping"),
        friction=dynamics("friction"),
        lower=limits[:, 0], upper=limits[:, 1], velocity=limits[:, 2], effort=limits[:, 3],
        tip=frame_in_body[tip_link],
        base_link=base,
        tip_link=tip_link,
        held=tuple(sorted(held.items())),
    )
