"""Turn a least-squares result into a :class:`~pipeline.records.SegmentFit`, with the sanity checks
that decide ``success`` (convergence, bounds, covariance, relative standard error)."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Mapping, Sequence

import numpy as np

from ..records import Segment, SegmentFit
from .least_squares import LeastSquaresResult

#: Relative standard error above which a key parameter counts as not identified.
MAX_RELATIVE_STDERR = 0.5
#: Lag-1 residual autocorrelation above which the white-noise covariance is called optimistic.
MAX_LAG1 = 0.5


def build_segment_fit(segment: Segment, model: str, channel: str, t: np.ndarray, y: np.ndarray,
                      result: LeastSquaresResult, key_params: Sequence[str],
                      notes: Sequence[str] = (), failures: Sequence[str] = ()) -> SegmentFit:
    """Assemble a :class:`SegmentFit` and decide whether it succeeded.

    A fit fails (``success=False``) when the solver did not converge, a parameter ended on a bound,
    the covariance could not be computed, a key parameter has a relative standard error above
    ``MAX_RELATIVE_STDERR``, or the caller reports a failure. Residual autocorrelation above
    ``MAX_LAG1`` is only noted: the estimate is fine, its error bar is too small.

    Parameters
    ----------
    segment : Segment
        Segment fitted.
    model : str
        Model name.
    channel : str
        Channel fitted.
    t, y : numpy.ndarray
        Time from segment start [s] and data.
    result : LeastSquaresResult
        The least-squares fit.
    key_params : sequence of str
        Parameters the coefficients come from (checked for relative standard error).
    notes : sequence of str
        Remarks that do not fail the fit (start values, short segment).
    failures : sequence of str
        Model-specific reasons to fail the fit.
    """
    fail = list(failures)
    if not result.converged:
        fail.append(result.message or "solver did not converge")
    elif result.message:
        fail.append(result.message)
    if result.at_bound:
        fail.append(f"parameter(s) {', '.join(result.at_bound)} ended on a bound")
    for name in key_params:
        i = result.names.index(name)
        v, se = float(result.values[i]), float(result.stderr[i])
        if math.isfinite(se) and abs(se) > MAX_RELATIVE_STDERR * abs(v):
            fail.append(f"{name} = {v:.4g} +- {se:.2g} has a relative standard error above "
                        f"{MAX_RELATIVE_STDERR:.0%}: not identified")
    extra = list(notes)
    if math.isfinite(result.lag1) and result.lag1 > MAX_LAG1:
        extra.append(f"lag-1 residual autocorrelation {result.lag1:.2f} > {MAX_LAG1}: residuals are not "
                     f"white (unmodelled dynamics?), so the standard errors are likely underestimated")
    rmse = math.sqrt(result.rss / result.n) if result.n else math.nan
    return SegmentFit(
        segment=segment, model=model, channel=channel, param_names=result.names,
        params={n: float(v) for n, v in zip(result.names, result.values)},
        stderr={n: float(s) for n, s in zip(result.names, result.stderr)},
        covariance=result.covariance, t=t, y=y, y_fit=result.y_fit, rmse=rmse,
        aic=result.aic, bic=result.bic, success=not fail, message="; ".join(fail + extra),
    )


def failed_segment_fit(segment: Segment, model: str, channel: str, reason: str,
                       t: np.ndarray | None = None, y: np.ndarray | None = None,
                       params: Mapping[str, float] | None = None) -> SegmentFit:
    """A :class:`SegmentFit` that records why a segment could not be fitted at all.

    Parameters
    ----------
    segment : Segment
        Segment.
    model : str
        Model that would have been fitted.
    channel : str
        Channel that would have been fitted ("" when unknown).
    reason : str
        The error message (names what was expected and what was found).
    t, y : numpy.ndarray, optional
        Data, when it could be read, for the figures.
    params : Mapping[str, float], optional
        Start values, when a guess was made.
    """
    t = np.empty(0) if t is None else t
    y = np.empty(0) if y is None else y
    params = dict(params or {})
    names = tuple(params)
    return SegmentFit(
        segment=segment, model=model, channel=channel, param_names=names, params=params,
        stderr={n: math.nan for n in names}, covariance=np.full((len(names), len(names)), np.nan),
        t=t, y=y, y_fit=np.full(y.shape, np.nan), rmse=math.nan, aic=math.nan, bic=math.nan,
        success=False, message=reason,
    )


#: Time constants of the slowest mode a window must hold after its input change for the response to
#: count as settled (exp(-5) < 1 % of the change left), each taken at its 95 % upper bound.
SETTLED_TIME_CONSTANTS = 5.0
#: Normal quantile of that upper bound.
UPPER_BOUND_Z = 1.96
#: Parameters that set the level a response settles to (a step's ``y_ss``; Nomoto's gain ``K`` and
#: rudder bias ``b``, the steady rate K (delta + b)): a fit with one of them reads that level from the
#: window's end, so the window must reach it. A coast-down's ``y0 exp(-t/T)`` settles to the known
#: zero and reads T from any part of the decay.
SETTLING_LEVEL_PARAMS = ("y_ss", "K", "b")


def slowest_time_constant(fit: SegmentFit) -> tuple[float, float, str]:
    """The slowest time constant of a fitted segment's response, its standard error and what it is.

    First order: ``T``. Second-order Nomoto with real poles: the larger pole time constant ``T1``;
    with complex poles (``T12 = T1 + T2``, ``T1T2 = T1 T2``): the envelope time constant
    ``2 T1T2 / T12`` (the inverse of the poles' real part), its error by the delta method on their
    covariance. (nan, nan, '') when the fit has none of these.

    Parameters
    ----------
    fit : SegmentFit
        A segment fit; its ``param_names`` give the covariance order.

    Returns
    -------
    tau : float
        Time constant [s].
    se : float
        Its standard error [s] (nan when not known).
    what : str
        Its name for a message.
    """
    p, e = fit.params, fit.stderr
    if "T12" in p and "T1T2" in p and p["T12"] ** 2 < 4.0 * p["T1T2"] and p["T12"] > 0:
        s, q = p["T12"], p["T1T2"]
        i, j = fit.param_names.index("T12"), fit.param_names.index("T1T2")
        g = np.array([-2.0 * q / s**2, 2.0 / s])
        cov = np.asarray(fit.covariance, float)[np.ix_([i, j], [i, j])]
        var = float(g @ cov @ g) if np.all(np.isfinite(cov)) else math.nan
        return 2.0 * q / s, math.sqrt(var) if var >= 0 else math.nan, "the complex poles' envelope time constant"
    if "T1" in p and "T2" in p:
        name = "T1" if p["T1"] >= p["T2"] else "T2"
        return float(p[name]), float(e.get(name, math.nan)), f"the slower pole's time constant {name}"
    if "T" in p and "T12" not in p:
        return float(p["T"]), float(e.get("T", math.nan)), "the time constant T"
    return math.nan, math.nan, ""


def settled_at_run_end(fit: SegmentFit, slowest: tuple[float, float, str] | None = None) -> SegmentFit:
    """``fit`` marked unsure when its window was ended by a run boundary before its response settled.

    A segment whose window the end of its data cut (``Segment.cut_at_run_end``, what cut it in
    ``Segment.cut_by``: a file boundary with a gap to the next run, the end of the log or of its last
    run, a dropout of its response or input; not the next input change) is judged by the time it holds after its input
    change, ``t_end - t_start``, when its model has a free settled level (``SETTLING_LEVEL_PARAMS``;
    not a coast-down, which decays to the known zero): fewer than ``SETTLED_TIME_CONSTANTS`` of the slowest time constant
    (:func:`slowest_time_constant`) at its 95 % upper bound means the response had not settled
    when the recording stopped, so the window holds the start of the transient only and its
    estimate leans on the model's shape rather than on the logged response (measured: a Clarke83
    rudder step back to zero cut to 26.6 s of its 80 s gave K +8.6 % +- 2.7 %). The fit is then
    failed with an ``unsure:`` message naming the window and the time constant; it is left out of
    the pooled estimates like any failed segment. Segments no boundary cut, fits already failed and
    fits without a free settled level are returned unchanged.

    Parameters
    ----------
    fit : SegmentFit
        A segment's fit; ``fit.segment.t_start`` is its input change [s, trial clock].
    slowest : tuple of (float, float, str), optional
        The slowest time constant to judge by [s], its standard error [s] and its name, when it is
        known better than from this window (the trial's records that nothing cut: a window cut
        before the slow mode shows may fit a structure without it); taken when larger than the fit's own.

    Returns
    -------
    SegmentFit
        ``fit``, or a copy with ``success=False`` and the reason first in its message.
    """
    seg = fit.segment
    if not seg.cut_at_run_end or not fit.success or not any(n in fit.params for n in SETTLING_LEVEL_PARAMS):
        return fit
    held = seg.t_end - seg.t_start
    tau, se, what = slowest_time_constant(fit)
    if slowest is not None and math.isfinite(slowest[0]) and \
            not (math.isfinite(tau) and _upper(tau, se) >= _upper(slowest[0], slowest[1])):
        tau, se, what = slowest
    if not math.isfinite(tau) or tau <= 0:
        return fit
    upper = _upper(tau, se)
    if held >= SETTLED_TIME_CONSTANTS * upper:
        return fit
    cause = seg.cut_by or "the end of its run (a file boundary, a gap to the next run)"
    why = (f"unsure: {cause} cut the window at "
           f"{held:.1f} s after the input change, {held / upper:.1f} times {what} at its 95 % upper bound "
           f"({tau:.3g} +- {se:.2g} s; settled needs {SETTLED_TIME_CONSTANTS:g}): the response had not settled "
           f"when its record stopped, so the estimate rests on the start of the transient only")
    return replace(fit, success=False, message=f"{why}; {fit.message}")


def _upper(tau: float, se: float) -> float:
    """95 % upper bound of a time constant [s] (``tau`` itself when its error is not known)."""
    return tau + UPPER_BOUND_Z * se if math.isfinite(se) else tau
