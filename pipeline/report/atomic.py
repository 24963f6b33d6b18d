"""Atomic file writes: a reader sees either the old file or the whole new one, never half of it.

The data go to a temporary file in the destination folder (so :func:`os.replace` is a rename on
one file system, which POSIX and Windows make atomic) and replace the target only once they are
complete and flushed to disk.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from ..errors import ReportError

# The temporary file is created 0600; a report is meant to be read by others like any file the
# user creates, so the final file gets the permissions ``open()`` would give it. The umask is read
# once: reading it means setting it, which is not thread-safe to repeat on every write.
_UMASK = os.umask(0)
os.umask(_UMASK)
_FILE_MODE = 0o666 & ~_UMASK

#: Prefix and suffix of the temporary files, so a crashed run's leftovers are recognisable.
TEMP_PREFIX = ".vesselid-"
TEMP_SUFFIX = ".tmp"


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically, creating the parent folder if missing.

    Parameters
    ----------
    path : str or os.PathLike
        Destination file.
    data : bytes
        Full file content.

    Returns
    -------
    pathlib.Path
        The destination path.

    Raises
    ------
    ReportError
        When the folder cannot be created or the file cannot be written; no temporary file is
        left behind.
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ReportError(f"cannot create output folder {path.parent}: {exc}") from exc
    tmp_name = None
    try:
        fd, tmp_name = tempfile.mkstemp(dir=path.parent, prefix=TEMP_PREFIX + path.name + ".",
                                        suffix=TEMP_SUFFIX)
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            # Without fsync a crash after the rename can leave an empty file under the new name.
            os.fsync(fh.fileno())
        os.chmod(tmp_name, _FILE_MODE)
        os.replace(tmp_name, path)
        tmp_name = None
    except OSError as exc:
        raise ReportError(f"cannot write {path}: {exc}") from exc
    finally:
        if tmp_name is not None:
            try:
                os.unlink(tmp_name)
            except OSError:
                pass
    return path


def atomic_write_text(path: str | os.PathLike, text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically (see :func:`atomic_write_bytes`).

    Parameters
    ----------
    path : str or os.PathLike
        Destination file.
    text : str
        Full file content; written with ``\\n`` line ends on every platform.
    encoding : str
        Text encoding.

    Returns
    -------
    pathlib.Path
        The destination path.
    """
    return atomic_write_bytes(path, text.encode(encoding))
