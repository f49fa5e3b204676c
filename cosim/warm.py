"""The set-up's warm-up (`cosim warm-up`, which `make venv` and `make test-venv` run):
compile every numba kernel and fused loop that pipelines' runs step, build their plant FMUs
and matplotlib's font list, into the caches a later `cosim run` loads them from, so that
the first run on a new machine starts at once instead of compiling for half a minute.

Work is spread over the cores: first the blocks' kernels, module by module, in worker
processes (a module's kernels compile independently of another's), then each distinct
fused loop (one per chain of kernels, their argument types and FMI version), which links
kernels loaded from the cache. A warm-up that finds a stamp for these sources and
pipelines, and every file it lists, says so and returns in a fraction of a second, without
importing numba.

    cosim warm-up [PIPELINE ...] [--workers K]
    python -m cosim.warm [PIPELINE ...]
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import pickle
import subprocess
import sys
import time
import tomllib
import zipfile
from pathlib import Path
from typing import TextIO

from . import jit_cache, kernel_digest

_PACKAGE = Path(__file__).resolve().parent
# The pipeline of the first run (README.md): `make demo`'s, `cosim run`'s example.
DEFAULT_PIPELINES = ("pipelines/paper_two_link.toml",)
# Steps each warm-up run takes: enough for every kernel and the fused loop to be called
# with the types a full run gives them (the types do not depend on the duration).
WARM_STEPS = 10


class WarmUpError(RuntimeError):
    """A warm-up that could not do its work; the message says which pipeline and why."""


def default_pipelines() -> list[Path]:
    """The README's pipeline, where a checkout has it: in the working folder, else beside
    the package (an editable install)."""
    found = []
    for name in DEFAULT_PIPELINES:
        for folder in (Path.cwd(), _PACKAGE.parent):
            if (folder / name).is_file():
                found.append(folder / name)
                break
    return found


# The stamp: a warm cache recognised without importing numba ---------------------------------

def _pipeline_files(path: Path, depth: int = 0) -> list[Path]:
    """The pipeline file and those it extends (what its resolved tables come from)."""
    files = [path]
    try:
        parent = tomllib.loads(path.read_text(encoding="utf-8")).get("extends")
    except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError):
        return files
    if isinstance(parent, str) and depth < 32:
        files += _pipeline_files(path.parent / parent, depth + 1)
    return files


def _urdf_files(pipeline_file: Path) -> list[Path]:
    """The URDF files a pipeline file names (every string value ending in ``.urdf``:
    ``[plant.urdf] file``, ``inertia_model.urdf``, ``safety.urdf``), each where it may be
    resolved: package://, beside the pipeline file or in the working folder. Their content
    makes the plant FMU and the nominal model a warm-up builds."""
    from plant_fmu.urdf import resolve_uri

    try:
        data = tomllib.loads(pipeline_file.read_text(encoding="utf-8"))
    except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError):
        return []
    names, tables = [], [data]
    while tables:
        for value in tables.pop().values():
            if isinstance(value, dict):
                tables.append(value)
            elif isinstance(value, str) and value.lower().endswith(".urdf"):
                names.append(value)
    return [resolve_uri(name, folder) for name in names
            for folder in dict.fromkeys((pipeline_file.parent, Path.cwd()))]


def stamp_path(pipeline: Path) -> Path:
    """Where the stamp of a warm-up of ``pipeline`` with these sources goes (beside numba's
    cache, so that clearing one clears the other): keyed by every source file of cosim and
    plant_fmu (kernels, the fused loop's template, the FMU's C), the content of the
    pipeline's files and of the URDFs they name, the Python and numba versions and the
    cache folders."""
    h = hashlib.sha256(_sources_digest().encode())
    for path in _pipeline_files(pipeline):  # their content: a copy elsewhere is as warm
        h.update(path.read_bytes() if path.is_file() else b"missing\0")
        for urdf in _urdf_files(path):  # an edited URDF builds another FMU
            h.update(f"{urdf}\0".encode()
                     + (urdf.read_bytes() if urdf.is_file() else b"missing\0"))
    for variable in ("COSIM_CACHE", "COSIM_ENGINE_CACHE", "MPLCONFIGDIR"):
        h.update(f"{variable}={os.environ.get(variable, '')}\0".encode())
    return jit_cache.default_base() / f"warm-up-{h.hexdigest()[:16]}.json"


@functools.cache
def _sources_digest() -> str:
    from importlib.metadata import PackageNotFoundError, version

    h = hashlib.sha256()
    for root in (_PACKAGE, _PACKAGE.parent / "plant_fmu"):
        for path in sorted(root.rglob("*")):
            if path.suffix in (".py", ".c", ".h") and "__pycache__" not in path.parts:
                h.update(f"{path.relative_to(root.parent)}\0".encode() + path.read_bytes())
    try:
        numba_version = version("numba")
    except PackageNotFoundError:
        numba_version = "?"
    h.update(f"{sys.version}\0{numba_version}\0".encode())
    return h.hexdigest()


def _unwritable(folder: Path, exc: OSError, variable: str = "NUMBA_CACHE_DIR") -> str:
    return (f"the cache folder {folder} cannot be written ({exc.strerror or exc}); set "
            f"{variable} to a writable folder; nothing was compiled")


def unwritable_caches() -> list[tuple[str, Path, str]]:
    """The cache folders a run writes that cannot be made or written here, as (the
    environment variable that moves it, the folder, why): numba's kernels, the fused
    loops' sources, the built plant FMUs."""
    from plant_fmu.build import default_cache_dir

    from .engine.fused import cache_dir

    problems = []
    for variable, folder in (("NUMBA_CACHE_DIR", jit_cache.default_base()),
                             ("COSIM_ENGINE_CACHE", cache_dir()),
                             ("COSIM_CACHE", default_cache_dir())):
        try:
            folder.mkdir(parents=True, exist_ok=True)
            probe = folder / f".writable-{os.getpid()}"
            probe.write_bytes(b"")
            probe.unlink()
        except OSError as exc:
            problems.append((variable, folder, exc.strerror or str(exc)))
    return problems


def is_warm(pipeline: Path) -> bool:
    """A stamp for this pipeline and these sources exists, and every file it lists is
    there and whole (an FMU cut short in the cache is not warm)."""
    try:
        stamp = json.loads(stamp_path(pipeline).read_text())
    except (OSError, ValueError):
        return False
    return all(_whole(Path(p)) for p in stamp.get("files", []))


def _whole(path: Path) -> bool:
    if path.suffix != ".fmu":
        return path.exists()
    try:
        with zipfile.ZipFile(path) as archive:
            return archive.testzip() is None
    except (OSError, zipfile.BadZipFile, EOFError):
        return False


# The work -------------------------------------------------------------------------------------

def _short(path: Path):
    """``path``'s pipeline, its runs WARM_STEPS steps long."""
    from .config import load_pipeline

    pipeline = load_pipeline(path, warn=None)
    step = pipeline.simulation.step
    return load_pipeline(path, [f"simulation.duration={WARM_STEPS * step!r}"], warn=None)


def _kernel_jobs(pipelines: list[Path]) -> tuple[dict[str, list], list, list[Path]]:
    """Per kernel module, the (kernel name, signature) its blocks step with and their parts
    (Block.warm_parts); one (pipeline, run) per distinct chain of kernels, their signatures
    and the FMI version (a fused loop each); and the plant FMU files (built here)."""
    from numba import typeof, types

    from .assemble import assemble
    from .plant_source import plant_files

    modules: dict[str, list] = {}
    loops: dict[tuple, tuple[str, str]] = {}
    fmus = []
    for path in pipelines:
        pipeline = _short(path)
        fmus.extend(plant_files(pipeline))
        scenario = assemble(pipeline)
        try:
            for name, plan in scenario.runs.items():
                trace = plan.new_trace(scenario.steps)
                scenario.plant.start(0.0)
                plan.reset(trace)  # the blocks' args, as the master gives them to kernels
                kernels = []
                for block in plan.blocks:
                    if block.kernel is None:
                        continue
                    signature = (types.int64, typeof(block.args))
                    kernel = block.kernel.py_func
                    kernels.append((f"{kernel.__module__}.{kernel.__name__}", signature))
                    for dispatcher, types_ in [(block.kernel, signature),
                                               *block.warm_parts()]:
                        function = dispatcher.py_func
                        jobs = modules.setdefault(function.__module__, [])
                        if (function.__name__, types_) not in jobs:
                            jobs.append((function.__name__, types_))
                # A fused loop per chain of kernels *and their argument types*: the same
                # kernels on another arm's model (planar, spatial) are another loop.
                chain = (tuple(kernels), getattr(scenario.plant, "fmi_version", None))
                loops.setdefault(chain, (str(path), name))
        finally:
            scenario.close()
    return modules, list(loops.values()), fmus


def compile_kernels(jobs: list[tuple[str, list]]) -> None:
    """Compile (or load) each (module, its kernels' (name, signature)) job, in this
    process."""
    import importlib

    for module, kernels in jobs:
        loaded = importlib.import_module(module)
        for name, signature in kernels:
            getattr(loaded, name).compile(signature)


def run_short(jobs: list[tuple[str, str]]) -> None:
    """Run each (pipeline, run) WARM_STEPS steps in this process: its fused loop compiles
    (the kernels it calls load from the cache)."""
    from .runner import run

    for path, name in jobs:
        pipeline = _short(Path(path))
        pipeline.runs = {name: pipeline.runs[name]}
        run(pipeline, None, progress=False, record=False, figures=False)


def _spread(items: list, workers: int, cost=lambda item: 1) -> list[list]:
    """``items`` in at most ``workers`` groups: each, the costliest first, to the group
    whose cost is least so far, fewest items first (1 each by default: round robin)."""
    groups: list[list] = [[] for _ in range(max(1, min(workers, len(items))))]
    loads = [0] * len(groups)
    for item in sorted(items, key=lambda i: -cost(i)):  # stable: equals keep their order
        least = min(range(len(groups)), key=lambda g: (loads[g], len(groups[g])))
        groups[least].append(item)
        loads[least] += cost(item)
    return [g for g in groups if g]


def _callees_first(group: list[tuple[str, list]]) -> list[tuple[str, list]]:
    """A process's kernel jobs, a part (Block.warm_parts) before the kernels that call it."""
    return sorted(group, key=lambda job: not any(
        job[0] != other[0] and job[0] in kernel_digest.closure(other[0]) for other in group))


def _in_parallel(kind: str, groups: list[list], stream: TextIO) -> None:
    """Each group of jobs in a worker process of its own (``python -m cosim.warm --worker
    KIND``, the jobs pickled on its stdin), the first in this one. The workers write their
    compile lines to our stderr as they go; one that fails fails the warm-up."""
    children = []
    for group in groups[1:]:
        child = subprocess.Popen([sys.executable, "-m", "cosim.warm", "--worker", kind],
                                 stdin=subprocess.PIPE)
        child.stdin.write(pickle.dumps(group))
        child.stdin.close()
        children.append(child)
    try:
        with jit_cache.announce_compiles(stream, header=False):
            _work(kind, groups[0])
    finally:
        statuses = [child.wait() for child in children]
    if any(statuses):
        raise WarmUpError(f"a warm-up worker ({kind}) failed with exit status "
                          f"{next(s for s in statuses if s)}; its error is above")


def _work(kind: str, jobs: list) -> None:
    if kind == "kernels":
        compile_kernels(jobs)
    else:
        run_short(jobs)


def warm_up(pipelines: list[Path], workers: int | None = None,
            stream: TextIO = sys.stderr) -> list[Path]:
    """Fill the caches for ``pipelines``' runs (those not warm already); returns the ones
    it warmed. Raises :class:`WarmUpError` or :class:`~cosim.schema.PipelineError`."""
    cold = [Path(p) for p in pipelines if not is_warm(Path(p))]
    warm = [str(p) for p in pipelines if Path(p) not in cold]
    if warm:
        print(f"cosim warm-up: the caches are warm for {', '.join(warm)}", file=stream)
    if not cold:
        return []
    began = time.monotonic()
    for variable, folder, why in unwritable_caches()[:1]:
        raise WarmUpError(_unwritable(folder, OSError(why), variable))
    workers = workers or os.cpu_count() or 1
    print(f"cosim warm-up: compiling the kernels and fused loops of "
          f"{', '.join(map(str, cold))} on {workers} process(es), building their plant FMU …",
          file=stream, flush=True)
    jit_cache.use_versioned_cache()
    modules, loops, fmus = _kernel_jobs(cold)
    print("  compiling the numba kernels and fused loops not cached yet (once per version of "
          "their sources; kept for later runs):", file=stream, flush=True)
    # Kernels not cached compile in parallel (a cached one loads in milliseconds), a job per
    # signature (a kernel, or a large callee a block names: Block.warm_parts), the costliest
    # first to the process with the least work so far, its callees' parts first; then the
    # fused loops, which link the cached kernels.
    missing = [(m, [kernel]) for m, k in modules.items() if not _cached(m, k) for kernel in k]
    if missing:
        groups = _spread(missing, workers, lambda job: _source_size(job[0]))
        _in_parallel("kernels", [_callees_first(group) for group in groups], stream)
    if loops:
        _in_parallel("loops", _spread(loops, workers), stream)
    _warm_matplotlib()
    _compile_bytecode()
    from .engine.fused import cache_dir

    files = [str(p) for p in fmus] + [str(p) for p in sorted(cache_dir().glob("fused_*.py"))]
    for pipeline in cold:
        stamp = stamp_path(pipeline)
        try:
            stamp.parent.mkdir(parents=True, exist_ok=True)
            stamp.write_text(json.dumps({"pipeline": str(pipeline), "files": files}, indent=1))
        except OSError as exc:
            raise WarmUpError(_unwritable(stamp.parent, exc)) from None
    print(f"cosim warm-up: done in {time.monotonic() - began:.1f} s; the first `cosim run` "
          "of these pipelines loads everything from the caches", file=stream)
    return cold


def _source_size(module: str) -> int:
    """The bytes of ``module``'s kernel closure: what its compile grows with, roughly."""
    paths = map(kernel_digest.module_file, kernel_digest.closure(module))
    return sum(path.stat().st_size for path in paths if path is not None)


def _cached(module: str, kernels: list) -> bool:
    """Every kernel of ``module`` has an index in its versioned folder (the signature is
    checked when it loads; a miss is compiled then, by the fused loop's compile)."""
    folder = jit_cache.cache_folder(module)
    stem = module.rpartition(".")[2]
    return all(any(folder.glob(f"{stem}.{name}-*.nbi")) for name, _ in kernels)


def _warm_matplotlib() -> None:
    """matplotlib's font list (built on its first import on a machine: seconds)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.font_manager  # noqa: F401


def _compile_bytecode() -> None:
    """cosim's and plant_fmu's bytecode, so that no process compiles their sources again
    (also where PYTHONDONTWRITEBYTECODE keeps imports from writing it)."""
    import compileall

    for root in (_PACKAGE, _PACKAGE.parent / "plant_fmu"):
        if os.access(root, os.W_OK):
            compileall.compile_dir(str(root), quiet=2, workers=1)


def _worker(kind: str) -> int:
    jobs = pickle.loads(sys.stdin.buffer.read())
    jit_cache.use_versioned_cache()
    with jit_cache.announce_compiles(sys.stderr, header=False):
        _work(kind, jobs)
    return 0


def main(argv: list[str] | None = None) -> int:
    import argparse

    parser = argparse.ArgumentParser(prog="python -m cosim.warm", description=__doc__)
    parser.add_argument("pipelines", nargs="*", type=Path)
    parser.add_argument("--workers", type=int, default=None)
    parser.add_argument("--worker", choices=("kernels", "loops"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        return _worker(args.worker)
    warm_up(args.pipelines or default_pipelines(), args.workers)
    return 0


if __name__ == "__main__":
    sys.exit(main())
