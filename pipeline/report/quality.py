"""Fit quality per segment, as MATLAB's System Identification Toolbox shows it.

``compare``: the fit percentage ``100 (1 - ||y - y_hat|| / ||y - mean(y)||)`` (normalised RMSE;
100 % is a perfect fit, 0 % no better than the mean, negative worse). ``resid``: the residual
autocorrelation and the residual-input cross-correlation with their confidence bands
(:mod:`pipeline.fit.residual_tests`). The parameter correlation matrix comes from each fit's
covariance, ``rho_ij = C_ij / sqrt(C_ii C_jj)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import FitError
from ..fit.residual_tests import ResidualTest, segment_fit_residual_test
from ..records import SegmentFit, Trial


def fit_percent(y: np.ndarray, y_fit: np.ndarray) -> float:
    """MATLAB ``compare`` fit: ``100 (1 - ||y - y_fit|| / ||y - mean(y)||)`` [%].

    Parameters
    ----------
    y, y_fit : numpy.ndarray
        Data and model output [any unit, the same for both]; samples where either is NaN are
        left out.

    Returns
    -------
    float
        Fit [%]; NaN with fewer than two usable samples or a constant ``y``.
    """
    y = np.asarray(y, float).ravel()
    yf = np.asarray(y_fit, float).ravel()
    if y.size != yf.size:
        return float("nan")
    ok = np.isfinite(y) & np.isfinite(yf)
    if ok.sum() < 2:
        return float("nan")
    y, yf = y[ok], yf[ok]
    spread = np.linalg.norm(y - y.mean())
    if spread == 0.0:
        return float("nan")
    return float(100.0 * (1.0 - np.linalg.norm(y - yf) / spread))


def correlation_matrix(covariance: np.ndarray) -> np.ndarray:
    """Parameter correlation ``C_ij / sqrt(C_ii C_jj)`` [-] (NaN where a variance is not positive).

    Parameters
    ----------
    covariance : numpy.ndarray
        Square parameter covariance [units of the parameters squared].
    """
    c = np.atleast_2d(np.asarray(covariance, float))
    if c.ndim != 2 or c.shape[0] != c.shape[1] or c.size == 0:
        return np.empty((0, 0))
    d = np.diag(c).copy()
    d[~(d > 0)] = np.nan
    s = np.sqrt(d)
    return c / np.outer(s, s)


@dataclass(frozen=True)
class SegmentQuality:
    """How well one segment fit reproduces its data.

    Attributes
    ----------
    fit_percent : float
        MATLAB ``compare`` fit [%] (NaN when it cannot be computed).
    resid : ResidualTest or None
        Whiteness and input-independence test; None when it could not be run (``message`` says why).
    correlation : numpy.ndarray
        Parameter correlation matrix [-], in ``SegmentFit.param_names`` order.
    message : str
        Why the residual test was not run.
    """

    fit_percent: float
    resid: ResidualTest | None
    correlation: np.ndarray
    message: str = ""


def segment_quality(sf: SegmentFit, trial: Trial | None = None) -> SegmentQuality:
    """Fit %, residual test and parameter correlation of one segment fit.

    Parameters
    ----------
    sf : SegmentFit
        The fit.
    trial : Trial, optional
        The trial, for the input cross-correlation (without it only whiteness is tested).
    """
    pct = fit_percent(sf.y, sf.y_fit)
    cov = sf.to_fit_result().covariance
    corr = correlation_matrix(cov) if np.size(cov) else np.empty((0, 0))
    try:
        resid = segment_fit_residual_test(sf, trial) if sf.success else None
        why = "" if sf.success else "the fit failed"
    except (FitError, ValueError) as exc:
        resid, why = None, str(exc)
    return SegmentQuality(pct, resid, corr, why)
