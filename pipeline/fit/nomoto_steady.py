"""Nomoto K from the steady levels of rudder steps: the turn rate per rudder angle between steady holds.

A rudder step's K is a steady-state gain: the change of the steady turn rate over the change of the
rudder, ``K_i = (r_after - r_before) / (delta_after - delta_before)`` (the secant between the two
holds). It does not depend on the transient's model structure (first-order Nomoto, or second order
with a pole-zero pair), and the rudder bias cancels in the difference. The whole-record fit reads K
from the transient as well, with the structure chosen across the segments
(:mod:`pipeline.fit.nomoto_structure`); where that choice is undecided and the first order is kept,
the first order's K carries the structure's bias (measured: PythonVehicleSimulator's tanker at 20 m,
commanded steps noise-free, first-order K per step -2.9 to +0.0 %, mean -1.74 %, against secants of
-0.68 to -1.18 %). :func:`steady_level_note` then gives K from the secants, and
:func:`pipeline.fit.nomoto_quality.judge_nomoto` reports it in place of the fits' combination (measured:
the same tanker, seeds 0-4, commanded steps / measured steps with waves, K median abs error 2.0 / 2.1 % before,
1.1 / 0.9 % with the steady levels, 10 of 10 intervals covering; the scipy output-error peer 1.4 / 1.3 %).

Each level is the slope of the heading (the mean of the yaw rate when no compass is logged; the
compass's slope over 90 s is several times more precise than the gyro's mean) over the second half of
a hold: the lead-in before the step and the end of the step's window. Its error is the noise's
(Newey-West: the wave noise is correlated over seconds) with a settling term (:func:`step_secant`). The steps'
secants are combined by :func:`pipeline.fit.combine.combine` (consecutive steps share a hold: their
windows overlap and are combined as correlated; when they disagree beyond their errors the
random-effects prediction error holds the spread).
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from .combine import Contribution, combine
from ..model.nomoto import step_amplitude_sq
from .nomoto_amplitude import amplitude_line, amplitude_note, undecided_reason
from .data import segment_label
from .nomoto_quality import (STEADY_BROKEN, STEADY_K, SUPERPOSITION_MATERIAL, SUPERPOSITION_SPREAD,
                             SUPERPOSITION_T)
from .nomoto_segment import NomotoWindow

#: Fewest samples in each half-hold whose slope or mean is a level.
MIN_SAMPLES = 20
#: Longest lag of the noise's correlation in a level's standard error [s].
HAC_SECONDS = 20.0
#: The settling's time constant over the step's first-order T [-].
SETTLE_FACTOR = 2.0


def hold_level(t: np.ndarray, y: np.ndarray, slope: bool) -> tuple[float, float]:
    """The steady turn rate over a half-hold: the heading's slope or the yaw rate's mean, with its noise error.

    Parameters
    ----------
    t : numpy.ndarray
        Sample times [s].
    y : numpy.ndarray
        Unwrapped heading [rad] (``slope``) or yaw rate [rad/s]; NaN allowed.
    slope : bool
        Read the level as the slope of a line fitted to ``y`` (a heading) rather than its mean.

    Returns
    -------
    level, stderr : float
        Turn rate [rad/s] and its standard error (Newey-West, Bartlett weights over ``HAC_SECONDS``:
        wave noise is correlated over seconds); NaN when fewer than ``MIN_SAMPLES`` finite samples.
    """
    ok = np.isfinite(y) & np.isfinite(t)
    t, y = t[ok], y[ok]
    n = len(y)
    if n < MIN_SAMPLES:
        return math.nan, math.nan
    x = t - t.mean() if slope else np.ones(n)
    xx = float(x @ x)
    if slope:
        level = float(x @ y / xx)
        e = y - y.mean() - level * x
    else:
        level = float(y.mean())
        e = y - level
    dt = float(np.median(np.diff(t))) if n > 1 else 1.0
    lags = int(min(n // 4, max(1, HAC_SECONDS / dt)))
    u = x * e
    var = float(u @ u)
    for lag in range(1, lags + 1):
        var += 2 * (1 - lag / (lags + 1)) * float(u[lag:] @ u[:-lag])
    return level, math.sqrt(max(var, 0.0)) / xx


def step_secant(win: NomotoWindow, tau: float) -> Contribution:
    """One rudder step's K from its steady levels (a :class:`Contribution`; ``ok=False`` with a reason when not read).

    Each level is read over the second half of its hold; its error adds the noise (:func:`hold_level`)
    and the settling: the step's turn-rate change times ``exp(-t_a / (SETTLE_FACTOR tau))``, ``t_a``
    the time from the hold's start to the half-hold's start (the structure left undecided, the slowest
    mode may be slower than the first order's T: the tanker at 20 m, complex poles whose real part
    decays in 18.3 s against first-order T of 7-11 s).

    Parameters
    ----------
    win : NomotoWindow
        The step's whole-record window: a steady lead-in before the step (``t_rel < 0``) and the
        new hold to the window's end.
    tau : float
        The step's first-order T [s].
    """
    rec, where = win.rec, segment_label(win.segment)
    t = np.asarray(win.t_rel, dtype=float)
    if rec.psi is not None and np.isfinite(rec.psi).sum() >= 2 * MIN_SAMPLES:
        psi = np.asarray(rec.psi, dtype=float)
        ok = np.isfinite(psi)
        y = np.full_like(psi, np.nan)
        y[ok] = np.unwrap(psi[ok])
        slope = True
    elif rec.r is not None and np.isfinite(rec.r).sum() >= 2 * MIN_SAMPLES:
        y, slope = np.asarray(rec.r, dtype=float), False
    else:
        return Contribution(math.nan, math.nan, where, ok=False, reason="no heading or yaw rate")
    before = t < 0
    end = float(t[-1])
    # Second halves of the holds: the lead-in's and the new level's after the step.
    t_lead = float(t[before][0]) if before.any() else 0.0
    lv = []
    for a, b in ((t_lead / 2, 0.0), (end / 2, end + 1e-9)):
        m = (t >= a) & (t < b)
        r_l, r_se = hold_level(t[m], y[m], slope)
        d_l = float(np.nanmean(rec.delta[m])) if m.any() else math.nan
        lv.append((r_l, r_se, d_l))
    (r0, s0, d0), (r1, s1, d1) = lv
    step = d1 - d0
    if not all(math.isfinite(v) for v in (r0, s0, r1, s1, step)) or step == 0:
        return Contribution(math.nan, math.nan, where, ok=False,
                            reason=f"steady levels not read (expected {MIN_SAMPLES} samples in each half-hold)")
    scale = SETTLE_FACTOR * max(tau, 0.0) if math.isfinite(tau) else math.inf
    settle = [abs(r1 - r0) * (math.exp(-ta / scale) if scale > 0 else 0.0) for ta in (-t_lead / 2, end / 2)]
    se = math.sqrt(s0**2 + s1**2 + settle[0]**2 + settle[1]**2) / abs(step)
    t0 = float(win.segment.t_start)
    return Contribution((r1 - r0) / step, se, where, window=(t0 + t_lead / 2, t0 + end))


def steady_level_note(wins: Sequence[NomotoWindow], taus: Sequence[float], why: str) -> str:
    """``STEADY_K`` note with K combined from the rudder steps' steady levels ('' when not read).

    Parameters
    ----------
    wins : sequence of NomotoWindow
        The trial's rudder steps' whole-record windows (other kinds make the note '').
    taus : sequence of float
        Each step's first-order T [s] (for the settling term).
    why : str
        Why the steady levels are used (the structure left undecided), for the note.

    Returns
    -------
    str
        ``"K from the steady levels: ... K = v +- se 1/s (...)"`` or ''.
    """
    if len(wins) < 2 or any(w.segment.kind != "rudder_step" for w in wins):
        return ""
    parts = [step_secant(w, tau) for w, tau in zip(wins, taus)]
    if sum(c.ok for c in parts) < 2:
        return ""
    est = combine("K_nomoto", "1/s", "steady levels", parts, prediction=True)
    if not (est.success and math.isfinite(est.value) and math.isfinite(est.stderr) and est.stderr > 0):
        return ""
    per = ", ".join(f"{c.value:.4g}" for c in parts if c.ok)
    broken = secant_superposition(parts, wins, abs(est.value))
    # The secants of steps of different amplitudes: K at zero amplitude where their slope is significant.
    line = amplitude_line([c.value if c.ok else math.nan for c in parts], [c.stderr for c in parts],
                          [step_amplitude_sq(w.segment.input_before, w.segment.input_after) for w in wins],
                          [c.window if c.ok else None for c in parts])
    value, se, amp = est.value, est.stderr, ""
    if line is not None:
        amp = f", {amplitude_note(line).replace('; ', ', ')}"
        if line.kept:
            value, se, amp = line.k0, line.se_k0, f" from the secants: {amplitude_note(line).replace('; ', ', ')}"
        else:
            # The constant kept: the steps' secants are read at their own amplitudes, and the line's K0 is where
            # the linear K lies if the curvature the test could not decide is there. Their difference is a
            # model term of the error (measured: PythonVehicleSimulator's Clarke83 re-timed with waves, seeds
            # 0-9: the secants' K -1.2 to -1.9 % with errors of 0.6-0.8 %, marked success, 8 of 10 missing);
            # where the secants lean to the curvature beyond the difference's error K is unsure (read as a broken
            # superposition, which judge_nomoto makes unsure), as for the transients' own K.
            term = abs(line.k0 - line.mean) if math.isfinite(line.k0) else 0.0
            if term > 0:
                se = math.hypot(se, term)
                amp += f", the constant and K0 differ by {term:.3g} 1/s: added to the error as the amplitude model's term"
            undecided = undecided_reason(line).replace("; ", ", ")
            if undecided:
                broken = f"{broken}, {undecided}" if broken else undecided
    return (f"{STEADY_K}: {why}: K = {value:.6g} +- {se:.3g} 1/s{amp if line is not None and line.kept else ''} (the "
            f"turn rate per rudder angle between steady holds, {sum(c.ok for c in parts)} steps: {per} 1/s, "
            f"{est.message.replace('; ', ', ')}{amp if line is not None and not line.kept else ''})"
            + (f"{STEADY_BROKEN}{broken}" if broken else ""))


def _group(cs: Sequence[Contribution]) -> tuple[float, float]:
    """Inverse-variance mean of secants and its error scaled by their Birge ratio (at least 1)."""
    x = np.array([c.value for c in cs])
    w = 1.0 / np.array([c.stderr for c in cs]) ** 2
    m = float(w @ x / w.sum())
    birge = math.sqrt(float(w @ (x - m) ** 2) / (len(x) - 1)) if len(x) > 1 else 1.0
    return m, max(birge, 1.0) / math.sqrt(float(w.sum()))


def secant_superposition(parts: Sequence[Contribution], wins: Sequence[NomotoWindow], scale: float) -> str:
    """The steps into a turn against those out of one, when their secants differ (superposition broken; '' otherwise).

    The rule of :func:`pipeline.fit.nomoto_quality.superposition_reason`, on the secants: a linear ship's
    steady turn rate is linear in the rudder, so the secants into and out of a turn agree; groups whose
    means differ by ``|t| >= SUPERPOSITION_T`` and more than ``SUPERPOSITION_MATERIAL`` of ``scale``, or by
    more than ``SUPERPOSITION_SPREAD`` of it, break it.

    Parameters
    ----------
    parts : sequence of Contribution
        The steps' secants (:func:`step_secant`).
    wins : sequence of NomotoWindow
        Their windows (the segments' levels before and after).
    scale : float
        The combined K's magnitude [1/s].
    """
    into, out = [], []
    for c, w in zip(parts, wins):
        a, b = abs(w.segment.input_before), abs(w.segment.input_after)
        half = 0.5 * abs(w.segment.input_after - w.segment.input_before)
        if c.ok and b - a > half:
            into.append(c)
        elif c.ok and a - b > half:
            out.append(c)
    if not into or not out or not scale > 0:
        return ""
    (mi, si), (mo, so) = _group(into), _group(out)
    t, rel = (mi - mo) / math.hypot(si, so), abs(mi - mo) / scale
    if not ((abs(t) >= SUPERPOSITION_T and rel > SUPERPOSITION_MATERIAL) or rel > SUPERPOSITION_SPREAD):
        return ""
    return (f"{len(into)} steps into a turn give K = {mi:.4g} +- {si:.2g} 1/s, {len(out)} out of one {mo:.4g} +- "
            f"{so:.2g} (difference {rel:.1%} of the value, t = {t:+.1f}): the steady turn rate is not linear in "
            f"the rudder, so the combined K is not the linear value")
