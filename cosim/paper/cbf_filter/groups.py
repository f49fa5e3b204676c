"""The hard rows of one step's QP in groups: a joint's side of a hard set, now or at the
hold's end, with a row per payload corner (unscaled), robust to the declared uncertainty
(see the package docstring); the solve takes rows from them as it needs them (cutting
planes, :func:`add_cuts`), and :func:`groups_record` says which bind and how close each
comes; :func:`payload_corners`, the payload grid's box corners a group's rows are taken
at. :mod:`.rows` builds a step's QP around them."""

from __future__ import annotations

import numpy as np

from ...numba_compat import no_refcount_jit
from ..linalg import dot
from .model import robust_model
from .scratch import Flag, GroupLabel, GroupValue, PointRow, PointVector, Vector
from .solver import add_row


@no_refcount_jit(cache=True)
def hard_groups(a, k, y, v, eps, minv, base, at_end):
    """The hard rows of row k in groups (one per joint, side and hard set; a row per payload
    corner: g_c = g_0 + Σ_j s_cj u_j, h_c = h_0 + Σ_j s_cj o_j, scratch.py's CbfWork), with
    the model (M̂, b̂, the payload's structure, the bias error) evaluated at (y, v) and the
    barriers at row k's state, appended to the groups already made at this step. The rows
    themselves are made only where needed (:func:`add_cuts`, or all of them:
    :func:`.rows.cbf_rows`). ``at_end``: the conditions at the end of the hold instead, at a
    predicted (y, v): a held τ must keep them there too, and q̈ drifts over a hold fast where
    M̂ is ill-conditioned and τ large. With q(dt) = q + dt q̇ + ½dt² q̈ and
    q̇(dt) = q̇ + dt q̈, a condition at the end weighs q̈ by 1 + k dt (velocity) or
    1 + 2p dt + ½p² dt² (position) and the position's by p² dt q̇."""
    n = y.shape[0]
    w = a.work
    vectors = w.vectors
    corners = robust_model(a, y, v, eps, minv, base)
    rows_error, plant_shift = vectors[Vector.ROWS_ERROR], vectors[Vector.PLANT_SHIFT]
    reach, room = vectors[Vector.REACH], vectors[Vector.ROOM]
    _reach(a, minv, corners, reach, room)
    phase = 1 if at_end else 0
    s_grid = w.s_grid
    for g in range(s_grid.shape[0]):
        for j in range(s_grid.shape[1]):
            w.s_phase[phase, g, j] = s_grid[g, j]
    terms = s_grid.shape[1] if corners > 1 else 0
    alpha, beta = w.point_rows[PointRow.ALPHA], w.point_vectors[PointVector.BETA]
    y0, v0, dt = a.position[k], a.velocity[k], a.dt
    for s in range(2):
        if not a.hard[s]:
            continue
        for i in range(n):
            for side in (1.0, -1.0):
                # side·q̈_i ≤ limit for every q, q̇ within the bounds
                if s == 0:
                    h = a.joint_bounds[0, i] - side * (y0[i] - a.centres[0, i])
                    limit = a.k0 * (h - a.noise_bound) - a.k1 * (side * v0[i] + eps[i])
                    scale = 1.0 + a.k1 * dt + 0.5 * a.k0 * dt * dt if at_end else 1.0
                    if at_end:
                        limit -= a.k0 * dt * side * v0[i]
                else:
                    # The true h is ≥ 0 until the set is first left (by induction) and at
                    # least h − ε: its worst case is max(h − ε, 0), not h − ε. So an estimate
                    # that may lie outside asks only "do not approach", not recovery at rate
                    # k from a state the plant may not be in.
                    h = a.joint_bounds[1, i] - side * (v0[i] - a.centres[1, i])
                    limit = a.k_velocity * max(h - eps[i], 0.0)
                    scale = 1.0 + a.k_velocity * dt if at_end else 1.0
                limit -= scale * rows_error[i]
                if corners == 1:
                    limit -= scale * max(-a.payload_low * side * plant_shift[i],
                                         -a.payload_high * side * plant_shift[i])
                # no torque within the limits could violate any corner's row: left out
                if scale * (reach[i] + room[i]) < limit + scale * side * base[i]:
                    continue
                g = int(w.flags[Flag.GROUPS])
                w.flags[Flag.GROUPS] = g + 1
                rows, values, labels = w.group_rows[g], w.group_values[g], w.group_labels[g]
                for col in range(n):
                    rows[0, col] = scale * side * minv[i, col]
                values[GroupValue.H_ZERO] = limit + scale * side * base[i]
                values[GroupValue.NORM_BOUND] = np.sqrt(dot(rows[0], rows[0]))
                for j in range(terms):
                    coefficient = scale * side * alpha[j, i]
                    for col in range(n):
                        rows[1 + j, col] = -coefficient * alpha[j, col]
                    values[GroupValue.OFFSETS + j] = coefficient * beta[j]
                    # s_j increases with the payload: its largest |s_j| at an end
                    values[GroupValue.NORM_BOUND] += max(abs(s_grid[0, j]), abs(s_grid[-1, j])) \
                        * np.sqrt(dot(rows[1 + j], rows[1 + j]))
                labels[GroupLabel.SET], labels[GroupLabel.JOINT] = s, i
                labels[GroupLabel.PHASE] = phase
                labels[GroupLabel.CORNERS] = corners
                w.group_added[g, :corners] = False


@no_refcount_jit(cache=True)
def _group_terms(a, g, tau, terms):
    """Group g's g_0·τ − h_0 and u_j·τ − o_j at τ, into ``terms`` (1 + d); returns the number
    of u_j it has (0 without a payload range)."""
    w = a.work
    rows, values = w.group_rows[g], w.group_values[g]
    count = w.s_phase.shape[2] if w.group_labels[g, GroupLabel.CORNERS] > 1 else 0
    terms[0] = dot(rows[0], tau) - values[GroupValue.H_ZERO]
    for j in range(count):
        terms[1 + j] = dot(rows[1 + j], tau) - values[GroupValue.OFFSETS + j]
    return count


@no_refcount_jit(cache=True)
def _corner_excess(a, g, c, terms, count):
    """Corner c's g_c·τ − h_c (unscaled), from group g's terms at τ (:func:`_group_terms`)."""
    w = a.work
    phase = w.group_labels[g, GroupLabel.PHASE]
    excess = terms[0]
    for j in range(count):
        excess += w.s_phase[phase, w.corner_index[c, j], j] * terms[1 + j]
    return excess


@no_refcount_jit(cache=True)
def _most_excess(a, g, terms, count):
    """The most any corner of group g may exceed its limit at τ (unscaled): every corner's
    s_cj lies between the grid's ends, so a sum of each term's largest over them."""
    w = a.work
    s_phase = w.s_phase[w.group_labels[g, GroupLabel.PHASE]]
    most = terms[0]
    for j in range(count):
        most += max(s_phase[0, j] * terms[1 + j], s_phase[-1, j] * terms[1 + j])
    return most


@no_refcount_jit(cache=True)
def _corner_row(a, g, c, row):
    """Group g's corner c: g_c (unscaled) into ``row``; returns h_c."""
    w = a.work
    rows, values, labels = w.group_rows[g], w.group_values[g], w.group_labels[g]
    n = row.shape[0]
    for col in range(n):
        row[col] = rows[0, col]
    limit = values[GroupValue.H_ZERO]
    if labels[GroupLabel.CORNERS] > 1:
        for j in range(w.s_phase.shape[2]):
            s = w.s_phase[labels[GroupLabel.PHASE], w.corner_index[c, j], j]
            for col in range(n):
                row[col] += s * rows[1 + j, col]
            limit += s * values[GroupValue.OFFSETS + j]
    return limit


@no_refcount_jit(cache=True)
def add_corner(a, count, g, c):
    """Row ``count`` of the QP: group g's corner c (scaled to unit norm by add_row); returns
    the next row's index."""
    w = a.work
    row = w.vectors[Vector.ROW]
    limit = _corner_row(a, g, c, row)
    w.group_added[g, c] = True
    qp = (a.rows, a.limits, a.weights, a.is_hard, a.kinds, a.joints)
    return add_row(qp, count, row, limit, a.rho_hard, True, w.group_labels[g, GroupLabel.SET],
                   w.group_labels[g, GroupLabel.JOINT])


@no_refcount_jit(cache=True, inline="always")
def add_cuts(a, count, tau):
    """Appends to the QP's first ``count`` rows every hard row of the groups not among them
    with g_c·τ − h_c > −hard_tolerance × (a bound on ‖g_c‖): at least every one that τ
    violates with its limit lowered by hard_tolerance (as the QP has it, scaled to unit
    norm), flagged as binding, with its lowered limit and weight in the solver's
    (``work.per_row``); returns the new count. A row left out is then met at τ with the
    tolerance to spare: a τ minimising the penalty form over the rows in it, where none
    left out adds to it, minimises it over all of them."""
    w = a.work
    terms = w.group_values[-1]  # the last row: scratch
    lowered, weights = w.per_row[0], w.per_row[1]
    for g in range(int(w.flags[Flag.GROUPS])):
        terms_count = _group_terms(a, g, tau, terms)
        room = -a.hard_tolerance * w.group_values[g, GroupValue.NORM_BOUND]
        if not _most_excess(a, g, terms, terms_count) > room:
            continue
        for c in range(w.group_labels[g, GroupLabel.CORNERS]):
            if w.group_added[g, c] or not _corner_excess(a, g, c, terms, terms_count) > room:
                continue
            count = add_corner(a, count, g, c)
            lowered[count - 1] = a.limits[count - 1] - a.hard_tolerance
            weights[count - 1] = a.weights[count - 1]
            w.binding[count - 1] = True
    return count


@no_refcount_jit(cache=True)
def groups_violated(a, tau):
    """Whether τ violates any hard row of the groups as given (its limit not lowered)."""
    terms = a.work.group_values[-1]
    for g in range(int(a.work.flags[Flag.GROUPS])):
        count = _group_terms(a, g, tau, terms)
        if not _most_excess(a, g, terms, count) > 0.0:
            continue
        for c in range(a.work.group_labels[g, GroupLabel.CORNERS]):
            if _corner_excess(a, g, c, terms, count) > 0.0:
                return True
    return False


@no_refcount_jit(cache=True, inline="always")
def groups_record(k, a, tau):
    """Row k's activity of the hard rows in groups under τ: each row within twice the
    hard_tolerance of its limit (scaled to unit norm, as the QP has it) binds, and marks its
    set and joint active. Returns (whether every one is met as given, how many bind)."""
    w = a.work
    terms, row = w.group_values[-1], w.vectors[Vector.ROW]
    met, active = True, 0
    for g in range(int(w.flags[Flag.GROUPS])):
        count = _group_terms(a, g, tau, terms)
        room = -2.0 * a.hard_tolerance * w.group_values[g, GroupValue.NORM_BOUND]
        if not _most_excess(a, g, terms, count) > room:
            continue
        labels = w.group_labels[g]
        for c in range(labels[GroupLabel.CORNERS]):
            excess = _corner_excess(a, g, c, terms, count)
            if not excess > room:
                continue
            met = met and not excess > 0.0
            norm = _corner_norm(a, g, c, row)
            if excess > -2.0 * a.hard_tolerance * norm:
                active += 1
                a.active_sets[labels[GroupLabel.SET], k, labels[GroupLabel.JOINT]] = 1.0
    return met, active


@no_refcount_jit(cache=True)
def _corner_norm(a, g, c, row):
    """‖g_c‖ of group g's corner c (1 for a row without τ, as add_row takes it), ``row`` its
    scratch."""
    _corner_row(a, g, c, row)
    norm = np.sqrt(dot(row, row))
    return norm if norm > 0.0 else 1.0


@no_refcount_jit(cache=True)
def _reach(a, minv, corners, reach, room):
    """Per joint i, what decides whether its hard rows can bind within the torque limits
    (hard_groups leaves out those that cannot): into ``reach`` the most any payload corner's
    row g·τ (unscaled) reaches over the box |τ| ≤ τ_max, with 0.1 % and 1e-3 N·m beyond it
    to spare (the solver's τ meets its limits to its tolerance); into ``room`` the most the
    corners lower the row's limit. Infinite with unlimited torque: then nothing is left out.
    Leaving rows out changes no answer within the limits; where the hard rows and the limits
    conflict (no torque in the box meets them all) the penalty form's compromise may move,
    and the check decides."""
    alpha, beta = a.work.point_rows[PointRow.ALPHA], a.work.point_vectors[PointVector.BETA]
    s_grid, n = a.work.s_grid, minv.shape[0]
    for i in range(n):
        largest, spread, lowered = 0.0, 0.0, 0.0  # spread: a bound on ‖g‖₁
        for col in range(n):
            largest += abs(minv[i, col]) * a.torque_limit[col]
            spread += abs(minv[i, col])
        if corners > 1:  # s_j increases with the payload: its largest |s_j| at an end
            for j in range(alpha.shape[0]):
                weight = abs(alpha[j, i]) * max(abs(s_grid[0, j]), abs(s_grid[-1, j]))
                lowered += weight * abs(beta[j])
                for col in range(n):
                    largest += weight * abs(alpha[j, col]) * a.torque_limit[col]
                    spread += weight * abs(alpha[j, col])
        reach[i] = largest * 1.001 + 1e-3 * spread
        room[i] = lowered


def payload_corners(grid: int, d: int) -> np.ndarray:
    """The grid points (of s_1 … s_d) of the box corners the payload's rows are taken at:
    s_j increases with Δm, so between two grid points (s_1 … s_d) lies in their box: its
    corner (g, …, g), then its 2^d − 2 mixed corners ((g, g+1), (g+1, g) in the plane); the
    last grid point's at the end. (2^d − 1) grid + 1 corners."""
    corner_index = np.zeros(((2**d - 1) * grid + 1, d), np.int64)
    corners = 0
    for g in range(grid + 1):
        corner_index[corners, :] = g
        corners += 1
        if g < grid:
            for mask in range(2**d - 2, 0, -1):  # coordinate j at g + bit j of the mask
                for j in range(d):
                    corner_index[corners, j] = g + ((mask >> j) & 1)
                corners += 1
    return corner_index
