"""``cosim sweep --resume DIR``: what makes two sweeps the same one (the resolved pipeline,
grid, samples, seed, runs, --set, the number of points and the content of every file the
points name, kept in DIR/sweep.json from the start), and, when DIR's differs from the
command's, what differs, by name."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from plant_fmu.named_file import read_text

from ..config import load_pipeline
from ..config.named_files import changed_files
from ..outputs.run_folder import jsonable
from .spec import SweepError, SweepSpec

SPEC_FILE = "sweep.json"


def identity(spec: SweepSpec, total_points: int, files: list[dict]) -> dict:
    """What a resumed sweep must share with the one it resumes (JSON-ready); ``files``:
    the digests of the files its points name (:func:`.spec.validate`)."""
    resolved = load_pipeline(spec.pipeline, spec.base, warn=None).model_dump(by_alias=True)
    return jsonable({"pipeline_file": spec.pipeline, "base_sets": spec.base,
                     "grid": {a.key: a.values for a in spec.grid},
                     "samples": {a.key: list(a.distribution) for a in spec.samples},
                     "samples_per_grid_point": spec.count, "seed": spec.seed,
                     "runs": spec.runs, "points": total_points,
                     "resolved_pipeline": resolved, "files": files})


def stored_identity(folder: Path) -> dict:
    """The identity DIR/sweep.json holds, or :class:`SweepError` saying why there is none."""
    try:
        document = json.loads(read_text(folder / SPEC_FILE))
    except FileNotFoundError:
        raise SweepError(f"--resume {folder}: no sweep was started there (no {SPEC_FILE}); "
                         "give the folder of an earlier cosim sweep") from None
    except (OSError, ValueError) as exc:
        raise SweepError(f"--resume {folder}: its {SPEC_FILE} cannot be read ({exc})") from None
    if not isinstance(document, dict) or "resolved_pipeline" not in document:
        raise SweepError(f"--resume {folder}: its {SPEC_FILE} is not a sweep's")
    return document


def check_same(folder: Path, stored: dict, current: dict) -> None:
    """:class:`SweepError` naming every difference between the stored and current
    identities (the pipeline's by its keys, old → new)."""
    labels = {"pipeline_file": "the pipeline file", "base_sets": "--set",
              "grid": "--grid", "samples": "--sample", "samples_per_grid_point": "--samples",
              "seed": "--seed", "runs": "--runs", "points": "the number of points"}
    differ = [f"{label} ({_short(stored.get(key))} → {_short(current[key])})"
              for key, label in labels.items()
              if key != "pipeline_file" and _canonical(stored.get(key)) != _canonical(current[key])]
    changed = _changed_keys(stored.get("resolved_pipeline"), current["resolved_pipeline"])
    if changed:
        shown = "; ".join(changed[:5]) + ("; …" if len(changed) > 5 else "")
        differ.append(f"the pipeline {current['pipeline_file']} ({shown})")
    if isinstance(stored.get("files"), list):
        differ += [f"the file {change}" for change in changed_files(
            [e for e in stored["files"] if isinstance(e, dict)], current["files"])]
    else:
        print(f"cosim: warning: --resume {folder}: its {SPEC_FILE} (an older cosim's) holds "
              "no digest of the files the sweep names (reference CSVs, URDFs, plugins, "
              "FMUs): they are taken to be unchanged", file=sys.stderr)
    if differ:
        raise SweepError(f"--resume {folder}: not the same sweep as the one started there; "
                         f"it differs in {', '.join(differ)}. Resume with the same command and "
                         "files, or start a new sweep in another --out")


def _canonical(value: object) -> str:
    return json.dumps(value, sort_keys=True)


def _short(value: object) -> str:
    text = json.dumps(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _changed_keys(old: object, new: object, prefix: str = "") -> list[str]:
    """Dotted keys whose values differ between two pipeline dumps, as ``key: old → new``."""
    if isinstance(old, dict) and isinstance(new, dict):
        out = []
        for key in dict.fromkeys([*old, *new]):
            out += _changed_keys(old.get(key), new.get(key), f"{prefix}{key}.")
        return out
    if _canonical(old) == _canonical(new):
        return []
    return [f"{prefix.rstrip('.')}: {_short(old)} → {_short(new)}"]
