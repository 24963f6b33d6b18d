"""Damaged copies of a real log for the readers' fuzz tests: truncated, bytes flipped, or both.

A reader given any of them must either read it (channels with strictly increasing times, the
input file unchanged) or stop with an IngestError; never anything else.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np

from pipeline.errors import IngestError


def damaged(data: bytes, rng: np.random.Generator, case: int) -> bytes:
    """Case 0, 3, ...: truncated; 1, 4, ...: 1-63 bytes flipped; 2, 5, ...: both."""
    b = bytearray(data)
    if case % 3 != 1:
        b = b[:int(rng.integers(0, len(b)))]
    if case % 3 != 0:
        for _ in range(int(rng.integers(1, 64))):
            if b:
                b[int(rng.integers(0, len(b)))] = int(rng.integers(0, 256))
    return bytes(b)


def fuzz_reader(data: bytes, read: Callable[[Path], object], folder: Path, suffix: str, seed: int,
                cases: int = 50) -> dict[str, int]:
    """Read ``cases`` damaged copies of ``data`` with ``read``; assert each outcome; count them."""
    rng = np.random.default_rng(seed)
    outcomes = {"read": 0, "IngestError": 0}
    for case in range(cases):
        b = damaged(data, rng, case)
        p = folder / f"fuzz{case}{suffix}"
        p.write_bytes(b)
        try:
            out = read(p)
        except IngestError:
            outcomes["IngestError"] += 1
            continue
        outcomes["read"] += 1
        for c in out.channels.values():
            assert len(c.t) == len(c.values) and len(c.t) > 0
            assert np.all(np.diff(c.t) > 0), (case, c.name)
        assert p.read_bytes() == b, "the reader must not change its input"
    return outcomes
