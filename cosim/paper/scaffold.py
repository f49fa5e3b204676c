"""`cosim new`: a pipeline for a robot from its URDF that runs as it is written.

From the URDF's chain (plant_fmu.urdf.read_urdf) it chooses what a user would otherwise
copy from another robot's pipeline and edit in a dozen places:

- the robot named once (``[robot]``: the plant, the nominal model and the safe sets);
- a start pose well inside every limit and a default motion around it: each joint out and
  back by a fraction of its range, in minimum-jerk segments whose peak speed stays within
  half its velocity limit;
- gains in accelerations, scaled by the nominal model's inertia (``scale = "inertia"``), so
  that the same numbers serve any arm at 1 kHz (cosim.paper.sampled_loop checks the step);
- the paper's observer and NN controller, the safety filter on the robot's own limits, and a
  PD + gravity baseline;
- the URDF's friction in the plant and in the nominal model alike, a payload range at the
  tip (a tenth of the arm's mass, the plant carrying half of it).

Continuous joints get a position set of ±π about their start (the safe sets need finite
ones) and a joint without a velocity limit one of 2 rad/s, both said in the file.
SI units, radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

# The default motion: each joint out by AMPLITUDE of its half-range (at most MAX_SWING rad),
# back through the start to the other side, and home, one segment of SEGMENT s each.
AMPLITUDE = 0.2
MAX_SWING = 0.4  # rad
SEGMENT = 2.0  # s
MIN_JERK_PEAK = 1.875  # a minimum-jerk segment's peak speed over its mean speed
CONTINUOUS_HALF_RANGE = math.pi  # rad: a continuous joint's position set about its start
DEFAULT_VELOCITY_LIMIT = 2.0  # rad/s, for a joint whose URDF gives none
POSITION_MARGIN = 0.05  # rad kept inside each position limit
PAYLOAD_SHARE = 0.1  # the declared payload range's top, as a share of the arm's mass
STEP = 1e-3  # s, the master step the pipeline is written for
DESCRIPTION = ("a default motion about its start, the paper's observer and NN controller, "
               "the filter on its own limits, PD baseline")


@dataclass(frozen=True)
class Plan:
    """What :func:`plan` chose for a chain: per joint the start (rad), the position set
    (rad, before the margin), its velocity limit (rad/s), the swing of the default motion
    (rad) and whether its URDF friction is kept; the payload range's top (kg)."""

    start: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    velocity: np.ndarray
    swing: np.ndarray
    payload: float
    friction: np.ndarray


FRICTION_CHOICES = ("auto", "keep", "none")


def plan(chain, friction: str = "auto", step: float = STEP) -> Plan:
    """The start, sets and motion of a pipeline for ``chain`` (module docstring); which
    joints keep the URDF's friction: ``friction`` "keep" (all), "none", or "auto" (all
    but those whose viscous friction damps faster than the observer's bound can hold at
    ``step``: :func:`stiff_friction`)."""
    continuous = ~(np.isfinite(chain.lower) & np.isfinite(chain.upper))
    lower_, upper_ = (np.where(continuous, 0.0, limit) for limit in (chain.lower, chain.upper))
    centre = 0.5 * (lower_ + upper_)
    half = np.where(continuous, CONTINUOUS_HALF_RANGE, 0.5 * (upper_ - lower_))
    # 0 where it lies in the middle half of the range (a robot's home is often there), else
    # the middle of the range
    start = np.where(np.abs(0.0 - centre) <= 0.5 * half, 0.0, centre)
    lower = np.where(continuous, start - CONTINUOUS_HALF_RANGE, chain.lower)
    upper = np.where(continuous, start + CONTINUOUS_HALF_RANGE, chain.upper)
    velocity = np.where(np.isfinite(chain.velocity), chain.velocity, DEFAULT_VELOCITY_LIMIT)
    room = np.minimum(start - lower, upper - start) - POSITION_MARGIN
    swing = np.minimum.reduce([np.full(len(start), MAX_SWING), AMPLITUDE * half, 0.5 * room,
                               0.5 * velocity * SEGMENT / (2.0 * MIN_JERK_PEAK)])
    payload = float(np.round(PAYLOAD_SHARE * float(np.sum(chain.mass)), 2)) or 0.01
    swing = np.maximum(swing, 0.0)
    kept = np.full(chain.n, friction != "none")
    if friction == "auto":
        positions = [start + s * swing for s in np.linspace(-1.0, 1.0, 9)]
        kept = ~stiff_friction(chain, positions, step)
    return Plan(start, lower, upper, velocity, swing, payload, kept)


def stiff_friction(chain, positions, step: float) -> np.ndarray:
    """Per joint, whether its URDF friction is left out: one by one, the joint whose viscous
    friction damps fastest (Σ_l |(M⁻¹)_il| b_l, the rate the observer's check takes,
    cosim.paper.sampled_loop.check_friction_step) while dt times it reaches the share that
    check allows, at one of ``positions`` without payload."""
    from ..dynamics.model import chain_model, model_geometry, model_mass
    from .sampled_loop import FRICTION_STEP_SHARE

    model = chain_model(chain)
    inverses = []
    for q in positions:
        mass = np.zeros((chain.n, chain.n))
        model_geometry(model, np.asarray(q, float))
        model_mass(model, 1.0, 0.0, mass)
        inverses.append(np.abs(np.linalg.inv(mass)))
    dropped = np.zeros(chain.n, bool)
    while True:
        damping = np.where(dropped, 0.0, chain.damping)
        rates = np.max([inverse @ damping for inverse in inverses], axis=0)
        if step * float(np.max(rates)) < FRICTION_STEP_SHARE:
            return dropped
        dropped[int(np.argmax(np.where(dropped, -np.inf, rates * (damping > 0))))] = True


def _list(values, digits: int = 4) -> str:
    return "[" + ", ".join(f"{float(v):.{digits}g}" for v in values) + "]"


def _quoted(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _robot_lines(chain, urdf: str, base: str | None, fixed: dict[str, float] | None
                 ) -> list[str]:
    """The [robot] table's lines: the URDF as the user named it, the chain's ends, the
    joints held."""
    robot = [f"file = {_quoted(urdf)}"]
    robot += [f"base = {_quoted(base)}"] if base else []
    robot += [f"tip = {_quoted(chain.tip_link)}"]
    if fixed:
        robot.append("fixed = { " + ", ".join(f"{_quoted(k)} = {v:g}" for k, v in
                                              fixed.items()) + " }   # rad (m: prismatic)")
    return robot


def _safety_overrides(chain, p) -> str:
    """[safety]'s finite limits where the URDF gives none ("" where it gives them all)."""
    n = chain.n
    continuous = [chain.joints[i] for i in range(n)
                  if not (np.isfinite(chain.lower[i]) and np.isfinite(chain.upper[i]))]
    unlimited = [chain.joints[i] for i in range(n) if not np.isfinite(chain.velocity[i])]
    if not (continuous or unlimited):
        return ""
    return ("# The URDF gives no position limits for " + (", ".join(continuous) or "no joint")
            + " (continuous) and no velocity limit for " + (", ".join(unlimited) or "no joint")
            + ":\n# the safe sets need finite ones, so these are chosen here (±π about the "
            "start; 2 rad/s).\n"
            f"position_lower = {_list(p.lower)}   # rad\n"
            f"position_upper = {_list(p.upper)}   # rad\n"
            f"velocity_limit = {_list(p.velocity)}   # rad/s\n")


# The pipeline's blocks and runs, the same for every arm (gains in accelerations, scaled by
# M̂(q)); ``payload``: the declared payload's upper end, kg.
_BLOCKS = '''[observer]
tau_d = 0.0                  # N·m: the plant's disturbance is 0
initial_velocity = "zero"    # rad/s: the arm starts at rest

# Gains in accelerations, scaled by each configuration's M̂(q): the same bandwidth on
# every joint, whatever its inertia (kv in 1/s, the robust terms in rad/s²).
[controller]
variant = "proposed"
scale = "inertia"
kv = 50.0         # 1/s
lambda = 10.0     # 1/s
init = "random"
init_scale = 0.1
kz = 0.1
z_wc = 1.0
c0 = 5.0
c1 = 0.1
delta = 1.0
psi_b = 3.0
kappa = 0.1

[pd_controller]
scale = "inertia"
kp = 400.0   # 1/s²
kd = 40.0    # 1/s

# The filter: the robot's limits hard (its torque limits the efforts), the tracking soft.
[cbf_filter]
hard = ["position", "velocity"]
soft = ["error", "error_rate"]
soft_norms = []
position_rate = 30.0     # 1/s
tracking_rate = 100.0    # 1/s
velocity_rate = 100.0    # 1/s
bound_margin = 0.002

# What the filter's and the observer's guarantees assume: the payload at the tip within
# [0, {payload:g}] kg (a tenth of the arm's mass), the position measured exactly, the
# observer's initial velocity error within 0.05 rad/s, no disturbance beyond the model's,
# and the URDF's friction exact.
[uncertainty]
payload = [0.0, {payload:g}]   # kg at the tip
noise_bound = 0.0              # rad
initial_velocity_error = 0.05  # rad/s
disturbance = 0.0              # N·m
viscous_friction = 0.0         # N·m·s/rad, |b − b̂|
coulomb_friction = 0.0         # N·m, |fc − f̂c|

[runs.proposed]
blocks = ["reference", "sensor", "inertia_model", "observer", "controller"]

[runs.proposed_cbf]
blocks = ["reference", "sensor", "inertia_model", "observer", "controller", "cbf_filter"]

[runs.pd]
blocks = ["reference", "sensor", "inertia_model", "pd_controller"]
'''


def pipeline_text(chain, urdf: str, name: str, base: str | None = None,
                  tip: str | None = None, fixed: dict[str, float] | None = None,
                  friction: str = "auto") -> str:
    """The pipeline file for ``chain`` (the URDF ``urdf`` as the user named it, its chain
    from ``base`` to ``tip`` with the joints ``fixed`` held; ``friction`` as :func:`plan`
    takes it)."""
    p = plan(chain, friction)
    n = chain.n
    waypoints = [p.start, p.start + p.swing * _signs(n), p.start - p.swing * _signs(n), p.start]
    times = [SEGMENT * i for i in range(len(waypoints))]
    robot = _robot_lines(chain, urdf, base, fixed)
    start = "\n".join(f'"q0[{i + 1}]" = {p.start[i]:.4g}   # {chain.joints[i]}' for i in range(n))
    safety_overrides = _safety_overrides(chain, p)
    held = ", ".join(f"{k} = {v:g}" for k, v in chain.held) or "none"
    friction_text = _friction_text(chain, p)
    rows = ",\n  ".join(_list(w) for w in waypoints)
    return f'''# {chain.name} from its URDF, made by `cosim new` ({n} moving joints from link
# '{chain.base_link}' to '{chain.tip_link}'; held: {held}). It runs as written:
#
#   cosim run {name}.toml --out runs/{name}
#
# Edit the motion ([reference.waypoints]), the payload ([uncertainty], plant.parameters) or
# the gains; `cosim params` lists every key. SI units, radians (m and N for a prismatic joint).
name = {_quoted(name)}
description = {_quoted(f"{chain.name} from its URDF: {DESCRIPTION}")}

[simulation]
duration = {times[-1]:g}   # s: the motion's last waypoint
step = 0.001      # s: checked before the run against the controllers' gains

# The robot, named once: the plant FMU, the blocks' nominal model (M̂, b̂ and the friction)
# and the safe sets (its <limit>s) are all this URDF's chain.
[robot]
{chr(10).join(robot)}

# The arm starts at rest at the first waypoint carrying half the declared payload, which
# the nominal model does not know.
[plant.parameters]
payload = {p.payload / 2:g}   # kg at the tip frame's origin ({chain.tip_link})
{start}
{friction_text.plant}
# Each joint out by a fraction of its range (at most {MAX_SWING:g} rad), back through the
# start to the other side, and home: minimum-jerk segments, at most half of each velocity
# limit, every position within its limits less the margin (checked before the run).
[reference]
limits = "refuse"
[reference.waypoints]
times = {_list(times)}   # s
positions = [   # rad, one row per time
  {rows},
]

# The robot's own limits are the hard sets: lower + margin ≤ q ≤ upper − margin, |q̇| ≤ its
# velocity limit, |τ| ≤ its effort limit; the tracking sets soft.
[safety]
limits = "urdf"
position_margin = {POSITION_MARGIN:g}   # rad
error_bound = 0.3          # |e_i|, rad
error_rate_bound = 2.0     # |ė_i|, rad/s
{safety_overrides}
[inertia_model]
source = "nominal"   # M̂ from the URDF at the measured position (not the plant's own M)
{friction_text.model}
{_BLOCKS.format(payload=p.payload)}'''


@dataclass(frozen=True)
class _FrictionText:
    plant: str  # the plant's friction parameters, with why
    model: str  # the nominal model's (inertia_model.b, fc)


def _friction_text(chain, p: Plan) -> _FrictionText:
    """The friction lines of the plant's parameters and the nominal model: the URDF's
    <dynamics> in both where kept, none in both where left out (and why)."""
    if not np.any(chain.damping) and not np.any(chain.friction):
        return _FrictionText("", "")
    if np.all(p.friction):
        return _FrictionText(
            "# Its friction is the URDF's <dynamics>, in the plant and the nominal model alike.\n",
            "")
    dropped = [i for i in range(chain.n) if not p.friction[i]]
    names = ", ".join(chain.joints[i] for i in dropped)
    why = ("# The URDF's <dynamics> friction is kept in the plant and the nominal model alike,\n"
           f"# but for {names}: left out of both (b, fc = 0): its viscous friction against\n"
           "# its inertia damps faster than the observer's certified bound can hold at a 1 ms\n"
           "# step (it takes friction as a bounded error; `cosim run` refuses it so).\n"
           if not np.all(~p.friction) else
           "# The URDF's <dynamics> friction is left out of the plant and the nominal model\n"
           "# alike (cosim new --friction none).\n")
    plant = why + "\n".join(f'"b[{i + 1}]" = 0.0\n"fc[{i + 1}]" = 0.0' for i in dropped) + "\n"
    model = (f"b = {_list(np.where(p.friction, chain.damping, 0.0))}    # N·m·s/rad: the "
             "URDF's, 0 where left out\n"
             f"fc = {_list(np.where(p.friction, chain.friction, 0.0))}   # N·m\n")
    return _FrictionText(plant, model)


def _signs(n: int) -> np.ndarray:
    """+1, −1, +1, … : neighbouring joints swing apart, so the motion is not one big arc."""
    return np.where(np.arange(n) % 2 == 0, 1.0, -1.0)


def chain_table(chain) -> str:
    """The chain as a table for the terminal: per moving joint its kind, limits (rad or m;
    rad/s or m/s; N·m or N), friction and the mass it carries; then the tip and the held
    joints."""
    kinds = ["prismatic" if k else "revolute" for k in chain.kind]
    kinds = [("continuous" if c else k) for k, c in zip(kinds, chain.continuous, strict=True)]
    head = (f"{'joint':<24} {'kind':<10} {'lower':>8} {'upper':>8} {'velocity':>8} "
            f"{'effort':>8} {'damping':>8} {'friction':>8} {'mass kg':>8}")
    lines = [f"{chain.name}: {chain.n} moving joints from link '{chain.base_link}' to "
             f"'{chain.tip_link}' (SI units, radians)", head]
    for i in range(chain.n):
        lines.append(f"{chain.joints[i][:24]:<24} {kinds[i]:<10} {chain.lower[i]:>8.4g} "
                     f"{chain.upper[i]:>8.4g} {chain.velocity[i]:>8.4g} {chain.effort[i]:>8.4g} "
                     f"{chain.damping[i]:>8.4g} {chain.friction[i]:>8.4g} "
                     f"{chain.mass[i]:>8.4g}")
    held = ", ".join(f"{k} = {v:g}" for k, v in chain.held)
    lines.append(f"held (folded into their parent body): {held or 'none'}; total moving mass "
                 f"{float(np.sum(chain.mass)):.4g} kg")
    return "\n".join(lines)


def default_name(chain, urdf: str) -> str:
    """The pipeline's name: the robot's, as a file name (letters, digits, _ - .)."""
    raw = chain.name or Path(urdf).stem
    name = "".join(ch if ch.isascii() and (ch.isalnum() or ch in "_-.") else "_" for ch in raw)
    name = name.strip("._-")[:64]
    return name if name and name[0].isalnum() else f"robot_{name}".rstrip("_")
