"""Atomic writes for the report stage: :mod:`pipeline.atomic`, with failures as ReportError."""

from __future__ import annotations

import os
from pathlib import Path

from .. import atomic as _atomic
from ..atomic import TEMP_PREFIX, TEMP_SUFFIX
from ..errors import ReportError

__all__ = ["atomic_write_bytes", "atomic_write_text", "TEMP_PREFIX", "TEMP_SUFFIX"]


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (see :func:`pipeline.atomic.atomic_path`).

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
    try:
        return _atomic.atomic_write_bytes(path, data)
    except OSError as exc:
        raise ReportError(f"cannot write {path}: expected a writable location, found {exc}") from exc


def atomic_write_text(path: str | os.PathLike, text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically; failures raise ReportError.

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
