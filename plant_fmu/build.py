"""Build a plant FMU: generate the description, compile with the system C compiler, pack.

Builds are cached by a digest of everything that goes into them (model, link count, FMI
version, variable table, C sources, compiler), so calling :func:`build_fmu` again is cheap,
and concurrent calls are safe (each writes a temporary file and renames it into place).
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import secrets
import shlex
import shutil
import subprocess
import sys
import tempfile
import zipfile
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

from . import description, variables
from .models import DEFAULT_MODEL, MODELS

# The FMI glue every model plugs into: one file per FMI version, and the instance they share.
FMI_DIR = Path(__file__).parent / "fmi"
FMI_SOURCES = ("fmu_instance.c",)
FMI_HEADERS = ("fmu_instance.h", "model.h")
CFLAGS = ["-O2", "-std=c99", "-Wall", "-Wextra", "-fPIC", "-shared"]


class BuildError(RuntimeError):
    """The FMU could not be built; the message says why and what to do."""


def default_cache_dir() -> Path:
    """Where built FMUs are cached: $COSIM_CACHE, else ~/.cache/cosim/fmus."""
    env = os.environ.get("COSIM_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "cosim" / "fmus"


def _fmi_headers() -> Path:
    import fmpy

    path = Path(fmpy.__file__).parent / "c-code"
    if not (path / "fmi2Functions.h").exists():
        raise BuildError(f"FMPy's FMI headers were not found in {path}: reinstall fmpy")
    return path


def _compiler() -> list[str]:
    """The C compiler's command: $CC (which may carry options, as make allows: "gcc -O0"),
    else cc or gcc on the PATH."""
    cc = os.environ.get("CC", "").strip()
    if cc:
        try:
            command = shlex.split(cc)
        except ValueError as exc:
            raise BuildError(f"CC={cc!r} is not a command ({exc})") from None
        if not shutil.which(command[0]):
            raise BuildError(f"CC={cc!r}: no program {command[0]!r} is found (on the PATH or "
                             "at that path); set CC to an installed C compiler, or unset it")
        return command
    found = shutil.which("cc") or shutil.which("gcc")
    if not found:
        raise BuildError("no C compiler found: install gcc (apt-get install gcc) or set CC")
    return [found]


def _platform_dir(fmi_version: int) -> str:
    from fmpy import platform, platform_tuple

    return platform if fmi_version == 2 else platform_tuple


def _shared_library_suffix() -> str:
    return {"win32": ".dll", "darwin": ".dylib"}.get(sys.platform, ".so")


def _cflags(model: ModuleType) -> list[str]:
    """The compiler options: the common ones, then the model's own (a later -O wins)."""
    return [*CFLAGS, *getattr(model, "CFLAGS", ())]


def _generated(model: ModuleType) -> dict[str, str]:
    """A model's generated sources (name -> text): a URDF chain's constants, say."""
    return getattr(model, "GENERATED", {})


def _sources_digest(model: ModuleType) -> str:
    h = hashlib.sha256()
    for path in sorted(_source_files(model, 2) + _source_files(model, 3)
                       + [Path(model.__file__), Path(variables.__file__)]):
        h.update(path.name.encode())
        h.update(path.read_bytes())
    for name, text in sorted(_generated(model).items()):
        h.update(name.encode())
        h.update(text.encode())
    return h.hexdigest()


def _source_files(model: ModuleType, fmi_version: int) -> list[Path]:
    """The C files an FMU of ``fmi_version`` is built from: the model's and the glue."""
    glue = [FMI_DIR / name for name in (*FMI_SOURCES, *FMI_HEADERS, f"fmi{fmi_version}.c")]
    return [*model.SOURCES, *model.HEADERS, *glue]


def _build_key(model: ModuleType, links: int, fmi_version: int, cc: str) -> str:
    """The cache key (``cc``: the compiler's command as one string)."""
    h = hashlib.sha256()
    h.update(f"{model.MODEL_IDENTIFIER}|{links}|{fmi_version}|{cc}|{' '.join(_cflags(model))}|"
             .encode())
    h.update(_sources_digest(model).encode())
    h.update(Path(description.__file__).read_bytes())
    # The table itself: a URDF chain's start values (its damping, limits) are not in a file.
    h.update(repr(model.variables(links)).encode())
    return h.hexdigest()[:16]


def _model(name: str) -> ModuleType:
    if name not in MODELS:
        raise BuildError(f"model {name!r} is not a built-in plant model (built-in: "
                         f"{', '.join(MODELS)})")
    return MODELS[name]


def _check_options(model: ModuleType, links: int, fmi_version: int) -> None:
    if not isinstance(links, int) or not 1 <= links <= model.MAX_LINKS:
        raise BuildError(f"links must be a whole number from 1 to {model.MAX_LINKS}, got "
                         f"{links!r}")
    if fmi_version not in (2, 3):
        raise BuildError(f"fmi_version must be 2 or 3, got {fmi_version!r}")


def build_fmu(links: int = 2, fmi_version: int = 2, output: str | Path | None = None,
              cache_dir: str | Path | None = None, model: str = DEFAULT_MODEL) -> Path:
    """Build (or take from the cache) the ``links``-link FMU of the built-in ``model``
    (:data:`plant_fmu.models.MODELS`: the rigid arm, or the arm with elastic joints) for
    FMI 2.0 or 3.0.

    The archive holds Co-Simulation and Model Exchange, the binary for this platform, and
    its C sources with a ``buildDescription.xml`` so that ``fmpy compile`` can rebuild it
    elsewhere. Returns the path of the FMU: ``output`` if given, else the cached file.
    """
    chosen = _model(model)
    return _build_cached(chosen, links, fmi_version, output, cache_dir,
                         f"{chosen.MODEL_IDENTIFIER}{links}")


def build_urdf_fmu(urdf: str | Path, base: str | None = None, tip: str | None = None,
                   fixed: dict[str, float] | None = None, fmi_version: int = 2,
                   output: str | Path | None = None,
                   cache_dir: str | Path | None = None, held_by: str = "--fix") -> Path:
    """Build (or take from the cache) the FMU of the spatial chain that ``urdf`` describes
    from link ``base`` to link ``tip``, the joints in ``fixed`` held at their value (rad or
    m): see :func:`plant_fmu.urdf.read_urdf` and :mod:`plant_fmu.models.spatial_chain`.
    Like :func:`build_fmu` otherwise; cached by everything the chain is made of (the URDF's
    content among it). Raises :class:`plant_fmu.urdf.UrdfError` for a URDF it refuses
    (``held_by``: how the caller holds joints, for its messages)."""
    from .models.spatial_chain import MAX_LINKS, SpatialChainModel
    from .urdf import UrdfError, read_urdf

    chain = read_urdf(urdf, base=base, tip=tip, fixed=fixed, held_by=held_by)
    if chain.n > MAX_LINKS:
        tip_option, fix = (("--tip", "--fix NAME=VALUE") if held_by.startswith("--") else
                           (f"{held_by.rsplit('.', 1)[0]}.tip", f"{held_by}.NAME = VALUE"))
        raise UrdfError(f"{urdf}: {chain.n} joints move between base link "
                        f"'{chain.base_link}' and tip link '{chain.tip_link}', more than the "
                        f"{MAX_LINKS} a URDF plant has: choose a nearer tip ({tip_option}) or "
                        f"hold joints ({fix})")
    model = SpatialChainModel(chain, source=str(urdf))
    # The file's name from the robot's, kept short: a file system's names end at 255 bytes.
    stem = "".join(ch if ch.isascii() and (ch.isalnum() or ch in "-_") else "_"
                   for ch in chain.name)[:64] or "robot"
    return _build_cached(model, chain.n, fmi_version, output, cache_dir, stem)


def _build_cached(chosen: ModuleType, links: int, fmi_version: int,
                  output: str | Path | None, cache_dir: str | Path | None, stem: str) -> Path:
    _check_options(chosen, links, fmi_version)
    cc = _compiler()
    cache = Path(cache_dir) if cache_dir else default_cache_dir()
    key = _build_key(chosen, links, fmi_version, " ".join(cc))
    cached = cache / f"{stem}_fmi{fmi_version}_{key}.fmu"
    if not _whole(cached):  # missing, or damaged (truncated): built again
        try:
            cache.mkdir(parents=True, exist_ok=True)
            _build_into(chosen, cached, links, fmi_version, cc)
        except OSError as exc:
            where = exc.filename or cache
            raise BuildError(f"the FMU cache {cache}: cannot write there ({where}: "
                             f"{exc.strerror or exc}); set COSIM_CACHE to a folder you can "
                             "write") from None
    if output is None:
        return cached
    output = Path(output)
    output.parent.mkdir(parents=True, exist_ok=True)
    write_atomically(output, lambda tmp: shutil.copyfile(cached, tmp))
    return output


def _whole(fmu: Path) -> bool:
    """The cached FMU is there and every entry passes its CRC check (a few hundred kB: a
    millisecond), so that a truncated file in the cache is rebuilt, not used by every run."""
    try:
        with zipfile.ZipFile(fmu) as archive:
            return archive.testzip() is None
    except (OSError, zipfile.BadZipFile, EOFError):
        return False


def write_atomically(target: Path, produce) -> None:
    """``produce(tmp)`` then rename: an interrupted or failed write leaves nothing behind."""
    tmp = target.with_name(f".{target.name}.{os.getpid()}.tmp")
    try:
        produce(tmp)
        os.replace(tmp, target)
    except BaseException:  # Ctrl-C, SIGTERM, a full disk
        tmp.unlink(missing_ok=True)
        raise


@contextlib.contextmanager
def _scratch_directory(prefix: str) -> Iterator[Path]:
    """A new folder in the temporary directory, removed on the way out whatever happens.
    Named before it is made, and made inside the ``try``: a signal (Ctrl-C, SIGTERM: their
    handlers raise) landing just after the folder exists cannot leave it behind, as one
    could inside tempfile.TemporaryDirectory before its clean-up was set up (seen once in a
    fresh-clone CI: SIGTERM as the build's folder appeared)."""
    root = Path(tempfile.gettempdir()) / f"{prefix}{os.getpid()}_{secrets.token_hex(6)}"
    try:
        root.mkdir(mode=0o700)
        yield root
    finally:
        shutil.rmtree(root, ignore_errors=True)


def _build_into(model: ModuleType, target: Path, links: int, fmi_version: int,
                cc: list[str]) -> None:
    token = description.instantiation_token(model, links, _sources_digest(model))
    with _scratch_directory("plant_fmu_") as root:
        sources = root / "sources"
        sources.mkdir()
        for path in _source_files(model, fmi_version):  # flat: fmpy compile builds from here
            shutil.copyfile(path, sources / path.name)
        (sources / "variables.h").write_text(description.variables_header(model, links, token))
        (sources / "variables.c").write_text(description.variables_source(model, links))
        for name, text in _generated(model).items():
            (sources / name).write_text(text)
        compiled = [*(path.name for path in model.SOURCES), *FMI_SOURCES, "variables.c",
                    f"fmi{fmi_version}.c"]
        (sources / "buildDescription.xml").write_text(
            description.build_description(model, fmi_version, compiled))
        (root / "modelDescription.xml").write_text(
            description.model_description(model, links, fmi_version, token))

        binary_dir = root / "binaries" / _platform_dir(fmi_version)
        binary_dir.mkdir(parents=True)
        binary = binary_dir / (model.MODEL_IDENTIFIER + _shared_library_suffix())
        command = [*cc, *_cflags(model), f"-I{sources}", f"-I{_fmi_headers()}",
                   *[str(sources / s) for s in compiled], "-o", str(binary), "-lm"]
        try:
            result = subprocess.run(command, capture_output=True, text=True)
        except OSError as exc:  # found a moment ago, gone or not executable now
            raise BuildError(f"the C compiler {' '.join(cc)} could not be run "
                             f"({exc.strerror or exc}); set CC to an installed C compiler"
                             ) from None
        if result.returncode != 0:
            raise BuildError(f"compiling the {links}-link FMI {fmi_version} "
                             f"{model.MODEL_IDENTIFIER} plant failed ({' '.join(command)}):\n"
                             f"{result.stderr}")

        def pack(tmp: Path) -> None:
            with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as archive:
                for path in sorted(root.rglob("*")):
                    if path.is_file():
                        archive.write(path, path.relative_to(root).as_posix())

        write_atomically(target, pack)
