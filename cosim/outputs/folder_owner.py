"""Whose files a folder holds: what cosim wrote into a run or sweep folder (its summary.json
accounts for them) against what it did not, and why a folder cannot be a new run folder
(:func:`refusal_reason`): one that holds files is refused unless ``--force``, and ``--force``
replaces only what cosim wrote."""

from __future__ import annotations

import json
from pathlib import Path

from plant_fmu.named_file import read_text

from .formats import EXPORT_FORMATS

LOCK = ".cosim.lock"  # the run folder's lock file (cosim.outputs.run_folder)


# What cosim writes into a run or sweep folder besides what summary.json lists: the files a
# run killed before its summary caught up may leave (exact names, never patterns).
OUR_NAMES = ("summary.json", "summary.md", "recording.rrd", "results.parquet", "results.csv",
             "sweep.json", "sweep_safety.png", "rows.jsonl")


def our_entries(summary: dict) -> set[str]:
    """The names a folder with this summary.json holds that cosim wrote: what the summary
    lists as written, cosim's fixed names, each run's trace and export (of the runs the
    summary names), and the temporaries of all of these. Nothing matched by a pattern: a
    user's ``fig_final.png`` or ``export_my_data.csv`` is not ours."""
    from .figures import figure_files

    runs = summary.get("runs")
    names = list(runs) if isinstance(runs, dict | list) else []
    pipeline = summary.get("pipeline")
    if isinstance(pipeline, dict) and isinstance(pipeline.get("runs"), dict):
        names += list(pipeline["runs"])
    files = summary.get("files")
    ours = {*(files if isinstance(files, dict) else ()), *OUR_NAMES, *figure_files()}
    for run in map(str, names):
        ours.add(f"trace_{run}.npz")
        ours.update(f"export_{run}{suffix}" for suffix in EXPORT_FORMATS.values())
    return ours | {f".{name}.tmp" for name in ours} | {".summary.json.crashed"}


def ours_summary(path: Path) -> dict | None:
    """The folder's summary.json when cosim wrote it (else None)."""
    try:
        data = json.loads(read_text(path / "summary.json"))
    except (OSError, ValueError):
        return None
    if isinstance(data, dict) and "complete" in data and ("provenance" in data
                                                          or "runs" in data):
        return data
    return None


def recorded_point(summary: dict, name: str) -> bool:
    """A sweep's ``--record`` run folder: ``best_<run>_point<i>`` or ``worst_…`` of a run
    the sweep's summary names."""
    if summary.get("kind") != "sweep":
        return False
    runs = summary.get("runs") if isinstance(summary.get("runs"), list) else []
    return any(name.startswith((f"best_{run}_point", f"worst_{run}_point"))
               and name.rsplit("_point", 1)[1].isdigit() for run in map(str, runs))


def not_ours(path: Path, names: list[str]) -> list[str]:
    """The entries of ``path`` that cosim did not write: everything when the folder has no
    summary.json of ours; else what its summary does not account for (a sweep's recorded
    points are run folders of ours, checked the same way)."""
    summary = ours_summary(path)
    if summary is None:
        return names
    ours = our_entries(summary)
    out = []
    for name in names:
        entry = path / name
        if entry.is_symlink() or not entry.is_dir():
            if name in ours:
                continue
        elif recorded_point(summary, name) and ours_summary(entry) is not None \
                and not not_ours(entry, [p.name for p in entry.iterdir() if p.name != LOCK]):
            continue
        out.append(name)
    return out


def refusal_reason(path: Path, existing: list[str], force: bool) -> str | None:
    """Why a folder holding ``existing`` cannot be the run folder (None: it can)."""
    if existing and not force:
        what = describe_existing(path)
        resume = (f", `cosim sweep … --resume {path}` to go on with it"
                  if " sweep folder" in what else "")
        return (f"--out {path}: already holds {len(existing)} file"
                f"{'s' * (len(existing) != 1)} ({what}); pass --force to replace them"
                f"{resume}, or choose another --out")
    foreign = not_ours(path, existing)
    if existing and foreign:
        shown = ", ".join(foreign[:5]) + (", …" if len(foreign) > 5 else "")
        return (f"--out {path}: --force replaces only what cosim wrote, and this folder holds "
                f"{len(foreign)} entr{'ies' if len(foreign) != 1 else 'y'} it did not write "
                f"({shown}); nothing was deleted: choose another --out, or remove them "
                "yourself")
    return None


def would_refuse(path: str | Path, force: bool = False) -> str | None:
    """What :meth:`RunFolder.create` would refuse ``path`` for, without touching it (for
    --dry-run); None if it would be used."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        return f"--out {path}: is a file, not a folder; choose another --out"
    if not path.is_dir():
        return None
    return refusal_reason(path, sorted(p.name for p in path.iterdir() if p.name != LOCK), force)


def describe_existing(path: Path) -> str:
    summary = path / "summary.json"
    try:
        data = json.loads(read_text(summary))
        started = data.get("provenance", {}).get("started", "")
        state = "a complete" if data.get("complete") else "an incomplete"
        when = f" started {started}" if started else ""
        if data.get("kind") == "sweep":  # (its summary names no pipeline)
            rows = data.get("rows")
            return (f"{state} sweep folder{when}"
                    + (f", {rows} row(s) in its journal" if isinstance(rows, int) else ""))
        name = data.get("pipeline", {}).get("name", "?")
        return f"{state} run folder of {name}{when}"
    except (OSError, ValueError, AttributeError):
        names = sorted(p.name for p in path.iterdir() if p.name != LOCK)
        return ", ".join(names[:3]) + (", …" if len(names) > 3 else "")
