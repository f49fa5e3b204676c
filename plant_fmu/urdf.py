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

Finding the file and the files it names, and the checks its XML passes before it is read,
are :mod:`plant_fmu.urdf_files`; reading and checking each joint and link,
:mod:`plant_fmu.urdf_elements`.

A URDF the plant cannot honestly simulate is refused with :class:`UrdfError`, one message
naming the element at fault. Units are the URDF's: SI, radians.
"""

from __future__ import annotations

import os
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .urdf_elements import (
    check_inertial,
    check_joint,
    joint_limits,
    joint_motion,
    origin,
    unit_axis,
)
from .urdf_files import (
    UrdfError,
    check_meshes,
    checked_meshes,
    load_robot,
    mesh_files,
    package_dirs,
    resolve_uri,
)

# the reader's public names, those of finding the files among them (plant_fmu.urdf_files)
__all__ = ["Chain", "UrdfError", "check_meshes", "mesh_files", "package_dirs", "read_urdf",
           "resolve_uri"]

GRAVITY = np.array([0.0, 0.0, -9.81])  # m/s^2 along the base's -z
REVOLUTE, PRISMATIC = 0, 1  # Chain.kind


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


def _check_held(fixed: dict[str, float], subtree: list, base: str, held_by: str,
                path: Path) -> None:
    """Each held joint a moving joint below the base, held at a finite value within its
    limits (rad or m)."""
    by_name = {joint.name: joint for joint in subtree}
    for name, value in fixed.items():
        if name not in by_name or by_name[name].type == "fixed":
            raise UrdfError(f"{path}: {_held(held_by, name)}: not a moving joint below base link "
                            f"'{base}'; moving joints: "
                            f"{[j.name for j in subtree if j.type != 'fixed']}")
        if not np.isfinite(value):
            raise UrdfError(f"{path}: {_held(held_by, name, value)}: the value is not a finite "
                            "number; give the angle in rad (m for a prismatic joint)")
        lower, upper, _, _ = joint_limits(by_name[name])
        if not lower <= value <= upper:
            raise UrdfError(f"{path}: {_held(held_by, name, value)}: outside the joint's limits "
                            f"[{lower}, {upper}] (rad or m)")


def _bodies(subtree: list, base: str, on_path: set[str], fixed: dict[str, float],
            held_by: str, path: Path) -> tuple[list, list, dict, dict, dict]:
    """The subtree walked from the base: the moving joints with their parent body, their
    placements, the joints held (at ``fixed``'s value, else 0 or its nearest limit), and
    each link's body (-1 the base) and frame in that body's frame."""
    body_of, frame_in_body = {base: -1}, {base: np.eye(4)}
    moving, placements, held = [], [], {}
    for joint in subtree:
        body, frame = body_of[joint.parent], frame_in_body[joint.parent] @ origin(joint)
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
            lower, upper, _, _ = joint_limits(joint)
            held[joint.name] = fixed.get(joint.name, float(np.clip(0.0, lower, upper)))
        body_of[joint.child] = body
        frame_in_body[joint.child] = frame @ joint_motion(joint, held.get(joint.name, 0.0), path)
    return moving, placements, held, body_of, frame_in_body


def _lumped_bodies(robot, moving: list, body_of: dict, frame_in_body: dict,
                   path: Path) -> list[tuple[float, np.ndarray, np.ndarray]]:
    """Each moving body's mass, centre of mass and inertia, its links' lumped (each link's
    <inertial> checked)."""
    carried_by = {j.child: j.name for j, _ in moving}
    links_by_name = {link.name: link for link in robot.links}
    parts: list[list] = [[] for _ in moving]
    for link_name, body in body_of.items():
        link = links_by_name[link_name]
        check_inertial(link, carried_by.get(link_name), path)
        if body < 0 or link.inertial is None or not link.inertial.mass:
            continue
        to_body = frame_in_body[link_name] @ origin(link.inertial)
        rotation = to_body[:3, :3]
        parts[body].append((float(link.inertial.mass), to_body[:3, 3],
                            rotation @ np.asarray(link.inertial.inertia, float) @ rotation.T))
    return [_lumped(p) for p in parts]


def read_urdf(path: str | os.PathLike, base: str | None = None, tip: str | None = None,
              fixed: dict[str, float] | None = None, held_by: str = "--fix") -> Chain:
    """The chain of ``path`` from link ``base`` (default: the root link) to link ``tip``
    (default: from the base, the one way on to a moving joint, stopping where the arm forks;
    see ``_path``), with the joints in ``fixed`` held at their value (rad or m); ``held_by``
    names how the caller holds them, for messages (an option, or a pipeline key). Raises
    :class:`UrdfError`."""
    path = path if isinstance(path, Path) else Path(path)  # resolve_uri's _NotFound kept
    robot = load_robot(path)
    fixed = dict(fixed or {})
    parent_joint, child_joints = _tree(robot, path)
    if base is None:
        base = _root(robot, parent_joint, path)
    elif base not in child_joints:
        raise UrdfError(f"{path}: base link '{base}' is not a <link> of the URDF; links: "
                        f"{sorted(child_joints)}")
    subtree = _subtree(base, child_joints)
    for joint in subtree:
        check_joint(joint, path)
    checked_meshes(robot, path)
    _check_held(fixed, subtree, base, held_by, path)
    chain_path = _path(base, tip, parent_joint, child_joints, path)
    tip_link = chain_path[-1].child if chain_path else base
    moving, placements, held, body_of, frame_in_body = _bodies(
        subtree, base, {joint.name for joint in chain_path}, fixed, held_by, path)
    if not moving:
        raise UrdfError(f"{path}: no revolute, continuous or prismatic joint moves between "
                        f"base link '{base}' and tip link '{tip_link}'")
    lumped = _lumped_bodies(robot, moving, body_of, frame_in_body, path)
    limits = np.array([joint_limits(j) for j, _ in moving]).reshape(-1, 4)

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
        axis=np.array([unit_axis(j, path) for j, _ in moving]),
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
