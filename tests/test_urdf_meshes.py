"""A URDF's meshes are copied into the recording, which gets shared: a mesh must be a mesh
(by its content) inside the URDF's package or folder (plant_fmu/meshes.py). Every way out
(``..``, an absolute path, ``file://``, ``package://pkg/../..``, ``package://pkg//abs``, a
link to a private file) and every file that is not a mesh is refused with one message
naming the link, the mesh and why; the meshes of real robots pass; and the 3-D view checks
again beside Rerun's loader, before it reads a byte."""

from __future__ import annotations

import json
import os
import struct
from pathlib import Path

import pytest
from cli_helpers import assert_message, cosim_cli, error_line
from urdf_helpers import ARMS, OWN_ROBOT

from cosim.outputs.recording.arm3d import log_model
from cosim.outputs.recording.layout import UrdfArm
from plant_fmu.meshes import LARGEST_MESH
from plant_fmu.urdf import UrdfError, check_meshes, read_urdf

ROBOT = """<?xml version="1.0"?>
<robot name="leaky">
  <link name="base"/>
  <link name="arm">
    <inertial><mass value="1"/><origin xyz="0.2 0 0"/>
      <inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>
    <visual><geometry><mesh filename="{mesh}"/></geometry></visual>
  </link>
  <joint name="shoulder" type="revolute"><parent link="base"/><child link="arm"/>
    <axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="10" velocity="2"/></joint>
</robot>
"""
SECRET = "SECRET-TOKEN-7d1f"
TRIANGLE = struct.pack("<12fH", *[0.0] * 3, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0)
BINARY_STL = b"cosim test".ljust(80, b"\0") + struct.pack("<I", 1) + TRIANGLE
ASCII_STL = ("solid t\n facet normal 0 0 1\n  outer loop\n   vertex 0 0 0\n   vertex 1 0 0\n"
             "   vertex 0 1 0\n  endloop\n endfacet\nendsolid t\n")
OBJ = "# a triangle\no t\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//1 3//1\n"
COLLADA = ('<?xml version="1.0"?>\n<COLLADA xmlns="http://www.collada.org/2005/11/'
           'COLLADASchema" version="1.4.1"><asset/></COLLADA>\n')
GLTF = json.dumps({"asset": {"version": "2.0"}, "meshes": []})


def glb() -> bytes:
    chunk = b'{"asset":{"version":"2.0"}}'.ljust(28, b" ")
    body = struct.pack("<II", len(chunk), 0x4E4F534A) + chunk
    return b"glTF" + struct.pack("<II", 2, 12 + len(body)) + body


def robot(folder: Path, mesh: str) -> Path:
    """A one-joint URDF at ``folder/robot.urdf`` whose link draws ``mesh``, and a private
    file beside the folder that no mesh may copy."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder.parent / "secret.txt").write_text(SECRET)
    path = folder / "robot.urdf"
    path.write_text(ROBOT.format(mesh=mesh))
    return path


def refusal(path: Path) -> str:
    with pytest.raises(UrdfError) as caught:
        read_urdf(path)
    message = str(caught.value)
    prefix = f"{path}: link 'arm' <visual><mesh filename="
    assert message.startswith(prefix), message
    assert message.endswith(". The FMU ignores meshes for its dynamics, but the 3-D view "
                            "draws them: fix the path, or remove the <mesh>"), message
    return message[len(prefix):].split(". The FMU ignores")[0]


def test_a_path_out_of_the_urdfs_folder_is_refused_where_it_leads(tmp_path):
    path = robot(tmp_path / "robot", "../secret.txt")
    assert refusal(path) == (
        f"'../secret.txt'>: the path leads to {tmp_path / 'secret.txt'}, outside "
        f"{tmp_path / 'robot'}, where the URDF's meshes must lie (the URDF's folder, or the "
        "one above a folder named urdf): the recording copies meshes, and recordings are "
        "shared")


@pytest.mark.parametrize("mesh", ["/etc/hostname", "file:///etc/hostname", "{tmp}/secret.txt",
                                  "meshes/../../secret.txt", "~/.bashrc"])
def test_absolute_home_and_file_paths_outside_are_refused(tmp_path, mesh):
    path = robot(tmp_path / "robot", mesh.format(tmp=tmp_path))
    assert "outside " + str(tmp_path / "robot") + ", where the URDF's meshes" in refusal(path)


@pytest.mark.parametrize("rest", ["../" * 12 + "etc/hostname", "/etc/hostname",
                                  "robots/" + "../" * 14 + "etc/hostname"])
def test_a_package_path_stays_inside_its_package(tmp_path, rest):
    package = ARMS["panda"].parents[3]  # the example-robot-data package's folder
    path = robot(tmp_path / "robot", f"package://example-robot-data/{rest}")
    assert refusal(path) == (
        f"'package://example-robot-data/{rest}'>: the path leads to /etc/hostname, outside "
        f"{package}, where the URDF's meshes must lie (the package's folder): the recording "
        "copies meshes, and recordings are shared")


def test_a_ros_package_is_the_home_of_its_urdfs(tmp_path):
    """A URDF in a ROS package (package.xml above it) may name the package's meshes with
    ``..``, and no further."""
    (tmp_path / "pkg" / "meshes").mkdir(parents=True)
    (tmp_path / "pkg" / "package.xml").write_text("<package/>")
    (tmp_path / "pkg" / "meshes" / "arm.stl").write_bytes(BINARY_STL)
    path = robot(tmp_path / "pkg" / "robots" / "deep", "../../meshes/arm.stl")
    assert read_urdf(path).joints == ("shoulder",)
    path.write_text(ROBOT.format(mesh="../../../secret.txt"))
    assert "(the package's folder)" in refusal(path)


def test_a_description_packages_urdf_folder_reaches_its_meshes(tmp_path):
    (tmp_path / "robot" / "meshes").mkdir(parents=True)
    (tmp_path / "robot" / "meshes" / "arm.obj").write_text(OBJ)
    path = robot(tmp_path / "robot" / "urdf", "../meshes/arm.obj")
    assert read_urdf(path).joints == ("shoulder",)


def test_a_link_to_a_private_file_is_refused_as_not_a_mesh(tmp_path):
    path = robot(tmp_path / "robot", "meshes/arm.stl")
    (tmp_path / "robot" / "meshes").mkdir()
    (tmp_path / "robot" / "meshes" / "arm.stl").symlink_to(tmp_path / "secret.txt")
    assert refusal(path) == (
        f"'meshes/arm.stl'>: {tmp_path / 'robot/meshes/arm.stl'} is not a STL mesh: neither a "
        "binary STL (its size is not 84 bytes plus 50 per triangle) nor an ASCII one "
        "('solid … facet … endsolid')")


def test_a_linked_folder_of_meshes_is_followed(tmp_path):
    """ROS workspaces link their packages' folders: a mesh reached through a link inside
    the home is read, and is a mesh."""
    path = robot(tmp_path / "robot", "meshes/block.stl")
    (tmp_path / "robot" / "meshes").symlink_to(OWN_ROBOT.parent / "meshes")
    assert read_urdf(path).joints == ("shoulder",)


@pytest.mark.parametrize("name, content, reason", [
    ("notes.txt", SECRET, "'notes.txt' is not a mesh the 3-D view draws: give STL (.stl), "
     "COLLADA (.dae), Wavefront OBJ (.obj) or glTF (.gltf, .glb)"),
    ("zeros.dae", b"\0" * 100_000, "{p} is not a DAE mesh: no <COLLADA> element in its first "
     "64 kB"),
    ("key.obj", "v 0 0 0\n-----BEGIN OPENSSH PRIVATE KEY-----\n",
     "{p} is not a OBJ mesh: line 2 starts with '-----BEGIN', not an OBJ statement"),
    ("empty.obj", "# nothing\n", "{p} is not a OBJ mesh: it has no vertices (v) or no faces (f)"),
    ("binary.obj", b"v 0 0 0\n\xff\xfe\n", "{p} is not a OBJ mesh: line 2 is not text"),
    ("short.stl", BINARY_STL[:-1], "{p} is not a STL mesh: neither a binary STL (its size is not "
     "84 bytes plus 50 per triangle) nor an ASCII one ('solid … facet … endsolid')"),
    ("config.gltf", '{"password": "x"}', "{p} is not a GLTF mesh: no 'asset' in its JSON"),
    ("text.gltf", SECRET, "{p} is not a GLTF mesh: not JSON"),
    ("fake.glb", b"glTF" + b"\0" * 20, "{p} is not a GLB mesh: no glTF header ('glTF', version, "
     "the file's length)"),
])
def test_a_file_that_is_not_a_mesh_is_refused_by_its_content(tmp_path, name, content, reason):
    path = robot(tmp_path / "robot", name)
    mesh = tmp_path / "robot" / name
    mesh.write_bytes(content if isinstance(content, bytes) else content.encode())
    assert refusal(path) == f"'{name}'>: " + reason.format(p=mesh)


def test_a_folder_a_pipe_and_a_huge_file_are_refused_without_reading_them(tmp_path):
    path = robot(tmp_path / "robot", "parts")
    (tmp_path / "robot" / "parts").mkdir()
    assert refusal(path).endswith("is not a regular file (a folder, a device or a pipe)")
    os.mkfifo(tmp_path / "robot" / "pipe.stl")
    path.write_text(ROBOT.format(mesh="pipe.stl"))
    assert refusal(path).endswith("is not a regular file (a folder, a device or a pipe)")
    with (tmp_path / "robot" / "huge.stl").open("wb") as sparse:
        sparse.truncate(LARGEST_MESH + 1)
    path.write_text(ROBOT.format(mesh="huge.stl"))
    assert refusal(path).endswith(f"has {LARGEST_MESH + 1} bytes, more than the 100 MiB a "
                                  "link's mesh may have here: simplify it (a decimated copy)")


@pytest.mark.parametrize("name, content", [
    ("a.stl", BINARY_STL), ("b.STL", ASCII_STL), ("c.obj", OBJ), ("d.dae", COLLADA),
    ("e.gltf", GLTF), ("f.glb", glb())])
def test_every_mesh_format_the_view_draws_is_accepted(tmp_path, name, content):
    path = robot(tmp_path / "robot", f"meshes/{name}")
    (tmp_path / "robot" / "meshes").mkdir()
    (tmp_path / "robot" / "meshes" / name).write_bytes(
        content if isinstance(content, bytes) else content.encode())
    assert read_urdf(path).joints == ("shoulder",)


@pytest.mark.parametrize("arm", sorted(ARMS))
def test_real_robots_meshes_pass(arm):
    check_meshes(ARMS[arm])


def test_build_fmu_refuses_a_leaking_urdf_with_one_message_and_writes_nothing(tmp_path):
    path = robot(tmp_path / "robot", "../secret.txt")
    before = sorted(tmp_path.rglob("*"))
    result = cosim_cli("build-fmu", "--urdf", str(path), "--output", f"{tmp_path / 'out'}/")
    assert_message(error_line(result), (
        f"--urdf {path}: link 'arm' <visual><mesh filename='../secret.txt'>: the path leads to "
        f"{tmp_path / 'secret.txt'}, outside {tmp_path / 'robot'}, where the URDF's meshes "
        "must lie (the URDF's folder, or the one above a folder named urdf): the recording "
        "copies meshes, and recordings are shared. The FMU ignores meshes for its dynamics, "
        "but the 3-D view draws them: fix the path, or remove the <mesh>; nothing was "
        "written"))
    assert sorted(tmp_path.rglob("*")) == before


def test_the_3d_view_checks_the_meshes_before_rerun_reads_them(tmp_path):
    """A URDF changed after the run read it: the recording's loader is never handed it."""
    path = robot(tmp_path / "robot", "../secret.txt")
    with pytest.raises(UrdfError, match="outside"):
        log_model(None, "run", UrdfArm(str(path), ("shoulder",)))
