"""Results taken elsewhere and compared: `cosim export` round-trips every array of a run's
trace with its unit (Parquet, CSV, MAT, each read back by its own reader: pyarrow, the csv
module and NumPy, SciPy's loadmat), and `cosim compare` gates a change by its exit status.
Real runs of the paper's pipeline through the CLI."""

from __future__ import annotations

import csv
import json
import re

import numpy as np
import pyarrow.parquet as pq
import pytest
from cli_helpers import PAPER, cosim_cli
from scipy.io import loadmat

from cosim.assemble import assemble
from cosim.config import load_pipeline

SHORT = ["--set", "simulation.duration=2", "--no-recording", "--no-figures"]
# Units a reader of the paper expects, written here rather than taken from the code.
KNOWN_UNITS = {"time": "s", "q": "rad", "qdot": "rad/s", "qdot_hat": "rad/s", "tau": "N·m",
               "M": "kg·m²", "check_position_joint1": "rad",
               "check_velocity_true_joint1": "rad/s", "check_error_norm": "rad",
               "check_error_rate_joint1": "rad/s", "check_filtered_error_norm": "rad/s"}


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    """A: the paper's pipeline for 2 s; B: the same, the proposed run's reference on joint 1
    faster (0.58 rad/s, not 0.5) under the same bounds, so checks that held in A fail in B."""
    base = tmp_path_factory.mktemp("export")
    a, b = base / "a", base / "b"
    done = cosim_cli("run", PAPER, "--out", str(a), *SHORT)
    assert done.returncode == 0, done.stderr[-2000:]
    held = json.loads((a / "summary.json").read_text())["runs"]["proposed"]["safety"]
    assert held["velocity_true_joint1"]["satisfied"]
    done = cosim_cli("run", PAPER, "--out", str(b), *SHORT, "--set",
                     "runs.proposed.reference.frequency=[[0.58], [1.0]]")
    assert done.returncode == 0, done.stderr[-2000:]
    return a, b


def trace_arrays(folder, run):
    with np.load(folder / f"trace_{run}.npz") as data:
        return {k: data[k] for k in data.files if k != "_units"}


def declared_units(run: str) -> dict[str, str]:
    """What the assembled blocks declare, for every signal of the run."""
    pipeline = load_pipeline(PAPER, ["simulation.duration=0.01"])
    scenario = assemble(pipeline)
    try:
        return {name: s.unit for name, s in scenario.runs[run].signals.items()}
    finally:
        scenario.close()


def flat(name: str, values: np.ndarray) -> dict[str, np.ndarray]:
    """The columns an array should become: name, name[i] or name[i,j], 1-based."""
    if values.ndim == 1:
        return {name: values}
    if values.ndim == 2:
        return {f"{name}[{i + 1}]": values[:, i] for i in range(values.shape[1])}
    n = values.shape[1]
    return {f"{name}[{i + 1},{j + 1}]": values[:, i, j] for i in range(n) for j in range(n)}


def test_export_parquet_round_trips_every_array_with_its_unit(folders):
    a, _ = folders
    done = cosim_cli("export", str(a), "--format", "parquet")
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == [str(a / "export_baseline.parquet"),
                                   str(a / "export_proposed.parquet")]
    arrays = trace_arrays(a, "proposed")
    table = pq.read_table(a / "export_proposed.parquet")
    units = {f.name: f.metadata[b"unit"].decode() for f in table.schema}
    expected = {}
    for name, values in arrays.items():
        expected.update(flat(name, values))
    assert table.column_names[0] == "time" and set(table.column_names) == set(expected)
    for column, values in expected.items():
        np.testing.assert_array_equal(table.column(column).to_numpy(), values, err_msg=column)
    declared = declared_units("proposed")
    for column, unit in units.items():
        base = column.split("[")[0]
        if base in declared:
            assert unit == declared[base], column
        if base in KNOWN_UNITS:
            assert unit == KNOWN_UNITS[base], column
    assert all(base in {c.split("[")[0] for c in units} for base in KNOWN_UNITS)
    about = table.schema.metadata
    assert about[b"cosim.run"] == b"proposed" and about[b"cosim.pipeline"] == b"paper_two_link"


def test_export_csv_round_trips_exactly_with_units_in_the_header(folders, tmp_path):
    a, _ = folders
    done = cosim_cli("export", str(a), "--format", "csv", "--run", "baseline", "--out",
                     str(tmp_path))
    assert done.returncode == 0, done.stderr
    path = tmp_path / "export_baseline.csv"
    with path.open(encoding="utf-8") as f:
        header = next(csv.reader(f))
    data = np.loadtxt(path, delimiter=",", skiprows=1)
    expected = {}
    for name, values in trace_arrays(a, "baseline").items():
        expected.update(flat(name, values))
    parsed = [re.fullmatch(r"(\S+?)(?: \((.+)\))?", cell).groups() for cell in header]
    assert [p[0] for p in parsed] == list(expected)
    for c, (name, unit) in enumerate(parsed):
        np.testing.assert_array_equal(data[:, c], expected[name], err_msg=name)
        base = name.split("[")[0]
        if base in KNOWN_UNITS:
            assert unit == KNOWN_UNITS[base], name
    assert not (a / "export_baseline.csv").exists()  # --out: nothing in the run folder


def test_export_mat_keeps_shapes_and_units(folders, tmp_path):
    a, _ = folders
    done = cosim_cli("export", str(a), "--format", "mat", "--out", str(tmp_path))
    assert done.returncode == 0, done.stderr
    mat = loadmat(tmp_path / "export_proposed.mat", squeeze_me=False)
    arrays = trace_arrays(a, "proposed")
    for name, values in arrays.items():
        got = mat[name]
        np.testing.assert_array_equal(got.reshape(values.shape), values, err_msg=name)
        if values.ndim > 1:
            assert got.shape == values.shape, name
    units = mat["units"][0, 0]
    for name, unit in KNOWN_UNITS.items():
        assert str(units[name][0]) == unit, name


def test_export_refuses_what_it_cannot_or_must_not_do(folders, tmp_path):
    a, _ = folders
    taken = tmp_path / "export_proposed.parquet"
    taken.write_bytes(b"the user's own file")
    done = cosim_cli("export", str(a), "--out", str(tmp_path))
    assert done.returncode == 2
    assert done.stderr.strip() == (f"cosim: error: {taken}: already exists; pass --force to "
                                   "replace it")
    assert taken.read_bytes() == b"the user's own file"
    assert not (tmp_path / "export_baseline.parquet").exists()  # refused before any write
    done = cosim_cli("export", str(a), "--run", "nope")
    assert done.returncode == 2 and "--run nope: " in done.stderr
    assert "its runs are baseline, proposed" in done.stderr
    done = cosim_cli("export", str(tmp_path))
    assert done.returncode == 2 and "not a cosim run folder" in done.stderr
    assert "Traceback" not in done.stderr


def test_exports_in_a_run_folder_are_cosims_own(tmp_path):
    """An export written into the run folder does not make it foreign: --force replaces it.
    (`cosim run --run NAME` runs only that run.)"""
    target = tmp_path / "run"
    assert cosim_cli("run", PAPER, "--out", str(target), "--run", "proposed", "--no-recording",
                     "--no-figures", "--set", "simulation.duration=0.2").returncode == 0
    assert list(json.loads((target / "summary.json").read_text())["runs"]) == ["proposed"]
    assert cosim_cli("export", str(target), "--format", "csv").returncode == 0
    assert sorted(p.name for p in target.iterdir()) == ["export_proposed.csv", "summary.json",
                                                        "summary.md", "trace_proposed.npz"]
    done = cosim_cli("run", PAPER, "--out", str(target), "--no-recording", "--no-figures",
                     "--set", "simulation.duration=0.2", "--force")
    assert done.returncode == 0, done.stderr
    assert not (target / "export_proposed.csv").exists()


def test_compare_gates_a_regression_by_its_exit_status(folders):
    a, b = folders
    same = cosim_cli("compare", str(a), str(a))
    assert same.returncode == 0, same.stderr
    assert "no regression: every check that held in A holds in B" in same.stdout
    worse = cosim_cli("compare", str(a), str(b))
    assert worse.returncode == 1, worse.stderr
    regressions = worse.stdout.split("regression(s):")[1].split("\n")
    named = [line.strip() for line in regressions if line.strip()]
    assert {line.split(":")[0] for line in named} == {
        "proposed/velocity_true_joint1", "proposed/velocity_estimated_joint1",
        "proposed/observer_error_norm"}
    assert any(line.startswith("proposed/velocity_true_joint1: held in A") for line in named)
    assert "REGRESSED" in worse.stdout
    better = cosim_cli("compare", str(b), str(a))
    assert better.returncode == 0 and "now holds" in better.stdout
    assert max(len(line) for line in worse.stdout.splitlines()) <= 100
    missing = cosim_cli("compare", str(a), str(a.parent))
    assert missing.returncode == 2 and "not a cosim run folder" in missing.stderr


def test_every_export_format_has_its_writer_and_is_offered_by_the_command():
    """The formats are listed once (cosim/outputs/formats.py): each has a writer, the
    command offers each, and the run folder counts each export file as its own."""
    from cosim.outputs.export import WRITERS
    from cosim.outputs.folder_owner import our_entries
    from cosim.outputs.formats import EXPORT_FORMATS

    assert set(WRITERS) == set(EXPORT_FORMATS)
    offered = cosim_cli("export", "--help").stdout
    assert all(name in offered for name in EXPORT_FORMATS)
    assert {f"export_paper{suffix}" for suffix in EXPORT_FORMATS.values()} <= \
        our_entries({"runs": {"paper": {}}})


def test_every_metric_has_its_unit_in_the_summary_and_in_compare(folders):
    """Each number a run's metrics give has the unit its evaluator declares (summary.json's
    metric_units), and `cosim compare` shows it beside the metric, in text and JSON."""
    from cosim.evaluate.parts import metric_unit
    from cosim.outputs.compare import _numbers

    a, b = folders
    for run in json.loads((a / "summary.json").read_text())["runs"].values():
        bare = [m for m in _numbers(run["metrics"]) if metric_unit(run["metric_units"], m) is None]
        assert not bare, bare
        assert metric_unit(run["metric_units"], "peak_torque[2]") == "N·m"
        assert metric_unit(run["metric_units"], "theorem1.R") == "rad/s"
    assert metric_unit({"a": "s"}, "b") is None and metric_unit({}, "a.b[1]") is None
    text = cosim_cli("compare", str(a), str(b), "--run", "proposed")
    assert text.returncode == 1 and "metric (unit)" in text.stdout
    assert re.search(r"^  rms_error\[1\] \(rad\) ", text.stdout, re.M), text.stdout
    assert re.search(r"^  peak_torque\[1\] \(N·m\) ", text.stdout, re.M), text.stdout
    document = json.loads(cosim_cli("compare", str(a), str(b), "--run", "proposed",
                                    "--json").stdout)
    metrics = document["runs"]["proposed"]["metrics"]
    assert metrics["rms_error_rate[2]"]["unit"] == "rad/s"
    assert metrics["wall_time_s"]["unit"] == "s"


def test_compare_says_when_units_are_missing_or_differ(folders, tmp_path):
    """Folders of an older cosim (no metric_units, or an entry that is not a table) are
    compared with the metrics bare, and said so; a metric whose unit differs between A and
    B is not subtracted, and said so."""
    import shutil

    a, b = folders
    copies = {}
    for name, change in (("old_a", None), ("old_b", None), ("text", "N·m"),
                         ("kilo", {"peak_torque": "kN·m"})):
        copies[name] = tmp_path / name
        shutil.copytree(b if name != "old_a" else a, copies[name])
        summary = json.loads((copies[name] / "summary.json").read_text())
        for run in summary["runs"].values():
            if change is None:
                del run["metric_units"]
            elif isinstance(change, str):
                run["metric_units"] = change
            else:
                run["metric_units"].update(change)
        (copies[name] / "summary.json").write_text(json.dumps(summary))
    old = cosim_cli("compare", str(copies["old_a"]), str(copies["old_b"]), "--run", "proposed")
    assert old.returncode == 1, old.stderr
    assert "(neither folder declares its metrics' units: written by an older cosim" in old.stdout
    assert re.search(r"^  peak_torque\[1\] ", old.stdout, re.M), old.stdout
    text = cosim_cli("compare", str(a), str(copies["text"]), "--run", "proposed")
    assert text.returncode == 1 and "Traceback" not in text.stderr, text.stderr
    assert re.search(r"^  peak_torque\[1\] \(N·m\) ", text.stdout, re.M), text.stdout
    kilo = cosim_cli("compare", str(a), str(copies["kilo"]), "--run", "proposed", "--json")
    peak = json.loads(kilo.stdout)["runs"]["proposed"]["metrics"]["peak_torque[1]"]
    assert peak["unit"] is None and (peak["unit_a"], peak["unit_b"]) == ("N·m", "kN·m")
    assert peak["b_minus_a"] is None
    shown = cosim_cli("compare", str(a), str(copies["kilo"]), "--run", "proposed").stdout
    assert re.search(r"^  peak_torque\[1\] \(A N·m, B kN·m\) .*units differ: not "
                     r"subtracted$", shown, re.M), shown


# compare as a gate that verifies: a summary edited or damaged is not judged ------------------

def edited(source, folder, change) -> object:
    """A copy of the run folder ``source`` at ``folder`` whose summary.json's proposed run's
    error_joint1 entry (or, given a whole-summary change, the summary) ``change`` edits."""
    import shutil

    shutil.copytree(source, folder)
    summary = json.loads((folder / "summary.json").read_text())
    change(summary, summary["runs"]["proposed"]["safety"]["error_joint1"])
    (folder / "summary.json").write_text(json.dumps(summary))
    return folder


KEY = "summary.json's runs.proposed.safety.error_joint1"
EDITS = {
    # (the catalogue's false successes: a verdict believed, not recomputed)
    "worse than its bound, said held": (lambda s, e: e.update(worst=99), "{key} disagrees with "
                                        "its own numbers: satisfied = true, but its worst value "
                                        "99 rad is beyond its bound 1.0 rad; a summary.json "
                                        "edited or damaged is not judged"),
    "NaN": (lambda s, e: e.update(worst=float("nan")), "{key} disagrees with its own numbers: "
            "satisfied = true, but its worst value is NaN, not known to be within its bound "
            "1.0 rad; a summary.json edited or damaged is not judged"),
    "not its trace's": (lambda s, e: e.update(worst=0.5), "{key} disagrees with the run's trace: "
                        "worst 0.5 rad, satisfied = true in summary.json; worst {worst} rad, "
                        "satisfied = true from trace_proposed.npz's check_error_joint1 against "
                        "the bound 1.0 rad; a summary.json edited or damaged is not judged"),
    # (a traceback, and a string taken as true)
    "a worst value in quotes": (lambda s, e: e.update(worst="0.1"),
                                '{key}.worst = "0.1" is not a number (or null: unknown)'),
    "satisfied = 'yes'": (lambda s, e: e.update(satisfied="yes"),
                          '{key}.satisfied = "yes" is not true or false (or null: unknown)'),
    "an unknown kind": (lambda s, e: e.update(kind="bogus"),
                        '{key}.kind = "bogus" is not one of hard, soft, sufficient'),
}


@pytest.mark.parametrize("case", EDITS)
def test_compare_refuses_a_summary_its_numbers_disagree_with(folders, tmp_path, case):
    from cli_helpers import error_line, here, tree

    a, _ = folders
    change, expected = EDITS[case]
    worst = json.loads((a / "summary.json").read_text())[
        "runs"]["proposed"]["safety"]["error_joint1"]["worst"]
    b = edited(a, tmp_path / "b", change)
    before = tree(tmp_path)
    message = error_line(here("compare", str(a), str(b)))
    assert message == "cosim: error: B " + f"{b}: " + expected.format(key=KEY, worst=worst)
    assert tree(tmp_path) == before


def test_compare_refuses_a_folder_it_cannot_verify(folders, tmp_path):
    """A summary that is not JSON (it said "no summary.json" of one it has), a run without
    its trace."""
    from cli_helpers import error_line, here

    a, _ = folders
    garbled = edited(a, tmp_path / "garbled", lambda s, e: None)
    (garbled / "summary.json").write_text("{not json")
    traceless = edited(a, tmp_path / "traceless", lambda s, e: None)
    (traceless / "trace_baseline.npz").unlink()
    assert error_line(here("compare", str(a), str(garbled))) == (
        f"cosim: error: B {garbled}: its summary.json cannot be read (not JSON: Expecting "
        "property name enclosed in double quotes: line 1 column 2 (char 1)); give folders "
        "`cosim run --out` wrote, as it wrote them")
    assert error_line(here("compare", str(traceless), str(a))) == (
        f"cosim: error: A {traceless}: trace_baseline.npz does not exist, so the checks of run "
        "baseline cannot be verified against their values; give folders `cosim run --out` "
        "wrote, as it wrote them")


def test_compare_counts_a_check_of_one_side_only(folders, tmp_path):
    """A check new in B and violated there was never counted (regression: false); one
    violated in A and gone from B is counted too (B no longer checks it)."""
    from cli_helpers import here

    a, b = folders
    check = "velocity_true_joint1"
    entry = json.loads((b / "summary.json").read_text())["runs"]["proposed"]["safety"][check]
    assert entry["satisfied"] is False  # violated in B (the faster reference)
    shown = f"{entry['worst']:.4g} VIOLATED"

    def without(summary, _):
        del summary["runs"]["proposed"]["safety"][check]

    new = here("compare", str(edited(a, tmp_path / "a_without", without)), str(b), "--json")
    assert new.returncode == 1, new.stderr
    document = json.loads(new.stdout)
    assert f"proposed/{check}: not in A, {shown} in B" in document["regressions"]
    assert document["runs"]["proposed"]["checks"][check]["change"] == "only in b"
    gone = here("compare", str(b), str(edited(b, tmp_path / "b_without", without)), "--json")
    assert gone.returncode == 1, gone.stderr
    assert json.loads(gone.stdout)["regressions"] == [
        f"proposed/{check}: checked in A ({shown}), not in B (-)"]


def test_compare_reads_no_trace_entry_larger_than_its_run(folders, tmp_path):
    """A trace's check values are read to verify the summary (a new reader of a shared
    folder's files): an entry larger than the run's rows is refused before it is read."""
    import shutil
    import zipfile

    a, _ = folders
    b = tmp_path / "b"
    shutil.copytree(a, b)
    with np.load(b / "trace_proposed.npz") as data:
        arrays = {key: data[key] for key in data.files}
    arrays["check_error_joint1"] = np.tile(arrays["check_error_joint1"], 1000)
    np.savez(b / "trace_proposed.npz", **arrays)
    with zipfile.ZipFile(b / "trace_proposed.npz") as archive:
        size = archive.getinfo("check_error_joint1.npy").file_size
    from cli_helpers import assert_message, error_line, here

    assert_message(error_line(here("compare", str(a), str(b))), re.compile(
        rf"B {re.escape(str(b))}: trace_proposed\.npz's check_error_joint1 cannot be read "
        rf"\(it says it holds {size} bytes, more than the run's rows take \(\d+\)\)"))
