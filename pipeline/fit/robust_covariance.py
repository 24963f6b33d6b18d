"""Parameter covariance of a least-squares fit that stays valid when the residuals are coloured.

The Gauss-Newton covariance ``(J^T J)^-1 s^2`` assumes white, equal-variance residuals. Simulation
(output-error) residuals of a logged channel are rarely white: a navigation filter, interpolation
between GNSS samples or a model error that varies slowly over a record make neighbouring residuals
alike, and the covariance then comes out too small. The heteroscedasticity and autocorrelation
consistent (HAC) sandwich (Newey & West 1987) replaces ``s^2 J^T J`` by the long-run covariance of
the scores ``g_t = J_t r_t``, summed over lags with Bartlett weights within each record (records are
independent)::

    S = sum_records sum_|l|<=L (1 - |l| / (L + 1)) sum_t g_t g_(t+l)^T,   cov = B S B,   B = (J^T J)^-1

The bandwidth ``L`` is Andrews' (1991) AR(1) plug-in for the Bartlett kernel,
``L = 1.1447 (alpha n)^(1/3)`` with ``alpha = 4 rho^2 / ((1 - rho)^2 (1 + rho)^2)``, from the pooled
lag-1 autocorrelation ``rho`` of the residuals and the median record length ``n``; the covariance is
scaled by ``n / (n - k)`` as the classic one is.

References: Newey, W. K. & West, K. D. (1987). Econometrica 55(3), 703-708. Andrews, D. W. K. (1991).
Econometrica 59(3), 817-858.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Largest bandwidth as a share of the median record length (beyond it the estimate is mostly noise).
MAX_BANDWIDTH_SHARE = 0.5
#: Lag-1 autocorrelation is clipped here before the plug-in (rho -> 1 gives an infinite bandwidth).
MAX_RHO = 0.97


@dataclass(frozen=True)
class RobustCovariance:
    """A HAC covariance and how it was made.

    Attributes
    ----------
    covariance : numpy.ndarray
        Sandwich covariance (k x k) [units of the parameters squared].
    classic : numpy.ndarray
        Gauss-Newton ``(J^T J)^-1 s^2`` for comparison.
    rho : float
        Pooled lag-1 autocorrelation of the residuals within records [-].
    bandwidth : int
        Bartlett lags used ``L``.
    inflation : numpy.ndarray
        Ratio of sandwich to classic standard errors per parameter [-].
    """

    covariance: np.ndarray
    classic: np.ndarray
    rho: float
    bandwidth: int
    inflation: np.ndarray


def pooled_lag1(resid: np.ndarray, groups: np.ndarray) -> float:
    """Lag-1 autocorrelation of residuals, pooled over records (pairs within one record only) [-].

    Parameters
    ----------
    resid : numpy.ndarray
        Residuals, time-ordered within each record.
    groups : numpy.ndarray
        Record index of each residual.
    """
    r = np.asarray(resid, float)
    g = np.asarray(groups)
    same = g[1:] == g[:-1]
    den = float(np.sum(r**2))
    if den <= 0 or not same.any():
        return 0.0
    return float(np.sum((r[1:] * r[:-1])[same]) / den)


def andrews_bandwidth(rho: float, n: int) -> int:
    """Andrews' (1991) AR(1) plug-in bandwidth of the Bartlett kernel [lags].

    Parameters
    ----------
    rho : float
        Lag-1 autocorrelation [-].
    n : int
        Samples per record.
    """
    rho = float(np.clip(rho, -MAX_RHO, MAX_RHO))
    alpha = 4 * rho**2 / ((1 - rho) ** 2 * (1 + rho) ** 2)
    lags = 1.1447 * (alpha * n) ** (1.0 / 3.0)
    return int(min(math.floor(lags), max(int(MAX_BANDWIDTH_SHARE * n), 0)))


def hac_covariance(jac: np.ndarray, resid: np.ndarray, groups: np.ndarray, bandwidth: int | None = None
                   ) -> RobustCovariance:
    """Newey-West sandwich covariance of least-squares parameters, records treated as independent.

    Parameters
    ----------
    jac : numpy.ndarray
        Jacobian of the (weighted) residuals, one row per residual (n x k).
    resid : numpy.ndarray
        Residuals at the solution (n), time-ordered within each record.
    groups : numpy.ndarray
        Record index per residual (n); a row of its own group (e.g. a steady-state point) has no lags.
    bandwidth : int, optional
        Bartlett lags; default :func:`andrews_bandwidth` of the pooled lag-1 autocorrelation.

    Returns
    -------
    RobustCovariance
    """
    jac = np.asarray(jac, float)
    r = np.asarray(resid, float)
    g = np.asarray(groups)
    n, k = jac.shape
    bread = np.linalg.pinv(jac.T @ jac)
    s2 = float(r @ r) / max(n - k, 1)
    classic = bread * s2
    rho = pooled_lag1(r, g)
    sizes = np.unique(g, return_counts=True)[1]
    L = andrews_bandwidth(rho, int(np.median(sizes))) if bandwidth is None else int(bandwidth)
    scores = jac * r[:, None]
    meat = scores.T @ scores
    for lag in range(1, L + 1):
        same = g[lag:] == g[:-lag]
        if not same.any():
            break
        a, b = scores[lag:][same], scores[:-lag][same]
        c = a.T @ b
        meat += (1.0 - lag / (L + 1.0)) * (c + c.T)
    cov = bread @ meat @ bread * (n / max(n - k, 1))
    with np.errstate(invalid="ignore", divide="ignore"):
        infl = np.sqrt(np.clip(np.diag(cov), 0, None)) / np.sqrt(np.clip(np.diag(classic), 0, None))
    return RobustCovariance(covariance=cov, classic=classic, rho=rho, bandwidth=L, inflation=infl)
