"""Coast-downs found from the speed alone, for trials that logged no surge input.

Many real sea-trial logs hold only a GPS (the CE6 Limfjord runs: 20 Hz NMEA, the throttle in the
file name): the moment the throttle was cut is not logged, so the input-driven detector of
:mod:`pipeline.segment.detect` finds nothing. A coast-down still shows in the response: a steady
speed, then a sustained deceleration. This module finds it and checks that it is one:

1. **steady before**: for ``STEADY_S`` seconds the smoothed speed stays within ``STEADY_REL`` of
   its mean ``V0 >= V_MIN`` and does not trend;
2. **sustained deceleration**: the smoothed deceleration exceeds ``A_MIN`` for ``A_MIN_S`` seconds
   and the speed falls by at least ``DROP_MIN`` of ``V0`` without rising again;
3. **consistent with a first-order decay**: ``y_ss + (y0 - y_ss) exp(-t/T)`` (the closed-form
   integral regression of :func:`pipeline.model.first_order.guess_step`) explains at least
   ``R2_MIN`` of the variance with ``0 < T``;
4. **not a turn**: the course rate (and the gyro yaw rate when logged) stays below
   ``TURN_RATE_MAX``, since a boat also loses speed in a turn, and a cut during a turn couples
   surge with sway and yaw.

The segment starts where the speed leaves its steady band (the cut) and ends at the first of: the
speed settling (deceleration below ``A_END`` for ``SETTLE_S``), the speed rising again (throttle
back on), a dropout, the start of a turn, or ``MAX_S`` seconds. Candidates that fail a check are
returned with the reason by :func:`find_coast_downs`, so a report can say why a run was not used.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..geo import wrap_pi
from ..records import Segment, Trial
from .quality import detection_quality, noise_std, true_runs

#: Lowest steady speed a coast-down starts from [m/s].
V_MIN = 0.5
#: Length of the steady stretch required before the cut [s].
STEADY_S = 3.0
#: Largest standard deviation of the speed in the steady stretch, and largest trend across it,
#: relative to its mean [-]; real boats surge by a few percent in waves.
STEADY_REL = 0.06
TREND_REL = 0.10
#: Smoothed deceleration that starts a candidate [m/s^2], held for ``A_MIN_S`` [s].
A_MIN = 0.05
A_MIN_S = 0.5
#: Smallest speed drop, relative to the steady speed [-].
DROP_MIN = 0.3
#: The deceleration has died out when it stays below this [m/s^2] for ``SETTLE_S`` [s].
A_END = 0.02
SETTLE_S = 3.0
#: Longest coast-down kept [s].
MAX_S = 120.0
#: Smallest share of the variance a first-order decay must explain [-].
R2_MIN = 0.9
#: Largest turn rate (median |course rate| or |r|) of a coast-down [rad/s] (5 deg/s; GPS course
#: noise on a straight run reads 1.5 to 2.5 deg/s at 20 Hz, turning circles 11 to 34 deg/s).
TURN_RATE_MAX = math.radians(5.0)
#: Speed above which course over ground is trusted for the turn check [m/s].
COURSE_SOG_MIN = 0.5
#: Smoothing window for speed and deceleration [s].
SMOOTH_S = 1.0


@dataclass(frozen=True)
class Candidate:
    """A deceleration examined by :func:`find_coast_downs`.

    Attributes
    ----------
    t_start, t_end : float
        Bounds [s, trial clock].
    accepted : bool
        True when it passed every check and became a segment.
    reason : str
        Why it was rejected, or the label of the segment.
    """

    t_start: float
    t_end: float
    accepted: bool
    reason: str


def response_channel(trial: Trial) -> str | None:
    """The surge-speed channel a coast-down is read from: ``u``, else ``sog``, else a ``sog@...``.

    Parameters
    ----------
    trial : Trial
        The aligned trial.

    Returns
    -------
    str or None
        Column name; None when the trial has no speed at all.
    """
    for c in ("u", "sog"):
        if trial.has(c):
            return c
    for c in trial.data.columns:
        if c.split("@")[0] == "sog" and trial.has(c):
            return c
    return None


def _smooth(y: np.ndarray, w: int) -> np.ndarray:
    """Centred moving average over the finite samples (zero phase: the cut is not delayed)."""
    if w <= 1:
        return y.copy()
    ok = np.isfinite(y)
    k = np.ones(w)
    num = np.convolve(np.where(ok, y, 0.0), k, mode="same")
    den = np.convolve(ok.astype(float), k, mode="same")
    out = np.where(den >= 0.5 * w, num / np.maximum(den, 1e-12), np.nan)
    return out


def _turn_rate(trial: Trial, i0: int, i1: int) -> tuple[float, str]:
    """Median |turn rate| [rad/s] over samples i0..i1 from the gyro or the course, and its source."""
    if trial.has("r"):
        r = trial.data["r"].to_numpy()[i0:i1]
        if np.isfinite(r).sum() > 3:
            return float(np.nanmedian(np.abs(r))), "r"
    for c in trial.data.columns:
        if c.split("@")[0] != "cog" or not trial.has(c):
            continue
        sog = trial.data["sog" + c[3:]].to_numpy()[i0:i1] if ("sog" + c[3:]) in trial.data else None
        cog = trial.data[c].to_numpy()[i0:i1]
        if sog is None or len(cog) < 3:
            continue
        t = trial.t[i0:i1]
        w = max(int(round(SMOOTH_S * trial.fs)), 1)
        # Course difference over one smoothing window, so GPS course noise averages out.
        if len(cog) <= w:
            continue
        rate = wrap_pi(cog[w:] - cog[:-w]) / (t[w:] - t[:-w])
        ok = np.isfinite(rate) & (np.minimum(sog[w:], sog[:-w]) >= COURSE_SOG_MIN)
        if ok.sum() >= 3:
            return float(np.median(np.abs(rate[ok]))), f"d({c})/dt"
    return math.nan, "none"


def _first_order_r2(t: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Time constant [s] and R^2 of the closed-form first-order fit to a decay."""
    from ..model.first_order import guess_step, step_response

    ok = np.isfinite(y)
    if ok.sum() < 10:
        return math.nan, math.nan
    g = guess_step(t[ok], y[ok])
    fit = step_response(t[ok], g["y0"], g["y_ss"], g["T"])
    ss = float(np.sum((y[ok] - np.mean(y[ok])) ** 2))
    r2 = 1.0 - float(np.sum((y[ok] - fit) ** 2)) / ss if ss > 0 else math.nan
    return float(g["T"]), r2


def _steady(t: np.ndarray, y: np.ndarray, s0: int, s1: int) -> tuple[float, float, str]:
    """Mean and standard deviation of the speed over ``s0..s1`` [m/s], and why it is not steady ('' if it is)."""
    seg = y[s0:s1]
    ok = np.isfinite(seg)
    v0, sd = float(np.mean(seg[ok])), float(np.std(seg[ok]))
    trend = float(abs(np.polyfit(t[s0:s1][ok], seg[ok], 1)[0]) * STEADY_S)
    if v0 < V_MIN or sd > STEADY_REL * v0 or trend > TREND_REL * v0:
        return v0, sd, (f"not steady before {t[s1]:.1f} s: mean {v0:.2f} m/s, std {sd:.3f} m/s, trend {trend:.3f} m/s "
                        f"over {STEADY_S:g} s (expected >= {V_MIN:g} m/s, std <= {STEADY_REL:.0%} and trend <= "
                        f"{TREND_REL:.0%} of it)")
    return v0, sd, ""


def _steady_before(t: np.ndarray, y: np.ndarray, i0: int, n_steady: int, gaps=()) -> tuple[float, float, str]:
    """:func:`_steady` over the ``n_steady`` samples before ``i0``; a stretch with dropouts (under 90 %
    finite, or overlapping one of ``gaps``) is not steady either."""
    s0, s1 = i0 - n_steady, i0
    if np.isfinite(y[s0:s1]).sum() < 0.9 * n_steady or any(t[s0] < g.t_end and g.t_start < t[s1] for g in gaps):
        return math.nan, math.nan, "dropout in the steady stretch before the cut"
    return _steady(t, y, s0, s1)


def _change_point(t: np.ndarray, y: np.ndarray, lo: int, hi: int, n_pre: int, w: int) -> int:
    """Index ``k`` in ``lo..hi`` where a steady speed turns into a decline, best in least squares.

    Each candidate is scored by the squared error of the raw speed against its mean over the
    ``n_pre`` samples before ``k``, plus that of the ``w`` samples after ``k`` against the line
    through ``(t_k, mean)`` with the least-squares slope; a decline (negative slope) is required.
    The windows have the same length for every ``k``, so the scores compare.
    """
    best, best_k = math.inf, lo
    for k in range(lo, hi + 1):
        pre = y[max(k - n_pre, 0):k]
        pre = pre[np.isfinite(pre)]
        post_y = y[k:k + w]
        post_t = t[k:k + w] - t[k]
        ok = np.isfinite(post_y)
        if len(pre) < 3 or ok.sum() < 3:
            continue
        v0 = float(np.mean(pre))
        dt, dy = post_t[ok], post_y[ok] - v0
        slope = float(np.dot(dt, dy) / max(float(np.dot(dt, dt)), 1e-12))
        if slope >= 0:
            continue
        sse = float(np.sum((pre - v0) ** 2) + np.sum((dy - slope * dt) ** 2))
        if sse < best:
            best, best_k = sse, k
    return best_k


def find_coast_downs(trial: Trial, channel: str | None = None) -> tuple[list[Segment], list[Candidate]]:
    """Coast-downs in the speed of a trial without a surge input (see the module docstring).

    Parameters
    ----------
    trial : Trial
        The aligned trial.
    channel : str, optional
        Speed channel; default :func:`response_channel` (``u``, else ``sog``).

    Returns
    -------
    segments : list[Segment]
        ``coast_down`` in surge with ``input_channel=None``, ``origin='detected'``, a quality in
        [0, 1] (signal-to-noise and length in time constants, as for input-driven segments) and
        a label with the steady speed, the drop, the first-order T and R^2 and the turn rate.
    candidates : list[Candidate]
        Every deceleration examined, accepted or not, with the reason.
    """

    channel = channel or response_channel(trial)
    if channel is None or not trial.has(channel):
        return [], []
    fs = trial.fs
    t = trial.t
    y = trial.data[channel].to_numpy(float)
    n = len(y)
    w = max(int(round(SMOOTH_S * fs)), 1)
    ys = _smooth(y, w)
    # NaN (a dropout) stays NaN in the gradient: filling it would fake a deceleration at the gap.
    acc = _smooth(np.gradient(ys, t) if n > 1 else np.zeros(n), w)
    acc[~np.isfinite(ys)] = np.nan
    noise = noise_std(y)
    n_steady = max(int(round(STEADY_S * fs)), 3)
    decel = np.nan_to_num(acc, nan=0.0) < -A_MIN
    segs: list[Segment] = []
    cands: list[Candidate] = []
    busy_until = -math.inf
    for a, b in true_runs(decel):
        if b - a < A_MIN_S * fs or t[a] < busy_until:
            continue
        # The cut: a change point (steady before, declining after) near the strongest deceleration
        # of the run; a run may begin with a wave-induced slowdown before the throttle is cut.
        k_peak = a + int(np.nanargmin(acc[a:b]))
        # Smoothing puts the strongest deceleration up to a window after the cut.
        lo, hi = max(k_peak - 2 * w, a - w, n_steady), min(k_peak + w // 2, n - 2)
        if hi <= lo:
            cands.append(Candidate(float(t[a]), float(t[min(b, n - 1)]), False,
                                   f"deceleration at {t[a]:.1f} s without {STEADY_S:g} s of record before it"))
            continue
        i0 = _change_point(t, y, lo, hi, n_steady, w)
        v0, sd, unsteady = _steady_before(t, y, i0, n_steady, trial.gaps)
        if unsteady:
            cands.append(Candidate(float(t[i0 - n_steady]), float(t[i0]), False, unsteady))
            continue
        # Sustained: the speed falls by DROP_MIN without levelling off or rising on the way.
        below = np.flatnonzero(np.nan_to_num(ys[i0:], nan=np.inf) <= (1.0 - DROP_MIN) * v0)
        if not len(below):
            cands.append(Candidate(float(t[i0]), float(t[min(b, n - 1)]), False,
                                   f"speed never fell {DROP_MIN:.0%} below {v0:.2f} m/s after {t[i0]:.1f} s: a "
                                   f"slowdown, not a coast-down"))
            continue
        i_drop = i0 + int(below[0])
        # Refine the cut: the last moment the (lightly smoothed) speed was still in the steady band
        # before it fell for good. A change point picked early, in the steady stretch, moves up to
        # the real cut; one picked late moves back to it.
        light = _smooth(y, max(int(round(0.25 * fs)), 1))
        band = v0 - 2.0 * sd
        in_band = np.flatnonzero(np.nan_to_num(light[:i_drop], nan=-np.inf) >= band)
        if len(in_band) and in_band[-1] >= n_steady and in_band[-1] != i0:
            i0 = int(in_band[-1])
            v0, sd, unsteady = _steady_before(t, y, i0, n_steady)
            if unsteady:
                cands.append(Candidate(float(t[i0 - n_steady]), float(t[i0]), False, unsteady))
                continue
        mid = np.nan_to_num(acc[min(i0 + w, i_drop):i_drop], nan=0.0) > -A_END
        if any(e - s >= w for s, e in true_runs(mid)):
            cands.append(Candidate(float(t[i0]), float(t[i_drop]), False,
                                   f"deceleration from {t[i0]:.1f} s not sustained: the speed levelled off or rose "
                                   f"for a second or more before falling {DROP_MIN:.0%}"))
            continue
        # End: settled, speeding up again, a dropout, or MAX_S.
        i_max = min(n, i0 + int(round(MAX_S * fs)))
        for g in trial.gaps:
            k = int(np.searchsorted(t, g.t_start))
            if i0 < k < i_max:
                i_max = k
        run_low = 0
        lowest = ys[i0]
        i1 = i_max
        rise = max(0.1 * v0, 5.0 * (noise if math.isfinite(noise) else 0.0) / math.sqrt(w))
        for i in range(i0 + 1, i_max):
            if not math.isfinite(ys[i]):
                i1 = i
                break
            lowest = min(lowest, ys[i])
            if ys[i] > lowest + rise:
                # Throttle back on: end where the speed was lowest.
                i1 = int(i0 + np.nanargmin(ys[i0:i]))
                break
            run_low = run_low + 1 if abs(acc[i]) < A_END else 0
            if run_low >= SETTLE_S * fs and v0 - ys[i] >= DROP_MIN * v0:
                i1 = i - run_low + 1 + int(round(SETTLE_S * fs / 2))
                break
        i1 = min(max(i1, i0 + 1), n)
        t0, t1 = float(t[i0]), float(t[i1 - 1])
        busy_until = t1
        drop = v0 - float(np.nanmin(ys[i0:i1]))
        if drop < DROP_MIN * v0:
            cands.append(Candidate(t0, t1, False, f"speed fell only {drop:.2f} m/s from {v0:.2f} m/s (expected at "
                                                  f"least {DROP_MIN:.0%}): a slowdown, not a coast-down"))
            continue
        turn, turn_src = _turn_rate(trial, max(i0 - n_steady, 0), i1)
        if math.isfinite(turn) and turn > TURN_RATE_MAX:
            cands.append(Candidate(t0, t1, False, f"turning: median |{turn_src}| {math.degrees(turn):.1f} deg/s "
                                                  f"(expected below {math.degrees(TURN_RATE_MAX):g} deg/s for a "
                                                  f"straight coast-down)"))
            continue
        T, r2 = _first_order_r2(t[i0:i1] - t0, y[i0:i1])
        if not (math.isfinite(T) and T > 0 and r2 >= R2_MIN):
            cands.append(Candidate(t0, t1, False, f"not a first-order decay: T {T:.3g} s, R^2 {r2:.3f} "
                                                  f"(expected T > 0 and R^2 >= {R2_MIN:g})"))
            continue
        snr = drop / max(noise if math.isfinite(noise) else 0.0, 1e-12)
        turn_text = (f"turn rate {math.degrees(turn):.1f} deg/s ({turn_src})" if math.isfinite(turn)
                     else "turn rate not measurable (no r, no course above 0.5 m/s)")
        label = (f"input-free coast-down from {channel}: steady {v0:.2f} m/s for {STEADY_S:g} s, then "
                 f"{v0:.2f} -> {v0 - drop:.2f} m/s; first-order T~{T:.2f} s (R^2 {r2:.3f}); {turn_text}; SNR {snr:.0f}")
        seg = Segment("coast_down", "surge", t0, t1, None, 0.0, 0.0, quality=detection_quality(snr, (t1 - t0) / T),
                      origin="detected", label=label)
        segs.append(seg)
        cands.append(Candidate(t0, t1, True, label))
    return segs, cands


def coast_down_segments(trial: Trial) -> list[Segment]:
    """The input-free coast-downs of :func:`find_coast_downs` (segments only).

    Parameters
    ----------
    trial : Trial
        The aligned trial (its speed channel ``u`` or ``sog``).
    """
    return find_coast_downs(trial)[0]


__all__ = ["Candidate", "find_coast_downs", "coast_down_segments", "response_channel"]
