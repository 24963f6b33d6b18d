"""ingest stage: log files -> RawLog (one reader per format; raw names mapped to canonical channels).

:func:`read_log` picks the reader from the file's extension; each reader can also be called
directly. Every reader returns a :class:`pipeline.records.RawLog` whose summary counts the
messages read and skipped per type.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

from ..errors import IngestError
from ..records import RawLog
from .csv_log import read_csv_log


def _read_tlog(path: Path, vessel=None, **_: Any) -> RawLog:
    from .mavlink_tlog import read_tlog

    return read_tlog(path, vessel=vessel)


def _read_csv(path: Path, vessel=None, columns=None, units=None, **_: Any) -> RawLog:
    return read_csv_log(path, columns=columns, units=units)


#: File extension -> reader.
READERS: dict[str, Callable[..., RawLog]] = {
    ".csv": _read_csv,
    ".tlog": _read_tlog,
}


def read_log(path: str | Path, vessel=None, **options: Any) -> RawLog:
    """Read one log file with the reader for its extension.

    Parameters
    ----------
    path : str or Path
        Log file.
    vessel : pipeline.vessel.Vessel, optional
        Needed by readers that map actuator channels (MAVLink servo outputs).
    **options
        Reader options (``columns``, ``units`` for CSV).

    Raises
    ------
    IngestError
        Unknown extension, or the reader's own errors.
    """
    p = Path(path)
    reader = READERS.get(p.suffix.lower())
    if reader is None:
        raise IngestError(f"{p}: expected a log with extension {sorted(READERS)}, found {p.suffix or 'none'!r}")
    return reader(p, vessel=vessel, **options)


__all__ = ["read_log", "read_csv_log", "READERS"]
