"""Noise level and detection quality of a segment's response, shared by the input-driven detector
(:mod:`pipeline.segment.detect`) and the speed-event detector (:mod:`pipeline.segment.speed_events`).
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
