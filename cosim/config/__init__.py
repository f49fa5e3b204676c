"""Pipeline configuration: the schema (assembled from the block registry), loading TOML
files and ``--set`` overrides.

``schema`` holds what blocks build their parameter tables from; ``pipeline`` needs the
registered blocks, so it is imported on first use (blocks import ``schema``).
"""

from importlib import import_module

from .schema import PipelineError, Section

_PIPELINE = ("Pipeline", "Run", "apply_override", "load_pipeline", "pipeline_model", "validate")
__all__ = ["PipelineError", "Section", *_PIPELINE]


def __getattr__(name: str):
    if name in _PIPELINE:
        return getattr(import_module(".pipeline", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
