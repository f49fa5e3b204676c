"""What goes where in the recording, and how it looks: pure functions, no Rerun I/O.

Layout (one subtree per run; one timeline, ``sim_time``, in seconds; SI units, radians):

    /<run>/<entity of each declared signal>      e.g. plant/q, observer/qdot_hat, controller/e
    /<run>/plant/tau                            the torque applied to the plant
    /<run>/<parent>/<true>_err                  true minus estimate for a signal that
                                                estimates another, beside the estimate's
                                                own entity (observer/q_hat -> observer/q_err)
    /<run>/safety/<family>/{value, upper, lower}  a series per check: every joint, the norm
    /<run>/safety/<family>/violation/<check>
    /<run>/barrier/{H1, H2, H}
    /<run>/barrier_condition                     Ḣ + α·H where it fails (< 0): first row
                                                of each stretch, then every 10 ms
    /<run>/arm/{links, joints, desired}         the planar arm, drawn at 50 Hz
    /<run>/arm3d/...                            an arm read from a URDF, in 3-D, at 50 Hz
                                                (:mod:`.arm3d`), instead of the planar one

Multi-joint signals are one entity with series ``<label>1``, ``<label>2``, … in the same
colours in every run, and so are a check family's joints (its norm in grey). Constant bounds
are two rows (start and end of the run). ``violation`` holds the value at the rows where it
leaves its bound: its first row, then every 10 ms.
"""

from __future__ import annotations

from collections.abc import Collection, Iterable, Iterator, Mapping
from dataclasses import dataclass, field

import numpy as np

from ...evaluate.checks import Declaration
from ...signals import Signal

# One colour per joint, the same in every run (matplotlib's tab10).
JOINT_COLORS = [(31, 119, 180), (255, 127, 14), (44, 160, 44), (148, 103, 189),
                (140, 86, 75), (227, 119, 194), (127, 127, 127)]
BOUND_COLOR = (0, 150, 60)
NORM_COLOR = (90, 90, 90)
VIOLATION_COLOR = (220, 20, 20)
REFERENCE_COLOR = (120, 120, 120)
ARM_RATE_HZ = 50.0  # the arm drawing does not need 1 kHz
VIOLATION_RATE_HZ = 100.0

def derived_entities(signals: Mapping[str, Signal], present: Collection[str]
                     ) -> dict[str, tuple[str, str, str]]:
    """entity -> (true, estimate, stem) of the estimation errors a run can record: for each
    recorded signal that ``estimates`` another, both ``present`` (produced, or a plant
    output the plant maps), the error true − estimate beside the estimate's own entity
    (observer/q_hat -> observer/q_err)."""
    out = {}
    for estimate, signal in signals.items():
        true = signal.estimates
        if signal.entity and true and true in present and estimate in present:
            parent = signal.entity.rpartition("/")[0]
            stem = f"{true}_err"
            out[f"{parent}/{stem}" if parent else stem] = (true, estimate, stem)
    return out


def check_views(declarations: Iterable[Declaration]) -> list[tuple[str, str]]:
    """(view title, family) of each declared family drawn in a figure, grouped by figure
    in declaration order: a family's entity holds every joint's check and the norm's."""
    drawn = [d for d in declarations if d.figure]
    figures = list(dict.fromkeys(d.figure for d in drawn))
    return [(f"{d.quantity}, every joint and the norm ({d.unit})", d.family)
            for figure in figures for d in drawn if d.figure == figure]


@dataclass(frozen=True)
class UrdfArm:
    """An arm the recording draws in 3-D from its URDF."""

    path: str  # the URDF file
    joints: tuple[str, ...]  # the URDF names of the plant's joints, q's columns in order
    held: dict[str, float] = field(default_factory=dict)  # joints the plant holds, rad or m


@dataclass
class RunSpec:
    """What the writer needs to know of one run before its rows arrive."""

    name: str
    links: int
    dt: float
    duration: float
    entities: dict[str, tuple[str, str, int]]  # entity -> (trace key, series stem, width)
    bounds: dict[str, tuple[float, float]]  # check -> (lower, upper)
    link_lengths: np.ndarray
    barriers: tuple[str, ...] = ()  # the barrier series evaluated (H1, H2, H; none without)
    # the derived_entities the run records (none without an observer)
    derived: dict[str, tuple[str, str, str]] = field(default_factory=dict)
    # check -> (its family, its joint or None for the norm): a family's checks are one
    # entity, a series each
    check_families: dict[str, tuple[str, int | None]] = field(default_factory=dict)
    urdf: UrdfArm | None = None  # drawn in 3-D from its URDF, else as a planar chain

    def family(self, check: str) -> str:
        return self.check_families.get(check, (check, None))[0]

    def families(self) -> dict[str, list[str]]:
        """Family -> its checks, in their order (a check without a family is its own)."""
        out: dict[str, list[str]] = {}
        for check in self.bounds:
            out.setdefault(self.family(check), []).append(check)
        return out

    def color(self, check: str) -> tuple[int, int, int]:
        """A joint's check in that joint's colour, a norm in grey."""
        joint = self.check_families.get(check, (check, None))[1]
        return NORM_COLOR if joint is None else JOINT_COLORS[(joint - 1) % len(JOINT_COLORS)]


def violations(values: Mapping[str, np.ndarray], bounds: Mapping[str, tuple[float, float]],
               first_row: int, stride: int) -> Iterator[tuple[str, np.ndarray, np.ndarray]]:
    """(check, row indices within the chunk, values) where a check leaves its bound: the
    first row of every excursion, then every ``stride``-th row (by global index) of it."""
    for name, value in values.items():
        lower, upper = bounds[name]
        outside = (value > upper) | (value < lower)
        if not outside.any():
            continue
        index = first_row + np.arange(len(outside))
        starts = outside & ~np.concatenate(([False], outside[:-1]))
        where = np.flatnonzero(outside & ((index % stride == 0) | starts))
        yield name, where, value[where]


def arm_points(q: np.ndarray, link_lengths: np.ndarray) -> np.ndarray:
    """Joint positions (rows, n+1, 2) of the planar chain, base at the origin, angles from
    the horizontal and relative (q_i is link i's angle to link i-1); y drawn up, so negated
    for Rerun's y-down 2D views."""
    angles = np.cumsum(q, axis=1)
    steps = np.stack([np.cos(angles), -np.sin(angles)], axis=2) * link_lengths[None, :, None]
    out = np.zeros((q.shape[0], q.shape[1] + 1, 2))
    out[:, 1:] = np.cumsum(steps, axis=1)
    return out


def series_names(stem: str, width: int) -> list[str]:
    return [stem] if width == 1 else [f"{stem}{j + 1}" for j in range(width)]


# Up to this many runs sit side by side (the paper's pair, compared at a glance); more get a
# tab each, every one full width (five columns of eight plots are unreadable).
SIDE_BY_SIDE = 2


def blueprint(run_names: list[str], block_views: dict[str, list] | None = None,
              error_views: dict[str, list] | None = None,
              checks: dict[str, list[tuple[str, str]]] | None = None,
              spatial: Collection[str] = ()):
    """For every run: the checks drawn in figures (``checks[run]``: (title, family), from
    :func:`check_views`), the torque, then barriers, the observer's velocity error
    where the run has one (``error_views[run]``: (entity, title)) and the arm (in 3-D for
    the runs in ``spatial``, whose plant was read from a URDF), and the views
    the run's blocks add (``block_views[run]``: (entity, title) pairs, e.g. a CBF filter's
    barrier values and how much it corrects the torque); runs side by side up to
    :data:`SIDE_BY_SIDE`, else a tab per run; time panel on sim_time, paused."""
    import rerun.blueprint as rrb

    columns = []
    for run in run_names:
        views = [rrb.TimeSeriesView(origin=f"/{run}/safety/{family}", name=f"{run}: {title}")
                 for title, family in (checks or {}).get(run) or []]
        views.append(rrb.TimeSeriesView(origin=f"/{run}/plant/tau",
                                        name=f"{run}: torque τ (N·m)"))
        views.append(rrb.Horizontal(
            rrb.TimeSeriesView(origin=f"/{run}/barrier", name=f"{run}: barrier functions"),
            rrb.TimeSeriesView(origin=f"/{run}/barrier_condition",
                               name=f"{run}: barrier condition (≥ 0 where it holds)"),
            *(rrb.TimeSeriesView(origin=f"/{run}/{entity}", name=f"{run}: {title}")
              for entity, title in (error_views or {}).get(run) or []),
            (rrb.Spatial3DView(origin=f"/{run}/arm3d", name=f"{run}: arm (m)")
             if run in spatial else
             rrb.Spatial2DView(origin=f"/{run}/arm", name=f"{run}: arm (m)")),
        ))
        extra = (block_views or {}).get(run) or []
        if extra:
            views.append(rrb.Horizontal(*(
                rrb.TimeSeriesView(origin=f"/{run}/{entity}", name=f"{run}: {title}")
                for entity, title in extra)))
        columns.append(rrb.Vertical(*views, name=run))
    runs = (rrb.Horizontal(*columns) if len(columns) <= SIDE_BY_SIDE
            else rrb.Tabs(*columns, name="runs"))
    return rrb.Blueprint(
        runs,
        rrb.TimePanel(timeline="sim_time", play_state="paused", expanded=False),
        collapse_panels=True,
    )
