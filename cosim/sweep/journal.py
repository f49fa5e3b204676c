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

import json
import os
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import pyarrow as pa

JOURNAL = "rows.jsonl"
CHUNK = 256  # rows a chunk when reading back: as dicts, ~15 kB a row of 200 columns


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


def _lines(path: Path) -> Iterator[dict]:
    """The journal's rows; a last line cut short (a killed client) is left out."""
    if not path.exists():
        return
    with path.open(encoding="utf-8") as f:
        for line in f:
            if not line.endswith("\n"):
                return
            yield json.loads(line)


def points_done(path: Path) -> set[int]:
    """The points of which the journal holds rows (a task's rows are written together)."""
    return {row["point"] for row in _lines(path)}


def read_table(path: Path) -> pa.Table:
    """Every row of the journal as one Arrow table, sorted by (point, run): a column a row
    lacks is null there, integers and floats of one column are floats."""
    import pyarrow as pa

    chunks, chunk = [], []
    for row in _lines(path):
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
