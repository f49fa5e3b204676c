"""A curated mutation run (`make mutants`): plausible one-line bugs in the core modules — the
paper's laws, the filter, the evaluation, the run folder, the sweep's statistics, export and
compare, the limits — each applied to a fresh copy of the repository and run against the
tests that cover its module. Prints the score and every survivor. Outside CI's budget (most
mutants touch numba kernels and recompile: ~1 min each on 2 cores).

    .venv/bin/python benchmarks/mutants.py             # all
    .venv/bin/python benchmarks/mutants.py --only obs  # the ids containing "obs"

A mutant is killed when its tests fail (or time out); it survives when they pass. The copy is
`git archive HEAD` (commit your work first), imported ahead of the editable install through
PYTHONPATH; the working tree is never touched.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

LAWS = ["tests/test_references.py", "tests/test_blocks.py"]
FILTER = ["tests/test_robust_safety.py", "tests/test_safety.py"]
EVALUATION = ["tests/test_references.py", "tests/test_cosim.py", "tests/test_robust_safety.py",
              "tests/test_guarantee.py"]
FOLDER = ["tests/test_errors.py", "tests/test_recording.py"]
SWEEP = ["tests/test_references.py", "tests/test_sweep.py"]
LIMITS = ["tests/test_errors.py", "tests/test_resources.py"]
RESULTS = ["tests/test_export.py"]
BOUND = ["tests/test_observer_bound.py"]
VIABILITY = FILTER + ["tests/test_viability.py", "tests/test_guarantee.py"]
CUTS = ["tests/test_filter_speed.py", *FILTER]
STEPS = ["tests/test_steps.py"]
PREMISES = ["tests/test_premises.py"]
COMPARISONS = ["tests/test_guarantee_comparisons.py", "tests/test_guarantee.py",
               "tests/test_premises.py"]
URDF = ["tests/test_urdf_plant.py", "tests/test_guarantee_comparisons.py"]
RULES = ["tests/test_check_rules.py", "tests/test_viability.py"]
GROWTH = ["tests/test_rollout_growth.py"]

# (id, file, text, replacement, tests): the text must occur exactly once in the file.
MUTANTS = [
    # the paper's laws
    ("inertia-centripetal", "cosim/dynamics/planar.py",
     "chain[Link.FX, i] = m[i] * (ax - w2 * chain[Link.CX, i])",
     "chain[Link.FX, i] = m[i] * (ax + w2 * chain[Link.CX, i])", LAWS),
    ("inertia-link-vs-com", "cosim/dynamics/planar.py",
     "        ax -= w2 * chain[Link.LX, i]\n", "        ax -= w2 * chain[Link.CX, i]\n", LAWS),
    ("obs-gain-sqrt", "cosim/paper/observer_block.py",
     "den_scale=2.0 * math.sqrt(p.kp * p.kd)", "den_scale=2.0 * (p.kp * p.kd)", LAWS),
    ("obs-input-one-substep-off", "cosim/paper/observer.py",
     "frac = (j + 1) / a.substeps", "frac = j / a.substeps", LAWS),
    ("obs-kd-dropped", "cosim/paper/observer.py",
     "denom = 1.0 + hc + hh * k0", "denom = 1.0 + h * kp + hh * k0", LAWS),
    ("obs-drift-injection", "cosim/paper/observer.py",
     "+ (k0 - kp * a.kd) * x1_err[i]", "+ k0 * x1_err[i]", LAWS + ["tests/test_robust_safety.py"]),
    ("obs-envelope-noise", "cosim/paper/position_windows.py",
     "spread = 2.0 * noise / span", "spread = 0.0", LAWS + BOUND),
    # the envelope's forcing without the payload's share, or without the disturbance d̄
    ("obs-envelope-payload-dropped", "cosim/paper/envelope.py",
     "a, b = -s[0, j] * z, -s[1, j] * z", "a, b = 0.0, 0.0", BOUND),
    ("obs-envelope-disturbance-dropped", "cosim/paper/envelope.py",
     "work[l] = worst + env.disturbance", "work[l] = worst", BOUND),
    ("ctrl-robust-term-e", "cosim/paper/controller.py",
     "v[i] = v[i] - sign_gain * r[i] - e[i] - psi_gain * r[i]",
     "v[i] = v[i] - sign_gain * r[i] - psi_gain * r[i]", LAWS),
    ("ctrl-psi-square", "cosim/paper/controller.py",
     "psi_gain = a.psi_b**2 / (a.delta + r_sq)", "psi_gain = a.psi_b / (a.delta + r_sq)", LAWS),
    ("ctrl-c0", "cosim/paper/controller.py",
     "** 2 / 4.0 + a.c0)", "** 2 / 4.0)", LAWS),
    ("ctrl-w-update-sprime", "cosim/paper/controller.py",
     "row = s - s * (1.0 - s) * act[m - 1]", "row = s", LAWS),
    ("ctrl-lambda", "cosim/paper/controller.py",
     "r[i] = edot[i] + a.lam[i] * e[i]", "r[i] = edot[i] + e[i]", LAWS),
    # the filter's margins
    ("cbf-noise-margin", "cosim/paper/cbf_filter/groups.py",
     "limit = a.k0 * (h - a.noise_bound) - a.k1 * (side * v0[i] + eps[i])",
     "limit = a.k0 * h - a.k1 * (side * v0[i] + eps[i])", FILTER),
    ("cbf-eps-position", "cosim/paper/cbf_filter/groups.py",
     "limit = a.k0 * (h - a.noise_bound) - a.k1 * (side * v0[i] + eps[i])",
     "limit = a.k0 * (h - a.noise_bound) - a.k1 * (side * v0[i])", FILTER),
    ("cbf-velocity-eps", "cosim/paper/cbf_filter/groups.py",
     "limit = a.k_velocity * max(h - eps[i], 0.0)", "limit = a.k_velocity * h", FILTER),
    ("cbf-bias-error-dropped", "cosim/paper/cbf_filter/groups.py",
     "                limit -= scale * rows_error[i]\n", "", FILTER),
    # (It drops the plane's box corner (g, g+1), mask 2. Dropping (g+1, g) instead is an
    # equivalent mutant: s2 = s1/(1 + (λ2 − λ1)s1) is concave in s1 with λ1 ≤ λ2, so the
    # curve never leaves the other three.)
    ("cbf-payload-corners", "cosim/paper/cbf_filter/groups.py",
     "for mask in range(2**d - 2, 0, -1):", "for mask in range(2**d - 3, 0, -1):", FILTER),
    ("cbf-hold-end-dropped", "cosim/paper/cbf_filter/rows.py",
     "    if known:\n        hard_groups(a, k, y_end, v_end, eps, minv_end, base_end, True)\n",
     "", FILTER),
    # the hard rows the solve leaves out (cutting planes): the payload corners' terms not
    # taken in a group's screen, rows within hard_tolerance of their lowered limit left out,
    # the QP not solved again with the rows added
    ("cbf-cuts-screen-centre", "cosim/paper/cbf_filter/groups.py",
     "        most += max(s_phase[0, j] * terms[1 + j], s_phase[-1, j] * terms[1 + j])\n",
     "        pass\n", CUTS),
    ("cbf-cuts-no-tolerance", "cosim/paper/cbf_filter/groups.py",
     "        room = -a.hard_tolerance * w.group_values[g, GroupValue.NORM_BOUND]\n",
     "        room = 0.0\n", CUTS),
    ("cbf-cuts-one-round", "cosim/paper/cbf_filter/step.py",
     "        if more == count:\n            return count\n", "        return more\n", CUTS),
    ("cbf-infeasible-flag", "cosim/paper/cbf_filter/step.py",
     "a.infeasible[k] = 0.0 if viable else 1.0", "a.infeasible[k] = 0.0", FILTER),
    # the backup's check (issue 30): each margin it takes, dropped
    ("cbf-tube-deviation-dropped", "cosim/paper/cbf_filter/check.py",
     "dv[i] = max(dv[i] * (1.0 - feedback) + feedback * eps[i] + widen[i] * h, eps[i])",
     "dv[i] = max(dv[i] * (1.0 - feedback) + feedback * eps[i], eps[i])", VIABILITY),
    # the estimate's error ε under the backup's feedback (the check once kept it as a floor)
    ("cbf-tube-feedback-estimate", "cosim/paper/cbf_filter/check.py",
     "dv[i] = max(dv[i] * (1.0 - feedback) + feedback * eps[i] + widen[i] * h, eps[i])",
     "dv[i] = max(dv[i] * (1.0 - feedback) + widen[i] * h, eps[i])", VIABILITY),
    # the tube's contraction first order, k_b h, not the holds' 1 − (1 − k_b dt)^(h/dt)
    ("cbf-tube-contraction-first-order", "cosim/paper/cbf_filter/holds.py",
     "    return 1.0 - (1.0 - held) ** holds\n", "    return min(rate * h, 1.0)\n", VIABILITY),
    # D taken once, not 1.5 times (the tube's empirical factor, docs/safety/filter.md)
    ("cbf-tube-factor-one", "cosim/paper/cbf_filter/holds.py",
     "TUBE_SAFETY = 1.5", "TUBE_SAFETY = 1.0", VIABILITY),
    ("cbf-tube-start-estimate", "cosim/paper/cbf_filter/check.py",
     "q[i], vel[i], dq[i], dv[i] = y[i], v[i], a.noise_bound, eps[i]",
     "q[i], vel[i], dq[i], dv[i] = y[i], v[i], a.noise_bound, 0.0", VIABILITY),
    # the disturbance d̄ left out of D and of the rows' bias error
    ("cbf-disturbance-dropped", "cosim/paper/cbf_filter/model.py",
     "    quadratic[:] = disturbance\n", "    quadratic[:] = 0.0\n", ["tests/test_viability.py"]),
    ("cbf-payload-deviation-dropped", "cosim/paper/cbf_filter/deviation.py",
     "    _payload_deviation(a, q_dot, acceleration, deviation, structure_taken)\n", "",
     VIABILITY),
    # the held steps' tube without q̈'s drift over the hold (taken at each step's start)
    ("cbf-held-drift-dropped", "cosim/paper/cbf_filter/check.py",
     "            held_drift(k, a, r[Rollout.TAU], limit, eps, widen, hold and step == 0)\n",
     "            pass\n",
     ["tests/test_steps.py"]),
    # the candidate's held step at 1 ms without q̈'s drift over it (backup_step > dt)
    ("cbf-candidate-drift-dropped", "cosim/paper/cbf_filter/check.py",
     "        if held or clipped:\n", "        if held or (backup and clipped):\n",
     ["tests/test_robust_safety.py"]),
    # a step where a limit binds in the backup without q̈'s drift over it
    ("cbf-limited-drift-dropped", "cosim/paper/cbf_filter/check.py",
     "        if held or clipped:\n", "        if held or not backup:\n",
     ["tests/test_rollout_holds.py", "tests/test_viability.py"]),
    # a step where a limit binds in the backup over several holds (backup_step)
    ("cbf-limited-step-several-holds", "cosim/paper/cbf_filter/check.py",
     "h = a.backup_step if backup and not clipped else a.dt",
     "h = a.backup_step if backup else a.dt", ["tests/test_rollout_holds.py"]),
    # the steps that grow: the holds' average q̈ held over a grown step, for the rollout's
    # position and for the plan's box inside it; D at a free step's start alone; the band
    # where the backup steers a joint in left out of what keeps a step from growing
    ("cbf-grown-position-average", "cosim/paper/cbf_filter/check.py",
     "q[i] += h * vel[i] + travel * r[Rollout.HOLD_ACC, i]",
     "q[i] += h * vel[i] + 0.5 * h * h * acc[i]", GROWTH),
    ("cbf-grown-box-first-hold", "cosim/paper/cbf_filter/check.py",
     "position, travel = held_position(a, h, s), held_travel(a, h, s)",
     "position, travel = 0.5 * s * s, held_travel(a, h, s)", GROWTH),
    # a free step's tube over several holds: the position's departure contracted by the
    # step's whole feedback from its start; the grown step's torque not looked at its end
    ("cbf-free-share-whole", "cosim/paper/cbf_filter/check.py",
     "_, contracted, gathered, gathered_integral = held_share(a, h)",
     "_, contracted, gathered, gathered_integral = held_share(a, h)\n"
     "        contracted = h * (1.0 - contraction)", RULES),
    ("cbf-free-gathered-within-hold", "cosim/paper/cbf_filter/holds.py",
     "gathered_integral += a.dt * gathered * (1.0 - 0.5 * c) + 0.5 * a.dt * a.dt",
     "gathered_integral += a.dt * gathered * (1.0 - 0.5 * c)", RULES),
    ("cbf-grown-end-torque", "cosim/paper/cbf_filter/check.py",
     "may_grow(a, stride) and free_at_end(a, stride, limit)", "may_grow(a, stride)", GROWTH),
    ("cbf-end-deviation-dropped", "cosim/paper/cbf_filter/check.py",
     "            later_deviation(a, h, eps, widen)\n", "            pass\n", GROWTH),
    # the start's D with the payload's structure of whatever D was taken before (the step
    # before's end), not its own configuration's
    ("cbf-structure-stale", "cosim/paper/cbf_filter/check.py",
     "deviation_bound(a, vel, eps, acc, deviation, False)",
     "deviation_bound(a, vel, eps, acc, deviation, True)", GROWTH),
    # the interval predicted with the hull the check took for another torque
    ("cbf-checked-torque-ignored", "cosim/paper/cbf_filter/interval.py",
     "if (r[Rollout.CHECKED_TAU, i] != tau[i] or r[Rollout.CHECKED_Q, i] != y[i]",
     "if (r[Rollout.CHECKED_Q, i] != y[i]", ["tests/test_filter_speed.py"]),
    ("cbf-grown-band-guard", "cosim/paper/cbf_filter/holds.py",
     "if a.hard[0] and reach > a.viable_bounds[0, i] - HOLD:", "if False:", GROWTH),
    # the plan's box inside a step of several holds at the first hold's q̈ throughout
    ("cbf-held-travel-first-order", "cosim/paper/cbf_filter/holds.py",
     "    remains = (1.0 - c) ** holds\n", "    remains = 1.0 - c * holds\n",
     ["tests/test_viability.py"]),
    # a free backup's step at its first hold's q̈ throughout (not the holds' average)
    ("cbf-held-average-dropped", "cosim/paper/cbf_filter/check.py",
     "            held_average(a, h, contraction)\n", "            pass\n",
     ["tests/test_viability.py"]),
    # the payload's departure at the range's ends only (the grid's first and last point)
    ("cbf-payload-ends-only", "cosim/paper/cbf_filter/deviation.py",
     "start, end = weight * s_grid[g, j], weight * s_grid[g + 1, j]",
     "start = end = weight * s_grid[grid, j]", VIABILITY),
    ("cbf-turning-point", "cosim/paper/cbf_filter/check.py",
     "max(abs(q[i] - a.centres[0, i]), abs(turn - a.centres[0, i]))", "abs(q[i] - a.centres[0, i])",
     VIABILITY),
    ("cbf-viable-inside", "cosim/paper/cbf_filter/policy.py",
     "kept = inside(k, a)", "kept = True", VIABILITY),
    # the check holding the whole bound: no half-margin left for the motion between its points
    ("cbf-check-whole-bound", "cosim/paper/cbf_filter/block.py",
     "viable_bounds=joint_bounds * (1.0 - 0.5 * p.bound_margin) / (1.0 - p.bound_margin),",
     "viable_bounds=joint_bounds / (1.0 - p.bound_margin),", VIABILITY),
    ("cbf-torque-clip", "cosim/paper/cbf_filter/policy.py",
     "tau[i] = min(max(tau[i], -a.torque_limit[i]), a.torque_limit[i])", "pass", VIABILITY),
    ("cbf-interval-deviation", "cosim/paper/cbf_filter/interval.py",
     "low[i] = min(low[i], acceleration[i] - TUBE_SAFETY * deviation[i])",
     "low[i] = min(low[i], acceleration[i])", VIABILITY),
    # the velocity's interval about the estimate instead of the envelope's centre; the
    # observer's centre put on its estimate (the old x̂2 ± ε, wider than it need be)
    ("cbf-interval-about-estimate", "cosim/paper/cbf_filter/interval.py",
     "low, high = centre[i] - half, centre[i] + half", "low, high = v[i] - half, v[i] + half",
     VIABILITY),
    ("obs-envelope-centre-estimate", "cosim/paper/observer.py",
     "a.envelope_centre[k, i] = centre", "a.envelope_centre[k, i] = qdot_hat[i]", FILTER),
    # the rollout's model carrying the payload's middle: D taken from 0, or the model unloaded
    ("cbf-payload-range-unshifted", "cosim/paper/cbf_filter/deviation.py",
     "payload_structure(a.payload_low - centre, a.payload_high - centre,",
     "payload_structure(a.payload_low, a.payload_high,", VIABILITY),
    ("cbf-rollout-unloaded", "cosim/paper/cbf_filter/backup.py",
     "model_mass(a.model, 1.0, centre, mass)", "model_mass(a.model, 1.0, 0.0, mass)",
     VIABILITY),
    ("cbf-authority-unscaled", "cosim/paper/cbf_filter/step.py",
     "mu = min(mu, (np.sign(tau[i]) * cap - tau_hard[i]) / (tau[i] - tau_hard[i]))",
     "mu = min(mu, 1.0)", FILTER),
    ("cbf-braking-reserve-ignored", "cosim/paper/cbf_filter/policy.py",
     "    if a.braking_reserve:  # braking within braking_torque first, the limits in reserve",
     "    if False:", FILTER),
    ("cbf-braking-held-not-tried", "cosim/paper/cbf_filter/policy.py",
     "    if reserve and a.braking_reserve:", "    if False:", FILTER),
    ("cbf-startup-policy-ignored", "cosim/paper/cbf_filter/policy.py",
     "unplanned = a.torque_limit if flags[Flag.VIABLE_ONCE] > 0.0 else a.startup_torque",
     "unplanned = a.torque_limit", ["tests/test_robust_safety.py"]),
    ("cbf-rows-left-out-always", "cosim/paper/cbf_filter/groups.py",
     "if scale * (reach[i] + room[i]) < limit + scale * side * base[i]:", "if True:", FILTER),
    # the steps the filter supports (cbf_filter/steps.py): the backup's hold allowed to
    # overshoot, the observer's bound asked only not to grow, its gain G without the
    # velocity set's spread or without the payload range's upper end
    ("steps-backup-overshoot", "cosim/paper/cbf_filter/steps.py",
     'if p.backup == "verified" and p.backup_rate * dt >= 1.0:',
     'if p.backup == "verified" and p.backup_rate * dt >= 2.0:', STEPS),
    ("steps-envelope-share", "cosim/paper/cbf_filter/steps.py",
     "ENVELOPE_SHARE = 0.5", "ENVELOPE_SHARE = 2.0 / 3.0", STEPS),
    ("steps-velocity-box-dropped", "cosim/paper/cbf_filter/steps.py",
     "+ np.abs(slopes) @ velocity_half", "", STEPS),
    ("steps-payload-low-end-only", "cosim/paper/cbf_filter/steps.py",
     "sorted({low, high})", "[low]", STEPS),
    # the premises measured along a run (premises.py): the interval, the tube's room and
    # the motion between samples, each taken more loosely than the check's
    ("premises-interval-doubled", "cosim/paper/premises.py",
     "excess = np.abs(truth - centre) - spread",
     "excess = np.abs(truth - centre) - 2.0 * spread", PREMISES),
    ("premises-tube-room-doubled", "cosim/paper/premises.py",
     "room = allowance[row] - excess", "room = 2.0 * allowance[row] - excess", PREMISES),
    # the plan's tube judged on every row, not only where the plan was followed
    ("premises-plan-rows-all", "cosim/paper/premises.py",
     "judged = np.isfinite(room) & followed[:, None]", "judged = np.isfinite(room)", PREMISES),
    ("premises-between-meet-dropped", "cosim/paper/premises.py",
     "for tau in (meet, first_top, second_top):", "for tau in (first_top, second_top):",
     PREMISES),
    ("premises-rate-cross-dropped", "cosim/paper/premises.py",
     "return np.maximum(ends, np.minimum(v0 + high * cross, v1 - low * (dt - cross)))",
     "return ends", PREMISES),
    # the check's rules an outside audit found the viability tests let through: a joint
    # stopped only moving one way, inside only below the upper velocity bound, the tube's
    # position half-width grown with the control step where the rollout's step is meant,
    # the plan's box contracted by the whole step's feedback at its first hold
    ("cbf-stopped-one-sided", "cosim/paper/cbf_filter/check.py",
     "stopped = stopped and abs(vel[i] - a.centres[1, i] - r[Rollout.TARGET, i]) <= STOPPED",
     "stopped = stopped and (vel[i] - a.centres[1, i] - r[Rollout.TARGET, i]) <= STOPPED", RULES),
    ("cbf-inside-one-sided", "cosim/paper/cbf_filter/interval.py",
     "abs(r[Rollout.CENTRE, i] - a.centres[1, i]) + r[Rollout.HALF, i]",
     "(r[Rollout.CENTRE, i] - a.centres[1, i]) + r[Rollout.HALF, i]", RULES),
    ("cbf-tube-dq-dt-for-h", "cosim/paper/cbf_filter/check.py",
     "dq[i] += h * dv[i] + 0.5 * h * h * widen[i]",
     "dq[i] += h * dv[i] + 0.5 * a.dt * a.dt * widen[i]", RULES),
    ("cbf-plan-box-share-whole", "cosim/paper/cbf_filter/check.py",
     "remains, contracted = held_share(a, s)[:2]", "remains, contracted = held_share(a, h)[:2]",
     RULES),
    ("guarantee-every-hard-set", "cosim/paper/guarantee.py",
     "if c.declared.family in assumes.keeps or c.declared.family not in KEPT_SETS}",
     "if c.declared.family}", ["tests/test_guarantee.py"]),
    # the classifier's comparisons, each a bug an outside audit planted that the tests of
    # the day let through: the start-up's last row, a one-sided reach, the smoothing law
    # compared only where both have Coulomb friction, the drives' budget without the plant's
    # own disturbance, the last joint's rotor skipped, extra parameters read backwards
    ("guarantee-startup-last-row", "cosim/paper/guarantee.py",
     "check.outside[:first + 1].any()", "check.outside[:first].any()", COMPARISONS),
    ("viable-reach-one-sided", "cosim/paper/viable_start.py",
     "reach = np.abs(centre - sets[2]) + spread", "reach = (centre - sets[2]) + spread",
     COMPARISONS),
    ("within-smoothing-both-coulomb", "cosim/paper/within_bounds.py",
     "if (coulomb or table[Friction.COULOMB, i - 1])",
     "if (coulomb and table[Friction.COULOMB, i - 1])", COMPARISONS),
    ("within-drives-budget-whole", "cosim/paper/within_bounds.py",
     "budget = np.maximum(uncertainty.disturbance\n"
     "                        - _disturbance_errors(parameters, tau_d_model, n), 0.0)",
     "budget = np.full(n, float(uncertainty.disturbance))", COMPARISONS),
    ("within-rotor-last-joint", "cosim/paper/within_bounds.py",
     "        for i in range(1, n + 1):", "        for i in range(1, n):", COMPARISONS),
    ("within-extra-parameters-backwards", "cosim/paper/within_bounds.py",
     "extra = [name for name in parameters if name not in modelled]",
     "extra = [name for name in modelled if name not in parameters]", COMPARISONS),
    # the URDF reader's held joints (the same audit)
    ("urdf-held-nearest-limit-dropped", "plant_fmu/urdf.py",
     "fixed.get(joint.name, float(np.clip(0.0, lower, upper)))", "fixed.get(joint.name, 0.0)",
     URDF),
    ("urdf-held-folded-at-given-only", "plant_fmu/urdf.py",
     "joint_motion(joint, held.get(joint.name, 0.0), path)",
     "joint_motion(joint, fixed.get(joint.name, 0.0), path)", URDF),
    ("urdf-prismatic-sign", "plant_fmu/urdf_elements.py",
     "transform[:3, 3] = axis * value", "transform[:3, 3] = -axis * value", URDF),
    ("urdf-held-lower-limit-unchecked", "plant_fmu/urdf.py",
     "if not lower <= value <= upper:", "if not value <= upper:", URDF),
    ("urdf-held-fixed-joint-accepted", "plant_fmu/urdf.py",
     'if name not in by_name or by_name[name].type == "fixed":', "if name not in by_name:", URDF),
    # the evaluation
    ("eval-position-centre", "cosim/evaluate/sets.py",
     '"position": rows["q"] - position_centre,', '"position": rows["q"],', EVALUATION),
    ("eval-theorem1-r", "cosim/paper/theorem.py",
     "safe.error_rate_bound * lmin / (lmin + lmax))", "safe.error_rate_bound * lmin / lmax)",
     EVALUATION),
    ("eval-h1-k0", "cosim/paper/theorem.py",
     "h1 = 0.5 * ((k0 * eps**2 - k0 * x1_err)", "h1 = 0.5 * ((eps**2 - k0 * x1_err)",
     EVALUATION),
    ("eval-h2-sigma", "cosim/paper/theorem.py",
     "+ (sigma_max * r_bound**2 - r_m_r)", "+ (r_bound**2 - r_m_r)", EVALUATION),
    ("eval-satisfied-strict", "cosim/evaluate/checks.py",
     "return (self.value > self.upper) | (self.value < self.lower)",
     "return (self.value > 1.01 * self.upper) | (self.value < self.lower)",
     EVALUATION),
    ("eval-attainable", "cosim/evaluate/checks.py",
     'entry["attainable"] = not bool(((reference > check.upper)',
     'entry["attainable"] = True or bool(((reference > check.upper)', EVALUATION),
    ("eval-guarantee-covered", "cosim/paper/guarantee.py",
     "covered = bool(filtered and starts_inside and start is not None and not outside)",
     "covered = bool(filtered and starts_inside and not outside)", EVALUATION),
    # the run folder
    ("folder-complete-ignores-files", "cosim/outputs/run_folder.py",
     'files_complete = all(f["complete"] for f in self.files.values())',
     "files_complete = True", FOLDER),
    ("folder-no-verification", "cosim/outputs/run_folder.py",
     "            if problem:\n                raise OSError(f\"the written file is {problem}\")\n",
     "", FOLDER),
    # the sweep's statistics
    ("sweep-wilson-variance", "cosim/evaluate/reports.py",
     "math.sqrt(p * (1 - p) / trials", "math.sqrt(p * (1 - p) / (trials + 1)", SWEEP),
    ("sweep-failed-counted", "cosim/sweep/tables.py",
     'low, high = wilson(kept, len(ok))', 'low, high = wilson(kept, len(mine))', SWEEP),
    # export and compare (the gate a user's CI relies on)
    ("compare-regression", "cosim/outputs/compare.py",
     "if held_a and not held_b:", "if held_a and not held_b and False:", RESULTS),
    ("export-csv-digits", "cosim/outputs/export.py", 'fmt="%.17g"', 'fmt="%.9g"', RESULTS),
    # the limits
    ("limit-substeps", "cosim/config/pipeline.py",
     "if substeps > self.simulation.max_plant_substeps:", "if False:", LIMITS),
    ("limit-unpack-size", "cosim/plant/unpack.py",
     "if total > MAX_MEGABYTES * 1e6:\n        return (f\"it unpacks to {total",
     "if False:\n        return (f\"it unpacks to {total", LIMITS),
    ("limit-seed", "cosim/schema.py",
     "Seed = Annotated[int, Field(ge=0)]", "Seed = int", LIMITS),
]


# The editable install's import hook would still find the working tree's packages ahead of
# PYTHONPATH; a sitecustomize (run after the .pth files, in every process the tests start,
# Dask workers included) removes it, so the copy is what every process imports.
SITECUSTOMIZE = """import sys
sys.meta_path[:] = [f for f in sys.meta_path if "editable" not in repr(f).lower()]
"""


def copy_of_head() -> Path:
    folder = Path(tempfile.mkdtemp(prefix="cosim_mutants_"))
    archive = subprocess.run(["git", "archive", "HEAD"], cwd=ROOT, capture_output=True,
                             check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(folder)], input=archive, check=True)
    (folder / ".site").mkdir()
    (folder / ".site" / "sitecustomize.py").write_text(SITECUSTOMIZE)
    return folder


def environment(copy: Path) -> dict[str, str]:
    """Imports from the copy; kernels compile into the copy's own cache (the user's is never
    filled with mutants)."""
    return {**os.environ, "PYTHONPATH": f"{copy / '.site'}{os.pathsep}{copy}",
            "NUMBA_CACHE_DIR": str(copy / ".numba")}


def run_tests(copy: Path, tests: list[str], timeout: float) -> tuple[bool, str]:
    """(True if the tests pass: the mutant survives; the end of pytest's report)."""
    try:
        done = subprocess.run([sys.executable, "-m", "pytest", "-x", "-q", "-p",
                               "no:cacheprovider", *tests], cwd=copy, env=environment(copy),
                              capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return False, f"timed out after {timeout:g} s"
    return done.returncode == 0, "\n".join(done.stdout.splitlines()[-40:])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", default="", help="run the mutants whose id contains this")
    parser.add_argument("--timeout", type=float, default=900.0, help="per mutant, s")
    args = parser.parse_args()
    chosen = [m for m in MUTANTS if args.only in m[0]]
    copy = copy_of_head()
    print(f"{len(chosen)} mutants on a copy of HEAD in {copy}", flush=True)
    survivors, killed = [], 0
    try:
        imported = subprocess.run(
            [sys.executable, "-c", "import cosim, plant_fmu; print(cosim.__file__)"],
            cwd=copy, env=environment(copy), capture_output=True, text=True)
        if not imported.stdout.startswith(str(copy)):
            raise SystemExit(f"the copy is not what Python imports: {imported.stdout.strip()}")
        every = sorted({t for m in chosen for t in m[4]})
        passed, report = run_tests(copy, every, 4 * args.timeout)
        if not passed:  # a mutant is killed by a failure, so the unmutated copy must pass
            raise SystemExit(f"the tests fail on the unmutated copy: fix them first\n{report}")
        print("  unmutated: the tests pass", flush=True)
        for ident, name, text, replacement, tests in chosen:
            path = copy / name
            original = path.read_text()
            if original.count(text) != 1:
                print(f"  {ident}: its text occurs {original.count(text)} times in {name}; "
                      "update the mutant", flush=True)
                survivors.append((ident, "stale mutant"))
                continue
            path.write_text(original.replace(text, replacement))
            start = time.monotonic()
            try:
                survived, _ = run_tests(copy, tests, args.timeout)
            finally:
                path.write_text(original)
            verdict = "SURVIVED" if survived else "killed"
            print(f"  {ident:32s} {verdict:8s} ({time.monotonic() - start:.0f} s)", flush=True)
            if survived:
                survivors.append((ident, f"{name}: {text.strip()!r} -> {replacement.strip()!r}"))
            else:
                killed += 1
    finally:
        subprocess.run(["rm", "-rf", str(copy)], check=False)
    total = killed + len(survivors)
    print(f"\nmutation score: {killed}/{total} = {100 * killed / max(total, 1):.1f} % killed")
    for ident, what in survivors:
        print(f"  survivor {ident}: {what}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
