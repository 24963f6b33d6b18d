"""Roll and pitch free decays from a release: heeling tests and hand releases.

A heeling test holds a known heeling moment (``tau_k``, weights or a line) and then releases it;
a pool decay test heels the hull by hand and lets go. Either way the free oscillation starts at
the release, not where the heel began: a segment that includes the heel ramp or the hold fits a
forced response as if it were free and biases the damping. Two ways to find the release:

- a logged moment (``tau_k``/``tau_m``) that steps (released to zero, or changed): the release is
  the input change itself (:func:`release_decays`);
- no logged moment: the angle itself. The release is the end of the hold: the last sample, before
  the angle first swings through its equilibrium, that is still within 2 % (or three noise
  standard deviations) of the largest deviation (:func:`release_index`).

The decay ends once the angle has stayed within ``max(3 noise, 5 % of the release deviation)`` of
its final level for one second, or at the next input change, or at a dropout or run boundary.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..records import INPUT_UNITS, Segment, Trial
from .inputs import input_tolerance

#: Moment input -> (DOF, attitude channel) of a heeling or trimming test.
MOMENT_DOF = {"tau_k": ("roll", "phi"), "tau_m": ("pitch", "theta")}
#: Fraction of the largest deviation within which the hold still counts as held [-].
HOLD_FRACTION = 0.02


def _noise(y: np.ndarray) -> float:
    d = np.diff(y[np.isfinite(y)])
    if len(d) < 3:
        return float("nan")
    return float(np.median(np.abs(d - np.median(d))) / 0.6745 / np.sqrt(2))


def equilibrium(y: np.ndarray, fs: float, noise: float) -> float:
    """The level a roll or pitch record oscillates about [rad].

    The median of a whole record is not it when a heel is held for long (a heeling test, a hand
    heel in a pool): half the samples may sit at the heel. A free decay swings through its
    equilibrium again and again, so among the candidates (the median, the mode, and the median
    of the first and the last two seconds) the one the angle crosses most often, counting only
    samples clear of the noise, is taken.

    Parameters
    ----------
    y : numpy.ndarray
        Angle [rad], uniformly sampled.
    fs : float
        Sample rate [Hz].
    noise : float
        Noise standard deviation [rad].

    Returns
    -------
    float
        Equilibrium [rad]; NaN for a record without finite samples.
    """
    ok = y[np.isfinite(y)]
    if len(ok) == 0:
        return float("nan")
    w = max(int(2 * fs), 1)
    width = max(4 * noise, np.radians(0.2)) if np.isfinite(noise) else np.radians(0.2)
    bins = max(int(np.ptp(ok) / width), 1)
    hist, edges = np.histogram(ok, bins=bins)
    k = int(np.argmax(hist))
    candidates = [float(np.median(ok)), float(np.median(ok[:w])), float(np.median(ok[-w:])),
                  0.5 * float(edges[k] + edges[k + 1])]
    clear = 3 * noise if np.isfinite(noise) else 0.0

    def crossings(b: float) -> int:
        d = ok - b
        d = d[np.abs(d) > clear]
        return int(np.sum(np.diff(np.sign(d)) != 0))

    return max(candidates, key=crossings)


def release_index(dev: np.ndarray, j: int, noise: float) -> int:
    """Index of the release in a deviation record that first exceeds the threshold at ``j``.

    Parameters
    ----------
    dev : numpy.ndarray
        Signed deviation of the angle from its equilibrium [rad], uniformly sampled.
    j : int
        First index above the detection threshold.
    noise : float
        Noise standard deviation of the angle [rad].

    Returns
    -------
    int
        The last index before the first swing through equilibrium (sign change of ``dev``) at
        which ``|dev|`` is within ``max(3 noise, HOLD_FRACTION * peak)`` of its peak: the end of
        the hold for a held heel, the peak itself for an instantaneous release.
    """
    n = len(dev)
    sign = np.sign(dev[j]) or 1.0
    after = np.flatnonzero(np.nan_to_num(dev[j:] * sign, nan=-1.0) <= 0)
    m = j + int(after[0]) if len(after) else n
    seg = np.abs(np.nan_to_num(dev[j:m]))
    if len(seg) == 0:
        return j
    peak = float(seg.max())
    near = np.flatnonzero(seg >= peak - max(3 * noise, HOLD_FRACTION * peak))
    return j + int(near[-1])


def decay_end(y: np.ndarray, k0: int, k_lim: int, fs: float, noise: float, level: float) -> int:
    """Index where a decay from ``k0`` has settled at ``level`` for a second (at most ``k_lim``).

    Parameters
    ----------
    y : numpy.ndarray
        Angle [rad], uniformly sampled at ``fs``.
    k0, k_lim : int
        Release index and the last index the decay may reach.
    fs : float
        Sample rate [Hz].
    noise : float
        Noise standard deviation [rad].
    level : float
        Final equilibrium [rad].

    Returns
    -------
    int
        The index one quiet second after the decay settled, or ``k_lim``.
    """
    dev = np.abs(np.nan_to_num(y[k0:k_lim + 1] - level, nan=np.inf))
    if len(dev) == 0:
        return k0
    w = max(int(round(fs)), 1)
    below = dev < max(3 * noise, 0.05 * dev[0])
    if len(below) < w:
        return k_lim
    run = np.convolve(below.astype(int), np.ones(w), mode="valid")
    done = np.flatnonzero(run >= w)
    return min(k0 + int(done[0]) + w, k_lim) if len(done) else k_lim


def _next_change(trial: Trial, i0: int) -> int:
    """Last index before any input changes (or stops) after ``i0``."""
    n = len(trial.data)
    end = n - 1
    for c in trial.data.columns:
        if c.split("@")[0] not in INPUT_UNITS:
            continue
        u = trial.data[c].to_numpy()
        if not np.isfinite(u[i0]):
            continue
        tol = input_tolerance(u)
        moved = np.flatnonzero(~(np.abs(u[i0 + 1:] - u[i0]) <= tol))
        if len(moved):
            end = min(end, i0 + int(moved[0]))
    for g in trial.gaps:
        if g.t_start >= trial.t[i0]:
            end = min(end, int(np.searchsorted(trial.t, g.t_start, side="right")) - 1)
    return end


def release_decays(trial: Trial, segments: list[Segment]) -> list[Segment]:
    """Turn roll/pitch moment steps (a released heeling moment) into free decays from the release.

    Parameters
    ----------
    trial : Trial
        The aligned trial, with ``phi``/``theta`` and the moment input.
    segments : list[Segment]
        Input-driven segments (:func:`pipeline.segment.detect.detect_segments`).

    Returns
    -------
    list[Segment]
        The same list, with each ``coast_down`` or ``step`` in roll or pitch driven by
        ``tau_k``/``tau_m`` replaced by a ``free_decay`` that starts at the input change and ends
        when the angle has settled (or at the next input change); a step whose angle does not
        oscillate (fewer than two swings through its final level) is left as it was.
    """
    out = []
    t = trial.t
    fs = trial.fs
    for s in segments:
        moment = MOMENT_DOF.get((s.input_channel or "").split("@")[0])
        if s.kind not in ("coast_down", "step") or moment is None or s.dof != moment[0] or not trial.has(moment[1]):
            out.append(s)
            continue
        y = trial.data[moment[1]].to_numpy()
        i0 = int(np.searchsorted(t, s.t_start - 0.5 / fs))
        k_lim = _next_change(trial, i0)
        tail = y[max(k_lim - max(int(fs), 2), i0):k_lim + 1]
        level = float(np.nanmedian(tail)) if np.isfinite(tail).any() else float("nan")
        noise = _noise(y[i0:k_lim + 1])
        if not (np.isfinite(level) and np.isfinite(noise)):
            out.append(s)
            continue
        k1 = decay_end(y, i0, k_lim, fs, noise, level)
        seg_y = y[i0:k1 + 1] - level
        # Swings through the final level, counted where the angle is clear of the noise.
        clear = seg_y[np.isfinite(seg_y) & (np.abs(seg_y) > 3 * noise)]
        swings = int(np.sum(np.diff(np.sign(clear)) != 0))
        if swings < 2 or k1 - i0 < 10:
            out.append(s)
            continue
        what = "release of" if s.kind == "coast_down" else "step in"
        out.append(replace(s, kind="free_decay", t_end=float(t[k1]), input_channel=None,
                           label=f"{what} {s.input_channel} {s.input_before:.4g} -> {s.input_after:.4g} N m "
                                 f"(heeling test), from {np.degrees(y[i0] - level):.1f} deg, {swings} zero crossings"))
    return out


__all__ = ["release_decays", "release_index", "decay_end", "MOMENT_DOF"]
