"""What a safety check is, declared once, and what "safe" means: one function of it.

A :class:`Declaration` names a family of checks (``position``), the quantity it bounds, its
SI unit and its :class:`Kind`; :meth:`Declaration.joints_and_norm` makes one
:class:`Check` per joint (``position_joint1`` … ``position_jointN``) and one of the norm
(``position_norm``). Every reader of a run's checks (the run table and summary.md, the
verdict, the figures and the Rerun layout, the trace's units, the sweep's columns and
tables, ``cosim compare`` and the filter's guarantee) reads these declarations, through the
entries :func:`safety_entries` writes into summary.json, and decides "safe" only through
:func:`left_sets` / :func:`is_safe` / :func:`kept`.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from enum import StrEnum

import numpy as np


class Kind(StrEnum):
    """What a check's set is, and so whether it counts in the verdict."""

    HARD = "hard"  # a physical set on the true state, per joint: what a safety filter keeps
    SOFT = "soft"  # a tracking or estimation set, or a norm of a physical one: reported
    SUFFICIENT = "sufficient"  # a sufficient condition for other sets: shown, not a verdict


# The kinds whose sets a run must keep to be called safe.
VERDICT_KINDS = frozenset({Kind.HARD, Kind.SOFT})


@dataclass(frozen=True)
class Declaration:
    """A family of checks: ``family`` (the stem of each check's name), ``quantity`` (what
    is bounded, in words and the paper's symbols), ``unit`` (SI), the :class:`Kind` of the
    per-joint checks and of the norm, and ``figure``: the figure and Rerun view it is drawn
    in ("" for none; checks sharing a figure are drawn side by side, in declaration order)."""

    family: str
    quantity: str
    unit: str
    kind: Kind
    norm_kind: Kind = Kind.SOFT
    figure: str = ""

    def name(self, joint: int | None) -> str:
        """``<family>_joint<j>`` (1-based), or ``<family>_norm``."""
        return f"{self.family}_norm" if joint is None else f"{self.family}_joint{joint}"

    def joints_and_norm(self, signal: np.ndarray, bound: float,
                        reference: np.ndarray | None = None) -> dict[str, Check]:
        """One check per joint of ``signal`` (rows × joints, signed, within ±bound) and one
        of its Euclidean norm (within [0, bound]); ``reference``: the same quantity for the
        reference trajectory."""
        out = {self.name(j + 1): Check(signal[:, j], bound, -bound,
                                       None if reference is None else reference[:, j],
                                       self, j + 1)
               for j in range(signal.shape[1])}
        out[self.name(None)] = self.norm(np.linalg.norm(signal, axis=1), bound,
                                         None if reference is None
                                         else np.linalg.norm(reference, axis=1))
        return out

    def joints(self, signal: np.ndarray, bounds: np.ndarray,
               reference: np.ndarray | None = None,
               centres: np.ndarray | None = None) -> dict[str, Check]:
        """One check per joint j of ``signal`` (rows × joints, signed, within ±bounds[j]) and
        no norm: a box of per-joint bounds (a robot's own joint limits) has none that means
        anything. ``centres``: each set's centre, where signal + centre is what the robot's
        limits bound (a joint's position between its lower and upper limit)."""
        return {self.name(j + 1): Check(signal[:, j], float(bounds[j]), -float(bounds[j]),
                                        None if reference is None else reference[:, j],
                                        self, j + 1,
                                        None if centres is None else float(centres[j]))
                for j in range(signal.shape[1])}

    def norm(self, value: np.ndarray, bound: float,
             reference: np.ndarray | None = None) -> Check:
        """The norm check alone: ``value`` ≥ 0 within [0, bound]."""
        return Check(value, bound, 0.0, reference, self, None)

    def kind_of(self, joint: int | None) -> Kind:
        return self.norm_kind if joint is None else self.kind


def family_of(check: str) -> str:
    """The family of a check named by :meth:`Declaration.name` (``position_joint2`` ->
    ``position``)."""
    stem, joint, number = check.rpartition("_joint")
    if joint and number.isdigit():
        return stem
    return check.removesuffix("_norm")


@dataclass
class Check:
    """One check's values over rows: ``value`` must stay within [lower, upper]. A joint
    check's value is signed (x1,j − q_s,j, say) with lower = −upper, so the figures show the
    signal itself against its band; a norm check's value is ≥ 0 with lower = 0.
    ``declared``/``joint``: what it is (every check an evaluator makes has them)."""

    value: np.ndarray
    upper: float
    lower: float
    reference: np.ndarray | None = None  # the same quantity for the reference trajectory
    declared: Declaration | None = None
    joint: int | None = None
    # the set's centre where value + centre is the quantity a limit bounds (a URDF joint's
    # position, shown against its lower and upper limit), None where the set is its own
    centre: float | None = None

    @property
    def magnitude(self) -> np.ndarray:
        return np.abs(self.value)

    @property
    def outside(self) -> np.ndarray:
        """Per row, whether the value is outside [lower, upper] (a NaN row is not known to
        be)."""
        return (self.value > self.upper) | (self.value < self.lower)

    @property
    def label(self) -> str:
        """The quantity with its joint or "norm" and unit, for axes and tables."""
        if self.declared is None:
            return ""
        where = "norm" if self.joint is None else f"joint {self.joint}"
        return f"{self.declared.quantity}, {where} ({self.declared.unit})"


def excursions(check: Check, dt: float) -> dict[str, float | None]:
    """When the check is first violated (s; None if never) and for how long in all (s)."""
    outside = check.outside
    first = np.flatnonzero(outside)
    return {"first_violation_s": float(first[0] * dt) if len(first) else None,
            "time_outside_s": float(np.count_nonzero(outside) * dt)}


def _declared(check: Check) -> dict:
    """What summary.json says a check is (its declaration, and its joint or "norm")."""
    d = check.declared
    if d is None:
        return {}
    return {"quantity": d.quantity, "unit": d.unit, "kind": str(d.kind_of(check.joint)),
            "joint": "norm" if check.joint is None else check.joint, "family": d.family,
            "figure": d.figure}


def safety_entries(checks: Mapping[str, Check], dt: float) -> dict:
    """summary.json's ``safety``: per check what it is (quantity, unit, kind, joint), its
    bound, worst value, whether it held, when it was first left and for how long, and the
    reference's own worst value with whether the set is attainable."""
    safety = {}
    for name, check in checks.items():
        entry = {**_declared(check), "bound": float(check.upper)}
        if not len(check.value):  # the run stopped at its first row: nothing is known
            safety[name] = {**entry, "worst": None, "satisfied": None,
                            "unavailable": "the run completed no row"}
            continue
        if np.isnan(check.value).all():
            # Only the ground-truth velocity can be missing: a plant without a qdot mapping.
            safety[name] = {**entry, "worst": None, "satisfied": None,
                            "unavailable": "needs the true joint velocity: the plant maps "
                            "no qdot"}
            continue
        # worst: the largest |value| over the rows that hold one; kept: no row outside
        # [lower, upper] (one test, that the excursions and the recording share)
        known = np.isfinite(check.value)
        worst = float(np.max(check.magnitude[known]))
        entry.update(worst=worst, satisfied=not bool(check.outside.any()),
                     **excursions(check, dt))
        if check.centre is not None:  # the quantity itself, against the limits themselves
            entry.update(limits=[check.lower + check.centre, check.upper + check.centre],
                         range=[float(np.min(check.value[known])) + check.centre,
                                float(np.max(check.value[known])) + check.centre])
        if not known.all():
            entry["rows_unknown"] = int(np.count_nonzero(~known))
        if check.reference is not None and len(check.reference):
            entry["reference_worst"] = float(np.max(np.abs(check.reference)))
            # A set the reference itself leaves cannot be kept by any controller that tracks.
            reference = check.reference
            entry["attainable"] = not bool(((reference > check.upper)
                                            | (reference < check.lower)).any())
        safety[name] = entry
    return safety


# Reading summary.json's entries: the one definition of "safe" ---------------------------

def kind(entry: Mapping) -> Kind:
    """A summary entry's kind (an entry written without one is a soft set)."""
    return Kind(entry.get("kind", Kind.SOFT))


def unit(entry: Mapping) -> str:
    return entry.get("unit", "")


def is_left(entry: Mapping) -> bool:
    """The run left this set, and some controller could have kept it (the reference
    stays inside)."""
    return (entry.get("worst") is not None and entry.get("satisfied") is False
            and entry.get("attainable") is not False)


def left_sets(safety: Mapping[str, Mapping], kinds: Iterable[Kind] = VERDICT_KINDS
              ) -> list[tuple[str, Mapping]]:
    """The attainable sets of ``kinds`` a run left, earliest first."""
    kinds = frozenset(kinds)
    left = [(name, e) for name, e in safety.items() if kind(e) in kinds and is_left(e)]
    return sorted(left, key=lambda item: item[1].get("first_violation_s") or 0.0)


def is_safe(safety: Mapping[str, Mapping]) -> bool:
    """Safe: kept every attainable hard and soft set, every joint and norm (a sufficient
    condition exceeded, or a set the reference itself leaves, does not count)."""
    return not left_sets(safety)


def kept(safety: Mapping[str, Mapping], kinds: Iterable[Kind]) -> bool:
    """Kept every set of ``kinds``, attainable or not (the hard sets a filter guarantees:
    ``kept(safety, [Kind.HARD])``)."""
    kinds = frozenset(kinds)
    return all(e.get("satisfied") is not False for e in safety.values() if kind(e) in kinds)
