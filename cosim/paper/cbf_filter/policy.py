"""The decision: which torque the filter applies. The QP's answer (clipped to the torque
limits, or the controller's where the QP's hard rows are not met within them) if the
braking backup can still keep every hard set after it (:func:`.check.verified`), else the
largest verified blend towards the backup, else the plan in force or the backup itself;
with ``braking_torque`` below the limits, all that first with the backup within it
(docs/safety/filter.md, "How hard the backup brakes")."""

from __future__ import annotations

from ...numba_compat import no_refcount_jit
from .backup import backup_at
from .check import verified
from .groups import groups_violated
from .interval import inside
from .scratch import Authority, Flag, Rollout

# Bisections of the blend between the QP's torque and the backup's, where the QP's alone is
# not verified: the blend found is within 2⁻⁴ of the largest verified one.
BISECTIONS = 4
# The backup's policies tried (cosim.paper.cbf_filter.backup.backup_torque): every joint
# alike, then the joints near their position bound first. A torque is verified if the backup
# can follow it under either: each is a way back, so either keeps the state viable.
POLICIES = 2


@no_refcount_jit(cache=True, inline="always")
def verified_policy(k, a, tau, limit):
    """The first backup policy under which ``tau``, held for the step, is verified with the
    backup within the torques ``limit`` (:func:`.check.verified`), else −1."""
    y, v, eps = a.position[k], a.work.rollout[Rollout.CENTRE], a.work.rollout[Rollout.HALF]
    for policy in range(POLICIES):
        if verified(k, a, y, v, eps, tau, True, policy, limit):
            return policy
    return -1


@no_refcount_jit(cache=True, inline="always")
def planned_with(a, policy, reserve):
    """Keeps the plan of the torque verified: its backup policy, and whether that backup
    brakes within the torque limits (1) or within braking_torque (0)."""
    a.work.flags[Flag.PLAN] = policy
    a.work.flags[Flag.PLAN_RESERVE] = 1.0 if reserve else 0.0


@no_refcount_jit(cache=True, inline="always")
def blend_verified(k, a, tau, limit, reserve):
    """With the backup within the torques ``limit`` (the torque limits if ``reserve``, else
    braking_torque): 0 if ``tau`` is verified (kept as it is), else the backup's share
    1 − λ of the torque verified (into ``tau``): with the limits in reserve, the backup
    within braking_torque held for the step (1), else the blend τ_b + λ(τ − τ_b) with the
    largest λ found by bisection; else (no verified torque) −1. The plan of the torque
    verified is kept (:func:`planned_with`)."""
    n = tau.shape[0]
    found = verified_policy(k, a, tau, limit)
    if found >= 0:
        planned_with(a, found, reserve)
        return 0.0
    backup = a.backup
    # With the limits in reserve, the backup within braking_torque is applied where it is
    # verified (held for the step, then the backup within the limits): the state is braked
    # back into where braking_torque keeps it, not held at the edge of where the limits do
    # (where the estimate's next move would call for all of them).
    y, v, eps = a.position[k], a.work.rollout[Rollout.CENTRE], a.work.rollout[Rollout.HALF]
    if reserve and a.braking_reserve:
        for policy in range(POLICIES):
            backup_at(k, a, policy, a.braking_torque, backup)
            if verified(k, a, y, v, eps, backup, True, policy, limit):
                for i in range(n):
                    tau[i] = backup[i]
                planned_with(a, policy, True)
                return 1.0
    for policy in range(POLICIES):
        backup_at(k, a, policy, limit, backup)
        if verified(k, a, y, v, eps, backup, True, policy, limit):
            found = policy
            break
    if found < 0:
        return -1.0
    candidate = a.work.rollout[Rollout.CANDIDATE]
    low, high = 0.0, 1.0  # λ = low is verified
    for _ in range(BISECTIONS):
        middle = 0.5 * (low + high)
        for i in range(n):
            candidate[i] = backup[i] + middle * (tau[i] - backup[i])
        if verified(k, a, y, v, eps, candidate, True, found, limit):
            low = middle
        else:
            high = middle
    for i in range(n):
        tau[i] = backup[i] + low * (tau[i] - backup[i])
    planned_with(a, found, reserve)
    return 1.0 - low


@no_refcount_jit(cache=True, inline="always")
def choose(k, a, tau):
    """The torque to apply, into ``tau``: the QP's answer clipped to the torque limits (the
    controller's, clipped, where the QP's hard rows are not met within the limits), itself
    if the backup can still keep every hard set after it (:func:`.check.verified`), else
    the verified blend τ_b + λ(τ − τ_b) with the largest λ found by bisection, each backup
    policy tried in turn; where braking_torque is below the limits, all that first with the
    backup within it (the plan followed if it needs no more), then with the limits (the
    torque, the backup within braking_torque held for the step, the blend). With no torque
    verified: the plan if there is one; else (not viable as seen) the backup within the
    limits. Viable: a torque verified, and every state the bounds allow inside the hard sets (else
    the verified torque brings the state back: recovery). Returns (viable, the backup's
    share 1 − λ). Without ``verify``: the QP's answer, viable where its hard rows hold as
    given."""
    n = tau.shape[0]
    a.planned[k] = 0.0  # set where the plan in force is followed
    for i in range(n):
        tau[i] = min(max(tau[i], -a.torque_limit[i]), a.torque_limit[i])
    # The hard rows as given: the groups' (every payload corner's, among the QP's rows or
    # not); the torque limits' rows the clip above meets.
    if not a.verify:
        return not groups_violated(a, tau), 0.0
    answer = a.work.authority[Authority.ANSWER]  # free here (cbf_step is done with it)
    substituted = a.torque_limited and groups_violated(a, tau)
    if substituted:
        # The hard rows are not met within the torque limits: the QP's answer is a penalty
        # compromise, most often every limit spent braking, with no standing of its own
        # (what keeps the sets is the check below). The controller's torque is tried in its
        # place, the backup's blend towards it where it is not verified; the QP's answer
        # itself last.
        for i in range(n):
            answer[i] = tau[i]
            tau[i] = min(max(a.tau_nominal[k, i], -a.torque_limit[i]), a.torque_limit[i])
    kept = inside(k, a)  # else verified means recovering: not viable
    flags = a.work.flags
    # If the step before was viable, its check proved the backup from every state its tube
    # allows, and the state is in that tube when the velocity is where it predicted
    # (Flag.CONSISTENT): the backup, as planned, is still viable. The plan is followed where no
    # torque is verified afresh, and where the interval the filter now holds pokes past a
    # set (a torque verified from it would prove a recovery, not that the sets are kept).
    planned = k > 0 and a.viable[k - 1] > 0.0 and flags[Flag.CONSISTENT] > 0.0
    plan = a.torque_limit if flags[Flag.PLAN_RESERVE] > 0.0 else a.braking_torque
    if not kept and planned:
        backup_at(k, a, int(flags[Flag.PLAN]), plan, tau)
        a.planned[k] = 1.0
        return True, 1.0
    braking = a.braking_torque
    if a.braking_reserve:  # braking within braking_torque first, the limits in reserve
        share = blend_verified(k, a, tau, braking, False)
        if share >= 0.0:
            return kept, share
        if planned and flags[Flag.PLAN_RESERVE] == 0.0:  # the plan needs no reserve
            backup_at(k, a, int(flags[Flag.PLAN]), braking, tau)
            a.planned[k] = 1.0
            return True, 1.0
    share = blend_verified(k, a, tau, a.torque_limit, True)
    if share >= 0.0:
        return kept, share
    if substituted:
        policy = verified_policy(k, a, answer, a.torque_limit)
        if policy >= 0:
            for i in range(n):
                tau[i] = answer[i]
            planned_with(a, policy, True)
            return kept, 0.0
    # No torque verified afresh: the plan, viable if planned (a check from a state on the
    # edge of the verified set may fail by the rollout's own discretisation); else not
    # viable as seen: the backup all the same, within the limits (within braking_torque
    # instead, more starts not viable left a set: docs/safety/measurements.md). (The plan's check
    # covered its tube, so the state need not be shown inside anew: the interval the
    # filter holds may be wider than the tube the plan was verified with, as it is what
    # the filter knows, not where the plan keeps the state.)
    # Before the first viable step (start-up), within the declared startup_torque.
    unplanned = a.torque_limit if flags[Flag.VIABLE_ONCE] > 0.0 else a.startup_torque
    backup_at(k, a, int(flags[Flag.PLAN]), plan if planned else unplanned, tau)
    a.planned[k] = 1.0 if planned else 0.0
    return planned, 1.0
