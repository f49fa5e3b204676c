"""What a supervised run process tells its supervisor as it goes (the run folder it made,
the plant, the plugin it is importing), so that when a plant's or a plugin's binary kills
it, the supervisor names the right folder and the culprit without loading anything itself.

The supervisor names a file in ``COSIM_RUN_NOTE``; the run process rewrites it (a small
JSON object) at each step. Outside a supervised run this does nothing.

Both variables are inherited by whatever the run process starts (a plugin's subprocess, a
nested ``cosim``), or may be set by a user. So a process is the supervised run process only
if ``COSIM_SUPERVISED`` names its own parent's pid, and the note only if it is the file the
supervisor made (in the temporary folder, named after that pid): otherwise a nested cosim
would overwrite a file it does not own, or signal a parent that is no supervisor.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

NOTE = "COSIM_RUN_NOTE"  # the environment variable naming the note file
SUPERVISED = "COSIM_SUPERVISED"  # the supervisor's pid, in the run process's environment
NOTE_PREFIX = "cosim-run-"  # the note files: cosim-run-<supervisor pid>-<random>.json


def supervised() -> bool:
    """Whether this process is the run process of a supervisor: its parent's pid is the
    one ``COSIM_SUPERVISED`` names."""
    return os.environ.get(SUPERVISED) == str(os.getppid())


def note_path() -> Path | None:
    """The note file the supervisor made for this process, or None (not supervised, or a
    ``COSIM_RUN_NOTE`` that is not a note the supervisor made)."""
    path = os.environ.get(NOTE)
    if not path or not supervised():
        return None
    note = Path(path)
    if note.parent != Path(tempfile.gettempdir()) or note.suffix != ".json" \
            or not note.name.startswith(f"{NOTE_PREFIX}{os.getppid()}-") or note.is_symlink():
        return None
    return note


def tell_supervisor(**fields: str | None) -> None:
    """Add ``fields`` to the note (a None value removes its key); silent when unsupervised
    or when the file cannot be written (the note only improves a crash's message)."""
    path = note_path()
    if path is None:
        return
    note = read_note(path)
    note.update(fields)
    note = {k: v for k, v in note.items() if v is not None}
    try:
        path.write_text(json.dumps(note))
    except OSError:
        pass


def read_note(path: Path) -> dict:
    try:
        note = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return note if isinstance(note, dict) else {}
