"""Noise level and detection quality of a segment's response, and the runs of a mask, shared by the
input-driven detector (:mod:`pipeline.segment.detect`), the speed-event detector
(:mod:`pipeline.segment.speed_events`) and the replay segments (:mod:`pipeline.segment.replay`).
"""

from __future__ import annotations

import numpy as np


def noise_std(y: np.ndarray) -> float:
    """Robust white-noise level of a signal [unit of y]: MAD of first differences / (0.6745 sqrt 2).

    Parameters
    ----------
    y : numpy.ndarray
        Uniformly sampled signal; non-finite samples are dropped first.

    Returns
    -------
    float
        Noise standard deviation [unit of y]; NaN with fewer than four finite samples.
    """
    d = np.diff(y[np.isfinite(y)])
    if len(d) < 3:
        return np.nan
    return float(np.median(np.abs(d - np.median(d))) / 0.6745 / np.sqrt(2))


def detection_quality(snr: float, length_in_t: float) -> float:
    """Quality of a detected segment in [0, 1]: saturating in SNR (good above ~50) and in length
    (good above ~4 T).

    Parameters
    ----------
    snr : float
        Signal-to-noise ratio of the segment's response [-].
    length_in_t : float
        Segment length in time constants (or half cycles) [-].
    """
    if not np.isfinite(snr) or not np.isfinite(length_in_t):
        return 0.0
    return float(np.clip(1 - np.exp(-snr / 20), 0, 1) * np.clip(1 - np.exp(-length_in_t / 2), 0, 1))


def true_runs(ok: np.ndarray, min_len: int = 1) -> list[tuple[int, int]]:
    """Index ranges ``[a, b)`` of consecutive True values at least ``min_len`` long.

    Parameters
    ----------
    ok : numpy.ndarray
        Boolean mask.
    min_len : int
        Shortest run kept [samples].

    Returns
    -------
    list[tuple[int, int]]
        Start and stop (exclusive) of each run, in order.
    """
    idx = np.flatnonzero(ok)
    if len(idx) == 0:
        return []
    breaks = np.flatnonzero(np.diff(idx) > 1)
    starts = np.concatenate([[idx[0]], idx[breaks + 1]])
    ends = np.concatenate([idx[breaks] + 1, [idx[-1] + 1]])
    return [(int(a), int(b)) for a, b in zip(starts, ends) if b - a >= min_len]
