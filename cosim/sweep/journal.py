"""A sweep's rows on disk as they finish, and back: ``rows.jsonl`` in the sweep folder, one
JSON object per (point, run) row, appended and synced as each task's points finish.

Why a journal and not the Parquet file itself: a Parquet file is readable only once its
footer is written (a client killed mid-sweep would leave none of it readable), and its
schema is fixed when it is opened, while the rows' columns are known only as they come (a
failed row has no check columns, each run its own). A line is written whole or, when the
client is killed in the middle of it, dropped on reading. JSON keeps every float's digits
(and NaN, ±inf). results.parquet and results.csv are made from the journal at the end, a
row group per chunk of lines, so neither the client nor the files ever hold more than a
chunk of rows as Python objects; :class:`Rows` gives the tables their rows as views on the
columns they read."""

from __future__ import annotations

import errno
import json
import os
import stat
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from plant_fmu.named_file import not_a_file

from .spec import SweepError

if TYPE_CHECKING:
    import pyarrow as pa

JOURNAL = "rows.jsonl"
CHUNK = 256  # rows a chunk when reading back: as dicts, ~15 kB a row of 200 columns
LONGEST_LINE = 64 * 2**20  # bytes: a row of thousands of columns is well below


class Journal:
    """``rows.jsonl`` opened for appending."""

    def __init__(self, path: Path):
        self.path = path
        _drop_cut_line(path)
        self._file = path.open("a", encoding="utf-8")
        self.rows = 0

    def add(self, rows: list[dict]) -> None:
        """Append ``rows`` and sync them to disk: a client killed after this keeps them."""
        if not rows:
            return
        self._file.write("".join(json.dumps(r, allow_nan=True) + "\n" for r in rows))
        self._file.flush()
        os.fsync(self._file.fileno())
        self.rows += len(rows)

    def close(self) -> None:
        self._file.close()


def _drop_cut_line(path: Path) -> None:
    """Cut the journal after its last whole line: a client killed mid-write leaves part of
    one, which the next row appended would otherwise be glued to."""
    if not path.exists():
        return
    with path.open("rb+") as f:
        stop = f.seek(0, os.SEEK_END)
        if stop == 0:
            return
        f.seek(stop - 1)
        if f.read(1) == b"\n":
            return
        while stop > 0:  # back from the end, a block at a time (the journal may be GBs)
            start = max(0, stop - 65536)
            f.seek(start)
            newline = f.read(stop - start).rfind(b"\n")
            if newline >= 0:
                f.truncate(start + newline + 1)
                return
            stop = start
        f.truncate(0)


def _lines(path: Path) -> Iterator[tuple[int, bytes]]:
    """The journal's whole lines, numbered from 1; a last line cut short (a killed client)
    is left out. Nothing when there is no journal; :class:`SweepError` for a journal that
    is not a regular file (opened without blocking: a named pipe would wait for a writer
    forever; a symbolic link is not followed: a sweep appends to and cuts its journal)."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOFOLLOW)
    except FileNotFoundError:
        return
    except OSError as exc:
        raise _not_rows(path, "is a symbolic link" if exc.errno == errno.ELOOP
                        else f"cannot be read ({exc.strerror})") from None
    with os.fdopen(fd, "rb") as f:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise _not_rows(path, not_a_file(path) or "is not a regular file")
        number = 0
        while line := f.readline(LONGEST_LINE + 1):
            number += 1
            if len(line) > LONGEST_LINE:  # not a row: read no more of it into memory
                raise SweepError(f"{path} holds a line longer than {LONGEST_LINE // 2**20} "
                                 f"MiB (line {number}), which no row is; nothing was run: "
                                 "remove it and resume (its point is then run again), or "
                                 "start a new sweep in another --out")
            if not line.endswith(b"\n"):
                return
            yield number, line


def _not_rows(path: Path, what: str) -> SweepError:
    return SweepError(f"{path} {what}: a sweep's rows are a file cosim writes; nothing was "
                      "run: remove it (every point is then run again), or start a new sweep "
                      "in another --out")


def _parsed(line: bytes) -> dict | str:
    """A journal line's row, or why it is not one."""
    try:
        text = line.decode("utf-8")
    except UnicodeDecodeError as exc:
        return f"not UTF-8 text (byte {exc.start})"
    try:
        row = json.loads(text)
    except json.JSONDecodeError as exc:
        where = ("at its end" if exc.pos >= len(text.rstrip())
                 else f"at character {exc.pos + 1}")
        return f"not a JSON row ({exc.msg} {where})"
    return row if isinstance(row, dict) else "not a JSON object"


def _rows(path: Path) -> Iterator[dict]:
    """The journal's rows, each (point, run) once (the first: :func:`check_journal` said
    which lines repeat one)."""
    seen: set[tuple] = set()
    for _, line in _lines(path):
        row = _parsed(line)
        if isinstance(row, dict) and (row.get("point"), row.get("run")) not in seen:
            seen.add((row.get("point"), row.get("run")))
            yield row


def check_journal(path: Path, all_points: list[dict], runs: list[str]
                  ) -> tuple[set[int], list[str]]:
    """The points of which the journal holds a row for every run (a task's rows are written
    together), and the repeated rows it holds (each (point, run) counts once: the first),
    said line by line. :class:`SweepError` naming the lines that are not rows of this
    sweep: damaged (cut mid-way, not UTF-8, not JSON), of a point or run it has not, or
    with values that are not their point's."""
    from .worker import point_row

    first: dict[tuple[int, str], int] = {}
    repeats, wrong = [], []
    for number, line in _lines(path):
        row = _parsed(line)
        if isinstance(row, str):
            wrong.append(f"line {number} is {row}")
            continue
        point, run = row.get("point"), row.get("run")
        if not isinstance(point, int) or isinstance(point, bool) \
                or not 0 <= point < len(all_points):
            wrong.append(f"line {number} is a row of point {json.dumps(point)[:20]}, which "
                         f"this sweep has not (points 0 to {len(all_points) - 1})")
        elif run not in runs:
            wrong.append(f"line {number} is a row of run {json.dumps(run)[:40]}, which this "
                         f"sweep does not run ({', '.join(runs)})")
        elif (expected := point_row(point, all_points[point], run)) != \
                {key: row.get(key) for key in expected} or "status" not in row:
            wrong.append(f"line {number} is a row of point {point} whose values are not "
                         "that point's")
        elif (point, run) in first:
            repeats.append(f"line {number} repeats the row of point {point}, run {run} (line "
                           f"{first[point, run]}): left out")
        else:
            first[point, run] = number
    if wrong:
        shown = "; ".join(wrong[:3]) + (f"; and {len(wrong) - 3} more" if len(wrong) > 3 else "")
        raise SweepError(f"{path} holds {len(wrong)} line{'s' * (len(wrong) != 1)} that "
                         f"{'is' if len(wrong) == 1 else 'are'} not a row of this sweep "
                         f"({shown}); nothing was run: remove "
                         + ("it and resume (its point is" if len(wrong) == 1
                            else "them and resume (their points are")
                         + " then run again), or start a new sweep in another --out")
    done = {point for point in range(len(all_points))
            if all((point, run) in first for run in runs)}
    return done, repeats


def read_table(path: Path) -> pa.Table:
    """Every row of the journal as one Arrow table, sorted by (point, run): a column a row
    lacks is null there, integers and floats of one column are floats."""
    import pyarrow as pa

    chunks, chunk = [], []
    for row in _rows(path):
        chunk.append(row)
        if len(chunk) == CHUNK:
            chunks.append(_arrow(chunk))
            chunk = []
    if chunk or not chunks:
        chunks.append(_arrow(chunk))
    table = pa.concat_tables(chunks, promote_options="permissive")
    if not table.num_rows:
        return table
    return table.sort_by([("point", "ascending"), ("run", "ascending")])


def _arrow(rows: list[dict]) -> pa.Table:
    import pyarrow as pa

    columns = list(dict.fromkeys(k for r in rows for k in r))
    try:
        return pa.Table.from_pylist([{c: r.get(c) for c in columns} for r in rows])
    except (pa.ArrowInvalid, pa.ArrowTypeError):  # one column of ints and floats: floats
        data = {c: [r.get(c) for r in rows] for c in columns}
        for c, values in data.items():
            if any(isinstance(v, float) for v in values):
                data[c] = [float(v) if isinstance(v, int) and not isinstance(v, bool) else v
                           for v in values]
        return pa.Table.from_pydict(data)


class Rows:
    """A sweep's rows, as the tables read them (a sequence of mappings), over an Arrow
    table: a column becomes Python values only when a table first reads it (a float column
    as a NumPy array, 8 bytes a value), and a row is a view, not a dict of its own. A
    column a row has no value in (null) is not one of its keys, as the row was made."""

    def __init__(self, table: pa.Table):
        self.table = table
        self.names = table.column_names
        self._known = frozenset(self.names)
        self._columns: dict[str, object] = {}
        self._present: dict[str, np.ndarray] = {}

    def column(self, name: str) -> list:
        """A column's values (None where a row has none)."""
        return self.table.column(name).to_pylist()

    def value(self, name: str, index: int) -> object:
        """Row ``index``'s value of column ``name`` (None: it has none)."""
        if name not in self._columns:
            import pyarrow as pa

            column = self.table.column(name)
            self._columns[name] = (column.to_numpy(zero_copy_only=False)
                                   if pa.types.is_floating(column.type) else column.to_pylist())
        if not self.present(name)[index]:
            return None
        value = self._columns[name][index]
        return float(value) if isinstance(value, np.floating) else value

    def present(self, name: str) -> np.ndarray:
        """Which rows have a value in column ``name`` (booleans)."""
        if name not in self._present:
            self._present[name] = np.asarray(
                self.table.column(name).is_valid().to_numpy(zero_copy_only=False), bool)
        return self._present[name]

    def __len__(self) -> int:
        return self.table.num_rows

    def __iter__(self) -> Iterator[Row]:
        return (Row(self, i) for i in range(self.table.num_rows))

    def __getitem__(self, index: int) -> Row:
        return Row(self, range(self.table.num_rows)[index])


class Row(Mapping):
    """Row ``index`` of :class:`Rows`."""

    __slots__ = ("_rows", "_index")

    def __init__(self, rows: Rows, index: int):
        self._rows, self._index = rows, index

    def __getitem__(self, key: str) -> object:
        value = self._rows.value(key, self._index) if key in self._rows._known else None
        if value is None:
            raise KeyError(key)
        return value

    def get(self, key: str, default: object = None) -> object:
        try:
            return self[key]
        except KeyError:
            return default

    def __contains__(self, key: object) -> bool:
        return key in self._rows._known and bool(self._rows.present(key)[self._index])

    def __iter__(self) -> Iterator[str]:
        return (k for k in self._rows.names if self._rows.present(k)[self._index])

    def __len__(self) -> int:
        return sum(1 for _ in self)
