"""Exact sampled simulation of the linear Nomoto models for a zero-order-held rudder.

The heading is the running sum of the stable yaw dynamics, which are run as IIR filters
(:func:`scipy.signal.lfilter`), so a candidate parameter vector of a fit costs a few microseconds
per sample. The discretisation itself is :func:`pipeline.model.discretise.zoh_fast`.
"""

from __future__ import annotations

import numpy as np
import scipy.signal

from ..model.discretise import zoh_fast


#: Exact zero-order-hold discretisation ``(A_d, B_d)`` (Van Loan 1978) for the fit's inner loop:
#: the one in :mod:`pipeline.model.discretise`, under the name the Nomoto fits have always used.
zoh_discretise = zoh_fast


def state_tf(ad: np.ndarray, bd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Transfer functions ``(zI - A)^-1 B`` to every state: numerators (n, n+1) and denominator.

    Parameters
    ----------
    ad : numpy.ndarray, shape (n, n)
        Discrete system matrix.
    bd : numpy.ndarray, shape (n,) or (n, 1)
        Discrete input column.
    """
    n = ad.shape[0]
    bd = np.asarray(bd, float).reshape(n)
    if n == 1:
        return np.array([[0.0, bd[0]]]), np.array([1.0, -ad[0, 0]])
    if n == 2:
        # (zI - A)^-1 = adj(zI - A) / det(zI - A), written out (no LAPACK in the inner loop).
        a = ad
        den = np.array([1.0, -(a[0, 0] + a[1, 1]), a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]])
        num = np.array([[0.0, bd[0], -a[1, 1] * bd[0] + a[0, 1] * bd[1]],
                        [0.0, bd[1], a[1, 0] * bd[0] - a[0, 0] * bd[1]]])
        return num, den
    num, den = scipy.signal.ss2tf(ad, bd.reshape(n, 1), np.eye(n), np.zeros((n, 1)))
    return np.asarray(num, float), np.asarray(den, float)


def stable_states(ad: np.ndarray, bd: np.ndarray, x0: np.ndarray, u: np.ndarray) -> np.ndarray:
    """States of ``x[k+1] = A x[k] + B u[k]``, ``x[0] = x0`` (A stable), by IIR filtering.

    Each state is a linear filter of the input (plus the free response to ``x0``), so
    :func:`scipy.signal.lfilter` runs the recursion in compiled code: the cost of a candidate
    parameter vector is a few microseconds per sample, not a Python loop.

    Parameters
    ----------
    ad, bd : numpy.ndarray
        Discrete model of the stable states.
    x0 : numpy.ndarray
        Initial state.
    u : numpy.ndarray
        Input per sample.
    """
    n = ad.shape[0]
    out = np.empty((u.size, n))
    num, den = state_tf(ad, bd)
    impulse = np.zeros(u.size + 1)
    impulse[0] = 1.0
    if np.any(x0):
        num0, _ = state_tf(ad, x0)
    for i in range(n):
        out[:, i] = scipy.signal.lfilter(num[i], den, u)
        if np.any(x0):
            # Impulse at k = 0 through B = x0 gives A^(k-1) x0 at k >= 1: shift by one sample.
            out[:, i] += scipy.signal.lfilter(num0[i], den, impulse)[1:]
    return out


def simulate_zoh(ad: np.ndarray, bd: np.ndarray, x0: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Exact sampled response of a Nomoto model (state 0 = heading, the integral of the rest).

    ``x[k+1] = A_d x[k] + B_d u[k]`` with ``A_d[0, 0] = 1`` and ``A_d[1:, 0] = 0``: the heading is
    accumulated from the stable yaw dynamics by a running sum, which avoids putting the marginally
    stable integrator pole inside a transfer-function recursion.

    Parameters
    ----------
    ad, bd : numpy.ndarray
        Discrete model from :func:`zoh_discretise` (``bd`` one column).
    x0 : numpy.ndarray, shape (n,)
        Initial state.
    u : numpy.ndarray, shape (N,)
        Input held over each sample interval (``delta - b``) [rad].

    Returns
    -------
    numpy.ndarray, shape (N, n)
        States at the sample times.
    """
    u = np.asarray(u, float)
    x0 = np.asarray(x0, float)
    bd = np.asarray(bd, float).reshape(-1)
    xr = stable_states(ad[1:, 1:], bd[1:], x0[1:], u)
    inc = xr @ ad[0, 1:] + bd[0] * u
    psi = np.empty(u.size)
    psi[0] = x0[0]
    psi[1:] = x0[0] + np.cumsum(inc[:-1])
    return np.column_stack([psi, xr])
