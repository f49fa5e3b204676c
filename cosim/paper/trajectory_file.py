"""A trajectory from a CSV file: one row per sample, comma-separated columns by position,

    t, q_1 … q_n                        positions only
    t, q_1 … q_n, q̇_1 … q̇_n             and velocities
    t, q_1 … q_n, q̇_1 … q̇_n, q̈_1 … q̈_n  and accelerations

in s, rad (m for a prismatic joint), rad/s and rad/s². A first line that is not numbers is
a header and is skipped, as are blank lines and lines starting with ``#``. Time starts at
0 and increases strictly; every value is finite. Each mistake is one
:class:`~cosim.schema.PipelineError` naming the file, the line and the column.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from ..schema import PipelineError
from .trajectory import Trajectory, through_samples

LAYOUTS = ("t, q", "t, q, q̇", "t, q, q̇, q̈")  # by the number of n-column groups after t


def read_trajectory(path: str | Path, joints: int) -> Trajectory:
    """The file's samples joined by quintic segments (:func:`.trajectory.through_samples`)."""
    path = Path(path)
    where = f"reference.csv: {path}"
    if not path.is_file():
        what = "is a folder, not a CSV file" if path.is_dir() else "does not exist"
        raise PipelineError(f"{where} {what}")
    widths = [1 + k * joints for k in (1, 2, 3)]
    expected = ", ".join(f"{w} ({layout})" for w, layout in zip(widths, LAYOUTS, strict=True))
    rows: list[list[float]] = []
    lines: list[int] = []  # each sample's line in the file
    started = False  # a line other than blank or a comment was read
    try:
        with path.open(newline="", encoding="utf-8") as file:
            for line, cells in enumerate(csv.reader(file), start=1):
                if not "".join(cells).strip() or cells[0].lstrip().startswith("#"):
                    continue
                first, started = not started, True
                values = [_number(c) for c in cells]
                if None in values:
                    if first:
                        continue  # a header
                    bad = values.index(None)
                    hint = ("; the columns are separated by commas (',')"
                            if ";" in cells[bad] or "\t" in cells[bad] else "")
                    raise PipelineError(f"{where}, line {line}, column {bad + 1}: "
                                        f"{cells[bad].strip()!r} is not a number{hint}")
                if len(values) not in widths:
                    raise PipelineError(f"{where}, line {line}: {len(values)} columns; for the "
                                        f"plant's {joints} joint{'s' * (joints != 1)} give "
                                        f"{expected}")
                if rows and len(values) != len(rows[0]):
                    raise PipelineError(f"{where}, line {line}: {len(values)} columns, the "
                                        f"first sample (line {lines[0]}) has {len(rows[0])}")
                bad = next((i for i, v in enumerate(values) if not math.isfinite(v)), None)
                if bad is not None:
                    raise PipelineError(f"{where}, line {line}, column {bad + 1} "
                                        f"({_column_name(bad, joints)}): {cells[bad].strip()} is "
                                        "not a finite number")
                rows.append(values)
                lines.append(line)
    except UnicodeDecodeError as exc:
        raise PipelineError(f"{where}: not a UTF-8 text file ({exc.reason} at byte "
                            f"{exc.start})") from None
    except csv.Error as exc:
        raise PipelineError(f"{where}: not a CSV file ({exc})") from None
    if len(rows) < 2:
        raise PipelineError(f"{where}: {len(rows)} sample{'s' * (len(rows) != 1)}; give at "
                            "least two")
    data = np.array(rows)
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
    present = (len(rows[0]) - 1) // joints
    return through_samples(times, groups[0], groups[1] if present > 1 else None,
                           groups[2] if present > 2 else None, f"{path.name}")


def _number(cell: str) -> float | None:
    try:
        return float(cell)
    except ValueError:
        return None


def _column_name(index: int, joints: int) -> str:
    if index == 0:
        return "t"
    group, joint = divmod(index - 1, joints)
    return f"{('q', 'q̇', 'q̈')[group]}_{joint + 1}"
