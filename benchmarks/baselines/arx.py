"""Generic black-box baseline: an ARX model by linear least squares, converted to Nomoto K and T.

``A(q) y[k] = B(q) u[k] + c + e[k]`` with ``A = 1 + a_1 q^-1 + ... + a_na q^-na`` and
``B = b_1 q^-nk + ... `` (Ljung 1999, sec. 4.2), solved in one linear least-squares step on the
sampled heading and rudder. The identified discrete model is taken back to continuous time by
inverting the zero-order hold (matrix logarithm of ``[[A_d, B_d], [0, 1]]``, the inverse of
:func:`pipeline.fit.nomoto_oe.zoh_discretise`), and read as ``K / (s (T s + 1))``: T is minus the
inverse of the continuous pole farthest from the origin, K the low-frequency gain of ``s G(s)``.

This is the estimator a general-purpose toolbox gives with its defaults. Its equation error is
``A(q) v``, coloured even for white measurement noise, so it is biased whenever the heading is
measured with noise (Ljung 1999, sec. 8.3); the accuracy benchmark runs it on the same records as
the Nomoto output-error and prediction-error fits to show by how much.

References
----------
Ljung, L. (1999). System Identification: Theory for the User, 2nd ed., Prentice Hall.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import scipy.linalg
import scipy.signal

from pipeline.errors import FitError


@dataclass(frozen=True)
class ArxFit:
    """An ARX fit and its continuous-time Nomoto reading.

    Attributes
    ----------
    a : numpy.ndarray
        ``[1, a_1, ..., a_na]``.
    b : numpy.ndarray
        ``[0, ..., b_nk, ..., ]`` numerator in powers of ``q^-1`` (length ``na + 1``).
    offset : float
        Constant term ``c`` [rad] (0 when not fitted).
    h : float
        Sample time [s].
    K : float
        Nomoto gain [1/s] (NaN when the model has no first-order-Nomoto reading).
    T : float
        Nomoto time constant [s].
    poles : numpy.ndarray
        Continuous poles of the identified model [1/s].
    message : str
        Why K or T are NaN.
    """

    a: np.ndarray
    b: np.ndarray
    offset: float
    h: float
    K: float
    T: float
    poles: np.ndarray
    message: str = ""


def d2c_zoh(ad: np.ndarray, bd: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Continuous ``(A, B)`` whose zero-order-hold discretisation is ``(A_d, B_d)``.

    ``logm([[A_d, B_d], [0, I]]) / h = [[A, B], [0, 0]]`` (principal logarithm; needs no discrete
    pole on the negative real axis).

    Parameters
    ----------
    ad, bd : numpy.ndarray
        Discrete system and input matrices.
    h : float
        Sample time [s].

    Raises
    ------
    FitError
        A discrete pole on the negative real axis or at the origin (no real logarithm).
    """
    ad = np.asarray(ad, float)
    n = ad.shape[0]
    bd = np.asarray(bd, float).reshape(n, -1)
    m = bd.shape[1]
    big = np.eye(n + m)
    big[:n, :n] = ad
    big[:n, n:] = bd
    poles = np.linalg.eigvals(ad)
    if np.any((np.abs(poles.imag) < 1e-12) & (poles.real <= 0)):
        raise FitError(f"d2c: discrete pole(s) {np.round(poles, 6)} on the negative real axis or at 0 have no "
                       f"continuous-time equivalent")
    lg = scipy.linalg.logm(big)
    lg = np.real_if_close(lg, tol=1e6)
    if np.iscomplexobj(lg):
        raise FitError("d2c: the matrix logarithm is complex: no real continuous model")
    lg = lg / h
    return lg[:n, :n], lg[:n, n:]


def fit_arx_nomoto(records: Sequence[tuple[np.ndarray, np.ndarray]], h: float, na: int = 2, nb: int = 2,
                   nk: int = 1, offset: bool = True) -> ArxFit:
    """ARX by least squares on heading records, read as Nomoto K and T.

    Parameters
    ----------
    records : sequence of (delta, psi)
        Rudder [rad] and heading [rad] per record, uniformly sampled at ``h``; headings are unwrapped.
    h : float
        Sample time [s].
    na, nb, nk : int
        Orders: poles, numerator coefficients and input delay [samples]. The default (2, 2, 1) is
        the structure of an exactly sampled ``K / (s (T s + 1))``.
    offset : bool
        Fit the constant ``c`` (a rudder bias gives ``c = -B(1) b``).

    Returns
    -------
    ArxFit

    Raises
    ------
    FitError
        Too few samples for the regression, or an order outside ``1 <= nk``, ``nb + nk - 1 <= na``.
    """
    if not (na >= 1 and nb >= 1 and nk >= 1 and nb + nk - 1 <= na):
        raise FitError(f"ARX: expected na >= 1, nb >= 1, nk >= 1, nb + nk - 1 <= na, found na={na}, nb={nb}, nk={nk}")
    lag = max(na, nb + nk - 1)
    rows, rhs = [], []
    for delta, psi in records:
        u = np.asarray(delta, float)
        y = np.unwrap(np.asarray(psi, float))
        if u.shape != y.shape or u.size <= lag + na + nb + 1:
            raise FitError(f"ARX: expected delta and psi of one length > {lag + na + nb + 1}, found {u.shape}, {y.shape}")
        k = np.arange(lag, y.size)
        cols = [-y[k - i] for i in range(1, na + 1)] + [u[k - nk - j] for j in range(nb)]
        if offset:
            cols.append(np.ones(k.size))
        rows.append(np.column_stack(cols))
        rhs.append(y[k])
    phi = np.vstack(rows)
    theta, *_ = np.linalg.lstsq(phi, np.concatenate(rhs), rcond=None)
    a = np.concatenate([[1.0], theta[:na]])
    b = np.zeros(na + 1)
    b[nk:nk + nb] = theta[na:na + nb]
    c = float(theta[-1]) if offset else 0.0
    with warnings.catch_warnings():
        # A zero or near-zero leading numerator coefficient is expected (strictly proper model).
        warnings.simplefilter("ignore", scipy.signal.BadCoefficients)
        try:
            ad, bd, cd, dd = scipy.signal.tf2ss(b, a)
            ac, bc = d2c_zoh(ad, bd, h)
        except (FitError, ValueError, np.linalg.LinAlgError) as exc:
            return ArxFit(a=a, b=b, offset=c, h=h, K=math.nan, T=math.nan, poles=np.array([]), message=str(exc))
        poles = np.linalg.eigvals(ac)
        num, den = scipy.signal.ss2tf(ac, bc, cd, dd)
    num = np.asarray(num, float).ravel()
    fast = poles[np.argmax(np.abs(poles))]
    if abs(fast.imag) > 1e-9 or not fast.real < 0:
        return ArxFit(a=a, b=b, offset=c, h=h, K=math.nan, T=math.nan, poles=poles,
                      message=f"continuous poles {np.round(poles, 6)}: no first-order Nomoto reading")
    T = -1.0 / float(fast.real)
    # G(s) ~ N(0) / (s (s - p_fast)) near s = 0 when the other pole is the integrator: K/T = N(0).
    K = float(num[-1]) * T
    return ArxFit(a=a, b=b, offset=c, h=h, K=K, T=T, poles=poles)
