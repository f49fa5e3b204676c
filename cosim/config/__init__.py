"""Pipeline configuration: the schema (assembled from the block registry), loading TOML
files and ``--set`` overrides.

What blocks build their parameter tables from (``Section``, the field types) and the
pipeline-wide declarations they may read (``[safety]``, ``[uncertainty]``) live below the
blocks, in :mod:`cosim.schema` and :mod:`cosim.declared`; ``Section`` and ``PipelineError``
are re-exported here for a block's author.
"""

from ..schema import PipelineError, Section
from .pipeline import Pipeline, Run, apply_override, load_pipeline, pipeline_model, validate

__all__ = ["Pipeline", "PipelineError", "Run", "Section", "apply_override", "load_pipeline",
           "pipeline_model", "validate"]
