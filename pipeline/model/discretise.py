"""Exact discretisation of linear models: zero-order hold and Van Loan's noise integral.

One module for every sampled model of the package (the fits' exact ZOH simulation, the PEM's
innovations filter, the autopilot's Kalman filter)::

    expm([[A, B], [0, 0]] h)         = [[A_d, B_d], [0, I]]                    (zero-order hold)
    expm([[-A, G], [0, A^T]] h)      = [[., F_12], [0, F_22]],  A_d = F_22^T,  Q_d = F_22^T F_12

with ``G = E Q E^T`` the continuous noise intensity, so ``Q_d = int_0^h exp(A s) G exp(A^T s) ds``
(Van Loan 1978). :func:`van_loan` and :func:`zoh` delegate the exponential to
:func:`scipy.linalg.expm`; :func:`zoh_fast` and :func:`noise_integral_fast` use
:func:`expm_small`, which is cheap enough to call for every candidate parameter vector of a fit
(scipy's Pade step calls threaded LAPACK solvers that cost milliseconds on a loaded machine).

References
----------
Van Loan, C. F. (1978). Computing integrals involving the matrix exponential. IEEE Trans. Autom.
Control 23(3), 395-404.
Moler, C., Van Loan, C. (2003). Nineteen dubious ways to compute the exponential of a matrix,
twenty-five years later. SIAM Review 45(1), 3-49.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg

#: Taylor terms of :func:`expm_small` after scaling to a 1-norm of at most 1/2 (error < 1e-16).
TAYLOR_TERMS = 16


def expm_small(m: np.ndarray) -> np.ndarray:
    """Matrix exponential of a small matrix by scaling and squaring of its Taylor series.

    The same result as :func:`scipy.linalg.expm` to rounding (the tests compare them), built only
    from small matrix products. With ``||M / 2^s||_1 <= 1/2`` the truncated series' error is below
    ``0.5^17 / 17! < 1e-19`` (Moler & Van Loan 2003, methods 1 and 3).

    Parameters
    ----------
    m : numpy.ndarray, shape (n, n)
        Matrix (already multiplied by the sample time) [-].

    Returns
    -------
    numpy.ndarray, shape (n, n)
        ``exp(m)``.
    """
    m = np.asarray(m, float)
    norm = float(np.abs(m).sum(axis=0).max()) if m.size else 0.0
    s = max(0, int(math.ceil(math.log2(norm / 0.5)))) if norm > 0.5 else 0
    x = m / 2.0**s
    eye = np.eye(m.shape[0])
    e = eye
    for k in range(TAYLOR_TERMS, 0, -1):
        e = eye + (x @ e) / k
    for _ in range(s):
        e = e @ e
    return e


def _check_h(h: float) -> float:
    h = float(h)
    if not (math.isfinite(h) and h > 0):
        raise ValueError(f"sample time: expected a positive number [s], found {h!r}")
    return h


def _zoh_block(a: np.ndarray, b: np.ndarray, h: float, expm) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(a, float)
    b = np.asarray(b, float).reshape(a.shape[0], -1)
    n, m = b.shape
    big = np.zeros((n + m, n + m))
    big[:n, :n] = a
    big[:n, n:] = b
    ex = expm(big * _check_h(h))
    return ex[:n, :n], ex[:n, n:]


def zoh(a: np.ndarray, b: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Zero-order-hold discretisation ``(A_d, B_d)`` of ``x_dot = A x + B u`` (scipy's expm).

    The same matrices as :func:`scipy.signal.cont2discrete` with ``method="zoh"``.

    Parameters
    ----------
    a : numpy.ndarray, shape (n, n)
        Continuous system matrix [1/s].
    b : numpy.ndarray, shape (n, m)
        Continuous input matrix.
    h : float
        Sample time [s].

    Returns
    -------
    ad, bd : numpy.ndarray
        ``exp(A h)`` and ``int_0^h exp(A s) ds B``.
    """
    return _zoh_block(a, b, h, scipy.linalg.expm)


def zoh_fast(a: np.ndarray, b: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`zoh` with :func:`expm_small`, for the inner loop of a fit.

    Parameters
    ----------
    a, b, h : numpy.ndarray, numpy.ndarray, float
        As in :func:`zoh`.

    Returns
    -------
    ad, bd : numpy.ndarray
        As :func:`zoh` returns them.
    """
    return _zoh_block(a, b, h, expm_small)


def _noise_block(a: np.ndarray, g: np.ndarray, h: float, expm) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(a, float)
    n = a.shape[0]
    big = np.zeros((2 * n, 2 * n))
    big[:n, :n] = -a
    big[:n, n:] = np.asarray(g, float)
    big[n:, n:] = a.T
    ex = expm(big * _check_h(h))
    ad = ex[n:, n:].T
    qd = ad @ ex[:n, n:]
    return ad, 0.5 * (qd + qd.T)


def noise_integral(a: np.ndarray, g: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """``(A_d, Q_d)``: Van Loan's ``Q_d = int_0^h exp(A s) G exp(A^T s) ds`` (scipy's expm).

    Parameters
    ----------
    a : numpy.ndarray, shape (n, n)
        Continuous system matrix [1/s].
    g : numpy.ndarray, shape (n, n)
        Continuous noise intensity ``E Q E^T`` [state unit^2 / s].
    h : float
        Sample time [s].

    Returns
    -------
    ad : numpy.ndarray
        ``exp(A h)``.
    qd : numpy.ndarray
        Covariance of the state increment over one sample [state unit^2], symmetrised.
    """
    return _noise_block(a, g, h, scipy.linalg.expm)


def noise_integral_fast(a: np.ndarray, g: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`noise_integral` with :func:`expm_small`, for the inner loop of a fit.

    Parameters
    ----------
    a, g, h : numpy.ndarray, numpy.ndarray, float
        As in :func:`noise_integral`.

    Returns
    -------
    ad, qd : numpy.ndarray
        As :func:`noise_integral` returns them.
    """
    return _noise_block(a, g, h, expm_small)


def van_loan(a: np.ndarray, b: np.ndarray, e: np.ndarray, q: np.ndarray, h: float
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Exact discretisation of ``x_dot = A x + B u + E w`` (Van Loan 1978).

    Parameters
    ----------
    a : numpy.ndarray, shape (n, n)
        Continuous system matrix [1/s].
    b : numpy.ndarray, shape (n, m)
        Input matrix (input held constant over a sample).
    e : numpy.ndarray, shape (n, p)
        Noise input matrix.
    q : numpy.ndarray, shape (p, p)
        Continuous noise intensity (power spectral density of w).
    h : float
        Sample time [s].

    Returns
    -------
    ad : numpy.ndarray
        ``exp(A h)``.
    bd, ed : numpy.ndarray
        ``int_0^h exp(A s) ds B`` and ``... E``.
    qd : numpy.ndarray
        ``int_0^h exp(A s) E Q E^T exp(A^T s) ds``, symmetrised.
    """
    b = np.asarray(b, float)
    e = np.asarray(e, float)
    ad, bed = zoh(a, np.hstack([b, e]), h)
    m = b.shape[1]
    _, qd = noise_integral(a, e @ np.asarray(q, float) @ e.T, h)
    return ad, bed[:, :m], bed[:, m:], qd
