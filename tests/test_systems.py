"""Systems of FMUs as the plant (docs/systems.md): the drives model against its closed form,
the arm behind ideal drives equal to the one-FMU arm whatever order the system lists them
in, an algebraic loop refused by name (and run where declared delayed), a foreign FMU
(PythonFMU) as a component, an SSP exported, read back by FMPy's own SSP reader and run by
a plain FMPy loop written here (multi-rate), every component's variables in the trace and
the recording, the guarantee on a drive's lag and rotor inertia, and one message for each
bad input. Real FMUs throughout, run for 0.3 s."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import PAPER, assert_message, cosim_cli
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
from fmpy.fmi3 import FMU3Slave
from fmpy.ssp.ssd import read_ssd
from test_plant_swapping import FOREIGN_ARM, build_pythonfmu

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))
from bench_systems import plain_fmpy_loop  # noqa: E402 (the benchmarks' folder, just added)

from cosim.assemble import assemble
from cosim.cli import main
from cosim.config import PipelineError, load_pipeline
from cosim.plant_source import open_plant
from cosim.runner import run
from plant_fmu import build_fmu

ROOT = Path(__file__).resolve().parent.parent
DURATION = 0.3  # s
ARM = "planar_arm"
# The arm behind its drives as a pipeline's [plant.system], drives declared after the arm:
# a master stepping in declaration order would hand the arm last step's torque.
CONNECTIONS = [*(f"tau[{i}] -> drives.tau_cmd[{i}]" for i in (1, 2)),
               *(f"drives.tau[{i}] -> arm.tau[{i}]" for i in (1, 2)),
               *(f"drives.J_reflected[{i}] -> arm.Jm[{i}]" for i in (1, 2)),
               *(f"arm.{p}[{i}] -> {p}[{i}]" for p in ("q", "qdot") for i in (1, 2)),
               *(f"arm.M[{i},{j}] -> M[{i},{j}]" for i in (1, 2) for j in (1, 2))]


def system_toml(tmp: Path, name: str, drives: dict | None = None, connections=CONNECTIONS,
                delayed=(), extends: str = PAPER, multiple: int = 1, arm: str | None = None,
                components: str = "") -> Path:
    """A pipeline file extending ``extends`` whose plant is the arm (built-in, or the FMU
    ``arm``) behind built-in drives with ``drives`` parameters."""
    arm_table = f'fmu = "{arm}"' if arm else f'builtin = {{ model = "{ARM}", links = 2 }}'
    values = "\n".join(f'"{k}" = {v!r}' for k, v in (drives or {}).items())
    text = f'''extends = "{ROOT / extends}"
[simulation]
duration = {DURATION}
[plant.system]
name = "{name}"
connections = {json.dumps(list(connections))}
delayed = {json.dumps(list(delayed))}
[plant.system.components.arm]
{arm_table}
[plant.system.components.drives]
builtin = {{ model = "drives", links = 2, fmi_version = 3 }}
step_multiple = {multiple}
[plant.system.components.drives.parameters]
{values}
{components}'''
    path = tmp / f"{name}.toml"
    path.write_text(text)
    return path


def one_fmu(sets: list[str] = (), extends: str = PAPER):
    return run(load_pipeline(ROOT / extends, [f"simulation.duration={DURATION}", *sets]), None,
               progress=False)


def run_file(path: Path, sets: list[str] = ()):
    return run(load_pipeline(path, list(sets)), None, progress=False)


# The drives model ----------------------------------------------------------------------------

def test_the_drives_follow_their_closed_form(fmu_cache, tmp_path):
    """Stepped by FMPy alone: the current's lag is exp(-t/T) towards the clipped command,
    the joint torque N kt i, the reflected inertia J N²; an ideal drive passes the command
    through within the instant."""
    for version, cls in ((2, FMU2Slave), (3, FMU3Slave)):
        path = build_fmu(links=2, fmi_version=version, model="drives", cache_dir=fmu_cache)
        md = read_model_description(str(path))
        vr = {v.name: v.valueReference for v in md.modelVariables}
        fmu = cls(guid=md.guid, unzipDirectory=extract(str(path), tmp_path / f"fmi{version}"),
                  modelIdentifier=md.coSimulation.modelIdentifier, instanceName="d")
        fmu.instantiate()
        setter = fmu.setReal if version == 2 else fmu.setFloat64
        getter = fmu.getReal if version == 2 else fmu.getFloat64
        if version == 2:
            fmu.setupExperiment(startTime=0.0)
            fmu.enterInitializationMode()
        else:
            fmu.enterInitializationMode(startTime=0.0)
        values = {"N[1]": 50.0, "kt[1]": 0.2, "i_max[1]": 30.0, "T[1]": 0.004, "J[1]": 1e-4,
                  "N[2]": 1.0, "kt[2]": 1.0}
        setter([vr[k] for k in values], list(values.values()))
        fmu.exitInitializationMode()
        names = ["tau[1]", "tau[2]", "current[1]", "J_reflected[1]"]
        setter([vr["tau_cmd[1]"], vr["tau_cmd[2]"]], [200.0, -7.5])
        tau1, tau2, _, reflected = getter([vr[n] for n in names])
        assert tau1 == 0.0 and tau2 == -7.5  # a lag starts where it settled; ideal: at once
        assert reflected == pytest.approx(1e-4 * 50.0 ** 2, rel=1e-15)
        h, t = 1e-3, 0.0
        for _ in range(7):
            fmu.doStep(t, h)
            t += h
        tau1, _, current, _ = getter([vr[n] for n in names])
        target = 200.0 / (50.0 * 0.2)  # 20 A, inside the 30 A limit
        assert current == pytest.approx(target * (1 - np.exp(-t / 0.004)), rel=1e-12)
        assert tau1 == pytest.approx(50.0 * 0.2 * current, rel=1e-15)
        setter([vr["tau_cmd[1]"]], [1e6])  # far beyond the limit
        for _ in range(200):
            fmu.doStep(t, h)
            t += h
        assert getter([vr["tau[1]"]])[0] == pytest.approx(50.0 * 0.2 * 30.0, rel=1e-9)
        fmu.terminate()
        fmu.freeInstance()
        done = subprocess.run([sys.executable, "-m", "fmpy.cli", "validate", str(path)],
                              capture_output=True, text=True)
        assert "No problems found" in done.stdout, done.stdout + done.stderr


# Dependency order and loops ------------------------------------------------------------------

@pytest.fixture(scope="module")
def paper_one_fmu():
    return one_fmu()


def test_ideal_drives_reproduce_the_one_fmu_arm_whatever_order_the_system_lists(
        paper_one_fmu, tmp_path):
    results = run_file(system_toml(tmp_path, "ideal"))
    for name, single in paper_one_fmu.items():
        system = results[name]
        assert system.complete
        for signal in ("q", "qdot", "tau", "M"):
            assert np.array_equal(system.trace[signal], single.trace[signal]), (name, signal)
        # the drives' input and output and the arm's input, recorded under their names
        assert np.array_equal(system.trace["drives.tau_cmd"][:-1], single.trace["tau"][:-1])
        assert np.array_equal(system.trace["arm.tau"][:-1], single.trace["tau"][:-1])
    # the same system with its drive torque one step late (declared delayed) is another run:
    # the equality above is the order's doing
    late = run_file(system_toml(tmp_path, "late", delayed=[f"drives.tau[{i}] -> arm.tau[{i}]"
                                                           for i in (1, 2)],
                                connections=[c for c in CONNECTIONS
                                             if not c.startswith("drives.tau[")]))
    gap = np.abs(late["baseline"].trace["q"] - paper_one_fmu["baseline"].trace["q"]).max()
    assert gap > 1e-6


def test_an_algebraic_loop_is_refused_naming_it_and_runs_where_declared_delayed(
        paper_one_fmu, tmp_path):
    """Joint 1 of the drives and of a second set of ideal drives (each passes its command
    through within the instant) in a ring; the plant's torque goes around it, through the
    drives' joint 2 and the ring's joint 2."""
    ring = ('[plant.system.components.ring]\n'
            'builtin = { model = "drives", links = 2, fmi_version = 2 }\n')
    around = ["tau[1] -> drives.tau_cmd[2]", "drives.tau[2] -> arm.tau[1]",
              "tau[2] -> ring.tau_cmd[2]", "ring.tau[2] -> arm.tau[2]",
              "drives.tau[1] -> ring.tau_cmd[1]"]
    closing = "ring.tau[1] -> drives.tau_cmd[1]"
    rest = [c for c in CONNECTIONS if not c.startswith(("tau[", "drives.tau["))]
    path = system_toml(tmp_path, "looped", connections=rest + around + [closing],
                       components=ring)
    with pytest.raises(PipelineError) as caught:
        open_plant(load_pipeline(path))
    assert_message(str(caught.value), (
        "plant.system: an algebraic loop through drives, ring: drives.tau_cmd[1] -> "
        "drives.tau[1] -> ring.tau_cmd[1] -> ring.tau[1] -> drives.tau_cmd[1] (each output "
        "there depends on its component's input within the same instant, by the FMUs' "
        "ModelStructure); break it by declaring one of its connections delayed (a step's "
        "delay: plant.system.delayed, or cosim's annotation in the SSD)"))
    broken = run_file(system_toml(tmp_path, "broken", connections=rest + around,
                                  components=ring, delayed=[closing]))
    for name, single in paper_one_fmu.items():
        assert np.array_equal(broken[name].trace["q"], single.trace["q"]), name


# Another exporter's FMU, and a failing component ---------------------------------------------

@pytest.fixture(scope="module")
def foreign_fmu(tmp_path_factory) -> Path:
    return build_pythonfmu(FOREIGN_ARM, tmp_path_factory.mktemp("pythonfmu"))


FOREIGN = [*(f"tau[{i}] -> drives.tau_cmd[{i}]" for i in (1, 2)),
           "drives.tau[1] -> arm.shoulder_torque", "drives.tau[2] -> arm.elbow_torque",
           "arm.shoulder -> q[1]", "arm.elbow -> q[2]",
           "arm.shoulder_rate -> qdot[1]", "arm.elbow_rate -> qdot[2]"]


def test_a_pythonfmu_arm_behind_the_drives_runs_as_on_its_own(foreign_fmu, tmp_path):
    mapping = ['plant.variables.tau=["shoulder_torque", "elbow_torque"]',
               'plant.variables.q=["shoulder", "elbow"]',
               'plant.variables.qdot=["shoulder_rate", "elbow_rate"]']
    alone = one_fmu([f'plant.fmu="{foreign_fmu}"', *mapping])
    path = system_toml(tmp_path, "foreign", connections=FOREIGN, arm=str(foreign_fmu))
    behind = run_file(path)
    for name, result in alone.items():
        assert np.array_equal(behind[name].trace["q"], result.trace["q"]), name
    # a component that fails names itself, its FMI call and its own message
    with pytest.raises(Exception) as caught:
        run_file(path, ['plant.parameters."arm.fail_at"=0.1'])
    assert re.search(r"component 'arm': PythonArm\.fmu: fmi2DoStep failed at t = 0\.1 s "
                     r"\(status Discard\): the arm refuses to step past fail_at", str(caught.value))


# SSP out and in, and a second master ---------------------------------------------------------

DRIVES = {"N[1]": 100.0, "N[2]": 100.0, "kt[1]": 0.1, "kt[2]": 0.1, "i_max[1]": 3.0,
          "i_max[2]": 3.0, "T[1]": 0.002, "T[2]": 0.001, "J[1]": 1e-5, "J[2]": 2e-5}


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """The arm behind lagging, limited drives stepped every 2 master steps, run inline and
    from its own SSP export."""
    tmp = tmp_path_factory.mktemp("ssp")
    path = system_toml(tmp, "multirate", DRIVES, multiple=2)
    ssp = tmp / "multirate.ssp"
    done = cosim_cli("export-ssp", str(path), "--output", str(ssp))
    assert done.returncode == 0, done.stderr
    inline = run_file(path)
    from_ssp = run_file(path, [f'plant.ssp="{ssp}"'])
    return ssp, inline, from_ssp


def test_an_exported_ssp_is_read_by_fmpy_and_runs_as_the_pipeline_did(exported):
    ssp, inline, from_ssp = exported
    ssd = read_ssd(str(ssp))  # FMPy's reader, checking the file against SSP 1.0's schema
    assert sorted(c.name for c in ssd.system.elements) == ["arm", "drives"]
    assert len(ssd.system.connections) == len(CONNECTIONS)
    for name, result in inline.items():
        for key, values in result.trace.arrays.items():
            assert np.array_equal(values, from_ssp[name].trace[key], equal_nan=True), key


def test_a_plain_fmpy_loop_gives_the_same_trajectories(exported, tmp_path):
    """The exported system stepped by FMPy alone (benchmarks/bench_systems.py's loop, which
    reads it with FMPy's SSP reader and steps the drives, whose torque depends on their
    command within the instant, before the arm, every 2 steps as the SSP's annotation
    says), with the torque cosim's run commanded: the same joint angles."""
    ssp, inline, _ = exported
    for name, result in inline.items():
        assert result.complete
        q = plain_fmpy_loop(ssp, tmp_path / name, result.trace["tau"], result.trace.dt, 2)
        assert np.abs(q - result.trace["q"]).max() <= 1e-9, name


# Every component's variables in the trace and the recording ----------------------------------

def test_every_components_variables_are_recorded_under_its_name(tmp_path):
    out = tmp_path / "run"
    assert main(["run", "pipelines/arm_with_drives.toml", "--run", "baseline", "--set",
                 "simulation.duration=0.1", "--out", str(out), "--no-figures", "--quiet"]) == 0
    trace = np.load(out / "trace_baseline.npz")
    expected = {"drives.tau_cmd": (101, 2), "drives.tau": (101, 2), "drives.current": (101, 2),
                "drives.J_reflected": (101, 2), "arm.tau": (101, 2), "arm.Jm": (101, 2),
                "arm.q": (101, 2), "arm.qdot": (101, 2), "arm.M": (101, 2, 2),
                "arm.energy": (101,)}
    assert {key: trace[key].shape for key in expected} == expected
    assert np.array_equal(trace["arm.q"], trace["q"])
    assert np.array_equal(trace["drives.tau_cmd"][:-1], trace["tau"][:-1])
    summary = json.loads((out / "summary.json").read_text())
    system = summary["plant"]["system"]
    assert system["arm"] == "arm" and system["arm_torque"] == "arm.tau"
    assert system["components"]["drives"]["parameters"]["T[1]"] == 5e-4
    from rerun.chunk import RrdReader

    store = RrdReader(out / "recording.rrd").stream().collect()
    table = store.reader("sim_time", contents="/baseline/plant/**").to_arrow_table()
    for key in expected:
        component, name = key.split(".")
        column = table.column(f"/baseline/plant/{component}/{name}:Scalars:scalars")
        values = np.array([v for v in column.to_pylist() if v is not None], dtype=float)
        assert np.array_equal(values, trace[key].reshape(101, -1)), key


# The guarantee on a system's drives ----------------------------------------------------------

def guarantee(sets: list[str]) -> dict:
    pipeline = load_pipeline(ROOT / "pipelines/arm_with_drives.toml",
                             [f"simulation.duration={DURATION}", *sets])
    pipeline.runs = {"proposed_cbf": pipeline.runs["proposed_cbf"]}
    return run(pipeline, None, progress=False)["proposed_cbf"].metrics["guarantee"]


def test_the_guarantee_names_a_drives_lag_and_inertia_and_holds_with_ideal_drives():
    lagging = guarantee([])
    assert lagging["covered"] is False and lagging["broken"] is False
    assert any(text.startswith("plant drive 'drives': J[1] = 2e-05 kg·m² puts its rotor's "
                               "inertia, J N² = 0.2 kg·m², on joint 1's M") for text in
               lagging["outside"])
    lags = [text for text in lagging["outside"] if "(its lag)" in text]
    assert len(lags) == 2 and "drives.T[1] = 0.0005 s (its lag)" in lags[0]
    assert re.match(r"plant drive torque up to [\d.]+ N·m away from the command on joint 1 \(t "
                    r"= [\d.]+ s\), more than the 0 N·m uncertainty\.disturbance leaves for "
                    r"it: drives\.T\[1\] = 0\.0005 s \(its lag\)$", lags[0])
    ideal = guarantee(["plant.parameters={" + ", ".join(
        f'"drives.{key}[{i}]" = {value}' for i in (1, 2) for key, value in
        (("N", 1.0), ("kt", 1.0), ("i_max", 1e300), ("T", 0.0), ("J", 0.0))) + "}"])
    single = one_fmu(["runs.proposed_cbf.blocks=[\"reference\", \"sensor\", \"inertia_model\", "
                      "\"observer\", \"controller\", \"cbf_filter\"]"],
                     extends="pipelines/paper_safety.toml")["proposed_cbf"]
    assert ideal == single.metrics["guarantee"]
    # the lag alone, its torque error within uncertainty.disturbance (the filter's torque
    # limited to 1000 N·m, its first command reaching the arm one lag late): not outside
    lag_only = ["cbf_filter.torque_limit=1000.0", "plant.parameters={" + ", ".join(
        f'"drives.{key}[{i}]" = {value}' for i in (1, 2)
        for key, value in (("i_max", 1e300), ("J", 0.0))) + "}"]
    assert any("drives.T[1] = 0.0005 s (its lag)" in text
               for text in guarantee(lag_only)["outside"])
    declared = guarantee([*lag_only, "uncertainty.disturbance=1000.0"])
    assert not any("drive" in text for text in declared["outside"])


# One message for each bad input --------------------------------------------------------------

def rewritten(ssp: Path, dest: Path, ssd=None, drop: tuple[str, ...] = ()) -> Path:
    """``ssp`` with its SystemStructure.ssd changed by ``ssd(text)`` and ``drop``'s entries
    left out."""
    with zipfile.ZipFile(ssp) as source, zipfile.ZipFile(dest, "w") as target:
        for item in source.infolist():
            if item.filename in drop:
                continue
            data = source.read(item)
            if item.filename == "SystemStructure.ssd" and ssd is not None:
                data = ssd(data.decode()).encode()
            target.writestr(item, data)
    return dest


def bad_systems(tmp: Path, ssp: Path) -> list[tuple[list[str], str]]:
    """(--set assignments, the whole message as a pattern) per bad input."""
    fmu = r"PlanarArm2_fmi2_[0-9a-f]{16}\.fmu"
    cases = []
    ssd = tmp / "broken"
    ssd.mkdir(exist_ok=True)
    # an SSD that is not valid SSP 1.0, one that is not XML
    no_kind = rewritten(ssp, ssd / "no_kind.ssp", lambda t: t.replace(
        '<ssd:Connector name="tau[1]" kind="input">', '<ssd:Connector name="tau[1]">', 1))
    cases.append((f'plant.ssp="{no_kind}"', re.escape(
        "no_kind.ssp: SystemStructure.ssd: not valid SSP 1.0 (line 5: Element "
        "'{http://ssp-standard.org/SSP1/SystemStructureDescription}Connector': The attribute "
        "'kind' is required but missing.)")))
    not_xml = rewritten(ssp, ssd / "not_xml.ssp", lambda t: t.replace("</ssd:System>", ""))
    cases.append((f'plant.ssp="{not_xml}"', r"not_xml\.ssp: SystemStructure\.ssd: not XML "
                  r"\(line \d+, column \d+: .*\)"))
    # a type the FMU's variable does not have, a unit it is not in
    typed = rewritten(ssp, ssd / "typed.ssp", lambda t: t.replace(
        '<ssd:Connector name="tau_cmd[1]" kind="input">\n            <ssc:Real unit="N.m"/>',
        '<ssd:Connector name="tau_cmd[1]" kind="input">\n            <ssc:Integer/>', 1))
    cases.append((f'plant.ssp="{typed}"', r"component 'drives' \(drives\.fmu\), connector "
                  r"'tau_cmd\[1\]' \(typed\.ssp: SystemStructure\.ssd line \d+\): declared "
                  r"Integer, but the FMU's variable is Float64"))
    # a missing resource
    missing = rewritten(ssp, ssd / "missing.ssp", drop=("resources/drives.fmu",))
    cases.append((f'plant.ssp="{missing}"', r"missing\.ssp: SystemStructure\.ssd \(line \d+\): "
                  r"component 'drives': its source resources/drives\.fmu is not in "
                  r"missing\.ssp \(a missing resource\)"))
    # a connector that does not exist, mismatched units, an input fed twice
    unknown = [c.replace("arm.tau[1]", "arm.torque[1]") for c in CONNECTIONS]
    cases.append((f'plant.system.connections={json.dumps(unknown)}', (
        r"connection drives\.tau\[1\] -> arm\.torque\[1\] \(plant\.system\.connections\[3\] "
        r"'drives\.tau\[1\] -> arm\.torque\[1\]'\): component 'arm': " + fmu + r" has no "
        r"variable 'torque\[1\]' \(its inputs: tau\[1\], tau\[2\], Jm\[1\], Jm\[2\]\)")))
    units = [c.replace("drives.tau[1] -> arm.tau[1]", "drives.J_reflected[1] -> arm.tau[1]")
             for c in CONNECTIONS]
    cases.append((f'plant.system.connections={json.dumps(units)}', re.escape(
        "connection drives.J_reflected[1] -> arm.tau[1] (plant.system.connections[3] "
        "'drives.J_reflected[1] -> arm.tau[1]'): drives.J_reflected[1] is in kg.m2, arm.tau[1] "
        "in N.m; cosim converts no units (connect variables of one unit)")))
    twice = [*CONNECTIONS, "drives.tau[2] -> arm.tau[1]"]
    cases.append((f'plant.system.connections={json.dumps(twice)}', re.escape(
        "connection drives.tau[2] -> arm.tau[1] (plant.system.connections[15] 'drives.tau[2] "
        "-> arm.tau[1]'): arm.tau[1] is fed already (by drives.tau[1]); an input has one "
        "source")))
    backwards = [c.replace("arm.q[1] -> q[1]", "arm.tau[1] -> q[1]") for c in CONNECTIONS]
    cases.append((f'plant.system.connections={json.dumps(backwards)}', re.escape(
        "connection arm.tau[1] -> q[1] (plant.system.connections[7] 'arm.tau[1] -> q[1]'): "
        "arm.tau[1] is an input, and a connection's start must be an output")))
    written = ["drives.tau[1] => arm.tau[1]"]
    cases.append((f'plant.system.connections={json.dumps(written)}', re.escape(
        "plant.system.connections[1] = 'drives.tau[1] => arm.tau[1]': write a connection as "
        "\"START -> END\", each COMPONENT.CONNECTOR or a connector of the system's own (e.g. "
        "\"drives.tau[1] -> arm.tau[1]\")")))
    return cases


def test_every_bad_system_gets_one_message_naming_the_element(exported, tmp_path):
    ssp = exported[0]
    base = system_toml(tmp_path, "base", DRIVES)
    for assignment, expected in bad_systems(tmp_path, ssp):
        with pytest.raises(PipelineError) as caught:
            open_plant(load_pipeline(base, [assignment]))
        assert_message(str(caught.value), re.compile(expected))


def test_a_component_that_fails_to_instantiate_is_named(tmp_path, fmu_cache):
    arm = build_fmu(links=2, fmi_version=2, cache_dir=fmu_cache)
    wrong = tmp_path / "wrong_token.fmu"
    with zipfile.ZipFile(arm) as source, zipfile.ZipFile(wrong, "w") as target:
        for item in source.infolist():
            data = source.read(item)
            if item.filename == "modelDescription.xml":
                data = re.sub(rb'guid="\{[^}]*\}"', b'guid="{00000000-0000-0000-0000-'
                              b'000000000000}"', data)
            target.writestr(item, data)
    with pytest.raises(PipelineError) as caught:
        assemble(load_pipeline(system_toml(tmp_path, "token", arm=str(wrong))))
    assert_message(str(caught.value), re.compile(
        r"component 'arm': wrong_token\.fmu: fmi2Instantiate failed at t = 0 s \(.*\): "
        r"instantiation token \{00000000-0000-0000-0000-000000000000\} does not match this "
        r"binary's .*"))


def test_the_cli_refuses_a_loop_in_one_line_and_inspects_a_system(exported, tmp_path, capsys):
    ssp = exported[0]
    # the plant's tau[1] straight to the arm, the drives' joint 1 fed by its own torque
    looped = rewritten(ssp, tmp_path / "looped.ssp", lambda t: t.replace(
        '<ssd:Connection startConnector="tau[1]" endElement="drives" '
        'endConnector="tau_cmd[1]"/>',
        '<ssd:Connection startConnector="tau[1]" endElement="arm" endConnector="tau[1]"/>'
    ).replace(
        '<ssd:Connection startElement="drives" startConnector="tau[1]" endElement="arm" '
        'endConnector="tau[1]"/>',
        '<ssd:Connection startElement="drives" startConnector="tau[1]" endElement="drives" '
        'endConnector="tau_cmd[1]"/>'))
    assert main(["run", PAPER, "--dry-run", "--set", f'plant.ssp="{looped}"']) == 2
    (message,) = capsys.readouterr().err.strip().splitlines()
    assert_message(message, f"{looped}: an algebraic loop through drives: drives.tau_cmd[1] "
                   "-> drives.tau[1] -> drives.tau_cmd[1] (each output there depends on its "
                   "component's input within the same instant, by the FMUs' ModelStructure); "
                   "break it by declaring one of its connections delayed (a step's delay: "
                   "plant.system.delayed, or cosim's annotation in the SSD)")
    assert main(["inspect", str(ssp)]) == 0
    done = capsys.readouterr()
    assert "  drives  Drives2 (FMI 3.0, generated by cosim plant_fmu), drives.fmu, every 2 " \
           "steps" in done.out
    assert "  1. drives: set tau_cmd[1], tau_cmd[2]\n  2. drives: get current[1], " \
           "current[2], tau[1], tau[2]\n  3. arm: set tau[1], tau[2], Jm[1], " \
           "Jm[2]\n" in done.out
    assert "fits the cosim plant interface: yes, 2 joints" in done.out
