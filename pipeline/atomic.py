"""Atomic file output: a reader sees either the old file or the whole new one, never half of it.

The data go to a temporary file in the destination folder (so :func:`os.replace` is a rename on
one file system, which POSIX makes atomic) and replace the target only once complete and flushed.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from typing import Iterator

#: Prefix and suffix of temporary files, so a crashed run's leftovers are recognisable.
TEMP_PREFIX = ".vesselid-"
TEMP_SUFFIX = ".tmp"

# mkstemp creates 0600; outputs get the permissions a plain open() would give. The umask is read
# once: reading it means setting it, which is not thread-safe to repeat on every write.
_UMASK = os.umask(0)
os.umask(_UMASK)
FILE_MODE = 0o666 & ~_UMASK


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path in the target's folder; on success rename it to ``path``.

    The caller writes the whole file to the yielded path. An exception leaves the target
    untouched and no temporary file behind.

    Parameters
    ----------
    path : str or os.PathLike
        Destination file.
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f"{TEMP_PREFIX}{target.name}.", suffix=TEMP_SUFFIX, dir=target.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        # Without fsync a crash after the rename can leave an empty file under the new name.
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.chmod(tmp, FILE_MODE)
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically, creating the parent folder if missing.

    Parameters
    ----------
    path : str or os.PathLike
        Destination file.
    data : bytes
        Full file content.
    """
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def atomic_write_text(path: str | os.PathLike, text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically (``\\n`` line ends on every platform).

    Parameters
    ----------
    path : str or os.PathLike
        Destination file.
    text : str
        Full file content.
    encoding : str
        Text encoding.
    """
    return atomic_write_bytes(path, text.encode(encoding))
