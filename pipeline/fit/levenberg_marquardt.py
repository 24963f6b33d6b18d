"""Levenberg-Marquardt on sparse normal equations, for least-squares problems too long to hold their Jacobian.

The caller supplies the cost ``0.5 |r(z)|^2`` and, at accepted points, the gradient ``g = J^T r``
and the Gauss-Newton matrix ``H = J^T J`` as a sparse matrix it accumulates in chunks, so neither
``J`` nor ``r`` need exist whole. Each step solves ``(H + lambda diag(H)) dz = -g`` (Marquardt 1963;
diagonal scaling as ``x_scale='jac'`` in scipy) with a sparse LU, projects onto the lower bounds,
and adapts ``lambda`` by the ratio of actual to predicted reduction (Nielsen 1999).

It stops when the gain is below the noise: residuals weighted by ``1/sigma`` make the cost a
chi-square over two, and a step that lowers it by less than ``gain_tol`` (default 0.005) while the
Gauss-Newton model predicts no more moves the estimate by less than a tenth of a standard error
along any direction (``0.5 dtheta^T F dtheta < 0.005``). Relative ``ftol``/``xtol`` tests as in
scipy's ``least_squares`` also end it.

References
----------
Marquardt, D. W. (1963). An algorithm for least-squares estimation of nonlinear parameters.
*J. SIAM* 11(2), 431-441.
Nielsen, H. B. (1999). Damping parameter in Marquardt's method. IMM-REP-1999-05, DTU.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy import sparse
from scipy.sparse import linalg as splinalg

#: Cost decrease (chi-square / 2 in noise units) below which a step counts as noise.
GAIN_TOL = 0.005


@dataclass(frozen=True)
class LMResult:
    """Outcome of :func:`levenberg_marquardt`.

    Attributes
    ----------
    x : numpy.ndarray
        Last accepted point.
    cost : float
        ``0.5 |r|^2`` there.
    converged : bool
        A stopping test was met (not the evaluation limit or a stalled damping).
    message : str
        Which test ended it.
    njev : int
        Gradient/Gauss-Newton evaluations.
    nfev : int
        Cost evaluations.
    """

    x: np.ndarray
    cost: float
    converged: bool
    message: str
    njev: int
    nfev: int


def levenberg_marquardt(cost: Callable[[np.ndarray], float],
                        normal: Callable[[np.ndarray], tuple[float, np.ndarray, sparse.spmatrix]],
                        x0: np.ndarray, lower: np.ndarray | None = None, max_njev: int = 40,
                        gain_tol: float = GAIN_TOL, ftol: float = 1e-7, xtol: float = 1e-7) -> LMResult:
    """Minimise ``0.5 |r(x)|^2`` subject to ``x >= lower``.

    Parameters
    ----------
    cost : callable
        ``cost(x) -> 0.5 |r(x)|^2``.
    normal : callable
        ``normal(x) -> (cost, g, H)`` with ``g = J^T r`` and ``H = J^T J`` (sparse, symmetric).
    x0 : numpy.ndarray
        Start (clipped to ``lower``).
    lower : numpy.ndarray, optional
        Lower bounds (``-inf`` for none).
    max_njev : int
        Most ``normal`` evaluations.
    gain_tol : float
        Stop when the actual and the predicted decrease of the cost are both below this.
    ftol, xtol : float
        Relative cost and step tolerances.

    Returns
    -------
    LMResult
    """
    x = np.asarray(x0, float).copy()
    lo = np.full(x.size, -np.inf) if lower is None else np.asarray(lower, float)
    x = np.maximum(x, lo)
    f, g, h = normal(x)
    njev, nfev = 1, 1
    lam = 1e-3
    nu = 2.0
    h = sparse.csc_matrix(h)
    while True:
        d = np.maximum(h.diagonal(), 1e-12 * max(float(h.diagonal().max(initial=0.0)), 1e-300))
        accepted = False
        while not accepted:
            a = (h + sparse.diags(lam * d)).tocsc()
            try:
                step = -splinalg.spsolve(a, g)
            except (RuntimeError, ValueError):
                step = np.full(x.size, np.nan)
            if not np.all(np.isfinite(step)):
                lam *= nu
                nu *= 2
                if lam > 1e16:
                    return LMResult(x, f, False, "the damped normal equations are singular", njev, nfev)
                continue
            x_new = np.maximum(x + step, lo)
            dx = x_new - x
            predicted = -(g @ dx + 0.5 * dx @ (h @ dx))
            f_new = cost(x_new)
            nfev += 1
            actual = f - f_new
            ratio = actual / predicted if predicted > 0 else -1.0
            if np.isfinite(f_new) and actual > 0 and ratio > 1e-4:
                accepted = True
                lam *= max(1.0 / 3.0, 1.0 - (2.0 * ratio - 1.0) ** 3)
                nu = 2.0
            else:
                lam *= nu
                nu *= 2
                if lam > 1e16 or (abs(actual) < gain_tol and predicted < gain_tol):
                    # No step lowers the cost by more than noise: x is as good as the data allow.
                    return LMResult(x, f, True, "no step lowers the cost by more than the noise", njev, nfev)
        x, f_old, f = x_new, f, f_new
        small_x = np.linalg.norm(dx) < xtol * (xtol + np.linalg.norm(x))
        if actual < gain_tol and predicted < gain_tol:
            return LMResult(x, f, True, f"gain below the noise ({actual:.2g} < {gain_tol:g})", njev, nfev)
        if actual < ftol * f_old:
            return LMResult(x, f, True, "relative cost change below ftol", njev, nfev)
        if small_x:
            return LMResult(x, f, True, "relative step below xtol", njev, nfev)
        if njev >= max_njev:
            return LMResult(x, f, False, f"stopped after {njev} Jacobian evaluations", njev, nfev)
        f, g, h = normal(x)
        h = sparse.csc_matrix(h)
        njev += 1


__all__ = ["LMResult", "levenberg_marquardt", "GAIN_TOL"]
