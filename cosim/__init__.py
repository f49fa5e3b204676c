"""cosim: co-simulate a robot-arm FMU with a safe adaptive output-feedback controller.

    from cosim import build_fmu, load_pipeline, run, inspect_fmu, linearize
    results = run(load_pipeline("pipelines/paper_two_link.toml"), "runs/paper")

SI units, angles in radians.
"""

from importlib import import_module

__version__ = "0.1.0"

# Imported on first use, so that `cosim --help` does not pay for numba, control and FMPy.
_PUBLIC = {"build_fmu": "plant_fmu", "inspect_fmu": "cosim.plant.inspection",
           "linearize": "cosim.plant.linearization", "load_pipeline": "cosim.config",
           "run": "cosim.runner"}
__all__ = sorted(_PUBLIC)


def __getattr__(name: str):
    if name not in _PUBLIC:
        raise AttributeError(f"module 'cosim' has no attribute {name!r}")
    return getattr(import_module(_PUBLIC[name]), name)
