"""Whether a run's plant and the filter's inputs are within what is declared: the guarantee's
``within_bounds`` and ``outside`` (cosim/paper/guarantee.py). The plant's parameters are
compared with the nominal model for everything not declared uncertain (the links through the
payload, gravity, friction, the disturbance), a system's components beside the arm (a
drive's rotor inertia, and the torque its lag or limit kept from the arm), and what the
filter reads (the noise, the initial observer error) with ``[uncertainty]``. Each
difference is named with both values.

Ground truth is used here, for evaluation only. SI units, radians.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from plant_fmu.models.planar_arm import MAX_LINKS
from plant_fmu.models.planar_arm import variables as rigid_arm_variables

from ..declared import Uncertainty
from ..dynamics.model import Friction, friction_table
from ..evaluate.safety import SafeSet, Signals
from .barrier_bounds import barrier_bounds
from .cbf_filter.assumptions import FilterAssumptions

# A tolerance for comparing declared and actual parameter values (rounding in TOML, FMI).
PARAMETER_TOLERANCE = 1e-9

# The plant's M(q) against the nominal model's, relative: one arm computed twice agrees to
# ~1e-14 (docs/plants.md); anything past this is another arm. Compared at this many states.
MODEL_TOLERANCE = 1e-8
MODEL_STATES = 20

# The rigid arm's parameters, by family, as the classifier treats them. Compared with the
# nominal model: the links (plant_payload), gravity, friction (the nominal model's, within
# the declared bounds) and the disturbance (undeclared_differences). Not model differences:
# the initial state (what the viable set judges), the integrator's step, the Coulomb
# smoothing velocity (compared on its own where there is Coulomb friction) and the
# disturbance's frequency (its amplitude bounds it at any frequency).
CHAIN = ("m", "l", "lc", "I")
GRAVITY = "g"
FRICTION = (("b", "viscous friction", "N·m·s/rad"), ("fc", "Coulomb friction", "N·m"))
DISTURBANCE = ("tau_d", "tau_d_amp")
COMPARED = frozenset({*CHAIN, GRAVITY, *(name for name, _, _ in FRICTION), *DISTURBANCE})
NOT_MODEL = frozenset({"q0", "qdot0", "rk4_step", "fc_vel", "tau_d_freq"})

# cosim's drives (plant_fmu/models/drives): the parameter families the guarantee reads
DRIVE_PARAMETERS = ("N", "kt", "i_max", "T", "J")


def apart(value: float, other: float, digits: int = 6) -> str:
    """``value`` with as many significant digits as it takes to tell it from ``other`` (up
    to 17), at least ``digits``: a value just past a bound never reads as the bound."""
    for shown in range(digits, 18):
        if f"{value:.{shown}g}" != f"{other:.{shown}g}":
            return f"{value:.{shown}g}"
    return f"{value:.17g}"


def rigid_chain_parameters(links: int) -> frozenset[str] | None:
    """The parameter names of the rigid arm's FMU: the model the filter's guarantee
    assumes (None beyond the built-in arm's link count)."""
    if links > MAX_LINKS:
        return None
    return frozenset(v.name for v in rigid_arm_variables(links) if v.causality == "parameter")


def plant_payload(parameters: dict, chain, modelled: frozenset[str] | None = None,
                  urdf: bool = False) -> tuple[float | None, list[str]]:
    """The payload the plant carries against the nominal chain (m[n] − m_n, kg), and what
    else sets the plant apart from it: link parameters that differ, and parameters the
    rigid chain's model does not have (``modelled``: its parameter names; the joint
    springs of the elastic-joint arm, say). For a spatial chain from a URDF (``urdf``: the
    nominal model is a URDF's), its ``payload`` parameter at the tip, the URDF compiled into
    both (whether they are one arm: :func:`plant_model_difference`). (None, [])
    when the plant does not expose the chain's parameters (a foreign FMU)."""
    if chain is None:
        if urdf and "payload" in parameters:
            return float(parameters["payload"]), []
        return None, []
    n = len(chain.m)
    names = {"m": chain.m, "l": chain.l, "lc": chain.lc, "I": chain.inertia}
    if not all(f"{key}[{i}]" in parameters for key in names for i in range(1, n + 1)):
        return None, []
    differ = [f"{key}[{i + 1}] = {apart(parameters[f'{key}[{i + 1}]'], values[i])} (nominal "
              f"{values[i]:g})"
              for key, values in names.items() for i in range(n)
              if not (key == "m" and i == n - 1)
              and abs(parameters[f"{key}[{i + 1}]"] - values[i]) > PARAMETER_TOLERANCE]
    if modelled is not None:
        extra = [name for name in parameters if name not in modelled]
        if extra:
            shown = ", ".join(extra[:6]) + (f" and {len(extra) - 6} more" if len(extra) > 6
                                            else "")
            differ.append(f"has parameters the nominal rigid chain does not ({shown}): it is "
                          "another model")
    return float(parameters[f"m[{n}]"] - chain.m[n - 1]), differ


def plant_model_difference(trace: Signals, model, payload: float | None) -> str | None:
    """Whether the plant is the nominal model's arm, where nothing else can tell (a URDF's
    chain has no parameters to compare): the plant's own M(q) and, where it outputs them,
    its bias forces h(q, q̇) = C q̇ + G (the trace's ``M``, ``h``) against the nominal
    model's M̂(q), b̂(q, q̇) with the plant's payload at the model's payload point, at up to
    MODEL_STATES recorded states; the largest difference relative to the largest entry,
    named with its time when above MODEL_TOLERANCE (another URDF, other masses, a base
    placed otherwise or the payload at another frame: a model error the uncertainty does
    not declare), else None. None too where the plant does not output M or its payload is
    unknown."""
    from ..dynamics.model import model_bias, model_geometry, model_mass, own_scratch

    if model is None or payload is None or "M" not in trace or not trace.rows_done:
        return None
    q = np.asarray(trace["q"], float)
    recorded = {"M(q)": np.asarray(trace["M"], float)}
    if "h" in trace and "qdot" in trace:
        recorded["h(q, q̇)"] = np.asarray(trace["h"], float)
    rows = np.unique(np.linspace(0, trace.rows_done - 1, MODEL_STATES).astype(int))
    model = own_scratch(model)
    n = q.shape[1]
    nominal = {"M(q)": np.zeros((n, n)), "h(q, q̇)": np.zeros(n)}
    worst = (0.0, 0, "M(q)")
    for k in rows:
        arrays = [q[k], *(values[k] for values in recorded.values())]
        if not all(np.isfinite(a).all() for a in arrays):
            continue
        model_geometry(model, q[k])
        model_mass(model, 1.0, payload, nominal["M(q)"])
        if "h(q, q̇)" in recorded:
            model_bias(model, np.asarray(trace["qdot"][k], float), 1.0, payload, 1.0,
                       nominal["h(q, q̇)"])
        for what, values in recorded.items():
            scale = np.max(np.abs(values[k]))
            if scale > 0.0:
                difference = float(np.max(np.abs(values[k] - nominal[what])) / scale)
                worst = max(worst, (difference, int(k), what))
    difference, at, what = worst
    if difference <= MODEL_TOLERANCE:
        return None
    return (f"{what} differs from the nominal model's with the plant's {payload:g} kg payload "
            f"by {difference:.2g} of its largest entry (t = {at * trace.dt:.4g} s): not the "
            "nominal arm (another URDF, other masses, its base placed otherwise or the "
            "payload at another frame), a model error the uncertainty does not declare")


def undeclared_differences(parameters: Mapping[str, float], chain, uncertainty: Uncertainty,
                           tau_d_model: np.ndarray | None, links: int,
                           friction: np.ndarray | None = None) -> list[str]:
    """What sets the plant's gravity, friction and disturbance apart from the nominal model
    beyond what is declared uncertain, each naming its parameter: gravity ``g`` against the
    nominal chain's, friction ``b[i]``, ``fc[i]`` against the nominal model's (``friction``,
    its rows as cosim.dynamics.model lays them out; None: no friction) within the declared
    bounds (``uncertainty.viscous_friction``, ``coulomb_friction``), the smoothing velocity
    ``fc_vel[i]`` against its own where either has Coulomb friction, and per joint the
    disturbance error |τ_d[i] − τ_d,model[i]| + |tau_d_amp[i]| (the sinusoid's amplitude is
    its largest value; compared whatever tau_d_freq, even 0 Hz where the plant's
    sin(2π·f·t) is 0: conservative) against ``uncertainty.disturbance``. ``tau_d_model``:
    the τ_d the filter's model assumes, N·m per joint (None: no model, 0). A parameter the
    plant does not have is not compared (a foreign FMU is judged by its missing chain
    instead). Each value is shown with the digits that tell it from what it passed."""
    out = []
    if chain is not None and GRAVITY in parameters \
            and abs(float(parameters[GRAVITY]) - chain.gravity) > PARAMETER_TOLERANCE:
        gravity = apart(float(parameters[GRAVITY]), chain.gravity)
        out.append(f"g = {gravity} m/s² (the nominal chain's {chain.gravity:g} m/s²): gravity "
                   "is not declared uncertain")
    table = friction_table(links) if friction is None else friction
    for (name, what, unit), row, error, key in zip(
            FRICTION, (Friction.DAMPING, Friction.COULOMB),
            (Friction.DAMPING_ERROR, Friction.COULOMB_ERROR),
            ("viscous_friction", "coulomb_friction"), strict=True):
        for i in range(1, links + 1):
            value = float(parameters.get(f"{name}[{i}]", table[row, i - 1]))
            nominal, declared = table[row, i - 1], table[error, i - 1]
            if abs(value - nominal) <= declared + PARAMETER_TOLERANCE:
                continue
            edge = nominal + np.sign(value - nominal) * declared  # the bound it passed
            out.append(f"{name}[{i}] = {apart(value, edge)} {unit} (nominal {nominal:g}"
                       + (f" ± {declared:g}): {what} beyond uncertainty.{key}" if declared
                          else f"): {what} is not declared uncertain (uncertainty.{key})"))
    for i in range(1, links + 1):  # a URDF arm's fc_vel[i], the planar arm's one fc_vel
        coulomb = float(parameters.get(f"fc[{i}]", 0.0))
        key = f"fc_vel[{i}]" if f"fc_vel[{i}]" in parameters else "fc_vel"
        nominal = table[Friction.COULOMB_VELOCITY, i - 1]
        smoothing = float(parameters.get(key, nominal))
        if (coulomb or table[Friction.COULOMB, i - 1]) \
                and abs(smoothing - nominal) > PARAMETER_TOLERANCE:
            named = (f"{key} = {apart(smoothing, nominal)} rad/s (the nominal model's "
                     f"{nominal:g} rad/s, ")
            if named not in "".join(out):  # the planar arm's one value, named once
                out.append(f"{named}inertia_model.fc_vel): another Coulomb friction law")
    return out + disturbance_differences(parameters, uncertainty, tau_d_model, links)


def disturbance_differences(parameters: Mapping[str, float], uncertainty: Uncertainty,
                            tau_d_model: np.ndarray | None, links: int,
                            key: str | None = None) -> list[str]:
    """Per joint, the plant's disturbance error |τ_d − τ_d,model| + |tau_d_amp| beyond
    ``uncertainty.disturbance``, named; ``key``: the block's key whose model it is, for a
    model other than the filter's own (the observer's, whose bound ε(t) the margins rest
    on)."""
    out = []
    model = np.broadcast_to(np.asarray(0.0 if tau_d_model is None else tau_d_model, float),
                            (links,))
    for i in range(1, links + 1):
        constant = float(parameters.get(f"tau_d[{i}]", model[i - 1])) - model[i - 1]
        amplitude = float(parameters.get(f"tau_d_amp[{i}]", 0.0))
        error = abs(constant) + abs(amplitude)
        if error <= uncertainty.disturbance + PARAMETER_TOLERANCE:
            continue
        whose = "model" if key is None else key
        named = [*([f"tau_d[{i}] = {constant + model[i - 1]:g} N·m ({whose} "
                    f"{model[i - 1]:g} N·m)"] if abs(constant) > PARAMETER_TOLERANCE else []),
                 *([f"tau_d_amp[{i}] = {amplitude:g} N·m at tau_d_freq[{i}] = "
                    f"{float(parameters.get(f'tau_d_freq[{i}]', math.nan)):g} Hz (nominal 0)"]
                   if abs(amplitude) > PARAMETER_TOLERANCE else [])]
        consequence = ("" if key is None else
                       f"; the bound ε(t) on the velocity's estimate, which the filter's "
                       f"margins rest on, assumes {key}")
        out.append(f"{', '.join(named)}: a disturbance error up to {error:g} N·m on joint {i} "
                   f"> the declared {uncertainty.disturbance:g} N·m (uncertainty.disturbance)"
                   f"{consequence}")
    return out


def _disturbance_errors(parameters: Mapping[str, float], tau_d_model: np.ndarray | None,
                        links: int) -> np.ndarray:
    """Per joint, the disturbance model's error bound |τ_d − τ_d,model| + |tau_d_amp|, N·m
    (the plant's parameters; one it does not have counts as the model's value)."""
    model = np.broadcast_to(np.asarray(0.0 if tau_d_model is None else tau_d_model, float),
                            (links,))
    return np.array([abs(float(parameters.get(f"tau_d[{i}]", model[i - 1])) - model[i - 1])
                     + abs(float(parameters.get(f"tau_d_amp[{i}]", 0.0)))
                     for i in range(1, links + 1)])


def system_differences(trace: Signals, system: Mapping[str, Any],
                       parameters: Mapping[str, float], uncertainty: Uncertainty,
                       tau_d_model: np.ndarray | None) -> list[str]:
    """How a system of FMUs as the plant (``system``: :data:`cosim.interface.PLANT_SYSTEM`)
    differs from the nominal model beyond what is declared, each naming the component and
    its parameter: a component besides the arm that is not one of cosim's drives (what it
    does is unknown); a drive's rotor inertia (J N² on its joint's M, which the nominal
    model does not have); and per joint the torque the arm was given against the torque
    the plant was asked for (a drive's lag or current limit), measured on the run's rows
    that were stepped, which with the disturbance model's own error must stay within
    ``uncertainty.disturbance`` (the filter's margins carry that bound: a drive's torque
    error is a disturbance torque to them). ``parameters``: the arm's."""
    n = trace.links
    out = []
    drives = {}
    for name, info in system["components"].items():
        if name == system["arm"]:
            continue
        values = info["parameters"]
        if not all(f"{key}[{i}]" in values for key in DRIVE_PARAMETERS
                   for i in range(1, n + 1)):
            out.append(f"component {name!r} ({info['model_name']}) is part of the plant "
                       "beside the arm, and not one of cosim's drives: what it does to the "
                       "torque is not declared")
            continue
        drives[name] = values
        for i in range(1, n + 1):
            inertia = values[f"J[{i}]"] * values[f"N[{i}]"] ** 2
            if inertia > PARAMETER_TOLERANCE:
                out.append(f"drive {name!r}: J[{i}] = {values[f'J[{i}]']:g} kg·m² puts its "
                           f"rotor's inertia, J N² = {inertia:g} kg·m², on joint {i}'s M: "
                           "the nominal model does not have it")
    key = system.get("arm_torque")
    rows = trace.rows_done - 1  # the rows a step followed (the last row's torque was not given)
    if not drives or rows < 1:
        return out
    if key is None or key not in trace or "tau" not in trace:
        return out + [f"drive torque not in the trace: the torque error of "
                      f"{', '.join(drives)} cannot be judged"]
    given, asked = np.asarray(trace[key][:rows], float), np.asarray(trace["tau"][:rows], float)
    error = np.abs(given - asked)
    budget = np.maximum(uncertainty.disturbance
                        - _disturbance_errors(parameters, tau_d_model, n), 0.0)
    for j in np.flatnonzero(np.max(error, axis=0) > budget + PARAMETER_TOLERANCE):
        i, at = j + 1, int(np.argmax(error[:, j]))
        peak = float(np.max(np.abs(asked[:, j])))
        causes = [f"{name}.T[{i}] = {values[f'T[{i}]']:g} s (its lag)"
                  for name, values in drives.items() if values[f"T[{i}]"] > 0]
        for name, values in drives.items():
            limit = values[f"N[{i}]"] * values[f"kt[{i}]"] * values[f"i_max[{i}]"]
            if limit < peak:
                causes.append(f"{name}.i_max[{i}] = {values[f'i_max[{i}]']:g} A (a limit of "
                              f"{limit:g} N·m at the joint, below the {peak:.4g} N·m "
                              "commanded)")
        out.append(f"drive torque up to {error[at, j]:.3g} N·m away from the command on "
                   f"joint {i} (t = {at * trace.dt:.4g} s), more than the {budget[j]:g} N·m "
                   "uncertainty.disturbance leaves for it: "
                   + ("; ".join(causes) or f"component(s) {', '.join(drives)}"))
    return out


def declared_inputs(trace: Signals, safe: SafeSet, uncertainty: Uncertainty,
                    payload: float | None, other_parameters: list[str], true_velocity: bool,
                    assumes: FilterAssumptions | None) -> tuple[list[str], dict, str | None]:
    """(what is outside the declared uncertainty, each named: the payload, the plant's
    ``other_parameters`` and what the filter reads; the observer's facts; the observer
    bound's violation, or None). Only what the
    filter reads is judged (``assumes``; without it, the measured position and the
    observer's velocity where the trace has them, as an output-feedback filter reads):
    the noise for "q_meas", the initial observer error and ε(t) for "qdot_hat"."""
    outside = []
    low, high = uncertainty.payload
    if payload is None:
        outside.append("payload unknown (the plant does not expose the nominal chain's "
                       "parameters)")
    elif not low - PARAMETER_TOLERANCE <= payload <= high + PARAMETER_TOLERANCE:
        outside.append(f"payload {apart(payload, min(max(payload, low), high))} kg outside "
                       f"[{low:g}, {high:g}]")
    outside += [f"plant {text}" for text in other_parameters]
    if not true_velocity:
        outside.append("true velocity unknown (the plant does not map qdot): the velocity set "
                       "cannot be judged")
    position = "q_meas" if assumes is None else assumes.position
    velocity = "qdot_hat" if assumes is None else assumes.velocity
    if position == "q_meas" and "q_meas" in trace:
        noise = float(np.max(np.abs(trace["q_meas"] - trace["q"])))
        if noise > uncertainty.noise_bound:
            outside.append(f"noise {apart(noise, uncertainty.noise_bound, 3)} rad > "
                           f"{uncertainty.noise_bound:g}")
    facts: dict[str, Any] = {"observer_bound_exceeded_steps": None}
    violation = None
    if not (true_velocity and "qdot_hat" in trace and np.isfinite(trace["qdot_hat"][0]).all()):
        return outside, facts, violation
    error = np.abs(trace["qdot"] - trace["qdot_hat"])
    facts["starts_inside_observer_set"] = bool(
        np.linalg.norm(error[0]) <= barrier_bounds(safe).observer_error_bound)
    if velocity != "qdot_hat":  # the filter reads the true velocity: the observer is moot
        return outside, facts, violation
    if np.max(error[0]) > uncertainty.initial_velocity_error:
        outside.append(f"initial observer error "
                       f"{apart(float(np.max(error[0])), uncertainty.initial_velocity_error, 3)}"
                       " rad/s > "
                       f"{uncertainty.initial_velocity_error:g}")
    if "qdot_hat_bound" in trace:
        rows = np.flatnonzero((error > trace["qdot_hat_bound"]).any(axis=1))
        facts["observer_bound_exceeded_steps"] = len(rows)
        if len(rows):
            violation = (f"observer error |q̇ − x̂2| above its bound ε(t) at {len(rows)} "
                         f"steps (first t = {rows[0] * trace.dt:.4g} s)")
    return outside, facts, violation
