"""No byte of a user's URDF reaches generated C except as an escaped string literal
(plant_fmu/c_literals.py): hostile robot and joint names (comment closers, newlines,
trigraphs, quotes, backslashes, non-ASCII, 10 kB) make sources that keep the grammar, whose
code outside literals is the code of a chain with plain names, and that the C compiler
reads back as the names' exact bytes. The reproducer of the issue (a robot name that
breaks out of a comment into a constructor that runs a command) builds an FMU that runs
nothing when it is loaded."""

from __future__ import annotations

import dataclasses
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import cosim_cli
from fmpy.fmi1 import FMICallException
from fmu_helpers import FmuInstance
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from plant_fmu import c_literals
from plant_fmu.description import variables_header, variables_source
from plant_fmu.models.spatial_chain import SpatialChainModel, chain_header
from plant_fmu.urdf import Chain

CC = shutil.which(os.environ.get("CC", "") or "cc") or shutil.which("gcc")
# Pieces a hostile name is made of: each closes, splices or escapes something in C.
HOSTILE = ["*/", "/*", "//", "\n", "\r", "??/", "??=", "??'", '"', "\\", "'", "#error x",
           "\x00", "\x7f", "ロボット", "\U0001f916", "%s%n", "\t", "}", ";", "\\\n"]


def _chain(names: list[str], robot: str) -> Chain:
    """A chain of len(names) revolute joints in a row, named as given."""
    n = len(names)
    eye = np.tile(np.eye(4), (n, 1, 1))
    eye[:, 0, 3] = 0.3
    return Chain(name=robot, joints=tuple(names), links=tuple(f"l{i}" for i in range(n)),
                 kind=np.zeros(n, int), continuous=np.zeros(n, bool),
                 parent=np.arange(n) - 1, placement=eye, axis=np.tile([0.0, 0.0, 1.0], (n, 1)),
                 mass=np.ones(n), com=np.tile([0.15, 0.0, 0.0], (n, 1)),
                 inertia=np.tile(np.eye(3) * 0.01, (n, 1, 1)), damping=np.zeros(n),
                 friction=np.zeros(n), lower=-np.ones(n), upper=np.ones(n),
                 velocity=np.full(n, np.inf), effort=np.full(n, 10.0), tip=np.eye(4),
                 base_link="base", tip_link=f"l{n - 1}")


def _read_back(header: str, n: int, folder: Path) -> list[bytes]:
    """Compile ``header`` with a main that prints each CHAIN_JOINTS[i] in hex, run it, and
    return the bytes the compiler made of each name."""
    (folder / "chain.h").write_text(header, encoding="utf-8")
    (folder / "main.c").write_text(
        '#include <stdio.h>\n#include "chain.h"\n'
        "int main(void) {\n"
        f"    for (int i = 0; i < {n}; ++i) {{\n"
        "        for (const unsigned char *c = (const unsigned char *)CHAIN_JOINTS[i]; *c; ++c)"
        ' printf("%02x", *c);\n'
        '        printf("\\n");\n    }\n    return CHAIN_KIND[0] + CHAIN_PARENT[0] + 1;\n}\n')
    binary = folder / "read_back"
    built = subprocess.run([CC, "-std=c99", "-Wall", "-Wextra", "-Werror", "-o", str(binary),
                            str(folder / "main.c"), "-lm"], capture_output=True, text=True)
    assert built.returncode == 0, built.stderr
    ran = subprocess.run([str(binary)], capture_output=True, text=True)
    assert ran.returncode == 0, ran.stderr
    return [bytes.fromhex(line) for line in ran.stdout.splitlines()]


hostile_text = st.lists(st.one_of(st.sampled_from(HOSTILE), st.text(max_size=12)),
                        min_size=1, max_size=8).map("".join)


@settings(max_examples=30, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(names=st.lists(hostile_text, min_size=1, max_size=4), robot=hostile_text)
def test_hostile_names_stay_inside_escaped_literals(names, robot, tmp_path):
    """Every generated source keeps the grammar, no name changes the code around the
    literals, and the compiler reads back each name's bytes (a NUL ends a C string: the
    bytes up to it)."""
    chain = _chain(names, robot)
    plain = _chain([f"j{i}" for i in range(len(names))], "robot")
    header = chain_header(chain)
    model = SpatialChainModel(chain, source=f"{robot}.urdf")
    for source in (header, variables_header(model, chain.n, "{token}"),
                   variables_source(model, chain.n)):
        c_literals.check_generated(source)
    assert c_literals.skeleton(header) == c_literals.skeleton(chain_header(plain))
    expected = [name.encode("utf-8", "surrogatepass").split(b"\0")[0] for name in names]
    assert _read_back(header, chain.n, tmp_path) == expected


def test_a_ten_kilobyte_name_is_read_back_whole(tmp_path):
    name = ("*/ ??/ \n ロ \"\\" * 700)[:10_000]
    header = chain_header(_chain([name], "r" * 10_000))
    c_literals.check_generated(header)
    assert _read_back(header, 1, tmp_path) == [name.encode()]


def test_a_number_is_written_by_us_and_a_nan_is_refused():
    assert [c_literals.number(x) for x in (1e-300, -2.5, np.inf, -np.inf, 3)] == [
        "1e-300", "-2.5", "INFINITY", "-INFINITY", "3.0"]
    with pytest.raises(ValueError, match="NaN"):
        c_literals.number(float("nan"))
    with pytest.raises(ValueError, match="NaN"):
        chain_header(dataclasses.replace(_chain(["a"], "r"), mass=np.array([np.nan])))
    with pytest.raises(TypeError):
        c_literals.integer(1.5)


def test_the_grammar_check_refuses_code_outside_literals():
    """The check the property test relies on fails on what an unescaped name would make."""
    for source in ('/* x */ int system(const char*); /* */ const char *a = "??/";',
                   'const char *a = "a\\"b";', 'const char *a = "\n";',
                   'int x; ??= define y'):
        with pytest.raises(ValueError, match="outside a string literal"):
            c_literals.check_generated(source)


PWNED = """<?xml version="1.0"?>
<robot name="x */ int system(const char*); __attribute__((constructor)) static void
  pwn(void){{system(&quot;touch {marker}&quot;);}} /* {padding}">
  <link name="base"/>
  <link name="l1"><inertial><mass value="1"/><origin xyz="0.2 0 0"/>
    <inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="l2"><inertial><mass value="1"/><origin xyz="0.2 0 0"/>
    <inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="a??/&#10;&#13;*/b" type="revolute"><parent link="base"/><child link="l1"/>
    <axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="10" velocity="2"/></joint>
  <joint name="c&quot;\\d ??= #error e" type="continuous"><parent link="l1"/><child link="l2"/>
    <origin xyz="0.4 0 0"/><axis xyz="0 0 1"/></joint>
</robot>
"""


def test_the_reproducer_builds_an_fmu_that_runs_nothing(tmp_path, fmu_cache):
    """The issue's URDF: the robot name that closes chain.h's comment and declares a
    constructor running `touch`, joints with a trigraph, a newline, a comment closer, a
    quote and #error, and 600 bytes long in all (the cache's file name is cut to fit). It
    builds (exit 0); loading the FMU through `cosim inspect` and instantiating it create no
    file."""
    marker = tmp_path / "pwned"
    urdf = tmp_path / "pwn.urdf"
    urdf.write_text(PWNED.format(marker=marker, padding="ロ" * 100 + "x" * 300))
    env = {**os.environ, "COSIM_CACHE": str(fmu_cache)}
    built = subprocess.run([sys.executable, "-m", "cosim.cli", "build-fmu", "--urdf", str(urdf),
                            "--output", str(tmp_path / "pwn.fmu")],
                           capture_output=True, text=True, env=env, timeout=600)
    assert built.returncode == 0, built.stderr
    inspected = cosim_cli("inspect", str(tmp_path / "pwn.fmu"))
    assert inspected.returncode == 0, inspected.stderr
    with pytest.raises(FMICallException):
        FmuInstance(tmp_path / "pwn.fmu", "CoSimulation", {"q0[1]": 5.0})
    plant = FmuInstance(tmp_path / "pwn.fmu", "CoSimulation")
    plant.do_step(0.0, 1e-3)
    plant.free()
    assert not marker.exists()
    assert sorted(path.name for path in tmp_path.iterdir()) == ["pwn.fmu", "pwn.urdf"]
