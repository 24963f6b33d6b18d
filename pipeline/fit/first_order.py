"""First-order exponential models: coast-downs and steps in surge, sway and yaw ("method one" of the
AAUSHIP identification journal).

With the input cut at ``t0`` the homogeneous equation ``m_eff y_dot + D y = 0`` gives
``y = y0 exp(-(t - t0)/T)`` with ``T = m_eff / D`` (Fossen 2021, sec. 6.4: one DOF of
``M nu_dot + D nu = tau``). A step of the generalised force gives
``y = y_ss + (y0 - y_ss) exp(-(t - t0)/T)`` with ``y_ss - y0 = delta_tau / D`` if the vessel was
settled before the step.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ..errors import FitError
from ..records import DOF_CHANNELS, Segment, SegmentFit, Trial
from .data import input_levels, noise_sigma, pick_channel, segment_label, segment_samples, steady_before
from ..model.first_order import decay, decay_jacobian, guess_step, step_jacobian, step_response
from .least_squares import LeastSquaresResult, fit_least_squares
from .robust_covariance import hac_covariance
from .segment_fit import build_segment_fit

#: Fewest samples a first-order fit accepts.
MIN_SAMPLES = 15
#: A segment shorter than this many time constants (of the start guess) cannot be fitted at all.
MIN_TIME_CONSTANTS = 0.5
#: Time constants a segment should span for a well-determined T and steady state.
RECOMMENDED_TIME_CONSTANTS = 3.0
#: Response (initial value or step size) needed, in multiples of the noise standard deviation.
MIN_SNR = 5.0

#: Lag-1 residual autocorrelation, in multiples of its white-noise spread ``1/sqrt(n)``, above which
#: the standard errors come from the autocorrelation-consistent covariance (when it is the larger).
HAC_SIGNIFICANCE = 3.0

DECAY_PARAMS = ("y0", "T")
STEP_PARAMS = ("y0", "y_ss", "T")


# --------------------------------------------------------------------------- closed-form starts
def guess_decay(t: np.ndarray, y: np.ndarray) -> dict[str, float]:
    """Closed-form start for :func:`decay` by log-linear regression on ``|y|``.

    ``ln|y| = ln|y0| - t/T`` is fitted with weights ``y^2`` (the variance of ``ln|y|`` is
    ``sigma^2/y^2``) on the samples before ``|y|`` first drops to three noise standard deviations,
    where the logarithm of a noisy value is no longer informative. Falls back to the integral
    regression of :func:`guess_step` when too few samples stand above the noise.

    Parameters
    ----------
    t, y : numpy.ndarray
        Time since the input was cut [s] and data.

    Returns
    -------
    dict
        ``y0`` [unit of y] and ``T`` [s].
    """
    t = np.asarray(t, float)
    y = np.asarray(y, float)
    a = np.abs(y)
    sigma = noise_sigma(y)
    thr = max(3.0 * sigma if math.isfinite(sigma) else 0.0, 0.02 * float(a.max(initial=0.0)))
    below = np.flatnonzero(a <= thr)
    stop = int(below[0]) if below.size else a.size
    if stop >= 3:
        slope, icpt = np.polyfit(t[:stop], np.log(a[:stop]), 1, w=a[:stop])
        if slope < 0:
            sign = 1.0 if np.median(y[:stop]) >= 0 else -1.0
            return {"y0": float(sign * math.exp(icpt)), "T": float(-1.0 / slope)}
    g = guess_step(t, y)
    return {"y0": g["y0"], "T": g["T"]}


# --------------------------------------------------------------------------- coloured noise
def coloured_noise_errors(res: LeastSquaresResult, jac: np.ndarray) -> tuple[LeastSquaresResult, str]:
    """Standard errors that hold when neighbouring residuals are alike.

    A channel logged slower than the trial grid (GNSS speed at 5 Hz on a 10 or 50 Hz grid, from
    which align derives ``u`` and ``v``) is interpolated between its samples, so neighbouring
    residuals share their noise and the white-noise covariance ``(J^T J)^-1 s^2`` is too small
    (for linear interpolation at twice the rate, by a factor of about 1.6 in standard error). When
    the residuals' lag-1 autocorrelation is significant (above ``HAC_SIGNIFICANCE / sqrt(n)``),
    the Newey-West covariance (:func:`pipeline.fit.robust_covariance.hac_covariance`) replaces it
    when it gives the larger error on ``T``; white residuals keep the classic covariance.

    Parameters
    ----------
    res : LeastSquaresResult
        The fit (parameters include ``T``), with its white-noise covariance.
    jac : numpy.ndarray
        Jacobian of the model at the estimate, shape (n, p).

    Returns
    -------
    LeastSquaresResult
        ``res``, or a copy with the HAC covariance and standard errors.
    str
        A note naming the correction ("" when none was made).
    """
    n = res.n
    if not (n > len(res.names) + 2 and math.isfinite(res.lag1) and res.lag1 > HAC_SIGNIFICANCE / math.sqrt(n)
            and np.all(np.isfinite(res.stderr))):
        return res, ""
    rob = hac_covariance(jac, res.residuals, np.zeros(n, int))
    se = np.sqrt(np.clip(np.diag(rob.covariance), 0.0, None))
    k = res.names.index("T")
    if not (np.all(np.isfinite(se)) and se[k] > res.stderr[k]):
        return res, ""
    note = (f"standard errors from the autocorrelation-consistent (Newey-West) covariance: residual lag-1 "
            f"autocorrelation {res.lag1:.2f} over {n} samples, {rob.bandwidth} lags, "
            f"{' '.join(f'{nm} x{f:.2f}' for nm, f in zip(res.names, se / res.stderr))} the white-noise errors")
    return replace(res, covariance=rob.covariance, stderr=se), note


# --------------------------------------------------------------------------- segment checks
def check_first_order_length(segment: Segment, t: np.ndarray, T_guess: float, response: float,
                             sigma: float) -> list[str]:
    """Refuse segments a first-order model cannot be fitted to; return notes for marginal ones.

    Parameters
    ----------
    segment : Segment
        For the message.
    t : numpy.ndarray
        Sample times [s].
    T_guess : float
        Start value of the time constant [s].
    response : float
        Size of the transient (initial value or step size) [unit of y].
    sigma : float
        Noise standard deviation [unit of y].

    Raises
    ------
    FitError
        Fewer than ``MIN_SAMPLES`` samples, shorter than ``MIN_TIME_CONSTANTS`` time constants,
        or a transient below ``MIN_SNR`` noise standard deviations.
    """
    where = segment_label(segment)
    n = t.size
    duration = float(t[-1] - t[0]) if n else 0.0
    expected = (f"expected at least {MIN_SAMPLES} samples and {MIN_TIME_CONSTANTS:g} time constants "
                f"({RECOMMENDED_TIME_CONSTANTS:g} recommended)")
    if n < MIN_SAMPLES:
        raise FitError(f"{where}: segment too short: {expected}, found {n} samples over {duration:.3g} s")
    if not (math.isfinite(T_guess) and duration >= MIN_TIME_CONSTANTS * T_guess):
        raise FitError(f"{where}: segment too short: {expected}, found {n} samples over {duration:.3g} s "
                       f"= {duration / T_guess:.2g} time constants (start guess T = {T_guess:.3g} s)")
    if math.isfinite(sigma) and abs(response) < MIN_SNR * sigma:
        raise FitError(f"{where}: no excitation: expected a transient of at least {MIN_SNR:g} noise "
                       f"standard deviations ({MIN_SNR * sigma:.3g}), found {abs(response):.3g}")
    if duration < RECOMMENDED_TIME_CONSTANTS * T_guess:
        return [f"segment spans only {duration / T_guess:.2g} time constants "
                f"(expected {RECOMMENDED_TIME_CONSTANTS:g}): T is less well determined"]
    return []


def time_constant_bounds(t: np.ndarray) -> tuple[float, float]:
    """Bounds on a time constant [s]: a tenth of a sample interval to 100 segment lengths.

    Parameters
    ----------
    t : numpy.ndarray
        Sample times of the segment [s], increasing, at least one; the sample interval is their
        median spacing (1 s for a single sample).

    Returns
    -------
    tuple[float, float]
        Lower and upper bound on T [s].
    """
    dt = float(np.median(np.diff(t))) if t.size > 1 else 1.0
    return 0.1 * dt, 100.0 * max(float(t[-1] - t[0]), dt)


#: Note added to a surge fit made on speed over ground.
SOG_NOTE = ("surge speed read from speed over ground (no body velocity u: no heading logged), so a current "
            "and any sideslip are in it")


def _velocity_channel(trial: Trial, segment: Segment) -> str:
    if segment.dof not in ("surge", "sway", "yaw"):
        raise FitError(f"{segment_label(segment)}: expected a {segment.kind} in surge, sway or yaw, "
                       f"found DOF {segment.dof!r}")
    # A GPS-only log (no heading) has no u; on a straight run its speed over ground is the surge
    # speed up to the current, which is what an input-free coast-down was detected on.
    extra = ["sog"] if segment.dof == "surge" else []
    return pick_channel(trial, segment, [DOF_CHANNELS[segment.dof][0]] + extra)


def measured_samples(trial: Trial, segment: Segment, channel: str, t: np.ndarray,
                     y: np.ndarray) -> tuple[np.ndarray, np.ndarray, str]:
    """Keep only the real measurements of a channel measured slower than the trial grid.

    A GNSS logged at 5 Hz on a 10 Hz grid (and ``u``, ``v`` derived from it) is interpolated
    between fixes; those values are not measurements. Fitted as if they were, they draw chords
    across the exponential (which lengthens ``T``) and make neighbouring residuals alike (which
    shrinks its standard error). ``Trial.sample_times`` names the real samples
    (:meth:`pipeline.records.Trial.measured_rows`); a channel measured at every grid sample is
    returned unchanged.

    Parameters
    ----------
    trial : Trial
        The trial.
    segment : Segment
        The segment (``t`` is relative to its ``t_start``).
    channel : str
        The fitted channel.
    t, y : numpy.ndarray
        Segment samples: time since ``segment.t_start`` [s] and values.

    Returns
    -------
    t, y : numpy.ndarray
        The real measurements only.
    str
        A note saying how many interpolated samples were left out ("" when none).
    """
    keep = trial.measured_rows(channel, t + segment.t_start)
    if keep.all():
        return t, y, ""
    note = (f"{int((~keep).sum())} of {t.size} samples of {channel} are interpolated between its real measurements "
            f"({int(keep.sum())}, {channel} is measured slower than the {trial.fs:g} Hz grid) and are not fitted")
    return t[keep], y[keep], note


#: Fewest samples a fit needs on its transient (the first three fitted time constants).
MIN_TRANSIENT_SAMPLES = 5


def resolution_failures(t: np.ndarray, res: LeastSquaresResult) -> list[str]:
    """A failure when fewer than ``MIN_TRANSIENT_SAMPLES`` samples lie on the transient.

    ``T`` is determined by the samples taken while the response still moves, within about three
    time constants of the start. A response that settles within two or three samples (a 0.4 s sway
    time constant in a 2 Hz log) leaves ``T`` to where those few happen to fall, and its linearised
    standard error is then far too small (measured: Y_v +3 standard errors at 2 Hz, 3 of 12 seeds).

    Parameters
    ----------
    t : numpy.ndarray
        Fitted sample times, from the segment start [s].
    res : LeastSquaresResult
        The fit (parameters include ``T``).

    Returns
    -------
    list[str]
        One failure message, or none.
    """
    T = float(res.values[res.names.index("T")])
    n = int(np.count_nonzero(np.asarray(t, float) < 3.0 * T)) if math.isfinite(T) else 0
    if n < MIN_TRANSIENT_SAMPLES:
        return [f"time constant not resolved: expected at least {MIN_TRANSIENT_SAMPLES} samples within 3 T of the "
                f"start, found {n} (T = {T:.3g} s)"]
    return []


# --------------------------------------------------------------------------- segment fits
def velocity_samples(trial: Trial, segment: Segment) -> tuple[str, np.ndarray, np.ndarray, int, str]:
    """The samples a first-order fit of ``segment`` uses, checked for the fewest a fit accepts.

    Parameters
    ----------
    trial : Trial
        Trial holding the velocity channel.
    segment : Segment
        A surge, sway or yaw segment.

    Returns
    -------
    channel : str
        The velocity channel read (``u``, ``v``, ``r`` or ``sog``).
    t, y : numpy.ndarray
        Time since the segment's start [s] and the channel [m/s or rad/s], at the measured sample
        times where the channel is measured slower than the grid.
    dropped : int
        Non-finite samples dropped.
    real_note : str
        A note on the measured sample times ("" when none).

    Raises
    ------
    FitError
        Fewer than ``MIN_SAMPLES`` samples.
    """
    channel = _velocity_channel(trial, segment)
    t, y, dropped = segment_samples(trial, segment, channel)
    t, y, real_note = measured_samples(trial, segment, channel, t, y)
    if t.size < MIN_SAMPLES:
        check_first_order_length(segment, t, math.nan, math.nan, math.nan)
    return channel, t, y, dropped, real_note


def _least_squares(model, jacobian, t: np.ndarray, y: np.ndarray, p0: list[float], names: tuple[str, ...],
                   lower: list[float], upper: list[float]) -> tuple[LeastSquaresResult, str]:
    """Least-squares fit of ``model(t, *p)`` with its analytic Jacobian, errors from
    :func:`coloured_noise_errors`; returns the result and that function's note."""
    res = fit_least_squares(lambda tt, p: model(tt, *p), lambda tt, p: jacobian(tt, *p), t, y, p0, names, lower, upper)
    return coloured_noise_errors(res, jacobian(t, *res.values))


def fit_coast_down(trial: Trial, segment: Segment) -> SegmentFit:
    """Fit ``y = y0 exp(-t/T)`` to a coast-down (input cut to zero at ``segment.t_start``).

    No offset is fitted: with zero input the linear model decays to zero, and a free offset would
    trade off against ``T`` on segments shorter than a few time constants.

    The segment needs no input levels: a coast-down found from the speed alone
    (:mod:`pipeline.segment.speed_events`, ``input_channel=None``) is fitted the same way.

    Parameters
    ----------
    trial : Trial
        Trial holding the velocity channel (``u``, ``v`` or ``r``; for surge ``sog`` when the
        trial has no ``u``, noted in the message).
    segment : Segment
        A ``coast_down`` segment in surge, sway or yaw.

    Returns
    -------
    SegmentFit
        Model ``first_order_decay`` with parameters ``y0`` [m/s or rad/s] and ``T`` [s].

    Raises
    ------
    FitError
        Missing channel, too few samples, too short or no excitation.
    """
    channel, t, y, dropped, real_note = velocity_samples(trial, segment)
    p0 = guess_decay(t, y)
    sigma = noise_sigma(y)
    notes = [f"start (log-linear guess): y0 = {p0['y0']:.4g}, T = {p0['T']:.4g} s"]
    notes += [SOG_NOTE] if channel == "sog" else []
    notes += check_first_order_length(segment, t, p0["T"], p0["y0"], sigma)
    if dropped:
        notes.append(f"{dropped} non-finite samples dropped")
    notes += [real_note] if real_note else []
    lo_T, hi_T = time_constant_bounds(t)
    res, hac_note = _least_squares(decay, decay_jacobian, t, y, [p0["y0"], p0["T"]], DECAY_PARAMS,
                                   [-np.inf, lo_T], [np.inf, hi_T])
    notes += [hac_note] if hac_note else []
    return build_segment_fit(segment, "first_order_decay", channel, t, y, res, ("T",), notes,
                             resolution_failures(t, res))


def fit_step(trial: Trial, segment: Segment) -> SegmentFit:
    """Fit ``y = y_ss + (y0 - y_ss) exp(-t/T)`` to a step of the input at ``segment.t_start``.

    Parameters
    ----------
    trial : Trial
        Trial holding the velocity channel (``u``, ``v`` or ``r``).
    segment : Segment
        A ``step`` segment in surge, sway or yaw.

    Returns
    -------
    SegmentFit
        Model ``first_order_step`` with parameters ``y0``, ``y_ss`` [m/s or rad/s] and ``T`` [s].

    Raises
    ------
    FitError
        Missing channel, too few samples, too short or no excitation.
    """
    channel, t, y, dropped, real_note = velocity_samples(trial, segment)
    p0 = guess_step(t, y)
    sigma = noise_sigma(y)
    notes = [f"start (integral-regression guess): y0 = {p0['y0']:.4g}, y_ss = {p0['y_ss']:.4g}, "
             f"T = {p0['T']:.4g} s"]
    notes += check_first_order_length(segment, t, p0["T"], p0["y_ss"] - p0["y0"], sigma)
    notes += [SOG_NOTE] if channel == "sog" else []
    _, _, level_note = input_levels(trial, segment)
    notes += [n for n in (level_note, f"{dropped} non-finite samples dropped" if dropped else "", real_note) if n]
    lo_T, hi_T = time_constant_bounds(t)
    res, hac_note = _least_squares(step_response, step_jacobian, t, y, [p0["y0"], p0["y_ss"], p0["T"]], STEP_PARAMS,
                                   [-np.inf, -np.inf, lo_T], [np.inf, np.inf, hi_T])
    notes += [hac_note] if hac_note else []
    sf = build_segment_fit(segment, "first_order_step", channel, t, y, res, ("T",), notes,
                           resolution_failures(t, res))
    _, steady_note = step_steadiness(trial, sf)
    return replace(sf, message="; ".join(m for m in (sf.message, steady_note) if m))


def step_steadiness(trial: Trial, fit: SegmentFit) -> tuple[bool | None, str]:
    """Whether the response was steady before a fitted step (see :func:`pipeline.fit.data.steady_before`).

    Evaluated with the fitted ``T`` and step size, so that :func:`fit_step` (which notes it) and
    the gain derivation (which acts on it) agree.

    Parameters
    ----------
    trial : Trial
        The trial.
    fit : SegmentFit
        A ``first_order_step`` fit.
    """
    p = fit.params
    if not all(k in p for k in STEP_PARAMS):
        return None, ""
    return steady_before(trial, fit.segment, fit.channel, p["T"], p["y_ss"] - p["y0"])
