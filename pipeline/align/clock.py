"""Put several raw logs on one clock: absolute time where a log has it, else cross-correlated rates.

A trial's files rarely share a clock: an autopilot log runs on boot time, a u-blox receiver on
GPS time of week, an NMEA logger on UTC, a ROS bag on the computer's wall clock. Where a reader
found the absolute UTC of ``t = 0`` (``RawLog.start_time``), the offset between two logs is the
difference of their start times. A log without one is placed by cross-correlating a rate it
shares with a log already placed: the gyro yaw rate ``r``, the heading rate ``d psi/dt`` and the
course rate ``d cog/dt`` (only where the speed over ground is high enough for the course to be
defined) all measure the turn rate of the hull, and ``d sog/dt`` or ``d u/dt`` the surge
acceleration. The lag of the highest normalised cross-correlation, refined to a fraction of a
sample by a parabola through the peak, is the clock offset; a peak that is weak, or not clearly
above the next best peak (a periodic manoeuvre), is refused rather than guessed.

References
----------
Knapp, C. H. and Carter, G. C. (1976), "The generalized correlation method for estimation of time
delay", IEEE Trans. ASSP 24(4): the delay variance (1 - rho^2) / (rho^2 N omega_rms^2) used here
with the peak curvature standing in for omega_rms^2.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, NamedTuple, Sequence

import numpy as np
from scipy.signal import correlate, correlation_lags

from ..errors import AlignError
from ..geo import wrap_pi
from ..records import RawLog

#: Speed over ground below which course over ground is not defined well enough to differentiate [m/s].
SOG_MIN = 0.5
#: Smallest peak normalised cross-correlation accepted [-].
MIN_PEAK = 0.5
#: Smallest Fisher z-score of the peak (atanh(rho) sqrt(N_eff - 3)) accepted [-]; N_eff counts
#: peak widths in the overlap, so slow manoeuvres give few independent samples.
MIN_Z = 3.0
#: The peak must beat the best correlation at any lag outside it by this much [-]; a periodic
#: manoeuvre (a long zig-zag alone) correlates almost as well one period off and is refused.
MIN_MARGIN = 0.15
#: Fraction of the shorter signal's valid samples that a lag must overlap to be considered [-].
MIN_OVERLAP_FRACTION = 0.5
#: Shortest overlap a lag must have [s].
MIN_OVERLAP_S = 20.0
#: Moving-average window applied to every rate signal before correlating [s]; it tames the noise
#: of differentiated GPS course and speed and is the same for both signals, so it adds no lag.
SMOOTH_S = 0.5
#: Finest and coarsest correlation grid step [s].
GRID_MIN_S = 0.01
GRID_MAX_S = 0.2
#: Sub-records the overlap is split into for the scatter-based standard error.
N_CHUNKS = 4
#: Nominal standard error of an offset from absolute time stamps (millisecond stamps) [s]. It
#: does not include a logger's unknown latency; the cross-check below reports that when it can.
ABSOLUTE_STDERR_S = 0.001


class ClockOffset(NamedTuple):
    """Offset to add to one log's times to put it on the common clock.

    Attributes
    ----------
    offset_s : float
        Offset [s]: ``t_common = t_log + offset_s``.
    stderr_s : float
        Standard error of the offset [s].
    method : str
        How it was found (``absolute time ...``, ``cross-correlation ...`` with the signals, the
        peak correlation and the overlap, or ``reference``).
    """

    offset_s: float
    stderr_s: float
    method: str


@dataclass(frozen=True)
class RateSignal:
    """A rate measured by one log, on that log's clock.

    Attributes
    ----------
    name : str
        What it is (``r``, ``d(psi)/dt``, ``d(cog@gps)/dt``, ``d(sog)/dt``).
    family : str
        ``yaw`` (turn rate [rad/s]) or ``surge`` (acceleration [m/s^2]); only signals of one
        family are correlated with each other.
    t : numpy.ndarray
        Sample times [s, log clock], increasing.
    values : numpy.ndarray
        Rate [rad/s or m/s^2]; NaN where it is not defined (course at low speed, gaps).
    dt : float
        Median sample interval [s].
    """

    name: str
    family: str
    t: np.ndarray
    values: np.ndarray
    dt: float


@dataclass(frozen=True)
class LagEstimate:
    """The lag that best aligns two rate signals.

    Attributes
    ----------
    lag_s : float
        Offset to add to the second signal's clock to put it on the first's [s].
    stderr_s : float
        Standard error [s]: the larger of the peak-curvature formula and the scatter of the lags
        of ``N_CHUNKS`` sub-records.
    peak : float
        Normalised cross-correlation at the peak [-].
    second_peak : float
        Best normalised cross-correlation away from the main peak [-] (ambiguity check).
    z : float
        Fisher z-score of the peak, ``atanh(peak) sqrt(n_eff - 3)`` [-].
    n_eff : float
        Effective number of independent samples in the overlap [-].
    overlap_s : float
        Length of the overlap at the peak [s].
    dt : float
        Correlation grid step [s].
    reason : str
        Empty when the peak is significant, else why it is not.
    """

    lag_s: float
    stderr_s: float
    peak: float
    second_peak: float
    z: float
    n_eff: float
    overlap_s: float
    dt: float
    reason: str = ""

    @property
    def significant(self) -> bool:
        """True when the peak passed every check."""
        return not self.reason


# --------------------------------------------------------------------------- rate signals
def _base(name: str) -> tuple[str, str]:
    base, _, sensor = name.partition("@")
    return base, (f"@{sensor}" if sensor else "")


def _median_dt(t: np.ndarray) -> float:
    return float(np.median(np.diff(t))) if len(t) > 1 else math.nan


def _angle_rate(t: np.ndarray, a: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Central-difference rate of an angle [rad/s], wrapping each difference (no unwrap needed).

    A sample's rate needs both neighbours valid and close in time (not across a dropout).
    """
    out = np.full(len(t), np.nan)
    if len(t) < 3:
        return out
    dt = t[2:] - t[:-2]
    limit = 5.0 * _median_dt(t) * 2
    good = ok[2:] & ok[:-2] & (dt > 0) & (dt <= limit)
    out[1:-1] = np.where(good, wrap_pi(a[2:] - a[:-2]) / np.where(dt > 0, dt, 1.0), np.nan)
    return out


def _rate(t: np.ndarray, v: np.ndarray) -> np.ndarray:
    out = np.full(len(t), np.nan)
    if len(t) < 3:
        return out
    dt = t[2:] - t[:-2]
    limit = 5.0 * _median_dt(t) * 2
    good = np.isfinite(v[2:]) & np.isfinite(v[:-2]) & (dt > 0) & (dt <= limit)
    out[1:-1] = np.where(good, (v[2:] - v[:-2]) / np.where(dt > 0, dt, 1.0), np.nan)
    return out


def rate_signals(log: RawLog, sog_min: float = SOG_MIN) -> list[RateSignal]:
    """The turn-rate and acceleration signals a log can offer for clock alignment.

    Parameters
    ----------
    log : RawLog
        Any raw log.
    sog_min : float
        Speed over ground below which a course rate is not formed [m/s].

    Returns
    -------
    list[RateSignal]
        ``r`` (gyro, any sensor suffix), ``d(psi)/dt``, ``d(cog)/dt`` where the matching ``sog``
        is at least ``sog_min``, and ``d(sog)/dt``, ``d(u)/dt``; only signals with at least ten
        finite samples and some variation.
    """
    out: list[RateSignal] = []
    ch = log.channels
    for name, c in ch.items():
        t = np.asarray(c.t, float)
        v = np.asarray(c.values, float)
        if len(t) < 10:
            continue
        base, sfx = _base(name)
        if base == "r":
            sig = RateSignal(name, "yaw", t, np.where(np.isfinite(v), v, np.nan), _median_dt(t))
        elif base == "psi":
            sig = RateSignal(f"d({name})/dt", "yaw", t, _angle_rate(t, v, np.isfinite(v)), _median_dt(t))
        elif base == "cog":
            sog = ch.get("sog" + sfx)
            if sog is None or len(sog.t) < 2:
                continue
            speed = np.interp(t, sog.t, sog.values, left=np.nan, right=np.nan)
            ok = np.isfinite(v) & np.isfinite(speed) & (speed >= sog_min)
            sig = RateSignal(f"d({name})/dt (sog >= {sog_min:g} m/s)", "yaw", t, _angle_rate(t, v, ok),
                             _median_dt(t))
        elif base in ("sog", "u"):
            sig = RateSignal(f"d({name})/dt", "surge", t, _rate(t, v), _median_dt(t))
        else:
            continue
        finite = np.isfinite(sig.values)
        if finite.sum() >= 10 and np.nanstd(sig.values) > 0 and math.isfinite(sig.dt) and sig.dt > 0:
            out.append(sig)
    return out


# --------------------------------------------------------------------------- correlation
def _on_grid(sig: RateSignal, shift: float, dt: float) -> tuple[float, np.ndarray, np.ndarray]:
    """Signal on its own uniform grid (start, values with 0 where invalid, mask), smoothed."""
    t = sig.t + shift
    n = int(math.floor((t[-1] - t[0]) / dt)) + 1
    grid = t[0] + np.arange(n) * dt
    ok = np.isfinite(sig.values)
    v = np.interp(grid, t[ok], sig.values[ok])
    # Valid where the nearest native samples on both sides are valid and not a dropout apart.
    j = np.clip(np.searchsorted(t, grid, side="right"), 1, len(t) - 1)
    near = ok[j - 1] & ok[j] & ((t[j] - t[j - 1]) <= 5.0 * sig.dt)
    near |= np.isclose(grid, t[j - 1]) & ok[j - 1]
    m = near.astype(float)
    w = max(int(round(SMOOTH_S / dt)), 1)
    if w > 1:
        # Normalised convolution: the moving average of the valid samples only.
        k = np.ones(w)
        num = np.convolve(v * m, k, mode="same")
        den = np.convolve(m, k, mode="same")
        v = np.where(den > 0.5 * w, num / np.maximum(den, 1e-12), 0.0)
        m = (den > 0.5 * w).astype(float)
    return float(grid[0]), v * m, m


def _masked_ncc(x: np.ndarray, mx: np.ndarray, y: np.ndarray, my: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pearson correlation of ``x[n + k]`` with ``y[n]`` over the samples both have, for every lag k.

    Six FFT correlations give, per lag, the overlap count and the sums needed to demean and
    normalise over exactly the overlapping valid samples (masked normalised cross-correlation).
    """
    def c(a, b):
        return correlate(a, b, mode="full", method="fft")

    n = c(mx, my)
    sx, sy = c(x, my), c(mx, y)
    sxx, syy = c(x * x, my), c(mx, y * y)
    sxy = c(x, y)
    lags = correlation_lags(len(x), len(y), mode="full")
    with np.errstate(invalid="ignore", divide="ignore"):
        nn = np.maximum(np.round(n), 1.0)
        cov = sxy - sx * sy / nn
        vx = sxx - sx * sx / nn
        vy = syy - sy * sy / nn
        rho = cov / np.sqrt(vx * vy)
    rho[~np.isfinite(rho) | (vx <= 0) | (vy <= 0)] = np.nan
    return lags, rho, np.round(n)


def _parabola(rho: np.ndarray, k: int) -> tuple[float, float]:
    """Sub-sample offset of a peak at index k and the curvature -rho'' there [per sample^2]."""
    if k <= 0 or k >= len(rho) - 1 or not np.isfinite(rho[k - 1:k + 2]).all():
        return 0.0, math.nan
    a, b, c = rho[k - 1], rho[k], rho[k + 1]
    den = a - 2 * b + c
    if den >= 0:
        return 0.0, math.nan
    return float(np.clip(0.5 * (a - c) / den, -0.5, 0.5)), float(-den)


def correlate_rates(x: RateSignal, y: RateSignal, x_shift: float = 0.0, y_shift: float = 0.0) -> LagEstimate:
    """Lag that best aligns ``y`` with ``x`` by normalised cross-correlation, with its uncertainty.

    Parameters
    ----------
    x, y : RateSignal
        Rate signals of one family, each on its own clock.
    x_shift, y_shift : float
        Offsets [s] already added to each signal's clock (the lag is found on top of them).

    Returns
    -------
    LagEstimate
        ``lag_s`` such that ``y`` on ``t + y_shift + lag_s`` matches ``x`` on ``t + x_shift``;
        ``reason`` says why a peak is not significant (too short an overlap, weak, ambiguous).

    Notes
    -----
    Both signals are put on a common grid step (the finer native interval, within
    ``GRID_MIN_S``..``GRID_MAX_S``), smoothed by a ``SMOOTH_S`` moving average over their valid
    samples, and correlated for every lag at which they overlap by at least
    ``MIN_OVERLAP_FRACTION`` of the shorter record and ``MIN_OVERLAP_S``. The peak is refined by
    a parabola through it and its neighbours. Its standard error is the larger of (Knapp and
    Carter 1976) ``sqrt((1 - rho^2) / (rho N_eff kappa))``, with ``kappa`` the peak curvature
    [1/s^2] and ``N_eff`` the overlap in smoothing windows, and the scatter of the peak lag over
    ``N_CHUNKS`` sub-records of the overlap divided by sqrt(N_CHUNKS).
    """
    dt = float(np.clip(min(x.dt, y.dt), GRID_MIN_S, GRID_MAX_S))
    x0, xv, mx = _on_grid(x, x_shift, dt)
    y0, yv, my = _on_grid(y, y_shift, dt)
    nan = math.nan
    if mx.sum() < 10 or my.sum() < 10:
        return LagEstimate(nan, nan, nan, nan, nan, 0.0, 0.0, dt, "fewer than 10 valid samples after smoothing")
    lags, rho, n = _masked_ncc(xv, mx, yv, my)
    need = max(MIN_OVERLAP_FRACTION * min(mx.sum(), my.sum()), min(MIN_OVERLAP_S / dt, 0.9 * min(mx.sum(), my.sum())))
    usable = (n >= need) & np.isfinite(rho)
    if not usable.any():
        return LagEstimate(nan, nan, nan, nan, nan, 0.0, 0.0, dt,
                           f"the records overlap by at most {n.max() * dt:.1f} s at any lag; expected "
                           f"{need * dt:.1f} s")
    score = np.where(usable, rho, -np.inf)
    k = int(np.argmax(score))
    peak = float(rho[k])
    frac, curv = _parabola(np.where(usable, rho, np.nan), k)
    # Offset: x[i] (at x0 + i dt) matches y[j] (at y0 + j dt) for i - j = lag.
    lag_s = x0 - y0 + (lags[k] + frac) * dt
    overlap_s = float(n[k] * dt)
    # Width of the peak: where rho falls to half of it; one correlation time on each side.
    half = 0.5 * peak
    left = k
    while left > 0 and usable[left - 1] and rho[left - 1] > half:
        left -= 1
    right = k
    while right < len(rho) - 1 and usable[right + 1] and rho[right + 1] > half:
        right += 1
    width_s = max((right - left + 1) * dt, SMOOTH_S, dt)
    n_eff = max(overlap_s / width_s, 4.0)
    z = float(np.arctanh(min(peak, 0.999999)) * math.sqrt(n_eff - 3)) if peak > 0 else 0.0
    away = usable.copy()
    guard = max(2 * (right - left + 1), int(round(2.0 / dt)))
    away[max(k - guard, 0):k + guard + 1] = False
    second = float(np.nanmax(np.where(away, rho, np.nan))) if away.any() else nan
    kappa = curv / dt**2 if math.isfinite(curv) else nan
    n_noise = max(overlap_s / max(SMOOTH_S, dt), 4.0)
    se_curv = (math.sqrt((1 - min(peak, 0.999999) ** 2) / (peak * n_noise * kappa))
               if peak > 0 and math.isfinite(kappa) and kappa > 0 else nan)
    se_chunks = _chunk_scatter(xv, mx, yv, my, lags[k], dt)
    candidates = [s for s in (se_curv, se_chunks) if math.isfinite(s)]
    stderr = max(candidates) if candidates else dt
    reason = ""
    if not peak >= MIN_PEAK:
        reason = f"peak correlation {peak:.2f} below {MIN_PEAK:g}"
    elif z < MIN_Z:
        reason = f"peak z-score {z:.1f} below {MIN_Z:g} (only {n_eff:.0f} independent samples)"
    elif math.isfinite(second) and peak - second < MIN_MARGIN:
        reason = (f"ambiguous: the peak {peak:.2f} is not {MIN_MARGIN:g} above the next best {second:.2f} at "
                  f"another lag (a periodic manoeuvre?)")
    return LagEstimate(float(lag_s), float(stderr), peak, second, z, float(n_eff), overlap_s, dt, reason)


def _chunk_scatter(xv, mx, yv, my, lag: int, dt: float) -> float:
    """Standard error of the peak lag from its scatter over sub-records of ``y`` [s]; NaN if unusable."""
    idx = np.flatnonzero(my)
    if len(idx) < N_CHUNKS * 20:
        return math.nan
    edges = np.linspace(idx[0], idx[-1] + 1, N_CHUNKS + 1).astype(int)
    found = []
    # Only a local refinement of the main peak: a sub-record with little manoeuvring would
    # otherwise wander to a distant spurious maximum and inflate the scatter without meaning.
    search = max(20, int(round(1.0 / dt)))
    for a, b in zip(edges[:-1], edges[1:]):
        m = np.zeros_like(my)
        m[a:b] = my[a:b]
        if m.sum() < 20:
            continue
        lags, rho, n = _masked_ncc(xv, mx, yv * m, m)
        near = (np.abs(lags - lag) <= search) & (n >= 0.5 * m.sum()) & np.isfinite(rho)
        if not near.any():
            continue
        k = int(np.argmax(np.where(near, rho, -np.inf)))
        if not rho[k] >= MIN_PEAK or abs(lags[k] - lag) >= search:
            continue  # weak, or still rising at the window edge: no local peak in this sub-record
        frac, _ = _parabola(np.where(near, rho, np.nan), k)
        found.append((lags[k] + frac) * dt)
    if len(found) < 3:
        return math.nan
    return float(np.std(found, ddof=1) / math.sqrt(len(found)))


# --------------------------------------------------------------------------- offsets
def _text(x: float) -> str:
    return f"{x:.2f}" if math.isfinite(x) else "none"


def _absolute_method(log: RawLog) -> str:
    from ..ingest._gpstime import unix_text

    return f"absolute time: t = 0 is {unix_text(log.start_time)} UTC ({log.format}, {log.time_reference} clock)"


def _best_pair(placed: Mapping[str, float], signals: Mapping[str, list[RateSignal]], source: str
               ) -> tuple[LagEstimate | None, str, str, str, list[str]]:
    """Best-correlating (placed log, signal pair) for ``source``; also a list of what was tried."""
    best: LagEstimate | None = None
    best_ref = best_x = best_y = ""
    tried: list[str] = []
    for ref, off in placed.items():
        for sx in signals[ref]:
            for sy in signals[source]:
                if sx.family != sy.family:
                    continue
                est = correlate_rates(sx, sy, x_shift=off)
                tried.append(f"{sy.name} vs {sx.name} of {ref}: "
                             + (f"peak {est.peak:.2f}" if math.isfinite(est.peak) else "no overlap")
                             + (f" ({est.reason})" if est.reason else ""))
                if not math.isfinite(est.peak):
                    continue
                rank = (est.significant, est.z)
                if best is None or rank > (best.significant, best.z):
                    best, best_ref, best_x, best_y = est, ref, sx.name, sy.name
    return best, best_ref, best_x, best_y, tried


def estimate_offsets(logs: Sequence[RawLog], sog_min: float = SOG_MIN, cross_check: bool = True
                     ) -> dict[str, ClockOffset]:
    """Clock offset of every log: from absolute time where known, else by cross-correlating rates.

    Parameters
    ----------
    logs : Sequence[RawLog]
        Logs of one trial (sources must differ).
    sog_min : float
        Speed over ground below which course rate is not used [m/s].
    cross_check : bool
        For logs placed by absolute time, also correlate a shared rate with the reference log
        and append the residual lag to the method text (it reveals a logger's latency).

    Returns
    -------
    dict[str, ClockOffset]
        ``RawLog.source`` -> (offset [s], standard error [s], method). ``t_common = t + offset``.
        With absolute times the first log that has one is the reference (offset 0); without any,
        the first log is.

    Raises
    ------
    AlignError
        No logs, repeated sources, or a log without absolute time that shares no usable rate
        with the logs already placed, or whose best correlation is not significant (the message
        names what was expected and what was found).
    """
    if not logs:
        raise AlignError("clock: expected at least one log, found none")
    sources = [log.source for log in logs]
    dup = sorted({s for s in sources if sources.count(s) > 1})
    if dup:
        raise AlignError(f"clock: expected one log per source, found {dup} more than once")
    by_source = {log.source: log for log in logs}
    absolute = [log for log in logs if math.isfinite(log.start_time)]
    out: dict[str, ClockOffset] = {}
    if absolute:
        ref_time = absolute[0].start_time
        for log in absolute:
            out[log.source] = ClockOffset(float(log.start_time - ref_time),
                                          0.0 if log is absolute[0] else ABSOLUTE_STDERR_S, _absolute_method(log))
    else:
        out[logs[0].source] = ClockOffset(0.0, 0.0, "reference clock (first log, no log has absolute time)")
    pending = [log.source for log in logs if log.source not in out]
    if not pending and not (cross_check and len(absolute) > 1):
        return out
    signals = {s: rate_signals(by_source[s], sog_min) for s in sources}

    if cross_check and len(absolute) > 1:
        ref = absolute[0].source
        for log in absolute[1:]:
            best, _, bx, by, _ = _best_pair({ref: 0.0}, signals, log.source)
            if best is None or not best.significant:
                continue
            residual = best.lag_s - out[log.source].offset_s
            flag = " (disagrees: latency or a wrong clock?)" if abs(residual) > max(3 * best.stderr_s, 2 * best.dt) else ""
            off = out[log.source]
            out[log.source] = off._replace(method=off.method + f"; cross-check {by} vs {bx}: correlation puts it "
                                                               f"{residual:+.3f} +- {best.stderr_s:.3f} s from the "
                                                               f"absolute time{flag}")

    while pending:
        placed = {s: o.offset_s for s, o in out.items()}
        candidates = []
        for src in pending:
            best, ref, bx, by, tried = _best_pair(placed, signals, src)
            candidates.append((best, ref, bx, by, tried, src))
        good = [c for c in candidates if c[0] is not None and c[0].significant]
        if not good:
            best, ref, bx, by, tried, src = max(candidates, key=lambda c: (c[0] is not None, c[0].z if c[0] else 0))
            if not tried:
                have = sorted(by_source[src].channels)
                ref_have = {s: sorted(by_source[s].channels) for s in placed}
                raise AlignError(
                    f"clock: {src} has no absolute time, so its offset must come from a rate it shares with "
                    f"another log: expected a yaw rate (r, psi, or cog with sog >= {sog_min:g} m/s) or a speed "
                    f"(sog, u) in both, found {src}: {have}; placed logs: {ref_have}")
            raise AlignError(f"clock: {src} has no absolute time and no significant cross-correlation with the "
                             f"placed logs: expected a peak >= {MIN_PEAK:g} with z >= {MIN_Z:g}, clearly above "
                             f"any other lag; found " + "; ".join(tried))
        best, ref, bx, by, _, src = max(good, key=lambda c: c[0].z)
        base = out[ref]
        # The placed log's offset was applied before correlating, so the lag is already on the common clock.
        out[src] = ClockOffset(float(best.lag_s), float(math.hypot(base.stderr_s, best.stderr_s)),
                               f"cross-correlation of {by} against {bx} of {ref}: peak {best.peak:.3f} "
                               f"(next best {_text(best.second_peak)}, z {best.z:.0f}) over {best.overlap_s:.0f} s "
                               f"on a {best.dt:g} s grid, parabolic peak")
        pending.remove(src)
    return out


__all__ = ["ClockOffset", "RateSignal", "LagEstimate", "rate_signals", "correlate_rates", "estimate_offsets",
           "SOG_MIN", "MIN_PEAK", "MIN_Z", "MIN_MARGIN"]
