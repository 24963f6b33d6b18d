"""Turn a least-squares result into a :class:`~pipeline.records.SegmentFit`, with the sanity checks
that decide ``success`` (convergence, bounds, covariance, relative standard error)."""

from __future__ import annotations

import math
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
