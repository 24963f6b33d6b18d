"""Atomic file output: a reader sees either the old file or the whole new one, never half of it.

The data go to a temporary file in the destination folder (so :func:`os.replace` is a rename on
one file system, which POSIX makes atomic) and replace the target only once complete and flushed.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterator

from .errors import OutputError

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

    Raises
    ------
    OutputError
        The folder cannot be created, or the file cannot be written or put in place (an
        ``OSError`` of the caller's own writing is turned into one too), naming the path.
    """
    target = Path(path)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f"{TEMP_PREFIX}{target.name}.", suffix=TEMP_SUFFIX, dir=target.parent)
    except OSError as exc:
        raise OutputError(f"{target}: expected a writable location, found: {exc.strerror or exc}") from None
    os.close(fd)
    try:
        yield Path(tmp)
        # Without fsync a crash after the rename can leave an empty file under the new name.
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.chmod(tmp, FILE_MODE)
        os.replace(tmp, target)
    except OSError as exc:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise OutputError(f"{target}: cannot write: {exc.strerror or exc}") from None
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


#: Files whose presence marks a folder as a vesselid report folder (safe to replace as a whole).
REPORT_MARKERS = ("coefficients.json", "report.html")


def check_output_folder(path: str | os.PathLike) -> Path:
    """Check, before any work starts, that ``path`` can become a report folder.

    It may be missing (its parent is created), empty, or an earlier report folder (it holds
    ``coefficients.json`` or ``report.html``): :func:`atomic_folder` replaces it as a whole, so a
    folder holding other files is refused rather than deleted.

    Parameters
    ----------
    path : str or os.PathLike
        The report folder.

    Raises
    ------
    OutputError
        ``path`` is a file, a non-empty folder that is not a report folder, or its parent is not
        writable.
    """
    target = Path(path)
    if target.exists() and not target.is_dir():
        raise OutputError(f"{target}: expected a report folder, found a file")
    if target.is_dir() and any(target.iterdir()) and not any((target / m).is_file() for m in REPORT_MARKERS):
        raise OutputError(f"{target}: expected a new, empty or earlier report folder (it is replaced as a "
                          f"whole), found a folder with other files; choose another output folder")
    parent = target.resolve().parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
        raise OutputError(f"{target}: expected a writable location, found {parent} not writable")
    return target


def check_output_file(path: str | os.PathLike, what: str = "output") -> Path:
    """Check, before any work starts, that the file ``path`` can be written.

    Parameters
    ----------
    path : str or os.PathLike
        The output file.
    what : str
        The flag or role, for the message (``--json``).

    Raises
    ------
    OutputError
        ``path`` is a folder or its folder is missing or not writable.
    """
    target = Path(path)
    if target.is_dir():
        raise OutputError(f"{what} {target}: expected a file name, found a folder")
    parent = target.parent if str(target.parent) else Path(".")
    if not parent.is_dir():
        raise OutputError(f"{what} {target}: expected an existing folder {parent}, found none")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise OutputError(f"{what} {target}: expected a writable folder, found {parent} not writable")
    return target


@contextlib.contextmanager
def atomic_folder(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a staging folder beside ``path``; on success it replaces ``path`` as a whole.

    A reader sees the old folder or the whole new one: files of an earlier run that this run did
    not write (a figure of a segment that is gone) do not survive. An exception leaves ``path``
    untouched and no staging folder behind.

    Parameters
    ----------
    path : str or os.PathLike
        The folder to write (checked with :func:`check_output_folder`).

    Raises
    ------
    OutputError
        The staging folder cannot be made or swapped in.
    """
    target = check_output_folder(path)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=f"{TEMP_PREFIX}{target.name}.", suffix=".staging",
                                        dir=target.parent))
        os.chmod(staging, 0o777 & ~_UMASK)
    except OSError as exc:
        raise OutputError(f"{target}: expected a writable location, found: {exc.strerror or exc}") from None
    try:
        yield staging
        old = None
        if target.exists():
            old = Path(tempfile.mkdtemp(prefix=f"{TEMP_PREFIX}{target.name}.", suffix=".old", dir=target.parent))
            os.rmdir(old)
            os.rename(target, old)
        try:
            os.rename(staging, target)
        except OSError:
            if old is not None:
                os.rename(old, target)
            raise
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    except OSError as exc:
        shutil.rmtree(staging, ignore_errors=True)
        raise OutputError(f"{target}: cannot write the report folder: {exc.strerror or exc}") from None
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
