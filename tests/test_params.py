"""`cosim params`: every key the schema accepts is listed, with a value `--set` takes back,
what it accepts and what it means; with a pipeline, its own values marked where they differ
from the defaults (and `--dry-run` lists those). The reference is pydantic's own dump of a
validated pipeline, not the listing's walk of the schema."""

from __future__ import annotations

import json
import re
import subprocess
import sys

from cli_helpers import PAPER, cosim_cli

from cosim.config import load_pipeline

LINE = re.compile(r"^([ *]) (\S+?)(?: = (.*?))?\s{2,}\[(.*)\](?:  # (.*))?$")

# What a meaning may name as its unit, after a comma or in parentheses: an SI unit (angles in
# radians), or, for a value that has none, what it is. "mixed units": the NN weights and
# their bounds, whose entries carry the units of the different inputs they multiply.
UNITS = ("s", "1/s", "Hz", "rad", "rad²", "rad/s", "rad/s²", "rad/s³", "(rad/s)²", "m",
         "m/s²", "kg", "kg·m²", "N·m", "N·m/rad", "N·m·s/rad", "1/(N·m)",
         "√(N·m·rad/s)")
NO_UNIT = ("dimensionless", "mixed units", "a name", "names", "a flag", "a path", "paths",
           "free text")
NAMES_A_UNIT = re.compile(r"(?:, |\()(" + "|".join(
    re.escape(unit) for unit in sorted(UNITS + NO_UNIT, key=len, reverse=True))
    + r")(?![\w/·])")
# Keys of the pipeline's own sections and of the controller's and the filter's blocks:
# checked by a test of their own, so that a failure says which group lost a unit.
RESTRUCTURED = ("name", "description", "plugins", "simulation.", "plant.builtin.",
                "plant.fmu", "plant.parameters", "controller.", "cbf_filter.")


def flatten(data: dict, prefix: str = "") -> dict[str, object]:
    out = {}
    for key, value in data.items():
        if key == "runs":
            continue
        if isinstance(value, dict) and value and all(isinstance(k, str) for k in value) \
                and key != "parameters":
            out.update(flatten(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def dumped(path: str | None = None) -> dict[str, object]:
    """pydantic's dump of the validated pipeline, in a fresh process (as the CLI sees the
    block registry: a test elsewhere may register a block in this one)."""
    code = ("import json, sys; from cosim.config import load_pipeline; "
            "print(json.dumps(load_pipeline(sys.argv[1] if len(sys.argv) > 1 else None)"
            ".model_dump(by_alias=True)))")
    done = subprocess.run([sys.executable, "-c", code, *([path] if path else [])],
                          capture_output=True, text=True, check=True, timeout=300)
    return flatten(json.loads(done.stdout))


def listing(*args: str) -> dict[str, tuple[str, str, str, str]]:
    done = cosim_cli("params", *args)
    assert done.returncode == 0, done.stderr
    rows = {}
    for line in done.stdout.splitlines():
        match = LINE.match(line)
        assert match, line
        mark, key, value, allowed, meaning = match.groups()
        rows[key] = (mark, value, allowed, meaning or "")
    return rows


def test_every_key_is_listed_with_a_value_set_takes_back_and_a_meaning():
    rows = listing()
    defaults = dumped()
    defaults.pop("plant.builtin", None)
    missing = [key for key in defaults if key not in rows]
    assert not missing, missing
    for key, (_, value, allowed, _) in rows.items():
        assert allowed, key
        if value in (None, "(unset)") or key in ("name", "plant.builtin"):
            continue
        # the printed value is TOML that --set accepts, and it is the default
        pipeline = load_pipeline(None, [f"{key}={value}"])
        assert json.loads(json.dumps(flatten(pipeline.model_dump(by_alias=True)).get(key))) \
            == defaults[key], key
    described = [key for key, row in rows.items() if row[3]]
    assert len(described) == len(rows), sorted(set(rows) - set(described))
    assert rows["simulation.duration"][3] == "simulated time of each run, s" \
        and "rad" in rows["sensor.noise_std"][3]
    assert rows["controller.kv"][2] == "number > 0 or list of number > 0"
    assert rows["cbf_filter.backup"][2] == 'one of "verified", "least_violation"'
    assert rows["simulation.step"][2] == "number > 0, ≤ 0.1"


def test_a_pipelines_values_are_marked_where_they_differ_and_dry_run_lists_them():
    path = "pipelines/monte_carlo.toml"
    rows = listing(path)
    defaults, mine = dumped(), dumped(path)
    differing = {key for key in rows if key in mine and mine[key] != defaults.get(key)}
    assert {key for key, row in rows.items() if row[0] == "*"} == differing
    assert {"uncertainty.payload", "inertia_model.source", "sensor.noise_std"} <= differing
    plan = cosim_cli("run", path, "--dry-run", "--out", "/nonexistent/never")
    assert plan.returncode == 0, plan.stderr
    assert '  inertia_model.source = "nominal" (default "auto")' in plan.stdout
    assert "  runs.baseline_cbf.cbf_filter.velocity = \"plant\"" in plan.stdout
    only = listing(path, "--grep", "uncertainty.")
    assert set(only) == {k for k in rows if k.startswith("uncertainty.")}
    none = cosim_cli("params", "--grep", "no such key anywhere")
    assert none.returncode == 2 and "--grep no such key anywhere: no key" in none.stderr


def without_a_unit(rows: dict[str, tuple[str, str, str, str]]) -> dict[str, str]:
    """The keys whose meaning is not words (three of three letters or more, not a bare
    symbol) naming one of UNITS or NO_UNIT."""
    return {key: meaning for key, (_, _, _, meaning) in rows.items()
            if len(re.findall(r"[^\W\d_]{3,}", meaning)) < 3
            or not NAMES_A_UNIT.search(meaning)}


def test_every_key_has_a_meaning_in_words_that_names_its_unit():
    rows = listing()
    assert len(rows) > 60
    mine = {key: row for key, row in rows.items() if not key.startswith(RESTRUCTURED)}
    assert without_a_unit(mine) == {}
    # the rule itself: a bare symbol is refused, a meaning in words with its unit is not
    examples = {"bare": "Kv", "worded": "gain Kv on the filtered error r̂ in (21), N·m·s/rad"}
    assert without_a_unit({k: ("", "", "", v) for k, v in examples.items()}) == {"bare": "Kv"}


def test_a_keys_unit_is_the_first_its_meaning_names():
    """What a sweep's results say of a varied key's column (cosim.config.params.key_units):
    the first unit its meaning names, "1" for dimensionless, "mixed" for mixed units, none
    for a name, a flag or a path; a run's key (runs.NAME.key) its top-level key's."""
    from cosim.config.params import key_units, unit_named

    for key, (*_, meaning) in listing().items():
        found = NAMES_A_UNIT.search(meaning)
        named = found[1] if found else None
        expected = {"dimensionless": "1", "mixed units": "mixed"}.get(
            named, None if named in NO_UNIT else named)
        assert unit_named(meaning) == expected, key
    pipeline = load_pipeline(PAPER)
    assert key_units(pipeline, ["runs.proposed.controller.kv", "sensor.seed", "controller.init",
                                "cbf_filter.position_rate", "no.such.key"]) == {
        "runs.proposed.controller.kv": "N·m·s/rad", "sensor.seed": "1",
        "cbf_filter.position_rate": "1/s"}


def test_the_restructured_sections_keys_name_their_units_too():
    rows = listing()
    assert without_a_unit({k: row for k, row in rows.items() if k.startswith(RESTRUCTURED)}) == {}
