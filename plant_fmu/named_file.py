"""A file a user names (a pipeline and what it extends, a URDF and its meshes, a reference
CSV, a plugin, an FMU): what the path is when it is not a regular file, said before anything
opens it, and its bytes read without ever blocking.

Why: opening a named pipe for reading waits for a writer that may never come, a device such
as /dev/zero never ends, and a folder or an empty name (read as the working folder) is not
what the user meant; each was a hang or a message that said "does not exist" of something
that does.
"""

from __future__ import annotations

import hashlib
import os
import stat
from typing import BinaryIO

CHUNK = 1 << 20  # bytes read at a time while hashing


def not_a_file(path: str | os.PathLike) -> str | None:
    """None if ``path`` is a regular file (through symbolic links); else what it is, as
    the rest of a sentence that starts with the path: "is a folder", "is a named pipe
    (FIFO)", "does not exist" and so on."""
    if str(path) == "":
        return "is an empty name (no file)"
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        return ("is a symbolic link to nothing" if os.path.islink(path)
                else "does not exist")
    except NotADirectoryError:
        return "does not exist (a part of its path is a file, not a folder)"
    except OSError as exc:
        return f"cannot be read ({exc.strerror or exc})"
    if stat.S_ISREG(mode):
        return None
    if stat.S_ISDIR(mode):
        return "is a folder, not a file"
    if stat.S_ISFIFO(mode):
        return "is a named pipe (FIFO), not a file"
    if stat.S_ISSOCK(mode):
        return "is a socket, not a file"
    return "is a device, not a file"


class NotAFile(OSError):
    """A named path that is not a regular file, or cannot be read; the message says which
    and why (the path first)."""


def open_regular(path: str | os.PathLike) -> BinaryIO:
    """The regular file at ``path`` opened for reading (binary), or :class:`NotAFile`
    saying what it is. It is opened without blocking and checked again once open: a path
    swapped for a pipe in between is refused, not waited on."""
    why = not_a_file(path)
    if why is not None:
        raise NotAFile(f"{path} {why}")
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY)
    except OSError as exc:
        raise NotAFile(f"{path} cannot be read ({exc.strerror or exc})") from None
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise NotAFile(f"{path} {not_a_file(path) or 'is no longer a regular file'}")
    return os.fdopen(fd, "rb")


def sha256(path: str | os.PathLike) -> tuple[str, int]:
    """The SHA-256 (hex) and size in bytes of the regular file at ``path``, read in
    chunks; :class:`NotAFile` otherwise (:func:`open_regular`)."""
    with open_regular(path) as f:
        digest, size = hashlib.sha256(), 0
        try:
            while block := f.read(CHUNK):
                digest.update(block)
                size += len(block)
        except OSError as exc:
            raise NotAFile(f"{path} cannot be read ({exc.strerror or exc})") from None
    return digest.hexdigest(), size


def read_text(path: str | os.PathLike, encoding: str = "utf-8") -> str:
    """The text of the regular file at ``path`` (:func:`open_regular`: a named pipe in a
    folder cosim reads, a summary.json or sweep.json, is :class:`NotAFile`, not a hang)."""
    with open_regular(path) as f:
        return f.read().decode(encoding)
