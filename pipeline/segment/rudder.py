"""Rudder manoeuvres from a measured rudder angle: steady holds, servo ramps, zig-zags, sinusoids.

A logged rudder *command* is piecewise constant and its changes are jumps (the level splitter of
:mod:`pipeline.segment.inputs` reads it exactly). A *measured* servo angle is noisy and moves
between holds as a ramp (rate limit) or an exponential (servo lag) lasting seconds. Here the
record is read by what the ship's rudder did:

1. Holds: maximal stretches of at least ``MIN_HOLD_S`` where every sample stays within a band
   (four noise standard deviations, at least 0.2 % of the rudder's range) of the stretch's mean.
2. A change between two holds is a *step* (a ramp or a jump) when it is short against the holds
   beside it; its size is the difference of the two holds' levels, measured between the steady
   levels before and after the whole change (never between a sample inside the ramp and the next
   hold).
3. Three or more successive steps alternating in sign with (nearly) equal magnitude are a zig-zag.
4. Changes that last as long as the holds beside them (a sinusoid's peaks look like short holds)
   form varying stretches, reported as a sinusoid when a sine fits them.
"""

from __future__ import annotations

from dataclasses import dataclass

import math

import numpy as np

#: Shortest hold [s].
MIN_HOLD_S = 1.0
#: A change is a step when it lasts at most this fraction of the shorter hold beside it ...
STEP_FRACTION = 0.5
#: ... or at most this long [s] (a slow servo's full reversal).
STEP_MAX_S = 15.0
#: A hold shorter than this fraction of both neighbours (and than 5 s) is part of a transient.
SHORT_HOLD_FRACTION = 0.1
#: Fraction of a sine fit's explained variance above which a varying stretch is a sinusoid.
SINE_R2 = 0.9


@dataclass(frozen=True)
class Hold:
    """A stretch where the rudder stays at one level.

    Attributes
    ----------
    i_start, i_end : int
        First and one-past-last sample index.
    value : float
        Mean rudder angle [rad].
    """

    i_start: int
    i_end: int
    value: float


@dataclass(frozen=True)
class RudderChange:
    """A change between two holds (a jump or a servo ramp).

    Attributes
    ----------
    before, after : Hold
        The holds on either side; the change runs from ``before.i_end`` to ``after.i_start``.
    """

    before: Hold
    after: Hold

    @property
    def size(self) -> float:
        """Step size between the steady levels [rad]."""
        return self.after.value - self.before.value


#: Consecutive moving samples from which a change is a ramp (a servo), not a jump (a held command).
RAMP_SAMPLES = 3


def is_command_like(u: np.ndarray) -> bool:
    """True when a rudder record is a held command: piecewise constant, changing by jumps.

    A measured servo angle is noisy (it never holds a value exactly), or, when it carries no sensor
    noise (a simulator's servo state), it holds exactly but moves between holds by ramps and
    exponentials over several samples: most of its moving samples lie in runs of at least
    ``RAMP_SAMPLES`` successive changes. A held command jumps (a change spans one or two samples,
    two when the logger interpolated it).

    Parameters
    ----------
    u : numpy.ndarray
        Rudder record [rad]; non-finite samples ignored.
    """
    d = np.diff(u[np.isfinite(u)])
    if not d.size or float(np.mean(d == 0.0)) < 0.5:
        return False
    moving = np.concatenate([[0], (d != 0.0).astype(int), [0]])
    edges = np.flatnonzero(np.diff(moving))
    runs = edges[1::2] - edges[0::2]
    return not (runs.size and runs[runs >= RAMP_SAMPLES].sum() > 0.5 * runs.sum())


#: Sample-to-sample noise below which a varying rudder record is a computed command [rad] (0.01 deg):
#: a rudder angle sensor is noisier; a command an autopilot or a script computed is not.
NOISE_FREE_RAD = math.radians(0.01)


def is_noise_free(u: np.ndarray) -> bool:
    """True when a rudder record carries no sensor noise (a computed command, e.g. a logged sine).

    The noise is the robust standard deviation of the second difference over ``sqrt(6)`` (a smooth
    signal sampled well above its bandwidth leaves only the white noise there).

    Parameters
    ----------
    u : numpy.ndarray
        Rudder record [rad]; non-finite samples ignored.
    """
    u = np.asarray(u, float)
    u = u[np.isfinite(u)]
    if u.size < 5:
        return False
    d2 = np.diff(u, 2)
    sigma = 1.4826 * float(np.median(np.abs(d2 - np.median(d2)))) / math.sqrt(6.0)
    return sigma < NOISE_FREE_RAD


def is_servo_command(u: np.ndarray, fs: float) -> bool:
    """True when a rudder record is what a servo is told, not the angle it reached.

    A held command (:func:`is_command_like`) or a noise-free varying record (a computed command,
    e.g. a logged sine: :func:`is_noise_free`). A noise-free record that spends most of its time
    in holds (:func:`find_holds`) and moves between them by ramps and exponential tails is a
    servo's angle logged without sensor noise (a simulator's rudder state): the servo is already
    in it. (A sine's peaks are holds for a small fraction of its period only, whatever its
    frequency.)

    Parameters
    ----------
    u : numpy.ndarray
        Rudder record [rad]; non-finite samples ignored.
    fs : float
        Sample rate [Hz].
    """
    u = np.asarray(u, float)
    if is_command_like(u):
        return True
    if not is_noise_free(u):
        return False
    held = sum(h.i_end - h.i_start for h in find_holds(u, fs, 0.0))
    return held < 0.5 * int(np.isfinite(u).sum())


def find_holds(u: np.ndarray, fs: float, noise: float) -> list[Hold]:
    """Holds of a (noisy) rudder record.

    Parameters
    ----------
    u : numpy.ndarray
        Rudder record [rad]; NaN ends a hold.
    fs : float
        Sample rate [Hz].
    noise : float
        White-noise standard deviation of the record [rad].

    Returns
    -------
    list of Hold
        In time order, at least ``MIN_HOLD_S`` long each.
    """
    finite = u[np.isfinite(u)]
    if finite.size == 0:
        return []
    band = max(4.0 * noise if np.isfinite(noise) else 0.0, 0.002 * float(np.ptp(finite)), 1e-9)
    min_len = max(int(round(MIN_HOLD_S * fs)), 3)
    n = len(u)
    holds = []
    i = 0
    while i < n:
        if not np.isfinite(u[i]):
            i += 1
            continue
        total, count, j = float(u[i]), 1, i + 1
        while j < n and np.isfinite(u[j]) and abs(u[j] - total / count) <= band:
            total += float(u[j])
            count += 1
            j += 1
        if count >= min_len and not _trending(u[i:j], fs, band):
            holds.append(Hold(i, j, total / count))
            i = j
        else:
            i += 1
    return _drop_tail_holds(holds, fs)


def _trending(seg: np.ndarray, fs: float, band: float) -> bool:
    """True when a stretch drifts by more than half the band over its length (a servo's exponential
    tail creeping into the next hold, not a hold)."""
    t = np.arange(len(seg)) / fs
    slope = np.polyfit(t, seg, 1)[0]
    return abs(slope) * t[-1] > 0.5 * band


def _drop_tail_holds(holds: list[Hold], fs: float) -> list[Hold]:
    """Leave out holds much shorter than both neighbours (a pause inside a servo transient)."""
    out = []
    for k, h in enumerate(holds):
        n = h.i_end - h.i_start
        prev = holds[k - 1].i_end - holds[k - 1].i_start if k > 0 else None
        nxt = holds[k + 1].i_end - holds[k + 1].i_start if k + 1 < len(holds) else None
        neighbours = [m for m in (prev, nxt) if m is not None]
        if neighbours and n < SHORT_HOLD_FRACTION * min(neighbours) and n < 5.0 * fs:
            continue
        out.append(h)
    return out


def classify_changes(holds: list[Hold], fs: float, min_step: float = 0.0
                     ) -> tuple[list[RudderChange], list[tuple[int, int]]]:
    """Split the transitions between holds into steps and varying stretches.

    Parameters
    ----------
    holds : list of Hold
        From :func:`find_holds`.
    fs : float
        Sample rate [Hz].
    min_step : float
        Smallest step [rad]: a short change smaller than this is not a manoeuvre.

    Returns
    -------
    steps : list of RudderChange
        Short changes between holds whose levels differ by at least ``min_step``.
    varying : list of (int, int)
        Sample ranges ``[i0, i1)`` of continuously varying rudder (short holds inside included).
    """
    steps: list[RudderChange] = []
    varying: list[tuple[int, int]] = []

    def short_change(a: Hold, b: Hold) -> bool:
        dur = (b.i_start - a.i_end) / fs
        shorter = min(a.i_end - a.i_start, b.i_end - b.i_start) / fs
        return dur <= min(STEP_MAX_S, max(STEP_FRACTION * shorter, 2.0 / fs))

    # One hold broken by a noise spike (a short change smaller than a step) is one hold again, so
    # a step's window runs on to the next real change.
    joined: list[Hold] = []
    for h in holds:
        if joined and min_step > 0 and short_change(joined[-1], h) and abs(h.value - joined[-1].value) < min_step:
            a = joined[-1]
            na, nb = a.i_end - a.i_start, h.i_end - h.i_start
            joined[-1] = Hold(a.i_start, h.i_end, (a.value * na + h.value * nb) / (na + nb))
        else:
            joined.append(h)
    holds = joined
    for a, b in zip(holds[:-1], holds[1:]):
        short = short_change(a, b)
        if short and abs(b.value - a.value) >= min_step:
            steps.append(RudderChange(a, b))
        elif not short:
            varying.append((a.i_end, b.i_start))
    # A sine's peaks look like short holds: varying stretches closer than their own length join,
    # and steps inside a joined stretch are part of it.
    merged: list[tuple[int, int]] = []
    for v in varying:
        if merged and v[0] - merged[-1][1] <= max(merged[-1][1] - merged[-1][0], v[1] - v[0]):
            merged[-1] = (merged[-1][0], v[1])
        else:
            merged.append(v)
    steps = [st for st in steps if not any(a <= st.before.i_end < b for a, b in merged)]
    return steps, merged


def zigzag_runs(steps: list[RudderChange]) -> list[list[int]]:
    """Runs of at least 3 successive steps to alternating-sign holds of (nearly) equal magnitude.

    Parameters
    ----------
    steps : list of RudderChange
        In time order.

    Returns
    -------
    list of list of int
        Indices into ``steps`` per run.
    """
    runs: list[list[int]] = []
    cur: list[int] = []
    for k, st in enumerate(steps):
        lvl = st.after.value
        mag = abs(lvl)
        ok = mag > 0 and abs(st.size) > 1.5 * mag  # a reversal through zero, not a step from zero
        if cur:
            p = steps[cur[-1]]
            if ok and p.after is st.before and np.sign(p.after.value) == -np.sign(lvl) and \
                    abs(abs(p.after.value) - mag) <= 0.1 * mag:
                cur.append(k)
                continue
            if len(cur) >= 2:
                runs.append(cur)
            cur = []
        # A run starts at the first step out to +-a (from zero or from the opposite side).
        if mag > 0:
            cur = [k]
    if len(cur) >= 2:
        runs.append(cur)
    # Three holds at +-a (the first step plus two reversals) make a zig-zag.
    return [r for r in runs if len(r) >= 3]


def sine_fit_r2(u: np.ndarray, fs: float) -> tuple[float, float, float]:
    """Best single sine over a stretch: ``(R^2, omega [rad/s], amplitude [rad])``.

    Parameters
    ----------
    u : numpy.ndarray
        Rudder samples [rad], finite.
    fs : float
        Sample rate [Hz].
    """
    n = len(u)
    if n < 8:
        return 0.0, float("nan"), float("nan")
    t = np.arange(n) / fs
    x = u - u.mean()
    spec = np.abs(np.fft.rfft(x, 8 * n))
    freqs = np.fft.rfftfreq(8 * n, 1 / fs)
    k = int(np.argmax(spec[1:]) + 1)
    w = 2 * np.pi * freqs[k]
    basis = np.column_stack([np.sin(w * t), np.cos(w * t), np.ones(n)])
    c, *_ = np.linalg.lstsq(basis, u, rcond=None)
    resid = u - basis @ c
    ss = float(np.sum(x**2))
    r2 = 1.0 - float(np.sum(resid**2)) / ss if ss > 0 else 0.0
    return r2, float(w), float(np.hypot(c[0], c[1]))
