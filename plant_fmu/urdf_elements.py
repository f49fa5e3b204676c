"""A URDF's elements as the reader needs them (:mod:`plant_fmu.urdf`): a joint's limits, axis,
origin and motion, read from yourdfpy's objects, and the checks each joint and link passes
before the chain is built, each refusal one :class:`UrdfError` naming the element at fault.
Units are the URDF's: SI, radians."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from .urdf_files import UrdfError

MOVING_TYPES = ("revolute", "continuous", "prismatic")
SUPPORTED_TYPES = (*MOVING_TYPES, "fixed")
# A moving joint's numbers: element, attribute, what it is, units (revolute, prismatic).
JOINT_NUMBERS = (("limit", "lower", "lower limit", ("rad", "m")),
                 ("limit", "upper", "upper limit", ("rad", "m")),
                 ("limit", "velocity", "velocity limit", ("rad/s", "m/s")),
                 ("limit", "effort", "effort limit", ("N m", "N")),
                 ("dynamics", "damping", "damping", ("N m s/rad", "N s/m")),
                 ("dynamics", "friction", "friction", ("N m", "N")))


def joint_limits(joint) -> tuple[float, float, float, float]:
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


def joint_motion(joint, value: float, path: Path) -> np.ndarray:
    """The joint's motion at ``value`` (rad or m) as a 4x4 transform."""
    transform = np.eye(4)
    if joint.type == "fixed" or value == 0.0:
        return transform
    axis = unit_axis(joint, path)
    if joint.type == "prismatic":
        transform[:3, 3] = axis * value
    else:
        k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        transform[:3, :3] = np.eye(3) + np.sin(value) * k + (1 - np.cos(value)) * k @ k
    return transform


def unit_axis(joint, path: Path) -> np.ndarray:
    axis = np.array([1.0, 0.0, 0.0]) if joint.axis is None else np.asarray(joint.axis, float)
    norm = np.linalg.norm(axis)
    if axis.shape != (3,) or not np.isfinite(norm) or norm == 0.0:
        raise UrdfError(f"{path}: joint '{joint.name}' <axis xyz='"
                        f"{' '.join(f'{x:g}' for x in axis.ravel())}'>: the axis must be a "
                        "non-zero vector of three finite numbers")
    return axis / norm


def origin(element) -> np.ndarray:
    return np.eye(4) if element.origin is None else np.asarray(element.origin, float)


def check_origin(element, name: str, path: Path) -> None:
    """``element``'s <origin> (a 4x4 transform once yourdfpy has read it), ``name`` in the
    message, is finite."""
    if not np.all(np.isfinite(origin(element))):
        raise UrdfError(f"{path}: {name}: its xyz (m) and rpy (rad) must be finite numbers")


def check_joint(joint, path: Path) -> None:
    """A joint below the base: a type the plant supports, a finite <origin>; if it moves,
    a finite non-zero <axis>, finite <limit>s with lower <= upper (a continuous joint's
    position limits are ignored), velocity, effort, damping and friction >= 0.

    lower == upper is accepted: held (off the chain, or by --fix), the joint is held there;
    on the chain it is q0's one valid value (the plant bounds q0 alone), and URDFs write
    0 and 0 for no limits (the spec's default; example-robot-data's double pendulum)."""
    if joint.type not in SUPPORTED_TYPES:
        raise UrdfError(f"{path}: joint '{joint.name}' has type '{joint.type}': the plant "
                        f"supports {', '.join(SUPPORTED_TYPES)} joints")
    check_origin(joint, f"joint '{joint.name}' <origin>", path)
    if joint.type == "fixed":
        return
    unit_axis(joint, path)
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
    lower, upper, _, _ = joint_limits(joint)
    if lower > upper:
        raise UrdfError(f"{path}: joint '{joint.name}' <limit lower='{lower:g}' upper="
                        f"'{upper:g}'>: lower must be <= upper ({('rad', 'm')[unit]}); no "
                        "position lies within these limits")


def check_inertial(link, carried_by, path: Path) -> None:
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
    check_origin(inertial, f"link '{link.name}' <inertial><origin>", path)
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
        warn_once(f"{path}: link '{link.name}' <inertial><inertia>: its principal moments "
                   f"{', '.join(f'{m:.6g}' for m in moments)} kg m^2 break the triangle "
                   "inequality (the two smaller sum to less than the largest): no rigid body "
                   "has this inertia; simulated as given")


# The masses (kg) and inertias (kg m^2, their largest entry) a link may have: far beyond any
# robot's links either way (example-robot-data's lightest frame is 1e-9 kg), yet far from
# where the dynamics' products leave double precision (a mass of 1e300 or 1e-300 kg).
LIGHTEST, HEAVIEST = 1e-12, 1e12
_warned: set[str] = set()


def warn_once(text: str) -> None:
    """A warning on stderr, once per process (the URDF is read by the build, the nominal
    model, the limits and the 3-D view alike)."""
    if text not in _warned:
        _warned.add(text)
        print(f"cosim: warning: {text}", file=sys.stderr)
