"""Writing files so that an interrupted write never leaves a partial file.

Every file the library writes goes through :func:`write_atomic`: the data go to a
temporary file in the same folder, are flushed to disk, and the temporary file then
replaces the target in one rename. A kill, a full disk or an exception at any point
leaves either the old file or the new one, never a truncated one.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from .errors import FileFormatError, SRDEError

__all__ = ["write_atomic", "backup_path", "folder_lock"]

# The rename that makes a write visible (a name of its own so tests can fail it).
_replace = os.replace


def write_atomic(path: str | os.PathLike, data: bytes | str, *,
                 error: type[SRDEError] = FileFormatError) -> Path:
    """Write ``data`` to ``path`` atomically (same-folder temporary file and rename).

    Parameters
    ----------
    path : path
        The file; its folder is created if needed.
    data : bytes or str
        The content; text is written as UTF-8.
    error : type of SRDEError
        Raised, naming the file, when the system refuses the write.

    Returns
    -------
    pathlib.Path
    """
    path = Path(path)
    if isinstance(data, str):
        data = data.encode("utf-8")
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        _replace(tmp, path)
        tmp = None
    except OSError as exc:
        raise error(f"{path}: could not write the file: {exc}") from None
    finally:
        if tmp is not None and os.path.exists(tmp):
            os.unlink(tmp)
    return path


def backup_path(path: str | os.PathLike) -> Path:
    """Return the first free backup name of ``path``: ``name.bak``, ``name.bak1``, ...

    Backups are never overwritten, so every earlier version of a file stays.
    """
    path = Path(path)
    candidate = path.with_name(path.name + ".bak")
    n = 0
    while candidate.exists():
        n += 1
        candidate = path.with_name(f"{path.name}.bak{n}")
    return candidate


#: Name of the lock file a writer keeps in its output folder while it runs.
LOCK_FILE = ".srde-fusion.lock"


@contextmanager
def folder_lock(folder: str | os.PathLike, *, error: type[SRDEError] = FileFormatError
                ) -> Iterator[Path]:
    """Hold an output folder for one writer: create it, and a lock file in it, or refuse.

    Two runs writing into one folder would interleave their files and both report
    success; the second one is refused instead, before it computes anything.

    Raises
    ------
    FileFormatError (or ``error``)
        The folder cannot be created or written, or another run holds it.
    """
    folder = Path(folder)
    lock = folder / LOCK_FILE
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
    except FileExistsError:
        raise error(f"{folder}: expected a folder no other run is writing into, got its lock "
                    f"file {LOCK_FILE} (remove it if no run is going on)") from None
    except OSError as exc:
        raise error(f"{folder}: could not create or write the output folder: {exc}") from None
    try:
        os.write(fd, f"{os.getpid()}\n".encode())
        os.close(fd)
        yield folder
    finally:
        lock.unlink(missing_ok=True)
