"""What a supervised run process tells its supervisor as it goes (the run folder it made,
the plant, the plugin it is importing), so that when a plant's or a plugin's binary kills
it, the supervisor names the right folder and the culprit without loading anything itself.

The supervisor names a file in ``COSIM_RUN_NOTE``; the run process rewrites it (a small
JSON object) at each step. Outside a supervised run this does nothing.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

NOTE = "COSIM_RUN_NOTE"  # the environment variable naming the note file


def tell_supervisor(**fields: str | None) -> None:
    """Add ``fields`` to the note (a None value removes its key); silent when unsupervised
    or when the file cannot be written (the note only improves a crash's message)."""
    path = os.environ.get(NOTE)
    if not path:
        return
    note = read_note(Path(path))
    note.update(fields)
    note = {k: v for k, v in note.items() if v is not None}
    try:
        Path(path).write_text(json.dumps(note))
    except OSError:
        pass


def read_note(path: Path) -> dict:
    try:
        note = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return note if isinstance(note, dict) else {}
