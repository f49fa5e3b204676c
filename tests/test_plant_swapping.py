"""Plant swapping: the same pipeline on other FMUs (FMI 3.0, another exporter, three links, a
payload the controller's model does not know), `cosim inspect`, linearisation, and a clear
error for every FMU or mapping that does not fit. Bad FMUs are built on the fly from real ones.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import PAPER, cosim_cli
from fmu_helpers import FmuInstance, fmu_parameters

from cosim import linearize  # the public, importable function
from cosim.cli import main
from cosim.config import load_pipeline
from cosim.paper.inertia import planar_mass_matrix
from cosim.plant.fmu import Fmu
from cosim.plant.inspection import inspect_fmu
from cosim.plant.linearization import linearize_at_start
from cosim.plant.mapping import FmuError
from cosim.runner import run

FOREIGN_ARM = Path(__file__).parent / "foreign" / "python_arm.py"
# The paper's pipeline through the PythonFMU arm's own names.
FOREIGN_MAPPING = ['plant.variables.tau=["shoulder_torque", "elbow_torque"]',
                   'plant.variables.q=["shoulder", "elbow"]',
                   'plant.variables.qdot=["shoulder_rate", "elbow_rate"]']


def build_pythonfmu(script: Path, dest: Path) -> Path:
    """Export a PythonFMU slave script with the real `pythonfmu build`."""
    dest.mkdir(parents=True, exist_ok=True)
    subprocess.run([sys.executable, "-m", "pythonfmu", "build", "-f", str(script), "-d",
                    str(dest)], check=True, capture_output=True, text=True)
    (fmu,) = dest.glob("*.fmu")
    return fmu


@pytest.fixture(scope="module")
def foreign_fmu(tmp_path_factory) -> Path:
    return build_pythonfmu(FOREIGN_ARM, tmp_path_factory.mktemp("pythonfmu"))


def paper_on(plant: list[str], duration: float = 20.0):
    pipeline = load_pipeline(PAPER, plant + [f"simulation.duration={duration}"])
    return run(pipeline, None, progress=False)


@pytest.fixture(scope="module")
def builtin_fmi2():
    return paper_on([])


# FMI 2.0 vs 3.0 ------------------------------------------------------------------------------

def test_fmi2_and_fmi3_builds_give_the_same_paper_result(builtin_fmi2):
    fmi3 = paper_on(["plant.builtin={ links = 2, fmi_version = 3 }"])
    for name, result in builtin_fmi2.items():
        other = fmi3[name]
        assert result.complete and other.complete
        for signal in ("q", "qdot", "tau", "qdot_hat", "M"):
            scale = max(1.0, np.abs(result.trace[signal]).max())
            assert np.abs(result.trace[signal] - other.trace[signal]).max() <= 1e-9 * scale, \
                (name, signal)
        for check, entry in result.safety.items():
            assert entry["satisfied"] == other.safety[check]["satisfied"]
            assert entry["worst"] == pytest.approx(other.safety[check]["worst"], abs=1e-9)


# Another exporter ----------------------------------------------------------------------------

def test_pythonfmu_arm_under_other_names_matches_the_builtin_plant(foreign_fmu, builtin_fmi2):
    """PythonFMU's arm has no M outputs: the controller's model is then the nominal one (the
    paper's arm, at the measured position), so this also checks the nominal model in the
    loop against the FMU's own M."""
    foreign = paper_on([f'plant.fmu="{foreign_fmu}"', *FOREIGN_MAPPING])
    for name, result in builtin_fmi2.items():
        other = foreign[name]
        assert other.complete and other.inertia_model["source"] == "nominal"
        assert result.inertia_model["source"] == "fmu"
        assert np.ptp(other.trace["q"][:, 0]) > 30  # it really tracked the ±20 rad reference
        assert np.isnan(other.trace["M"]).all()  # no M from this plant...
        assert np.abs(other.trace["M_model"] - result.trace["M_model"]).max() < 1e-8  # ...model
        assert np.abs(other.trace["q"] - result.trace["q"]).max() < 1e-8
        tau_scale = np.abs(result.trace["tau"]).max()
        assert np.abs(other.trace["tau"] - result.trace["tau"]).max() < 1e-8 * tau_scale
        assert {k: v["satisfied"] for k, v in other.safety.items()} == \
            {k: v["satisfied"] for k, v in result.safety.items()}


EXIT_SCRIPT = """
import sys
import cosim.paper.controller  # numba, numpy's Fortran runtime: what made the heap matter
from cosim.plant.fmu import Fmu
plant = Fmu(sys.argv[1], {"tau": ["shoulder_torque", "elbow_torque"],
                          "q": ["shoulder", "elbow"]})
for _ in range(2):
    plant.start(0.0)
    for k in range(100):
        plant.step(k * 1e-3, 1e-3)
plant.close()
"""


def test_a_process_that_ran_a_pythonfmu_plant_exits_cleanly(foreign_fmu):
    """PythonFMU 0.7.0 resets a destroyed static shared_ptr when its library unloads; before
    cosim released it first (fmu._release_pythonfmu), such a process aborted at exit with
    "corrupted double-linked list" in about half of the runs (measured 6/12 and 7/8)."""
    for _ in range(5):
        done = subprocess.run([sys.executable, "-c", EXIT_SCRIPT, str(foreign_fmu)],
                              capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, done.stderr[-2000:]


def test_mapping_from_the_command_line_with_a_notice_of_the_inertia_model(foreign_fmu,
                                                                          tmp_path):
    args = ["run", PAPER, "--out", str(tmp_path), "--no-recording", "--no-figures",
            "--set", "simulation.duration=0.2", "--set", f'plant.fmu="{foreign_fmu}"']
    for assignment in FOREIGN_MAPPING:
        args += ["--set", assignment]
    done = cosim_cli(*args)
    assert done.returncode == 0, done.stderr
    assert "inertia model nominal (m = [0.8, 2.3] kg" in done.stderr
    assert "PythonArm.fmu maps no M outputs" in done.stderr
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["plant"]["model_name"] == "PythonArm" and summary["complete"]
    assert summary["runs"]["proposed"]["inertia_model"]["m"] == [0.8, 2.3]


def test_a_plant_without_qdot_runs_the_proposed_controller_with_those_checks_unavailable(
        foreign_fmu, tmp_path):
    """Output feedback needs only q: the true velocity's checks are reported as unavailable,
    not as violated, and the recording is still written."""
    pipeline = load_pipeline(PAPER, [f'plant.fmu="{foreign_fmu}"', *FOREIGN_MAPPING[:2],
                                     "simulation.duration=1.5"])
    del pipeline.runs["baseline"]
    result = run(pipeline, tmp_path, progress=False, figures=False)["proposed"]
    assert result.complete and np.isnan(result.trace["qdot"]).all()
    for check in ("velocity_true_joint1", "velocity_true_norm", "observer_error_norm"):
        entry = result.safety[check]
        assert entry["worst"] is None and entry["satisfied"] is None
        assert "no qdot" in entry["unavailable"]
    assert result.safety["error_joint1"]["satisfied"]
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["complete"] and "qdot" not in summary["plant"]["variables"]
    assert summary["plant"]["variables"]["q"] == ["shoulder", "elbow"]
    assert (tmp_path / "recording.rrd").stat().st_size > 1e5


# Other pipelines -----------------------------------------------------------------------------

def test_three_link_pipeline_runs_and_reports_its_checks(tmp_path):
    done = cosim_cli("run", "pipelines/three_link.toml", "--out", str(tmp_path), "--no-figures")
    assert done.returncode == 0, done.stderr
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["complete"]
    proposed = summary["runs"]["proposed"]
    assert len(proposed["metrics"]["peak_torque"]) == 3
    assert proposed["inertia_model"]["source"] == "fmu"
    for check in ("error_norm", "error_rate_norm", "velocity_estimated_norm", "position_norm"):
        assert proposed["safety"][check]["satisfied"], check
        assert not summary["runs"]["baseline"]["safety"][check]["satisfied"], check
    assert max(proposed["metrics"]["torque_reversals_per_s"]) < 2  # no chattering
    assert (tmp_path / "recording.rrd").stat().st_size > 1e6
    assert "error_norm" in done.stdout  # the check table was printed


def test_payload_mismatch_pipeline_uses_the_true_and_the_nominal_model(tmp_path):
    results = run(load_pipeline("pipelines/payload_mismatch.toml"), tmp_path, progress=False,
                  record=False, figures=False)
    true_model, nominal = results["true_model"], results["nominal_model"]
    assert true_model.complete and nominal.complete
    assert true_model.inertia_model == {"source": "fmu"}
    assert nominal.inertia_model["source"] == "nominal"
    trace = nominal.trace
    # The plant carries the payload, the nominal model does not: M̂22 = 2.3 < M22 = 2.8.
    assert np.allclose(trace["M"][:, 1, 1], 2.8) and np.allclose(trace["M_model"][:, 1, 1], 2.3)
    assert np.array_equal(true_model.trace["M_model"], true_model.trace["M"])
    for result in results.values():
        assert result.safety["error_joint1"]["satisfied"]
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["plant"]["parameters"]["m[2]"] == 2.8


# The nominal inertia model -------------------------------------------------------------------

@pytest.mark.parametrize("links", [2, 3, 5])
def test_nominal_inertia_model_equals_the_fmus_M(plant_fmu, links):
    """planar_mass_matrix against the built-in FMU's M outputs (which test_plant_fmu checks
    against Pinocchio) for a chain with offsets and rotational inertias."""
    rng = np.random.default_rng(links)
    params = {"m": rng.uniform(0.5, 3, links), "l": rng.uniform(0.4, 1.5, links),
              "lc": rng.uniform(0.1, 0.9, links), "I": rng.uniform(0.01, 0.5, links)}
    for _ in range(3):
        q = rng.uniform(-3, 3, links)
        with Fmu(plant_fmu(links, 2), parameters=fmu_parameters(params, q0=q)) as plant:
            plant.start(0.0)
            expected = plant.values["M"].copy()
        out = np.zeros((links, links))
        planar_mass_matrix(q, params["m"], params["l"], params["lc"], params["I"], out)
        assert np.allclose(out, expected, rtol=1e-12, atol=1e-12)


# Clear errors --------------------------------------------------------------------------------

def rewrite(source: Path, dest: Path, change_xml=None, drop=(), add=()) -> Path:
    """A copy of an FMU with its model description changed, entries dropped or added."""
    with zipfile.ZipFile(source) as src, zipfile.ZipFile(dest, "w") as out:
        for item in src.infolist():
            if any(item.filename.startswith(prefix) for prefix in drop):
                continue
            data = src.read(item.filename)
            if item.filename == "modelDescription.xml" and change_xml:
                data = change_xml(data.decode()).encode()
            out.writestr(item, data)
        for name, data in add:
            out.writestr(name, data)
    return dest


def truncated(source: Path, dest: Path) -> Path:
    dest.write_bytes(source.read_bytes()[: source.stat().st_size // 2])
    return dest


def bad_plants(builtin: Path, tmp: Path) -> list[tuple[str, list[str], list[str]]]:
    """(case, --set assignments, fragments the error must contain)."""
    not_zip = tmp / "notes.fmu"
    not_zip.write_text("this is not an FMU")
    gear = ('<ScalarVariable name="gear" valueReference="9999" causality="local" '
            'variability="discrete" initial="exact"><Integer start="1"/></ScalarVariable>')
    cases = {
        "missing file": (tmp / "nowhere.fmu", [], ["nowhere.fmu", "does not exist"]),
        "truncated zip": (truncated(builtin, tmp / "truncated.fmu"), [],
                          ["truncated.fmu", "not a zip archive"]),
        "not a zip": (not_zip, [], ["notes.fmu", "not a zip archive"]),
        "no modelDescription.xml": (
            rewrite(builtin, tmp / "no_md.fmu", drop=["modelDescription.xml"]), [],
            ["no_md.fmu", "no modelDescription.xml"]),
        "no binary for this platform": (
            rewrite(builtin, tmp / "windows_only.fmu", drop=["binaries/"],
                    add=[("binaries/win64/PlanarArm.dll", b"MZ")]), [],
            ["windows_only.fmu", "no Co-Simulation binary for this platform",
             "binaries/linux64/PlanarArm.so", "win64", "fmpy compile"]),
        "no Co-Simulation": (
            rewrite(builtin, tmp / "me_only.fmu",
                    change_xml=lambda x: re.sub(r"<CoSimulation.*?/>", "", x, flags=re.S)), [],
            ["me_only.fmu", "no Co-Simulation interface", "Model Exchange only"]),
        "mapped variable missing": (builtin, ['plant.variables.q=["q[1]", "elbow"]'],
                                    ["plant.variables.q", "'elbow'", "not a variable",
                                     "q[1], q[2]"]),
        "variable of the wrong type": (
            rewrite(builtin, tmp / "with_gear.fmu",
                    change_xml=lambda x: x.replace("</ModelVariables>",
                                                   gear + "</ModelVariables>")),
            ['plant.variables.q=["q[1]", "gear"]'],
            ["with_gear.fmu", "plant.variables.q", "'gear'", "Integer", "must be Real"]),
        "variable of the wrong causality": (builtin, ['plant.variables.tau=["tau[1]", "q[2]"]'],
                                            ["plant.variables.tau", "'q[2]'",
                                             "causality is output", "must be an input"]),
        "the same variable mapped twice": (builtin, ['plant.variables.q=["q[1]", "q[1]"]'],
                                           ["plant.variables.q[2] names 'q[1]'",
                                            "plant.variables.q[1] already names"]),
        "a variable in another unit": (builtin, ['plant.variables.q=["q[1]", "M[1,1]"]'],
                                       ["plant.variables.q", "'M[1,1]', declared in kg",
                                        "the port takes rad or m", "converts no units"]),
        "unknown parameter": (builtin, ['plant.parameters.mass=2.0'],
                              ["plant.parameters", "'mass'", "m[1]"]),
        "error at initialisation": (builtin, ['plant.parameters."m[2]"=0'],
                                    ["fmi2", "failed at t = 0 s", "m[2] = 0 is not valid"]),
        "archive entry outside its folder": (
            rewrite(builtin, tmp / "escaping.fmu", add=[("../escaped.txt", b"x")]), [],
            ["escaping.fmu", "refusing to extract", "'../escaped.txt'"]),
    }
    return [(case, [f'plant.fmu="{path}"', *sets], fragments)
            for case, (path, sets, fragments) in cases.items()]


def test_every_bad_fmu_and_mapping_gets_one_clear_error(plant_fmu, tmp_path, capsys):
    for case, sets, fragments in bad_plants(plant_fmu(2, 2), tmp_path):
        out = tmp_path / "runs" / case.replace(" ", "_")
        args = ["run", PAPER, "--out", str(out), "--set", "simulation.duration=0.1"]
        for assignment in sets:
            args += ["--set", assignment]
        status = main(args)
        err = capsys.readouterr().err
        assert status == 2, (case, err)
        message = err.strip().splitlines()[-1]
        assert message.startswith("cosim: error: "), (case, err)
        for fragment in fragments:
            assert fragment in message, (case, fragment, message)
        assert not out.exists() or not (out / "recording.rrd").exists(), case
    assert not (Path(tempfile.gettempdir()) / "escaped.txt").exists()


def test_units_are_judged_by_what_they_are_and_a_variable_feeds_one_port(plant_fmu):
    """A unit spelled another way (Simulink's N*m, Nm) or defined by the FMU in SI base
    units is the port's; one of another quantity or scale (deg, by its definition or its
    spelling) is refused. One variable may give M[1,2] and M[2,1] (symmetric), never two
    per-joint entries (q and qdot)."""
    from fmpy.model_description import BaseUnit, Unit

    from cosim.plant.mapping import map_variables, read_description, unit_differences

    md = read_description(plant_fmu(2, 2))
    by_name = {v.name: v for v in md.modelVariables}

    def problems(units: dict[str, str], mapping=None) -> list[str]:
        for name, unit in units.items():
            by_name[name].unit = unit
        return map_variables(md, mapping)[1]

    assert problems({"tau[1]": "N*m", "tau[2]": "Nm"}) == []
    assert unit_differences(md, map_variables(md)[0]) is None  # the same unit: no warning
    md.unitDefinitions.append(Unit(name="newton_metre",
                                   baseUnit=BaseUnit(kg=1, m=2, s=-2)))
    md.unitDefinitions.append(Unit(name="degree", baseUnit=BaseUnit(rad=1, factor=0.0174533)))
    assert problems({"tau[1]": "newton_metre"}) == []
    assert problems({"q[1]": "degree"}) == [
        "plant.variables.q (joint angles) names 'q[1]', declared in degree; the port takes "
        "rad or m (a prismatic joint's), and cosim converts no units"]
    assert len(problems({"q[1]": "deg"})) == 1
    by_name["q[1]"].unit = "rad"
    symmetric = {"M": ["M[1,1]", "M[1,2]", "M[1,2]", "M[2,2]"]}
    assert problems({}, symmetric) == []
    assert problems({}, {"qdot": ["q[1]", "qdot[2]"]}) == [
        "plant.variables.qdot (joint velocities) names 'q[1]', declared in rad; the port "
        "takes rad/s or m/s (a prismatic joint's), and cosim converts no units"]
    by_name["q[1]"].unit = ""
    assert problems({}, {"qdot": ["q[1]", "qdot[2]"]}) == [
        "plant.variables.qdot[1] names 'q[1]', which plant.variables.q[1] already names: "
        "each FMU variable may feed one entry of one port"]


def test_an_fmu_that_fails_to_instantiate_names_the_call(foreign_fmu, tmp_path):
    # The PythonFMU arm with its script made to raise in its constructor: no instance.
    with zipfile.ZipFile(foreign_fmu) as archive:
        source = archive.read("resources/python_arm.py").decode()
    raising = "super().__init__(**kwargs)\n        raise RuntimeError('no licence')\n"
    broken = source.replace("super().__init__(**kwargs)\n", raising)
    # Under a module name of its own: PythonFMU imports the slave module by name, and this
    # process has imported python_arm already (sys.modules would hand back the good one).
    broken_fmu = rewrite(foreign_fmu, tmp_path / "refusing.fmu",
                         drop=["resources/python_arm.py", "resources/slavemodule.txt"],
                         add=[("resources/refusing_arm.py", broken.encode()),
                              ("resources/slavemodule.txt", b"refusing_arm")])
    plant = Fmu(broken_fmu, {"tau": ["shoulder_torque", "elbow_torque"],
                             "q": ["shoulder", "elbow"]})
    with pytest.raises(FmuError, match=r"refusing\.fmu: fmi2Instantiate failed"):
        plant.start()
    plant.close()


def test_an_fmu_failing_mid_run_names_the_call_and_keeps_what_was_computed(foreign_fmu,
                                                                           tmp_path, capsys):
    args = ["run", PAPER, "--out", str(tmp_path), "--no-figures",
            "--set", f'plant.fmu="{foreign_fmu}"', "--set", "plant.parameters.fail_at=0.25"]
    for assignment in FOREIGN_MAPPING:
        args += ["--set", assignment]
    assert main(args) == 2
    message = capsys.readouterr().err.strip().splitlines()[-1]
    assert "the plant FMU stopped the run at t = 0.25 s" in message
    assert "fmi2DoStep failed" in message and "PythonArm.fmu" in message
    assert "refuses to step past fail_at = 0.25 s" in message  # the FMU's own log message
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["complete"] is False
    assert summary["runs"]["baseline"]["metrics"]["simulated_time_s"] == pytest.approx(0.25)
    trace = np.load(tmp_path / "trace_baseline.npz")
    assert np.isfinite(trace["q"][:251]).all()
    assert (tmp_path / "recording.rrd").stat().st_size > 0


@pytest.mark.parametrize("sets,fragments", [
    (['reference.offset=[0.0, 0.0, 0.0]', 'reference.amplitude=[[1.0], [1.0], [1.0]]',
      'reference.frequency=[[1.0], [1.0], [1.0]]'],
     ["reference.offset has 3 entries", "has 2 joints"]),
    (["controller.kv=[20.0, 20.0, 20.0]"], ["controller.kv (run 'baseline') has 3 entries"]),
    (["runs.proposed.inertia_model.m=[1.0]"],
     ["inertia_model.m (run 'proposed') has 1 entries"]),
    (["plant.variables.qdot=[]"], ["run 'baseline'", "full-state baseline", "no qdot mapping",
                                   "plant.variables.qdot"]),
    (["plant.variables.M=[]", 'inertia_model.source="fmu"'],
     ['inertia_model.source = "fmu"', "no M mapping"]),
])
def test_sizes_and_needs_that_do_not_match_the_plant_are_refused(sets, fragments, capsys,
                                                                 tmp_path):
    args = ["run", PAPER, "--out", str(tmp_path / "out")]
    for assignment in sets:
        args += ["--set", assignment]
    assert main(args) == 2
    message = capsys.readouterr().err.strip().splitlines()[-1]
    for fragment in fragments:
        assert fragment in message, (fragment, message)
    assert not (tmp_path / "out" / "summary.json").exists()


# cosim inspect -------------------------------------------------------------------------------

def test_inspect_reports_the_fit_and_every_reason_it_does_not(plant_fmu, foreign_fmu, capsys):
    builtin = inspect_fmu(plant_fmu(3, 3))
    assert builtin.fits and builtin.mapping.links == 3 and builtin.fmi_version == "3.0"
    assert builtin.interfaces == ["Co-Simulation", "Model Exchange"]
    assert builtin.directional_derivatives
    text = str(builtin)
    assert "tau[1]  Float64  N.m" in text
    assert "fits the cosim plant interface: yes, 3 joints" in text

    foreign = inspect_fmu(foreign_fmu)
    assert not foreign.fits and "map the joint angles with plant.variables.q" in \
        foreign.problems[0]
    assert main(["inspect", str(foreign_fmu)]) == 1
    assert "fits the cosim plant interface: no" in capsys.readouterr().out

    wrong = inspect_fmu(foreign_fmu, {"q": ["shoulder", "elbow"], "tau": ["shoulder", "x"]})
    assert len(wrong.problems) == 2  # every reason, not only the first
    # tau left to its default names, which this FMU does not have: the key to give is named
    half = inspect_fmu(foreign_fmu, {"q": ["shoulder", "elbow"]})
    assert half.problems[0].startswith("the FMU has no input named tau[1], tau[2]: map the "
                                       "joint torques with plant.variables.tau = [...] (its "
                                       "Real inputs: "), half.problems
    assert main(["inspect", str(foreign_fmu), *sum((["--set", s] for s in FOREIGN_MAPPING),
                                                   [])]) == 0
    out = capsys.readouterr().out
    assert "tau  -> shoulder_torque, elbow_torque" in out and "M    -> not mapped" in out


# Linearisation -------------------------------------------------------------------------------

@pytest.mark.parametrize("fmi_version", [2, 3])
def test_linearization_agrees_with_finite_differences_of_the_fmus_derivatives(plant_fmu,
                                                                               fmi_version):
    path = plant_fmu(3, fmi_version)
    parameters = fmu_parameters({"lc": [0.5, 0.4, 0.7], "I": [0.1, 0.2, 0.05],
                                 "b": [0.3, 0.2, 0.1]}, q0=[0.3, -0.5, 0.8], qdot0=[1, -2, 0.5])
    point = linearize_at_start(path, parameters=parameters)
    system = point.system
    assert system.ninputs == 3 and system.noutputs == 6 and system.nstates == 6
    assert np.allclose(point.x0, [0.3, -0.5, 0.8, 1, -2, 0.5])

    inst = FmuInstance(path, "ModelExchange", parameters)
    try:
        z0 = np.concatenate([point.x0, point.u0])

        def derivatives(z):
            inst.set_states(z[:6])
            inst.set({f"tau[{i + 1}]": z[6 + i] for i in range(3)})
            return inst.derivatives()

        eps = 1e-6
        fd = np.column_stack([(derivatives(z0 + eps * e) - derivatives(z0 - eps * e)) / (2 * eps)
                              for e in np.eye(9)])
        assert np.allclose(derivatives(z0), point.xdot0, rtol=1e-12)
    finally:
        inst.free()
    ab = np.hstack([system.A, system.B])
    assert np.abs(ab - fd).max() <= 1e-6 * max(1.0, np.abs(fd).max())
    assert np.allclose(system.C, np.eye(6)) and np.allclose(system.D, 0)
    # q̇ is a state: the upper half of A is [0 I] exactly (the FMU's own derivatives say so)
    np.testing.assert_array_equal(system.A[:3], np.hstack([np.zeros((3, 3)), np.eye(3)]))
    # the poles against the eigenvalues of the finite-difference A (not the code's own A)
    reference = np.sort_complex(np.linalg.eigvals(fd[:, :6]))
    poles = np.sort_complex(system.poles())
    assert np.abs(poles - reference).max() <= 1e-5 * max(1.0, np.abs(reference).max())


def test_linearize_cli_prints_the_poles_and_refuses_a_cs_only_fmu(plant_fmu, foreign_fmu,
                                                                   capsys):
    assert main(["inspect", str(plant_fmu(2, 2)), "--linearize"]) == 0
    out = capsys.readouterr().out
    assert "poles (1/s):" in out and "not an equilibrium" in out
    poles = linearize(plant_fmu(2, 2)).poles()
    assert f"{poles[0].real:+.6g}" in out
    assert main(["inspect", str(foreign_fmu), "--linearize",
                 *sum((["--set", s] for s in FOREIGN_MAPPING), [])]) == 2
    assert "no Model Exchange interface" in capsys.readouterr().err


def test_extraction_refuses_entries_outside_its_folder(plant_fmu, tmp_path):
    from cosim.plant.unpack import extract

    for name in ("../escaped.txt", "/abs.txt", "a/../../escaped.txt"):
        bad = rewrite(plant_fmu(2, 2), tmp_path / "bad.fmu", add=[(name, b"x")])
        with pytest.raises(FmuError, match="refusing to extract"):
            extract(bad)
    good = extract(plant_fmu(2, 2))
    assert (Path(good) / "modelDescription.xml").is_file()
    shutil.rmtree(good)
