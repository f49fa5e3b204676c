"""The ledger of assumptions and margin terms (docs/safety/ledger.md) against the code it
describes: each row's place (a file and a function or an excerpt of its code), its test and
its mutant exist and agree, and every curated mutant of the filter, the observer, the
premises, the guarantee and Theorem 1's quantities has its row. Pure text: no kernel is
imported or compiled."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LEDGER = ROOT / "docs" / "safety" / "ledger.md"
COLUMNS = ["term", "formula", "place", "test", "mutant"]
# the files whose every curated mutant must have a row
LEDGERED = ("cosim/paper/cbf_filter/", "cosim/paper/observer.py", "cosim/paper/observer_block.py",
            "cosim/paper/envelope.py", "cosim/paper/position_windows.py",
            "cosim/paper/premises.py",
            "cosim/paper/guarantee.py", "cosim/paper/within_bounds.py",
            "cosim/paper/viable_start.py", "cosim/paper/theorem.py")


def mutants() -> list[tuple]:
    """benchmarks/mutants.py's MUTANTS: (id, file, text, replacement, tests)."""
    spec = importlib.util.spec_from_file_location("mutants", ROOT / "benchmarks" / "mutants.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.MUTANTS


def cells(line: str) -> list[str]:
    """A table row's cells: split at the pipes outside code spans that are not escaped."""
    out, current, code = [], "", False
    for i, char in enumerate(line.strip().strip("|")):
        if char == "`":
            code = not code
        if char == "|" and not code and (i == 0 or line.strip().strip("|")[i - 1] != "\\"):
            out.append(current.strip())
            current = ""
        else:
            current += char
    return [*out, current.strip()]


def ledger_rows(text: str) -> list[dict]:
    """Every row of the ledger's tables (each with the columns COLUMNS), with its group (the
    section it is in) and its line."""
    rows, group, header = [], None, None
    for number, line in enumerate(text.splitlines(), 1):
        if line.startswith("## "):
            group, header = line[3:], None
        elif line.startswith("|") and header is None:
            header = [c.lower() for c in cells(line)]
            assert header == COLUMNS, (number, header)
        elif line.startswith("|") and not set(line) <= set("|-: "):
            values = cells(line)
            assert len(values) == len(COLUMNS), (number, values)
            rows.append({"group": group, "line": number, **dict(zip(COLUMNS, values,
                                                                    strict=True))})
        elif not line.startswith("|"):
            header = None if not line.strip() else header
    return rows


def spans(cell: str) -> list[str]:
    return re.findall(r"`([^`]+)`", cell)


def problems(rows: list[dict], curated: list[tuple]) -> list[str]:
    """Every disagreement between the ledger's rows and the code, tests and mutants."""
    found = []
    by_id = {m[0]: m for m in curated}
    named = set()
    for row in rows:
        where = f"ledger line {row['line']} ({row['term']})"
        if not row["term"] or not row["formula"]:
            found.append(f"{where}: no term or formula")
        place = spans(row["place"])
        if len(place) != 2:
            found.append(f"{where}: the place is not `file` `function or excerpt`")
            continue
        path, excerpt = place
        source = ROOT / path
        if not source.is_file():
            found.append(f"{where}: no file {path}")
            continue
        if excerpt not in source.read_text(encoding="utf-8"):
            found.append(f"{where}: {excerpt!r} is not in {path}")
        tests = spans(row["test"])
        if not tests:
            found.append(f"{where}: no test")
        for node in tests:
            file, _, name = node.partition("::")
            test_file = ROOT / file
            if not name or not test_file.is_file():
                found.append(f"{where}: no test file {file} or no test named")
            elif not re.search(rf"^\s*def {re.escape(name)}\(", test_file.read_text(
                    encoding="utf-8"), re.MULTILINE):
                found.append(f"{where}: no def {name} in {file}")
        ids = [] if row["mutant"].startswith("none: ") else spans(row["mutant"])
        if not ids and not row["mutant"].startswith("none: "):
            found.append(f"{where}: the mutant is neither an id nor 'none: why'")
        for ident in ids:
            named.add(ident)
            if ident not in by_id:
                found.append(f"{where}: no mutant {ident} in benchmarks/mutants.py")
                continue
            _, file, text, _, _ = by_id[ident]
            if file != path:
                found.append(f"{where}: mutant {ident} is in {file}, the place in {path}")
            elif (ROOT / file).read_text(encoding="utf-8").count(text) != 1:
                found.append(f"{where}: mutant {ident}'s text no longer occurs once in {file}")
    for ident, file, *_ in curated:
        if file.startswith(LEDGERED) and ident not in named:
            found.append(f"mutant {ident} ({file}) has no row in the ledger")
    return found


def test_the_ledger_agrees_with_the_code_its_tests_and_its_mutants():
    rows = ledger_rows(LEDGER.read_text(encoding="utf-8"))
    assert len(rows) >= 60, len(rows)
    assert problems(rows, mutants()) == []


def test_the_ledger_has_every_group():
    groups = {row["group"] for row in ledger_rows(LEDGER.read_text(encoding="utf-8"))}
    assert groups == {"Assumptions declared", "Assumptions checked at run start",
                      "Premises measured along the run", "Margin terms of the filter",
                      "The observer's bound ε(t)", "Theorem 1's quantities (evaluation only)"}


def test_a_wrong_row_is_found():
    """Each check fails on a row planted wrong: a missing excerpt, test and mutant, a mutant
    in another file, and a curated mutant with no row."""
    rows = ledger_rows(LEDGER.read_text(encoding="utf-8"))
    row = {**rows[0], "place": "`cosim/paper/premises.py` `no such code`",
           "test": "`tests/test_premises.py::test_no_such_test`",
           "mutant": "`no-such-mutant` `cbf-velocity-eps`"}
    found = problems([row], mutants())
    assert any("'no such code' is not in" in p for p in found)
    assert any("no def test_no_such_test" in p for p in found)
    assert any("no mutant no-such-mutant" in p for p in found)
    assert any("mutant cbf-velocity-eps is in cosim/paper/cbf_filter/groups.py" in p
               for p in found)
    assert any(p.startswith("mutant premises-interval-doubled ") for p in found)
