"""What a sweep is: the pipeline, its grid and sampled keys, the seed, the runs, the --set
applied to every point; parsing ``--grid`` and ``--sample``, counting and making the points,
and refusing a sweep that is wrong or unbounded before any work."""

from __future__ import annotations

import itertools
import json
import math
import os
import re
import sys
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..config import Pipeline, PipelineError, load_pipeline
from ..config.files import read_toml

DISTRIBUTIONS = {"uniform": 2, "normal": 2, "integers": 2}
_SAMPLE = re.compile(r"^\s*(\w+)\s*\(\s*([^,]+?)\s*,\s*([^,]+?)\s*\)\s*$")
_ADDRESS = re.compile(r"^((tcp|tls|ws|wss)://)?[A-Za-z0-9_.\-\[\]:]+:\d{1,5}$")
MAX_WORKERS = 64  # and at most 4 per core: each worker is a process holding an FMU


class SweepError(ValueError):
    """A sweep that cannot run; the message names the option or point at fault."""


@dataclass
class Axis:
    key: str
    values: list  # grid values (TOML), or None for a sampled key
    distribution: tuple[str, float, float] | None = None


@dataclass
class SweepSpec:
    pipeline: str
    grid: list[Axis] = field(default_factory=list)
    samples: list[Axis] = field(default_factory=list)
    count: int = 0  # random draws per grid point
    seed: int = 0
    runs: list[str] | None = None
    base: list[str] = field(default_factory=list)  # --set applied to every point

    @property
    def keys(self) -> list[str]:
        return [a.key for a in self.grid + self.samples]


def parse_grid(item: str) -> Axis:
    """``KEY=V1,V2,...`` with TOML values (lists too: ``kv=[20,30],[25,25]``)."""
    key, sep, raw = item.partition("=")
    if not sep or not key.strip() or not raw.strip():
        raise SweepError(f"--grid {item!r}: expected KEY=V1,V2,..., e.g. controller.kv=20,40")
    try:
        values = tomllib.loads(f"values = [{raw}]")["values"]
    except tomllib.TOMLDecodeError:
        raise SweepError(f"--grid {item!r}: {raw!r} is not a comma-separated list of TOML "
                         'values (quote strings: observer.law="paper","error_driven")') from None
    if not values:
        raise SweepError(f"--grid {item!r}: no values")
    return Axis(key.strip(), values)


def parse_sample(item: str) -> Axis:
    """``KEY=uniform(a,b)``, ``normal(mean,std)`` or ``integers(low,high)`` (inclusive)."""
    key, sep, raw = item.partition("=")
    match = _SAMPLE.match(raw)
    if not sep or not key.strip() or not match or match[1] not in DISTRIBUTIONS:
        raise SweepError(f"--sample {item!r}: expected KEY=uniform(a,b), normal(mean,std) or "
                         "integers(low,high)")
    try:
        a, b = float(match[2]), float(match[3])
    except ValueError:
        raise SweepError(f"--sample {item!r}: {match[2]!r} and {match[3]!r} must be "
                         "numbers") from None
    if not (math.isfinite(a) and math.isfinite(b)):
        raise SweepError(f"--sample {item!r}: {match[2]!r} and {match[3]!r} must be finite "
                         "numbers")
    if match[1] == "integers" and not (a.is_integer() and b.is_integer()):
        raise SweepError(f"--sample {item!r}: integers(low,high) draws whole numbers from low "
                         f"to high inclusive; give whole-number bounds (got {match[2]} and "
                         f"{match[3]})")
    if (match[1] == "normal" and b < 0) or (match[1] != "normal" and b < a):
        raise SweepError(f"--sample {item!r}: the second value must be "
                         + ("≥ 0" if match[1] == "normal" else "≥ the first"))
    return Axis(key.strip(), None, (match[1], a, b))


def toml_value(value: object) -> str:
    """A value as TOML for --set (repr keeps every digit of a float)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    return str(value)


def count_points(spec: SweepSpec) -> int:
    """How many points the spec makes, without making them."""
    total = math.prod(len(a.values) for a in spec.grid)
    return total * (spec.count if spec.samples else 1)


def check_spec(spec: SweepSpec, max_points: int, workers: int | None,
               scheduler: str | None = None) -> int:
    """Refuse what would be wrong or unbounded before any work: repeated or conflicting keys
    and runs, a negative seed, a worker count outside 1..cap, a scheduler that is not an
    address, too many points. Returns the number of points."""
    seen: dict[str, str] = {}
    for option, keys in (("--set", [a.split("=", 1)[0].strip() for a in spec.base]),
                         ("--grid", [a.key for a in spec.grid]),
                         ("--sample", [a.key for a in spec.samples])):
        for key in keys:
            if key in seen and not (option == "--set" and seen[key] == "--set"):
                raise SweepError(f"{option} {key}: the key is already given by {seen[key]}; "
                                 "give each swept key once (one --grid with every value, or "
                                 "one --sample)")
            seen.setdefault(key, option)
    if spec.runs and len(set(spec.runs)) != len(spec.runs):
        twice = sorted({r for r in spec.runs if spec.runs.count(r) > 1})
        raise SweepError(f"--runs: {', '.join(twice)} given more than once")
    if scheduler is not None and not _ADDRESS.match(scheduler):
        raise SweepError(f"--scheduler {scheduler!r}: not a scheduler address; expected "
                         "tcp://HOST:PORT (e.g. tcp://127.0.0.1:8786)")
    if spec.seed < 0:
        raise SweepError(f"--seed {spec.seed}: a seed is a non-negative integer")
    if workers is not None:
        cap = min(MAX_WORKERS, 4 * (os.cpu_count() or 1))
        if not 1 <= workers <= cap:
            raise SweepError(f"--workers {workers}: give 1 to {cap} local worker processes "
                             f"(this machine has {os.cpu_count()} cores)")
    total = count_points(spec)
    if total > max_points:
        raise SweepError(f"the sweep makes {total:,} points, more than --max-points "
                         f"{max_points:,}; narrow the grid or the samples, or raise "
                         "--max-points if it is meant to be that large")
    return total


def points(spec: SweepSpec) -> list[dict]:
    """Every point: {key: value}, grid first, in a fixed order (the seed fixes the draws)."""
    grid = list(itertools.product(*[a.values for a in spec.grid])) or [()]
    rng = np.random.default_rng(spec.seed)
    out = []
    for combination in grid:
        fixed = dict(zip((a.key for a in spec.grid), combination, strict=True))
        for _ in range(spec.count if spec.samples else 1):
            point = dict(fixed)
            for axis in spec.samples:
                kind, a, b = axis.distribution
                point[axis.key] = (float(rng.uniform(a, b)) if kind == "uniform"
                                   else float(rng.normal(a, b)) if kind == "normal"
                                   else int(rng.integers(int(a), int(b) + 1)))
            out.append(point)
    return out


def assignments(spec: SweepSpec, point: dict) -> list[str]:
    """The --set assignments of a point: the sweep's own, then the point's values."""
    return [*spec.base, *(f"{key}={toml_value(value)}" for key, value in point.items())]


def validate(spec: SweepSpec, all_points: list[dict]) -> list[dict]:
    """Every point loads (keys, types, ranges), the runs exist, every file a point names is
    a regular file, and the first point assembles (plant FMU, wiring, sizes):
    :class:`SweepError` naming the point. Returns the digests of the files the points name
    (:func:`~cosim.config.named_files.file_digests`), each hashed once."""
    from ..assemble import assemble
    from ..config.named_files import file_digests, named_files

    def once(text: str) -> None:  # the first point's warnings, for the swept runs only
        if not spec.runs or any(f"run '{r}'" in text for r in spec.runs):
            print(f"cosim: warning: {text}", file=sys.stderr)

    digests: dict[str, dict] = {}
    try:  # the file itself (missing, not TOML, a bad extends): no point's fault
        read_toml(Path(spec.pipeline))
    except PipelineError as exc:
        raise SweepError(f"{exc}; nothing was run") from None
    for index, point in enumerate(all_points):
        try:
            pipeline = load_pipeline(spec.pipeline, assignments(spec, point),
                                     warn=once if index == 0 else None)
        except PipelineError as exc:
            # a key the point (or the sweep's --set) gave: the point's label says where
            cause = re.sub(r"^--set [^:]*: ", "", str(exc))
            raise SweepError(f"point {index} ({point_label(point)}): {cause}") from None
        except SystemExit as exc:  # a plugin's sys.exit() at import: not the sweep's end
            raise SweepError(f"point {index} ({point_label(point)}): importing the "
                             f"pipeline's plugins called sys.exit({exc.code!r}); a plugin "
                             "must only define and register its blocks; nothing was "
                             "run") from None
        missing = [r for r in spec.runs or [] if r not in pipeline.runs]
        if missing:
            raise SweepError(f"--runs {' '.join(missing)}: not a run of {spec.pipeline} (its "
                             f"runs: {', '.join(pipeline.runs)})")
        try:  # a file only a later point names, hashed here rather than failing there
            new = {path: key for path, key in named_files(only_runs(pipeline, spec.runs))
                   .items() if path not in digests}
            digests.update({entry["path"]: entry for entry in file_digests(new)})
        except PipelineError as exc:
            raise SweepError(f"point {index} ({point_label(point)}): {exc}") from None
        if index == 0:
            try:
                assemble(pipeline).close()
            except PipelineError as exc:
                raise SweepError(f"point 0 ({point_label(point)}): {exc}") from None
    return [digests[path] for path in sorted(digests)]


def point_label(point: dict) -> str:
    """A point as its assignments, for messages."""
    return ", ".join(f"{k}={toml_value(v)}" for k, v in point.items()) or "as is"


def only_runs(pipeline: Pipeline, runs: list[str] | None) -> Pipeline:
    """``pipeline`` keeping only ``runs`` (all of them when none are given), in place."""
    if runs:
        pipeline.runs = {name: pipeline.runs[name] for name in runs}
    return pipeline
