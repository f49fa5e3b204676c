"""Where a kernel module's compile time goes (issue 50, item 4): compile the kernels one
kernel module's blocks step in a pipeline's runs, cold (into a fresh numba cache, removed
after) unless --warm, and print each kernel's time with numba's own timers (the LLVM part
and the whole) and the functions that took longest to compile, callees included.

    .venv/bin/python benchmarks/compile_profile.py pipelines/paper_safety.toml \\
        cosim.paper.cbf_filter.step        # the planar filter's step: ~4 min on one core

Times are wall seconds in this one process; a function's time includes its callees'.
"""

from __future__ import annotations

import argparse
import importlib
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("pipeline", type=Path, help="a pipeline file")
    parser.add_argument("module", help="a kernel module, e.g. cosim.paper.cbf_filter.step")
    parser.add_argument("--warm", action="store_true",
                        help="use the usual cache ($NUMBA_CACHE_DIR, else ~/.cache/cosim/numba)")
    parser.add_argument("--top", type=int, default=20, help="functions listed")
    args = parser.parse_args()
    cold = None if args.warm else tempfile.mkdtemp(prefix="cosim-compile-profile-")
    if cold:  # before numba is imported: it reads the variable once
        os.environ["NUMBA_CACHE_DIR"] = cold
    try:
        return profile(args.pipeline, args.module, args.top)
    finally:
        if cold:
            shutil.rmtree(cold, ignore_errors=True)


def profile(pipeline: Path, module: str, top: int) -> int:
    from numba.core import event

    from cosim import jit_cache, warm

    jit_cache.use_versioned_cache()
    modules, _, _ = warm._kernel_jobs([pipeline])
    if module not in modules:
        print(f"compile_profile: {pipeline} steps no kernel of {module}; its kernel modules: "
              f"{', '.join(sorted(modules))}", file=sys.stderr)
        return 2
    loaded = importlib.import_module(module)
    began = time.monotonic()
    with event.install_recorder("numba:compile") as recorder:
        for name, signature in modules[module]:
            dispatcher = getattr(loaded, name)
            start = time.monotonic()
            dispatcher.compile(signature)
            timers = dispatcher.get_metadata(signature).get("timers", {})
            llvm, whole = timers.get("llvm_lock", 0.0), timers.get("compiler_lock", 0.0)
            print(f"{name}: {time.monotonic() - start:.1f} s (numba: LLVM {llvm:.1f} s of "
                  f"{whole:.1f} s)")
    print(f"total {time.monotonic() - began:.1f} s")
    starts: dict[str, list[float]] = {}
    spans = []
    for stamp, happened in recorder.buffer:
        data = happened.data or {}
        key = (data["dispatcher"].py_func.__qualname__ if "dispatcher" in data
               else str(data))
        if happened.is_start:
            starts.setdefault(key, []).append(stamp)
        elif starts.get(key):
            spans.append((stamp - starts[key].pop(), key))
    print(f"the {top} longest compiles (s, callees included):")
    for seconds, key in sorted(spans, reverse=True)[:top]:
        print(f"  {seconds:7.1f}  {key}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
