"""Helpers every reader shares: file checks and per-channel clean-up with counted drops."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import IngestError


def check_file(path: str | Path, what: str) -> Path:
    """Return ``path`` as a Path, or raise IngestError when it is missing or empty."""
    p = Path(path)
    if not p.is_file():
        raise IngestError(f"{what}: expected a file, found nothing at {p}")
    if p.stat().st_size == 0:
        raise IngestError(f"{p}: expected a {what}, found an empty file (0 bytes)")
    return p


def increasing(t: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Keep samples whose time is strictly above every earlier one; return how many were dropped.

    Duplicate and out-of-order stamps happen in real logs (re-sent messages, clock steps);
    readers report the count in their summary rather than dropping them silently.
    """
    t = np.asarray(t, float)
    if len(t) == 0:
        return t, np.asarray(values), 0
    keep = np.ones(len(t), bool)
    keep[1:] = t[1:] > np.maximum.accumulate(t)[:-1]
    return t[keep], np.asarray(values)[keep], int((~keep).sum())


def actuators_reading(maps, source: str, n: int, what: str, warnings: list[str]) -> list:
    """The actuator maps that read ``source`` (``servo`` or ``rc``); none: a warning, and the records are skipped.

    Parameters
    ----------
    maps : sequence of ActuatorMap
        The vessel's ``[[actuators]]``.
    source : str
        ``servo`` or ``rc``.
    n : int
        Records of the input message present.
    what : str
        Their name for the warning (``"RCOU record(s)"``, ``"SERVO_OUTPUT_RAW message(s)"``).
    warnings : list of str
        Appended to when no map reads ``source``.

    Returns
    -------
    list of ActuatorMap
        The maps reading ``source``, in the vessel's order.
    """
    mine = [a for a in maps if a.source == source]
    if not mine:
        warnings.append(f"inputs not mapped: {n} {what} present but no actuator map with source '{source}' given "
                        f"(pass a vessel with [[actuators]]); counted as skipped")
    return mine


def describe_failure(exc: BaseException, limit: int = 160) -> str:
    """A library's failure in one line for an error message, without the exception's class name.

    Libraries raise many low-level types on damaged files (``struct.error``, ``KeyError``,
    ``AnyReaderError`` with a multi-line message, ...). The user needs what went wrong, on one
    line; a Python class name means nothing to them. The first non-empty line of the message is
    kept (cut to ``limit`` characters); a message-less failure is described by its kind.

    Parameters
    ----------
    exc : BaseException
        The library's exception.
    limit : int
        Most characters kept.

    Returns
    -------
    str
        One line, never empty.
    """
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    text = lines[0] if lines else ""
    if isinstance(exc, KeyError) and text:
        text = f"missing entry {text}"
    if not text:
        text = {"KeyError": "a missing entry", "IndexError": "data shorter than its header says",
                "UnicodeDecodeError": "bytes that are not text", "EOFError": "an unexpected end of file",
                "MemoryError": "more data than fits in memory"}.get(type(exc).__name__, "data the library cannot parse")
    if len(lines) > 1:
        text += " ..."
    return text if len(text) <= limit else text[:limit - 3] + "..."
