"""A trajectory from a CSV file: one row per sample, comma-separated columns by position,

    t, q_1 … q_n                        positions only
    t, q_1 … q_n, q̇_1 … q̇_n             and velocities
    t, q_1 … q_n, q̇_1 … q̇_n, q̈_1 … q̈_n  and accelerations

in s, rad (m for a prismatic joint), rad/s and rad/s². A first line that is not numbers is
a header and is skipped, as are blank lines and lines starting with ``#`` (and a byte-order
mark). Time starts at 0 and increases strictly; every value is a finite number as a CSV
writes one (Python's ``1_0`` is not). Each mistake is one
:class:`~cosim.schema.PipelineError` naming the file, the line and the column.

The file is read only as far as it is used: up to ``until`` (the run's end, or the safe
sets' horizon if later) and :data:`BEYOND` samples more, so a file of 10⁶ samples for a run
of 1 s is read in a moment; what lies further is neither read nor checked. Why those
samples more: through positions alone, q̇ and q̈ at the samples come from a not-a-knot
cubic spline, which every sample moves a little; a sample k samples away moves them by
about 0.27^k of its own change, so past 64 samples the reference within ``until`` is the
whole file's to the last bit.
"""

from __future__ import annotations

import csv
import functools
import io
import itertools
import math
import os
from pathlib import Path

import numpy as np

from plant_fmu.named_file import NotAFile, open_regular

from ..schema import PipelineError
from .trajectory import SegmentOverflow, Trajectory, through_samples

LAYOUTS = ("t, q", "t, q, q̇", "t, q, q̇, q̈")  # by the number of n-column groups after t
BEYOND = 64  # samples read past ``until`` (see the module's docstring)
# Lines read at a time: the first few alone (a header, comments), then blocks that NumPy's
# parser reads at C speed when they are plain rows of numbers; any other block is read line
# by line, as the messages need.
FIRST_LINES, BLOCK_LINES = 64, 65536
PLAIN = str.maketrans("", "", "0123456789.,eE+-\r\n ")  # what a plain block is made of


class _Reader:
    """The state of one file's reading: its samples so far and where they were."""

    def __init__(self, where: str, joints: int, until: float):
        self.where, self.joints, self.until = where, joints, until
        self.widths = [1 + k * joints for k in (1, 2, 3)]
        self.blocks: list[np.ndarray] = []  # samples, rows × columns
        self.lines: list[np.ndarray] = []  # each sample's line in the file
        self.width: int | None = None  # the first sample's columns
        self.started = False  # a line other than blank or a comment was read
        self.past = 0  # samples read after ``until``
        self.first_line = 0  # the first sample's line

    def done(self) -> bool:
        return self.past > BEYOND

    def read(self, lines: list[str], first: int) -> None:
        """Lines ``first``, ``first`` + 1, … of the file."""
        block = self._plain(lines)
        if block is None:
            self._line_by_line(lines, first)
            return
        self._keep(block, np.arange(first, first + len(lines)))

    def _plain(self, lines: list[str]) -> np.ndarray | None:
        """The block's samples if every line is one of the first sample's width, of finite
        numbers only (digits, '.', 'e', signs: nothing float() and NumPy read differently);
        else None (NumPy passes over a blank line: a block of fewer rows than lines)."""
        if self.width is None or "".join(lines).translate(PLAIN):
            return None
        try:
            block = np.loadtxt(lines, delimiter=",", dtype=float, ndmin=2)
        except ValueError:
            return None
        if block.shape != (len(lines), self.width) or not np.isfinite(block).all():
            return None
        return block

    def _keep(self, block: np.ndarray, lines: np.ndarray) -> None:
        after = np.flatnonzero(block[:, 0] > self.until)
        if self.past + len(after) > BEYOND:  # the last one kept: BEYOND + 1 past ``until``
            stop = int(after[BEYOND - self.past]) + 1
            block, lines, after = block[:stop], lines[:stop], after[:BEYOND - self.past + 1]
        self.past += len(after)
        self.blocks.append(block)
        self.lines.append(lines)

    def _line_by_line(self, text: list[str], first: int) -> None:
        where, joints = self.where, self.joints
        rows, lines = [], []
        beyond = 0  # of these rows, after ``until``: what lies past the last one needed is
        for line, cells in enumerate(csv.reader(text), start=first):  # not even parsed
            if self.past + beyond > BEYOND:
                break
            values = _numbers(cells)
            if values is None:  # a blank line, a comment, a header, or a mistake
                if not "".join(cells).strip() or cells[0].lstrip().startswith("#"):
                    continue
                if not self.started:
                    self.started = True
                    continue  # a header
                bad = next(i for i, c in enumerate(cells) if _number(c) is None)
                hint = ("; the columns are separated by commas (',')"
                        if ";" in cells[bad] or "\t" in cells[bad] else "")
                raise PipelineError(f"{where}, line {line}, column {bad + 1}: "
                                    f"{cells[bad].strip()!r} is not a number{hint}")
            self.started = True
            if len(values) not in self.widths:
                expected = ", ".join(f"{w} ({layout})"
                                     for w, layout in zip(self.widths, LAYOUTS, strict=True))
                raise PipelineError(f"{where}, line {line}: {len(values)} columns; for the "
                                    f"plant's {joints} joint{'s' * (joints != 1)} give "
                                    f"{expected}")
            if self.width is None:
                self.width, self.first_line = len(values), line
            if len(values) != self.width:
                raise PipelineError(f"{where}, line {line}: {len(values)} columns, the first "
                                    f"sample (line {self.first_line}) has {self.width}")
            if not math.isfinite(sum(values)):  # (a sum of large ones may overflow)
                bad = next((i for i, v in enumerate(values) if not math.isfinite(v)), None)
                if bad is not None:
                    raise PipelineError(f"{where}, line {line}, column {bad + 1} "
                                        f"({_column_name(bad, joints)}): "
                                        f"{cells[bad].strip()} is not a finite number")
            rows.append(values)
            lines.append(line)
            beyond += values[0] > self.until
        if rows:
            self._keep(np.array(rows), np.array(lines))


def read_trajectory(path: str | Path, joints: int, until: float = math.inf) -> Trajectory:
    """The file's samples up to ``until`` s (and :data:`BEYOND` more) joined by quintic
    segments (:func:`.trajectory.through_samples`); read once per version of the file in a
    process (every run of a pipeline, every point of a sweep's worker, names the same)."""
    path = Path(path)
    try:
        raw = open_regular(path)
    except NotAFile as exc:
        what = str(exc).removeprefix(f"{path} ")
        raise PipelineError(f"reference.csv: {path} "
                            f"{what.replace(', not a file', ', not a CSV file')}") from None
    with raw:
        status = os.fstat(raw.fileno())
    return _read(path, joints, until, (status.st_dev, status.st_ino, status.st_size,
                                       status.st_mtime_ns))


@functools.lru_cache(maxsize=2)  # (a long CSV's trajectory is ~100 MB)
def _read(path: Path, joints: int, until: float, version: tuple) -> Trajectory:
    """:func:`read_trajectory`, for one ``version`` of the file (device, inode, size and
    time of its last change)."""
    where = f"reference.csv: {path}"
    try:
        raw = open_regular(path)
    except NotAFile as exc:  # replaced since: said as read_trajectory says it
        raise PipelineError(f"{where}: {exc}") from None
    reader = _Reader(where, joints, until)
    try:
        # utf-8-sig: a byte-order mark is not part of the first cell
        with io.TextIOWrapper(raw, encoding="utf-8-sig", newline="") as file:
            first, size = 1, FIRST_LINES
            while not reader.done() and (lines := list(itertools.islice(file, size))):
                reader.read(lines, first)
                first, size = first + len(lines), BLOCK_LINES
    except UnicodeDecodeError as exc:
        raise PipelineError(f"{where}: not a UTF-8 text file ({exc.reason} at byte "
                            f"{exc.start})") from None
    except csv.Error as exc:
        raise PipelineError(f"{where}: not a CSV file ({exc})") from None
    data = np.concatenate(reader.blocks) if reader.blocks else np.empty((0, 1))
    lines = np.concatenate(reader.lines) if reader.lines else np.empty(0, int)
    if len(data) < 2:
        raise PipelineError(f"{where}: {len(data)} sample{'s' * (len(data) != 1)}; give at "
                            "least two")
    times = data[:, 0]
    if times[0] != 0.0:
        raise PipelineError(f"{where}, line {lines[0]}: the first time is {times[0]:g} s; "
                            "the trajectory starts at t = 0 s, the run's start")
    step = np.flatnonzero(np.diff(times) <= 0)
    if len(step):
        k = int(step[0]) + 1
        raise PipelineError(f"{where}, line {lines[k]}: time {times[k]:g} s does not "
                            f"increase (line {lines[k - 1]}: {times[k - 1]:g} s); times must "
                            "increase strictly")
    groups = [data[:, 1 + g * joints:1 + (g + 1) * joints] for g in range(3)]
    present = (data.shape[1] - 1) // joints
    source = path.name + (f" (its samples up to t = {times[-1]:g} s)" if reader.done() else "")
    try:
        return through_samples(times, groups[0], groups[1] if present > 1 else None,
                               groups[2] if present > 2 else None, source)
    except SegmentOverflow as exc:
        k = exc.segment
        biggest = np.max(np.abs(data[k:k + 2, 1:]))
        raise PipelineError(f"{where}, lines {lines[k]} and {lines[k + 1]}: the segment from "
                            f"t = {times[k]:g} s to {times[k + 1]:g} s "
                            f"({times[k + 1] - times[k]:g} s, values up to {biggest:g}) makes "
                            "q_d, q̇_d or q̈_d too large for double precision: give samples of "
                            "a robot's scale") from None


def _numbers(cells: list[str]) -> list[float] | None:
    """A line's numbers, or None if a cell is not one (or there is no cell): the common
    case at one float() per cell, the 10⁶ lines of a long file in about a second."""
    try:
        values = [float(c) for c in cells]
    except ValueError:
        return None
    return values if values and "_" not in "".join(cells) else None


def _number(cell: str) -> float | None:
    """A cell's number; None if it is not one as a CSV writes numbers (Python's float()
    also reads ``1_0`` as 10)."""
    if "_" in cell:
        return None
    try:
        return float(cell)
    except ValueError:
        return None


def _column_name(index: int, joints: int) -> str:
    if index == 0:
        return "t"
    group, joint = divmod(index - 1, joints)
    return f"{('q', 'q̇', 'q̈')[group]}_{joint + 1}"
