"""Blocks from outside the package: a pipeline's ``plugins`` and the ``cosim.blocks`` entry
point group.

A plugin is a module whose import registers blocks (``@register_block``), like the
built-in ones. A pipeline names its own with ``plugins = ["my_blocks.py", "mypkg.blocks"]``:
a ``.py`` file (relative to the pipeline file that names it) or an importable module. An
installed package offers its blocks to every pipeline with an entry point::

    [project.entry-points."cosim.blocks"]
    my_blocks = "mypkg.blocks"

Each is imported once per process (a sweep's Dask workers import them as they load the
pipeline), and importing runs its code: every command that reads the pipeline (``run``,
``run --dry-run``, ``params``, ``inspect``, ``sweep``), through ``extends`` too, says on
stderr which file it is about to import. A plugin that fails to import (an exception,
``sys.exit``) is one error naming it and the cause.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import os
import sys
import sysconfig
import traceback
from importlib.metadata import entry_points
from pathlib import Path
from types import ModuleType

from plant_fmu.named_file import not_a_file

from ..schema import PipelineError

ENTRY_POINT_GROUP = "cosim.blocks"

_LOADED: dict[str, ModuleType] = {}  # plugin (resolved file or module name) -> module
_entry_points_loaded = False


def load_plugins(plugins: list[str]) -> list[ModuleType]:
    """Import each plugin (a ``.py`` file path, absolute by now, or a module name) once."""
    return [_load(plugin) for plugin in plugins]


def load_entry_points() -> None:
    """Import every installed package's ``cosim.blocks`` entry point (once per process)."""
    global _entry_points_loaded
    if _entry_points_loaded:
        return
    _entry_points_loaded = True  # a broken one is reported once, not at every pipeline
    for point in entry_points(group=ENTRY_POINT_GROUP):
        where = f"entry point {point.name!r} = {point.value!r} (group {ENTRY_POINT_GROUP})"
        if not point.value.startswith("cosim."):  # our own (the paper's blocks): no news
            _announce(where)
        _guarded(where, point.load)


def offered_kinds(plugins: list[str]) -> dict[str, type]:
    """The registered blocks (kind -> class) a pipeline naming these ``plugins`` may use:
    the built-in and entry-point ones and its own plugins', not another pipeline's. A
    process that loaded several pipelines (a sweep's worker, a test session, a notebook)
    keeps every plugin registered; one pipeline must neither use nor suggest another's."""
    from .base import BLOCKS

    mine = {_LOADED[key].__name__ for key in map(_key, plugins) if key in _LOADED}
    others = tuple(module.__name__ for module in _LOADED.values()
                   if module.__name__ not in mine)
    return {kind: cls for kind, cls in BLOCKS.items()
            if not any(cls.__module__ == name or cls.__module__.startswith(f"{name}.")
                       for name in others)}


def _key(plugin: str) -> str:
    """A plugin's key in _LOADED: a file's resolved path, a module's name."""
    return str(Path(plugin).resolve()) if plugin.endswith(".py") else plugin


def _load(plugin: str) -> ModuleType:
    if not isinstance(plugin, str) or not plugin:
        raise PipelineError(f"plugins: {plugin!r} is neither a .py file nor a module name")
    why = not_a_file(plugin) if plugin.endswith(".py") else None
    if why == "does not exist":
        raise PipelineError(f"plugins: {plugin}: no such file (a .py file is relative "
                            "to the pipeline file that names it)")
    if why is not None:  # (importing a named pipe would wait for a writer)
        raise PipelineError(f"plugins: {plugin} {why.replace(', not a file', ', not a .py file')}")
    key = _key(plugin)
    if key not in _LOADED:
        _announce(f"plugin {plugin}")
        _LOADED[key] = _guarded(f"plugins: {plugin}", lambda: _import(key))
    return _LOADED[key]


def _announce(what: str) -> None:
    """Say on stderr that a plugin's code is about to run (and tell a supervisor, should
    it crash the process)."""
    from ..run_note import tell_supervisor

    if not _in_a_dask_worker():  # the sweep's own process said so already
        print(f"cosim: importing {what} (its code runs now)", file=sys.stderr)
    tell_supervisor(importing=what)


def _in_a_dask_worker() -> bool:
    distributed = sys.modules.get("distributed")
    if distributed is None:
        return False
    try:
        distributed.get_worker()
    except ValueError:
        return False
    return True


def _import(key: str) -> ModuleType:
    if not key.endswith(".py"):
        return importlib.import_module(key)
    # A module name of its own per file (two users' "blocks.py" do not collide), kept in
    # sys.modules so that pickling a block's class finds it.
    path = Path(key)
    name = f"cosim_plugin_{path.stem}_{hashlib.sha1(key.encode()).hexdigest()[:8]}"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise
    return module


def _guarded(where: str, load):
    """``load()``, with any failure of the user's code turned into one PipelineError that
    names the plugin, the exception and the plugin's own line where it was raised."""
    cwd = os.getcwd()
    try:
        return load()
    except PipelineError:
        raise
    except SystemExit as exc:  # sys.exit() at import: not the end of the command
        raise PipelineError(f"{where}: failed to import: it called sys.exit({exc.code!r})"
                            f"{_users_line(exc)}; a plugin must only define and register its "
                            "blocks") from None
    except Exception as exc:  # the user's code: any exception is possible
        raise PipelineError(f"{where}: failed to import: {describe_exception(exc)}") from None
    finally:
        from ..run_note import tell_supervisor

        tell_supervisor(importing=None)
        if os.getcwd() != cwd:  # a plugin's os.chdir would move every relative path after
            os.chdir(cwd)


# Frames that are not the user's: cosim's own and the standard library's (importlib's).
_NOT_THEIRS = (str(Path(__file__).resolve().parents[1]), sysconfig.get_paths()["stdlib"],
               "<frozen")


def describe_exception(exc: BaseException) -> str:
    """``"NameError: name 'np' is not defined (my_blocks.py, line 26, in step)"``: the
    exception and the last line outside cosim and the standard library (the user's own
    code) on its way up; none when the user's code was never reached."""
    return f"{type(exc).__name__}: {exc}{_users_line(exc)}"


def _users_line(exc: BaseException) -> str:
    """`` (my_blocks.py, line 26, in step)``: where the user's code raised ``exc``."""
    frames = [f for f in traceback.extract_tb(exc.__traceback__)
              if not f.filename.startswith(_NOT_THEIRS)]
    return f" ({frames[-1].filename}, line {frames[-1].lineno}, in {frames[-1].name})" \
        if frames else ""
