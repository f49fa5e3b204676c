"""What a URDF's ``<mesh filename>`` may name: a mesh file inside the URDF's own package or
folder, and nothing else.

The 3-D view (cosim/outputs/recording/arm3d.py) hands the URDF to Rerun's loader, which
copies every mesh file's bytes into ``recording.rrd``, whatever they are; and recordings
are shared. So a URDF that names ``../../.ssh/id_rsa``, ``/etc/passwd`` or
``package://pkg/../../..`` as a mesh would copy a private file into a shared recording.
A mesh is therefore accepted only if

* the path as written, with ``..`` folded, stays inside its home: for ``package://NAME/…``
  the package's folder; for a relative, absolute or ``file://`` path the URDF's home
  (:func:`urdf_home`). A symbolic link inside the home is followed (ROS workspaces link
  their packages' folders), and what it leads to must pass the next rule;
* it is a regular file of a mesh format Rerun draws (STL, COLLADA ``.dae``, Wavefront OBJ,
  glTF ``.gltf``/``.glb``), by its content and not only its name: a binary STL whose size
  its triangle count gives, an ASCII STL of facets, a COLLADA document, an OBJ whose every
  line is an OBJ statement, a glTF whose JSON has an ``asset`` (a ``.glb`` with glTF's
  header and length); at most :data:`LARGEST_MESH` bytes.

Anything else is refused with one message naming the link, the element and why
(:class:`plant_fmu.urdf.UrdfError`, raised by the reader).
"""

from __future__ import annotations

import json
import os
import struct
from pathlib import Path

LARGEST_MESH = 100 * 2**20  # bytes: a robot's link mesh is a few MB; more is not a mesh we draw
FORMATS = "STL (.stl), COLLADA (.dae), Wavefront OBJ (.obj) or glTF (.gltf, .glb)"
# The statements an OBJ file is made of (geometry, grouping, materials, free-form).
OBJ_STATEMENTS = frozenset(
    "v vt vn vp f l p o g s mg mtllib usemtl lod bevel c_interp d_interp shadow_obj "
    "trace_obj ctech stech cstype deg bmat step curv curv2 surf parm trim hole scrv sp end "
    "con maplib usemap".split())


class MeshRefused(ValueError):
    """A mesh reference the 3-D view will not read; the message says why."""


def urdf_home(urdf: Path) -> Path:
    """Where a URDF's relative, absolute and ``file://`` mesh paths must stay: the ROS
    package it lies in (the nearest folder above it with a ``package.xml``), else, for a
    URDF in a folder named ``urdf`` (a description package's layout: ``urdf/`` beside
    ``meshes/``), that folder's parent, else the URDF's own folder."""
    folder = Path(os.path.abspath(urdf)).parent
    for candidate in (folder, *folder.parents):
        if (candidate / "package.xml").is_file():
            return candidate
    return folder.parent if folder.name == "urdf" else folder


def inside(path: Path, home: Path) -> bool:
    """Whether ``path`` as written, its ``..`` folded, lies in the folder ``home``."""
    path, home = os.path.normpath(os.path.abspath(path)), os.path.normpath(os.path.abspath(home))
    return path == home or path.startswith(home.rstrip(os.sep) + os.sep)


def check_mesh(path: Path, home: Path) -> None:
    """Refuse (:class:`MeshRefused`) a mesh path outside ``home`` or a file that is not a
    mesh of :data:`FORMATS`; see the module's docstring."""
    if not inside(path, home):
        leads_to = os.path.normpath(os.path.abspath(path))
        raise MeshRefused(f"the path leads to {leads_to}, outside {os.path.normpath(home)}, "
                          f"where the URDF's meshes must lie ({_home(home)}): the recording "
                          "copies meshes, and recordings are shared")
    if not path.exists():
        raise MeshRefused(f"no such file (looked for {path})")
    if not path.is_file():
        raise MeshRefused(f"{path} is not a regular file (a folder, a device or a pipe)")
    suffix = path.suffix.lower()
    if suffix not in _SNIFFERS:
        raise MeshRefused(f"'{path.name}' is not a mesh the 3-D view draws: give {FORMATS}")
    size = path.stat().st_size
    if size > LARGEST_MESH:
        raise MeshRefused(f"{path} has {size} bytes, more than the {LARGEST_MESH // 2**20} MiB "
                          "a link's mesh may have here: simplify it (a decimated copy)")
    try:
        with path.open("rb") as stream:
            reason = _SNIFFERS[suffix](stream, size)
    except OSError as exc:
        raise MeshRefused(f"{path} cannot be read ({exc.strerror or exc})") from None
    if reason:
        raise MeshRefused(f"{path} is not a {suffix[1:].upper()} mesh: {reason}")


def _home(home: Path) -> str:
    """What ``home`` is to the URDF, for messages."""
    return ("the package's folder" if (home / "package.xml").is_file()
            else "the URDF's folder, or the one above a folder named urdf")


def _stl(stream, size: int) -> str:
    head = stream.read(84)
    if len(head) == 84 and 84 + 50 * struct.unpack("<I", head[80:84])[0] == size:
        return ""  # binary: 80-byte header, triangle count, 50 bytes per triangle
    text = head + stream.read()
    if text.lstrip()[:5].lower() == b"solid" and b"facet" in text and b"endsolid" in text:
        try:
            text.decode("ascii")
            return ""
        except UnicodeDecodeError:
            return "an ASCII STL holds only ASCII text"
    return ("neither a binary STL (its size is not 84 bytes plus 50 per triangle) nor an "
            "ASCII one ('solid … facet … endsolid')")


def _collada(stream, size: int) -> str:
    head = stream.read(64 * 1024)
    if b"<COLLADA" in head:
        return ""
    return "no <COLLADA> element in its first 64 kB"


def _obj(stream, size: int) -> str:
    vertices = faces = 0
    for number, raw in enumerate(stream, 1):
        try:
            line = raw.decode("utf-8").strip()
        except UnicodeDecodeError:
            return f"line {number} is not text"
        if not line or line.startswith("#"):
            continue
        keyword = line.split(None, 1)[0]
        if keyword not in OBJ_STATEMENTS:
            return f"line {number} starts with '{keyword[:20]}', not an OBJ statement"
        vertices += keyword == "v"
        faces += keyword in ("f", "l", "p")
    return "" if vertices and faces else "it has no vertices (v) or no faces (f)"


def _gltf(stream, size: int) -> str:
    try:
        document = json.loads(stream.read().decode("utf-8"))
    except (UnicodeDecodeError, ValueError):
        return "not JSON"
    return "" if isinstance(document, dict) and "asset" in document else "no 'asset' in its JSON"


def _glb(stream, size: int) -> str:
    head = stream.read(12)
    if len(head) == 12 and head[:4] == b"glTF" and struct.unpack("<I", head[8:12])[0] == size:
        return ""
    return "no glTF header ('glTF', version, the file's length)"


_SNIFFERS = {".stl": _stl, ".dae": _collada, ".obj": _obj, ".gltf": _gltf, ".glb": _glb}
