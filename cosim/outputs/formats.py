"""The formats `cosim export` writes: name -> file suffix. The one list the command's
choices, the exporter and the run folder's own files read (the writer of each is
:data:`cosim.outputs.export.WRITERS`, which must cover exactly these)."""

from __future__ import annotations

EXPORT_FORMATS = {"parquet": ".parquet", "csv": ".csv", "mat": ".mat"}
