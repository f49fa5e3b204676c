"""Pipeline configuration: the schema (assembled from the block registry), loading TOML
files and ``--set`` overrides.

What blocks build their parameter tables from (``Section``, the field types) and the
pipeline-wide declarations they may read (``[safety]``, ``[uncertainty]``) live below the
blocks, in :mod:`cosim.schema` and :mod:`cosim.declared`; ``Section`` and ``PipelineError``
are re-exported here for a block's author.
"""

from ..schema import PipelineError, Section
from .load import load_pipeline
from .overrides import apply_override
from .pipeline import Pipeline, pipeline_model
from .runs import Run
from .validation import validate

__all__ = ["Pipeline", "PipelineError", "Run", "Section", "apply_override", "load_pipeline",
           "pipeline_model", "validate"]
