"""A run folder as `cosim compare` reads it: its summary.json, read strictly, and every
check in it verified against its own numbers and against the run's trace, which cosim wrote
beside it (a compare gate must not believe a summary edited, or damaged, into "no
regression")."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from plant_fmu.named_file import not_a_file, read_text

from ..config.sections import check_name
from ..evaluate.checks import Kind, unit


class CompareError(Exception):
    """A folder that cannot be compared: one line naming it."""


def read_summary(folder: Path, label: str) -> dict:
    """A folder's summary.json, read strictly: a folder without one, a summary that is not
    JSON, and a sweep's folder are each named as such."""
    where = f"{label} {folder}"
    path = folder / "summary.json"
    if not folder.is_dir() or not_a_file(path) == "does not exist":
        raise CompareError(f"{where}: not a cosim run folder (no summary.json with runs); "
                           "give folders `cosim run --out` wrote")
    try:
        document = json.loads(read_text(path))
    except (OSError, ValueError) as exc:
        why = f"not JSON: {exc}" if isinstance(exc, ValueError) else str(exc)
        raise CompareError(f"{where}: its summary.json cannot be read ({why}); give folders "
                           "`cosim run --out` wrote, as it wrote them") from None
    if isinstance(document, dict) and document.get("kind") == "sweep":
        raise CompareError(f"{where}: a sweep's folder, not a run folder; compare two run "
                           "folders (a sweep's --record writes its best and worst points' "
                           "run folders), or read the sweep's results.parquet")
    if not isinstance(document, dict) or "complete" not in document \
            or not isinstance(document.get("runs"), dict):
        raise CompareError(f"{where}: not a cosim run folder (no summary.json with runs); "
                           "give folders `cosim run --out` wrote")
    return document


def _number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def verify_summary(folder: Path, label: str, summary: dict) -> None:
    """:class:`CompareError` unless every check of every run is what its numbers say: a
    bound and a worst value that are numbers, a verdict that is true or false, a kind
    cosim knows; the verdict the worst value and the bound give (NaN: violated) is the
    one stored; and the worst value and the verdict are those of the check's values in the
    run's trace (trace_<run>.npz), which cosim wrote beside it. A compare gate must not
    believe a summary edited, or damaged, into "no regression"."""
    where = f"{label} {folder}: summary.json's"
    simulation = (summary.get("pipeline") or {}).get("simulation") or {}
    for key in ("duration", "step"):
        if key in simulation and not _number(simulation[key]):
            raise CompareError(f"{where} pipeline.simulation.{key} = "
                               f"{json.dumps(simulation[key])[:40]} is not a number")
    for name, run in summary["runs"].items():
        try:
            check_name(name, "run name")
        except ValueError as exc:
            raise CompareError(f"{where} runs: {exc}") from None
        safety = run.get("safety") if isinstance(run, dict) else None
        if not isinstance(run, dict) or not isinstance(safety, dict | None):
            raise CompareError(f"{where} runs.{name} is not a run's table (its safety a table "
                               "of checks)")
        done = (run.get("metrics") or {}).get("simulated_time_s")
        if done is not None and not _number(done):
            raise CompareError(f"{where} runs.{name}.metrics.simulated_time_s = "
                               f"{json.dumps(done)[:40]} is not a number")
        if not safety:
            continue
        rows = (round(simulation["duration"] / simulation["step"]) + 1
                if simulation.get("duration") and simulation.get("step") else None)
        trace = _TraceChecks(folder, label, name, rows)
        try:
            for check, entry in safety.items():
                _check_verified(f"{where} runs.{name}.safety.{check}", entry, trace, check)
        finally:
            trace.close()


def _check_verified(key: str, entry: object, trace: _TraceChecks, check: str) -> None:
    """One check's entry against itself and its trace (see :func:`verify_summary`)."""
    if not isinstance(entry, dict):
        raise CompareError(f"{key} is not a check's table")
    bound, worst, satisfied = entry.get("bound"), entry.get("worst"), entry.get("satisfied")
    for field_, value, valid, what in (
            ("bound", bound, _number(bound), "a number"),
            ("worst", worst, worst is None or _number(worst), "a number (or null: unknown)"),
            ("satisfied", satisfied, satisfied is None or isinstance(satisfied, bool),
             "true or false (or null: unknown)"),
            ("attainable", entry.get("attainable"),
             isinstance(entry.get("attainable"), bool | None), "true or false"),
            ("kind", entry.get("kind"), entry.get("kind", Kind.SOFT) in set(Kind),
             f"one of {', '.join(Kind)}")):
        if not valid:
            raise CompareError(f"{key}.{field_} = {json.dumps(value)[:40]} is not {what}")
    u = f" {unit(entry)}".rstrip()
    held = None if worst is None else bool(worst <= bound)  # NaN: not known inside, not held
    # a row of ±inf is outside its set without being the worst finite value
    excused = held is True and satisfied is False and "rows_unknown" in entry
    if satisfied is not held and not excused:
        raise CompareError(f"{key} disagrees with its own numbers: satisfied = "
                           f"{json.dumps(satisfied)}, but its worst value "
                           + (f"is unknown (null) against its bound {bound}{u}" if worst is None
                              else f"is NaN, not known to be within its bound {bound}{u}"
                              if worst != worst else
                              f"{worst}{u} is {'within' if held else 'beyond'} its bound "
                              f"{bound}{u}")
                           + "; a summary.json edited or damaged is not judged")
    values = trace.values(check, key)
    known = values[np.isfinite(values)]
    traced_worst = float(np.max(np.abs(known))) if known.size else None
    traced_held = None if traced_worst is None else not bool((np.abs(values) > bound).any())
    if traced_worst != worst or traced_held is not satisfied:
        raise CompareError(f"{key} disagrees with the run's trace: worst {worst}{u}, "
                           f"satisfied = {json.dumps(satisfied)} in summary.json; worst "
                           f"{traced_worst}{u}, satisfied = {json.dumps(traced_held)} from "
                           f"{trace.path.name}'s check_{check} against the bound {bound}{u}; "
                           "a summary.json edited or damaged is not judged")


class _TraceChecks:
    """The check values of a run's trace file, read as they are asked for, each at most
    ``rows`` long (the run's steps + 1; None: unknown): an entry that says it is larger is
    refused before it is read (a shared folder's trace could declare terabytes)."""

    def __init__(self, folder: Path, label: str, run: str, rows: int | None):
        self.path = folder / f"trace_{run}.npz"
        self.where = f"{label} {folder}"
        self.largest = NPY_HEADER + 8 * rows if rows is not None else None
        why = not_a_file(self.path)
        if why is not None:
            raise CompareError(f"{self.where}: {self.path.name} {why}, so the checks of run "
                               f"{run} cannot be verified against their values; give folders "
                               "`cosim run --out` wrote, as it wrote them")
        try:
            self.archive = np.load(self.path, allow_pickle=False)
        except (OSError, ValueError) as exc:
            raise CompareError(f"{self.where}: {self.path.name} cannot be read ({exc})") \
                from None

    def values(self, check: str, key: str) -> np.ndarray:
        entry = f"check_{check}"
        if entry not in self.archive.files:
            raise CompareError(f"{key} has no values in {self.path.name} (no {entry}): the "
                               "summary names a check its trace does not hold")
        try:
            size = self.archive.zip.getinfo(f"{entry}.npy").file_size
            if self.largest is not None and size > self.largest:
                raise ValueError(f"it says it holds {size} bytes, more than the run's rows "
                                 f"take ({self.largest})")
            return np.asarray(self.archive[entry], float)
        except (OSError, ValueError, KeyError) as exc:
            raise CompareError(f"{self.where}: {self.path.name}'s {entry} cannot be read "
                               f"({exc})") from None

    def close(self) -> None:
        self.archive.close()


NPY_HEADER = 4096  # bytes: an .npy entry's header is 128 (at most a few kB), then its values
