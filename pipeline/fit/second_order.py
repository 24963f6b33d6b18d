"""Second-order free decay in roll and pitch ("method two" of the AAUSHIP identification journal).

Released from a heel or trim angle, one DOF of ``M nu_dot + D nu + G eta = 0`` (Fossen 2021,
sec. 6.4) is ``I_eff phi_ddot + D phi_dot + C phi = 0``, whose under-damped solution is

    phi(t) = A exp(-zeta wn t) cos(wd t + phase) + offset,   wd = wn sqrt(1 - zeta^2)

with ``wn^2 = C / I_eff`` and ``2 zeta wn = D / I_eff``. The offset absorbs a static heel (a trim
weight, a sensor mounting error). The same form holds for the rate ``p`` (the derivative of a damped
cosine is a damped cosine with the same ``zeta`` and ``wn``), which is fitted when ``phi`` is absent.

The start values come from extrema and the logarithmic decrement when the record resolves the
swings (several samples per half period). A log at a few samples per period (a 1.6 Hz roll logged at
5 Hz) shows no clean extrema; there the start comes from linear prediction (Prony's method: the
samples of a damped cosine obey ``y[k] = a1 y[k-1] + a2 y[k-2] + c``, whose characteristic roots are
``exp(s dt)``). It is written here because it is a few lines of ``numpy.linalg.lstsq`` and
``numpy.roots``; no maintained library offers a damped-sinusoid Prony start for irregular records.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ..errors import FitError
from ..model.second_order import damped_oscillation, damped_oscillation_jacobian
from ..records import DOF_ANGLE, DOF_CHANNELS, Segment, SegmentFit, Trial
from .data import noise_sigma, pick_channel, segment_label, segment_samples
from .least_squares import fit_least_squares
from .segment_fit import build_segment_fit

PARAMS = ("A", "zeta", "wn", "phase", "offset")
#: Fewest samples a damped-oscillation fit accepts: three per parameter of the five.
MIN_SAMPLES = 15
#: Fewest samples per damped period the fit accepts (Nyquist is 2; below 2.5 the swings are barely
#: resolved and an aliased frequency cannot be told from the true one by the samples alone).
MIN_SAMPLES_PER_PERIOD = 2.5
#: Fewest alternating extrema above the noise (3 = one full period) a decay must show.
MIN_EXTREMA = 3
#: Fewest extrema, counting the release, when the decay sinks into the noise within a period.
MIN_EXTREMA_WITH_RELEASE = 2
#: Largest damping ratio the fit allows; at the bound the decay is not oscillatory.
MAX_ZETA = 0.99
#: Extrema smaller than this many noise standard deviations are not used by the guess.
MIN_PEAK_SNR = 5.0


def _extrema(t: np.ndarray, z: np.ndarray, h: float, keep_start: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Times and values of the alternating extrema of ``z`` beyond the hysteresis band ``+-h``.

    The band keeps noise near a zero crossing from splitting one half-cycle in two. Extrema on the
    last sample are dropped: that is where the segment was cut, not a turning point. So is one on the
    first sample unless ``keep_start``: a segment that starts at the release starts at a turning
    point, but one that starts late does not.
    """
    sign = np.where(z > h, 1, np.where(z < -h, -1, 0))
    nz = np.flatnonzero(sign)
    if nz.size == 0:
        return np.empty(0), np.empty(0)
    # Forward-fill the sign through the band so that each half-cycle is one run.
    filled = sign[nz][np.searchsorted(nz, np.arange(z.size), side="right") - 1]
    filled[: nz[0]] = 0
    edges = np.flatnonzero(np.diff(filled) != 0) + 1
    times, values = [], []
    for a, b in zip(np.r_[0, edges], np.r_[edges, z.size]):
        if filled[a] == 0:
            continue
        k = a + int(np.argmax(filled[a] * z[a:b]))
        if (k == 0 and not keep_start) or k == z.size - 1:
            continue
        # A least-squares parabola over +-30 degrees of phase around the largest sample averages the
        # noise; the largest sample alone is biased away from zero by the noise near small peaks.
        w = max(1, (b - a) // 6)
        lo, hi = max(a, k - w), min(b, k + w + 1)
        tk, zk = t[k], z[k]
        if hi - lo >= 3:
            c2, c1, c0 = np.polyfit(t[lo:hi] - t[k], z[lo:hi], 2)
            if c2 != 0:
                vertex = -c1 / (2 * c2)
                if abs(vertex) <= t[hi - 1] - t[lo]:
                    tk, zk = t[k] + vertex, c0 - c1**2 / (4 * c2)
        times.append(tk)
        values.append(zk)
    return np.asarray(times), np.asarray(values)


def _usable_extrema(t: np.ndarray, z: np.ndarray, h: float, sigma: float,
                    keep_start: bool) -> tuple[np.ndarray, np.ndarray]:
    """Extrema of :func:`_extrema` up to where the decay sinks into the noise.

    Past that point "extrema" are noise peaks at random times: stop at the first one below
    ``MIN_PEAK_SNR`` noise deviations, or the first one far off the half-period rhythm.
    """
    tk, ak = _extrema(t, z, h, keep_start)
    small = np.flatnonzero(np.abs(ak) < MIN_PEAK_SNR * sigma) if math.isfinite(sigma) else np.empty(0, int)
    keep = int(small[0]) if small.size else tk.size
    gaps = np.diff(tk[:keep])
    if gaps.size >= 2:
        off_rhythm = np.flatnonzero(gaps > 1.5 * np.median(gaps))
        if off_rhythm.size:
            keep = int(off_rhythm[0]) + 1
    return tk[:keep], ak[:keep]


def guess_damped_oscillation(t: np.ndarray, y: np.ndarray) -> dict[str, float]:
    """Closed-form start for :func:`damped_oscillation` from extrema and the logarithmic decrement.

    The spacing of alternating extrema is half the damped period, ``pi / wd``. The peak-to-peak
    amplitudes ``|a_k - a_(k+1)|`` decay as ``exp(-zeta wn t)`` whatever the offset, so a regression
    of their logarithm on time gives ``sigma = zeta wn`` (the logarithmic decrement per period is
    ``delta = 2 pi sigma / wd``). Then ``wn = sqrt(wd^2 + sigma^2)``, ``zeta = sigma / wn``, and a
    linear least-squares fit on ``exp(-sigma t) cos(wd t)``, ``exp(-sigma t) sin(wd t)`` and 1 gives the
    amplitude, phase and offset.

    Parameters
    ----------
    t, y : numpy.ndarray
        Time since release [s] and data.

    Returns
    -------
    dict
        ``A``, ``zeta``, ``wn``, ``phase``, ``offset`` and ``log_decrement`` [-].

    Raises
    ------
    FitError
        Fewer than ``MIN_EXTREMA`` extrema stand out of the noise and the linear-prediction start
        (:func:`guess_by_linear_prediction`, tried next) fails too; the message gives both reasons.
    """
    t = np.asarray(t, float)
    y = np.asarray(y, float)
    try:
        return _guess_from_extrema(t, y)
    except FitError as exc:
        try:
            return guess_by_linear_prediction(t, y)
        except FitError as lp:
            raise FitError(f"{exc}; linear prediction: {lp}") from None


def _guess_from_extrema(t: np.ndarray, y: np.ndarray) -> dict[str, float]:
    """The extrema and log-decrement start of :func:`guess_damped_oscillation`."""
    sigma = noise_sigma(y)
    z = y - np.median(y)
    h = max(3.0 * sigma if math.isfinite(sigma) else 0.0, 1e-3 * float(np.abs(z).max(initial=0.0)))
    tk, ak = _usable_extrema(t, z, h, sigma, keep_start=False)
    minimum = MIN_EXTREMA
    if tk.size < MIN_EXTREMA:
        # A heavily damped decay (pitch, zeta ~ 0.3) in strong noise may show only one turning
        # point above the noise after the release. The release is a turning point too (the hull
        # is let go at rest), and the two give the half period and the decay ratio; the
        # least-squares fit then decides how well the record determines them.
        tk, ak = _usable_extrema(t, z, h, sigma, keep_start=True)
        minimum = MIN_EXTREMA_WITH_RELEASE
    if tk.size < minimum:
        raise FitError(f"expected at least {MIN_EXTREMA} alternating extrema above the noise (one full "
                       f"oscillation period), or the release and {MIN_EXTREMA_WITH_RELEASE - 1} more, "
                       f"found {tk.size}")
    half_period = float(np.polyfit(np.arange(tk.size), tk, 1)[0])
    if minimum == MIN_EXTREMA_WITH_RELEASE and t[-1] - t[0] < 2 * half_period:
        # Two turning points are enough to start from only when the record goes on for a full
        # period (swings hidden in the noise still inform the fit); half a period is not a decay.
        raise FitError(f"expected at least {MIN_EXTREMA} alternating extrema above the noise, or the "
                       f"release and one more with a full period ({2 * half_period:.3g} s) of record, "
                       f"found {tk.size} over {t[-1] - t[0]:.3g} s")
    wd = math.pi / half_period
    p2p = np.abs(np.diff(ak))
    tm = 0.5 * (tk[1:] + tk[:-1])
    if p2p.size >= 2:
        slope = float(np.polyfit(tm, np.log(p2p), 1, w=p2p)[0])
    elif ak.size == 2 and ak[0] != 0 and ak[1] != 0:
        slope = math.log(abs(ak[1]) / abs(ak[0])) / (tk[1] - tk[0])
    else:
        slope = 0.0
    decay_rate = max(-slope, 1e-3 * wd)  # a non-decaying record still starts the fit at small zeta
    return _start_values(t, y, decay_rate, wd)


def _start_values(t: np.ndarray, y: np.ndarray, decay_rate: float, wd: float) -> dict[str, float]:
    """Amplitude, phase and offset by linear least squares once the decay rate and ``wd`` are known."""
    wn = math.hypot(wd, decay_rate)
    zeta = decay_rate / wn
    e = np.exp(-decay_rate * t)
    basis = np.column_stack([e * np.cos(wd * t), e * np.sin(wd * t), np.ones_like(t)])
    (a, b, off), *_ = np.linalg.lstsq(basis, y, rcond=None)
    return {"A": float(math.hypot(a, b)), "zeta": float(zeta), "wn": float(wn),
            "phase": float(math.atan2(-b, a)), "offset": float(off),
            "log_decrement": float(2 * math.pi * decay_rate / wd)}


def guess_by_linear_prediction(t: np.ndarray, y: np.ndarray) -> dict[str, float]:
    """Start for :func:`damped_oscillation` by linear prediction (Prony's method), for coarse logs.

    Sampled every ``dt``, ``A exp(-sigma t) cos(wd t + phase) + offset`` obeys exactly
    ``y[k] = a1 y[k-1] + a2 y[k-2] + c`` with characteristic roots ``z = exp((-sigma +- i wd) dt)``.
    The least-squares ``a1, a2, c`` give the roots; ``wd = |arg z| / dt`` and ``sigma = -ln|z| / dt``.
    Measurement noise pulls the roots towards the origin (more damping); this is only the start of
    the nonlinear fit, which removes that bias. A record that is not uniformly sampled is first
    interpolated onto its median step.

    Parameters
    ----------
    t, y : numpy.ndarray
        Time since release [s] and data.

    Returns
    -------
    dict
        As :func:`guess_damped_oscillation`.

    Raises
    ------
    FitError
        Fewer than ``MIN_SAMPLES`` samples, real roots (no oscillation), a root outside the unit
        circle (a growing oscillation), fewer than ``MIN_SAMPLES_PER_PERIOD`` samples per damped
        period, less than one period of record, or an oscillation that does not stand out of the
        prediction residual by ``MIN_PEAK_SNR``.
    """
    t = np.asarray(t, float)
    y = np.asarray(y, float)
    if t.size < MIN_SAMPLES:
        raise FitError(f"expected at least {MIN_SAMPLES} samples, found {t.size}")
    dt = float(np.median(np.diff(t)))
    grid = np.arange(t[0], t[-1] + 0.5 * dt, dt)
    yg = np.interp(grid, t, y)
    lagged = np.column_stack([yg[1:-1], yg[:-2], np.ones(yg.size - 2)])
    (a1, a2, _), *_ = np.linalg.lstsq(lagged, yg[2:], rcond=None)
    roots = np.roots([1.0, -a1, -a2])
    if abs(roots[0].imag) < 1e-12:
        raise FitError(f"the samples follow no oscillation (real characteristic roots {roots.real.round(3)})")
    root = roots[0]
    if abs(root) >= 1.0:
        raise FitError(f"the samples follow a growing oscillation (|root| = {abs(root):.3f})")
    wd = abs(math.atan2(root.imag, root.real)) / dt
    decay_rate = -math.log(abs(root)) / dt
    per_period = 2 * math.pi / wd / dt
    if per_period < MIN_SAMPLES_PER_PERIOD:
        raise FitError(f"expected at least {MIN_SAMPLES_PER_PERIOD:g} samples per period, found "
                       f"{per_period:.2g} ({wd / (2 * math.pi):.3g} Hz at {1 / dt:.3g} Hz): the swings are "
                       f"not resolved and an aliased frequency cannot be told from the true one")
    if t[-1] - t[0] < 2 * math.pi / wd:
        raise FitError(f"expected a full period ({2 * math.pi / wd:.3g} s) of record, found {t[-1] - t[0]:.3g} s")
    start = _start_values(t, y, decay_rate, wd)
    residual = y - damped_oscillation(t, *(start[n] for n in PARAMS))
    spread = float(np.std(residual))
    if not start["A"] > MIN_PEAK_SNR * spread:
        raise FitError(f"the oscillation (amplitude {start['A']:.3g}) does not stand out of the residual "
                       f"({spread:.3g}) by {MIN_PEAK_SNR:g} times")
    return start


def fit_free_decay(trial: Trial, segment: Segment) -> SegmentFit:
    """Fit :func:`damped_oscillation` to a roll or pitch free decay.

    Parameters
    ----------
    trial : Trial
        Trial holding ``phi`` / ``theta`` (or, failing that, ``p`` / ``q``).
    segment : Segment
        A ``free_decay`` segment in roll or pitch, starting at release.

    Returns
    -------
    SegmentFit
        Model ``damped_oscillation`` with parameters ``A``, ``zeta`` [-], ``wn`` [rad/s],
        ``phase`` [rad], ``offset``.

    Raises
    ------
    FitError
        Missing channel, too few samples or fewer than one full period above the noise.
    """
    where = segment_label(segment)
    if segment.dof not in ("roll", "pitch"):
        raise FitError(f"{where}: expected a free_decay in roll or pitch, found DOF {segment.dof!r}")
    channel = pick_channel(trial, segment, [DOF_ANGLE[segment.dof], DOF_CHANNELS[segment.dof][0]])
    t, y, dropped = segment_samples(trial, segment, channel)
    if t.size < MIN_SAMPLES:
        raise FitError(f"{where}: segment too short: expected at least {MIN_SAMPLES} samples and "
                       f"{MIN_EXTREMA} extrema, found {t.size} samples over "
                       f"{(t[-1] - t[0]) if t.size else 0.0:.3g} s")
    try:
        g = guess_damped_oscillation(t, y)
    except FitError as exc:
        raise FitError(f"{where}: segment too short or not oscillating: {exc} over {t[-1] - t[0]:.3g} s") from None
    notes = [f"start (log-decrement guess): wn = {g['wn']:.4g} rad/s, zeta = {g['zeta']:.4g}, "
             f"log decrement = {g['log_decrement']:.4g}"]
    if dropped:
        notes.append(f"{dropped} non-finite samples dropped")
    fs_nyquist = math.pi / float(np.median(np.diff(t)))
    p0 = [g[n] for n in PARAMS]
    res = fit_least_squares(lambda tt, p: damped_oscillation(tt, *p),
                            lambda tt, p: damped_oscillation_jacobian(tt, *p), t, y, p0, PARAMS,
                            [-np.inf, 0.0, 0.0, -np.inf, -np.inf], [np.inf, MAX_ZETA, fs_nyquist, np.inf, np.inf])
    if res.value("A") < 0:
        # Report a positive amplitude: A -> -A with phase + pi is the same curve; flip the signs of
        # A's covariance row and column so that correlations stay right.
        flip = np.array([-1.0, 1, 1, 1, 1])
        values = res.values * flip + np.array([0, 0, 0, math.pi, 0])
        res = replace(res, values=values, covariance=res.covariance * np.outer(flip, flip))
    wd = res.value("wn") * math.sqrt(max(1.0 - res.value("zeta") ** 2, 0.0))
    per_period = 2 * math.pi / wd / float(np.median(np.diff(t))) if wd > 0 else math.inf
    if per_period < MIN_SAMPLES_PER_PERIOD:
        raise FitError(f"{where}: the fitted oscillation ({wd / (2 * math.pi):.3g} Hz) has "
                       f"{per_period:.2g} samples per period, expected at least {MIN_SAMPLES_PER_PERIOD:g}: "
                       f"the log rate does not resolve it and an aliased frequency cannot be told from the true one")
    values = res.values.copy()
    values[PARAMS.index("phase")] = (values[PARAMS.index("phase")] + math.pi) % (2 * math.pi) - math.pi
    res = replace(res, values=values)
    return build_segment_fit(segment, "damped_oscillation", channel, t, y, res, ("zeta", "wn"), notes)
