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
