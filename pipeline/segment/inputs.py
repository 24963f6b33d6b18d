"""Find where inputs change: piecewise-constant levels, and stretches of continuous variation."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Level:
    """A stretch where an input is constant.

    Attributes
    ----------
    i_start, i_end : int
        First and one-past-last sample index.
    value : float
        Input level [SI].
    """

    i_start: int
    i_end: int
    value: float


@dataclass(frozen=True)
class Varying:
    """A stretch where an input changes continuously (sinusoid, ramp, manual steering)."""

    i_start: int
    i_end: int


def input_tolerance(u: np.ndarray) -> float:
    """Smallest change [SI] counted as a command change: 1% of the input's range, at least 1e-9.

    Parameters
    ----------
    u : numpy.ndarray
        Input record [SI]; non-finite samples are ignored.

    Returns
    -------
    float
        Tolerance [SI unit of u]; ``inf`` when ``u`` has no finite sample.
    """
    finite = u[np.isfinite(u)]
    if len(finite) == 0:
        return np.inf
    return max(0.01 * float(np.ptp(finite)), 1e-9)


def _drift(u: np.ndarray, valid: np.ndarray, change: np.ndarray, tol: float) -> np.ndarray:
    """Samples where the input has crept more than ``tol`` from the last change without a jump.

    A slow sinusoid or ramp changes by less than ``tol`` between samples (at 50 Hz, any sinusoid
    slower than 1 rad/s), so per-sample differences never see it; its distance from the value at
    the last change does grow.
    """
    out = np.zeros(len(u), bool)
    bounds = np.concatenate([[0], np.flatnonzero(change), [len(u)]])
    for a, b in zip(bounds[:-1], bounds[1:]):
        if b - a < 2 or not valid[a] or np.ptp(u[a:b]) <= tol:
            continue  # constant within tol (the usual case): nothing to scan
        ref = u[a]
        for i in range(a + 1, b):
            if abs(u[i] - ref) > tol:
                out[i] = True
                ref = u[i]
    return out


def split_levels(u: np.ndarray, fs: float, min_varying_s: float = 1.0) -> tuple[list[Level], list[Varying]]:
    """Split an input record into constant levels and continuously varying stretches.

    Parameters
    ----------
    u : numpy.ndarray
        Input samples on the trial grid [SI]; NaN where not logged.
    fs : float
        Sample rate [Hz].
    min_varying_s : float
        Changes closer together than this for longer than this count as one varying stretch [s].

    Returns
    -------
    levels, varying
        Constant levels (at least 2 samples) and varying stretches, in time order.
    """
    n = len(u)
    tol = input_tolerance(u)
    if not np.isfinite(tol):
        return [], []
    valid = np.isfinite(u)
    change = np.zeros(n, bool)
    change[1:] = (np.abs(np.diff(u)) > tol) | (valid[1:] != valid[:-1])
    drift = _drift(u, valid, change, tol)
    idx = np.flatnonzero(change | drift)
    # Runs of changes on (nearly) every sample are a varying input, not a sequence of steps; so
    # are successive drifts (a slow sinusoid moves less than tol per sample, but keeps moving).
    gap = max(int(round(0.2 * fs)), 2)
    varying: list[Varying] = []
    run_start = None
    prev = None
    for i in idx:
        if prev is not None and (i - prev <= gap or (drift[i] and drift[prev])):
            run_start = prev if run_start is None else run_start
        else:
            if run_start is not None and prev - run_start >= min_varying_s * fs:
                varying.append(Varying(int(run_start), int(prev)))
            run_start = None
        prev = i
    if run_start is not None and prev - run_start >= min_varying_s * fs:
        varying.append(Varying(int(run_start), int(prev)))
    bounds = np.concatenate([[0], idx, [n]])
    levels: list[Level] = []
    for a, b in zip(bounds[:-1], bounds[1:]):
        if b - a < 2 or not valid[a]:
            continue
        if any(v.i_start <= a < v.i_end for v in varying):
            continue
        levels.append(Level(int(a), int(b), float(np.median(u[a:b]))))
    return levels, varying
