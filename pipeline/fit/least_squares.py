"""Bounded nonlinear least squares with a Jacobian covariance, shared by every fit model.

The covariance is the Gauss-Newton estimate ``cov = (J^T J)^-1 s^2`` with ``s^2 = RSS / (n - p)``
(Seber & Wild 2003, sec. 2.1). It assumes white, homoscedastic residuals: coloured residuals
(unmodelled dynamics, waves, a filtered sensor) make the standard errors too small, which is why
the lag-1 residual autocorrelation is reported with every fit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
from scipy import optimize

from ..records import FitResult, confidence_interval, fit_result_from_arrays

__all__ = ["LeastSquaresResult", "fit_least_squares", "confidence_interval", "lag1_autocorrelation"]

#: Model function ``f(t, p) -> y`` and its Jacobian ``J(t, p) -> dy/dp`` of shape (n, len(p)).
ModelFn = Callable[[np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class LeastSquaresResult:
    """What :func:`fit_least_squares` found.

    Attributes
    ----------
    names : tuple[str, ...]
        Parameter names, in covariance order.
    values, stderr : numpy.ndarray
        Estimates and standard errors [parameter units]; stderr NaN when the covariance is singular.
    covariance : numpy.ndarray
        ``(J^T J)^-1 s^2``; NaN when it cannot be computed.
    y_fit, residuals : numpy.ndarray
        Model at the estimate, and ``y_fit - y``.
    rss : float
        Residual sum of squares.
    n, dof : int
        Samples, and degrees of freedom ``n - p``.
    aic, bic : float
        ``n ln(RSS/n) + 2p`` and ``n ln(RSS/n) + p ln n`` (as lmfit reports them).
    lag1 : float
        Lag-1 autocorrelation of the residuals (0 for white noise).
    converged : bool
        The solver reported convergence.
    at_bound : tuple[str, ...]
        Parameters that ended on a bound.
    message : str
        Solver status, or why the covariance is missing.
    """

    names: tuple[str, ...]
    values: np.ndarray
    stderr: np.ndarray
    covariance: np.ndarray
    y_fit: np.ndarray
    residuals: np.ndarray
    rss: float
    n: int
    dof: int
    aic: float
    bic: float
    lag1: float
    converged: bool
    at_bound: tuple[str, ...]
    message: str

    def value(self, name: str) -> float:
        """Estimate of parameter ``name``.

        Parameters
        ----------
        name : str
            One of ``names`` (``ValueError`` otherwise).
        """
        return float(self.values[self.names.index(name)])

    def to_fit_result(self, model: str = "least_squares", units: dict[str, str] | None = None) -> FitResult:
        """This result as a :class:`~pipeline.records.FitResult`.

        Parameters
        ----------
        model : str
            Name of the model fitted.
        units : dict, optional
            Unit per parameter name.
        """
        return fit_result_from_arrays(
            model, self.names, self.values, self.stderr, self.covariance, units, dof=self.dof if self.dof > 0 else math.inf,
            aic=float(self.aic), bic=float(self.bic), success=bool(self.converged) and not self.at_bound,
            message=self.message + (f"; at bound: {', '.join(self.at_bound)}" if self.at_bound else ""),
            ndata=int(self.n), provenance={"fitter": "pipeline.fit.least_squares.fit_least_squares",
                                           "covariance": "(J^T J)^-1 s^2, s^2 = RSS / (n - p)"},
            statistics={"rss": float(self.rss), "lag1": float(self.lag1)})


def lag1_autocorrelation(residuals: np.ndarray) -> float:
    """Lag-1 autocorrelation of a residual sequence [-].

    Parameters
    ----------
    residuals : numpy.ndarray
        Residuals in time order.

    Returns
    -------
    float
        ``sum(e_k e_{k+1}) / sum(e_k^2)`` of the mean-removed residuals; NaN for fewer than 3.
    """
    e = np.asarray(residuals, float)
    if e.size < 3:
        return math.nan
    e = e - e.mean()
    den = float(e @ e)
    return float(e[1:] @ e[:-1]) / den if den > 0 else 0.0


def _covariance(jac: np.ndarray, s2: float) -> tuple[np.ndarray, str]:
    # Column scaling before the SVD, so that parameters of very different size (a time constant of
    # 70 s next to a gain of 0.1 1/s) do not look rank-deficient.
    p = jac.shape[1]
    scale = np.linalg.norm(jac, axis=0)
    if not np.all(np.isfinite(jac)) or np.any(scale == 0):
        return np.full((p, p), np.nan), "Jacobian has a zero or non-finite column: a parameter does not affect the fit"
    _, sv, vt = np.linalg.svd(jac / scale, full_matrices=False)
    if sv[-1] <= sv[0] * max(jac.shape) * np.finfo(float).eps * 1e3:
        return np.full((p, p), np.nan), f"Jacobian is singular (condition number {sv[0] / max(sv[-1], 1e-300):.1e})"
    inv = (vt.T / sv**2) @ vt
    return inv / np.outer(scale, scale) * s2, ""


def fit_least_squares(model: ModelFn, jacobian: ModelFn, t: np.ndarray, y: np.ndarray,
                      p0: Sequence[float], names: Sequence[str],
                      lower: Sequence[float] | None = None, upper: Sequence[float] | None = None,
                      max_nfev: int = 200) -> LeastSquaresResult:
    """Fit ``y ~ model(t, p)`` by trust-region least squares and estimate the covariance.

    Parameters
    ----------
    model : callable
        ``model(t, p) -> y`` [unit of y].
    jacobian : callable
        ``jacobian(t, p) -> dy/dp``, shape (n, p).
    t, y : numpy.ndarray
        Times [s] and data; finite values only.
    p0 : sequence of float
        Start values (a model's ``guess()``); clipped into the bounds.
    names : sequence of str
        Parameter names.
    lower, upper : sequence of float, optional
        Bounds (``-inf``/``inf`` for none).
    max_nfev : int
        Maximum number of function evaluations.

    Returns
    -------
    LeastSquaresResult
        Values, covariance, residual statistics and solver status.
    """
    t = np.asarray(t, float)
    y = np.asarray(y, float)
    p = len(names)
    lo = np.full(p, -np.inf) if lower is None else np.asarray(lower, float)
    hi = np.full(p, np.inf) if upper is None else np.asarray(upper, float)
    # The trust-region solver needs a start strictly inside the bounds.
    span = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
    x0 = np.clip(np.asarray(p0, float), lo + 1e-9 * span, hi - 1e-9 * span)

    res = optimize.least_squares(lambda x: model(t, x) - y, x0, jac=lambda x: jacobian(t, x),
                                 bounds=(lo, hi), method="trf", x_scale="jac", max_nfev=max_nfev)
    x = res.x
    y_fit = model(t, x)
    resid = y_fit - y
    n = y.size
    dof = n - p
    rss = float(resid @ resid)
    at_bound = tuple(nm for nm, a in zip(names, res.active_mask) if a != 0)
    messages = [] if res.status > 0 else [f"solver did not converge: {res.message}"]
    if dof > 0:
        cov, why = _covariance(jacobian(t, x), rss / dof)
    else:
        cov, why = np.full((p, p), np.nan), f"no residual degrees of freedom ({n} samples, {p} parameters)"
    if why:
        messages.append(why)
    stderr = np.sqrt(np.clip(np.diag(cov), 0.0, None)) if not why else np.full(p, np.nan)
    log_l = n * math.log(rss / n) if rss > 0 else -math.inf
    return LeastSquaresResult(
        names=tuple(names), values=x, stderr=stderr, covariance=cov, y_fit=y_fit, residuals=resid,
        rss=rss, n=n, dof=dof, aic=log_l + 2 * p, bic=log_l + math.log(n) * p,
        lag1=lag1_autocorrelation(resid), converged=res.status > 0, at_bound=at_bound,
        message="; ".join(messages),
    )
