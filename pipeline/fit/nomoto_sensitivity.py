"""Exact derivatives of the sampled Nomoto simulation (discrete sensitivity equations).

The whole-record fit simulates ``x[k+1] = A_d x[k] + B_d (u[k] - b)`` with ``(A_d, B_d)`` the exact
zero-order-hold discretisation of the continuous model (:mod:`pipeline.fit.nomoto_zoh`).
Differentiating that recursion with respect to a parameter ``theta`` gives::

    s[k+1] = A_d s[k] + dA_d x[k] + dB_d (u[k] - b),      s[0] = dx[0]/dtheta

the same linear system driven by the base trajectory, so every column of the Jacobian costs a few
vectorised IIR filters (:func:`propagate`) instead of two further simulations of a central finite
difference. The derivatives of ``(A_d, B_d)`` are the Frechet derivatives of the matrix exponential
of the augmented matrix ``M = [[A, B], [0, 0]] h``, read from one exponential of a block-triangular
matrix (Van Loan 1978; Najfeld & Havel 1995)::

    expm([[M, dM_1, ..., dM_p], [0, M, 0 ...], ..., [0, ..., M]])[0, j] = L(M, dM_j)

and the derivatives of ``(A, B)`` themselves come from a complex step of
:func:`pipeline.model.nomoto.nomoto_matrices` (exact to rounding: it is plain arithmetic).

References
----------
Van Loan, C. F. (1978). Computing integrals involving the matrix exponential. IEEE Trans. Autom.
Control 23(3), 395-404.
Najfeld, I., Havel, T. F. (1995). Derivatives of the matrix exponential and their computation.
Advances in Applied Mathematics 16, 321-375.
Squire, W., Trapp, G. (1998). Using complex variables to estimate derivatives of real functions.
SIAM Review 40(1), 110-112.
"""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np
import scipy.signal

from ..model.discretise import expm_small
from .nomoto_zoh import state_tf

#: Imaginary step of the complex-step derivative (any tiny value: no subtraction, no cancellation).
COMPLEX_STEP = 1e-30


def complex_step(fn: Callable[[Sequence[complex]], np.ndarray], x: Sequence[float]) -> list[np.ndarray]:
    """Derivatives of ``fn`` at ``x`` along every coordinate, by the complex step.

    Parameters
    ----------
    fn : callable
        Real-analytic function of a parameter vector returning an array (it must accept complex input).
    x : sequence of float
        Point.

    Returns
    -------
    list of numpy.ndarray
        ``d fn / d x_j`` for every ``j``.
    """
    x = np.asarray(x, float)
    out = []
    for j in range(x.size):
        xc = x.astype(complex)
        xc[j] += 1j * COMPLEX_STEP
        out.append(np.imag(np.asarray(fn(xc))) / COMPLEX_STEP)
    return out


def zoh_derivatives(a: np.ndarray, b: np.ndarray, da: Sequence[np.ndarray], db: Sequence[np.ndarray],
                    h: float) -> tuple[np.ndarray, np.ndarray, list[np.ndarray], list[np.ndarray]]:
    """``(A_d, B_d)`` and their derivatives along the directions ``(dA_j, dB_j)``.

    Parameters
    ----------
    a, b : numpy.ndarray
        Continuous model, shapes (n, n) and (n, 1).
    da, db : sequence of numpy.ndarray
        Derivatives of ``a`` and ``b`` per parameter.
    h : float
        Sample time [s].

    Returns
    -------
    ad, bd : numpy.ndarray
        ``exp(A h)`` (n, n) and ``int_0^h exp(A s) ds B`` (n, 1).
    dad, dbd : list of numpy.ndarray
        Their derivatives per parameter.
    """
    n = a.shape[0]
    m = n + 1
    p = len(da)
    big = np.zeros((m * (p + 1), m * (p + 1)))
    for k in range(p + 1):
        big[k * m:k * m + n, k * m:k * m + n] = a * h
        big[k * m:k * m + n, k * m + n] = b.ravel() * h
    for j in range(p):
        c = (j + 1) * m
        big[:n, c:c + n] = da[j] * h
        big[:n, c + n] = np.asarray(db[j]).ravel() * h
    ex = expm_small(big)
    ad, bd = ex[:n, :n], ex[:n, n:m]
    dad = [ex[:n, (j + 1) * m:(j + 1) * m + n] for j in range(p)]
    dbd = [ex[:n, (j + 1) * m + n:(j + 2) * m] for j in range(p)]
    return ad, bd, dad, dbd


def propagate(ad: np.ndarray, v: np.ndarray, s0: np.ndarray) -> np.ndarray:
    """``s[k+1] = A_d s[k] + v[k]``, ``s[0] = s0``, for many right-hand sides at once.

    ``A_d`` has the Nomoto structure (state 0 the heading, the running sum of the others:
    ``A_d[0, 0] = 1``, ``A_d[1:, 0] = 0``); the stable states are run as IIR filters over all
    columns at once and the heading accumulated by a cumulative sum, as in
    :func:`pipeline.fit.nomoto_zoh.simulate_zoh`.

    Parameters
    ----------
    ad : numpy.ndarray, shape (n, n)
        Discrete system matrix.
    v : numpy.ndarray, shape (N, n, p)
        Driving terms per sample, state and column.
    s0 : numpy.ndarray, shape (n, p)
        Initial values per column.

    Returns
    -------
    numpy.ndarray, shape (N, n, p)
    """
    nsamp, n, p = v.shape
    out = np.empty((nsamp, n, p))
    ar = ad[1:, 1:]
    m = n - 1
    # The initial value is the input of a step before the first sample (zero state before it).
    drive = np.concatenate([s0[None, 1:, :], v[:-1, 1:, :]], axis=0)      # (N, m, p)
    _, den = state_tf(ar, np.eye(m)[:, 0])
    sr = np.zeros((nsamp, m, p))
    for l in range(m):
        num, _ = state_tf(ar, np.eye(m)[:, l])
        col = drive[:, l, :]
        if not np.any(col):
            continue
        for q in range(m):
            if np.any(num[q]):
                # Without num's leading zero (one sample of delay): s[k] sums A^(k-j) drive[j], j <= k.
                sr[:, q, :] += scipy.signal.lfilter(num[q][1:], den, col, axis=0)
    out[:, 1:, :] = sr
    inc = np.einsum("kmp,m->kp", sr[:-1], ad[0, 1:]) + v[:-1, 0, :]
    out[0, 0, :] = s0[0]
    out[1:, 0, :] = s0[0] + np.cumsum(inc, axis=0)
    return out


def propagate_outputs(ad: np.ndarray, v: np.ndarray, s0: np.ndarray, outputs: Sequence[int]) -> dict[int, np.ndarray]:
    """The heading (state 0) and/or yaw-rate (state 1) rows of :func:`propagate`, columns first.

    The same recursion ``s[k+1] = A_d s[k] + v[k]``, ``s[0] = s0``, but only the outputs the fit
    uses are formed: each is one all-pole IIR filter of a short FIR combination of the driving
    terms (every stable state shares the denominator ``det(zI - A_r)``, so the ``m x m`` filters
    of :func:`propagate` collapse into one per output), run along the contiguous sample axis
    of all columns at once. The heading is accumulated by a cumulative sum as before.

    Parameters
    ----------
    ad : numpy.ndarray, shape (n, n)
        Discrete system matrix (Nomoto structure, see :func:`propagate`).
    v : numpy.ndarray, shape (p, n, N)
        Driving terms per column, state and sample.
    s0 : numpy.ndarray, shape (n, p)
        Initial values per column.
    outputs : sequence of int
        States wanted: 0 (heading) and/or 1 (yaw rate).

    Returns
    -------
    dict
        State index -> sensitivities, shape (p, N).
    """
    p, n, nsamp = v.shape
    ar = ad[1:, 1:]
    m = n - 1
    _, den = state_tf(ar, np.eye(m)[:, 0])
    nums = [state_tf(ar, np.eye(m)[:, l])[0] for l in range(m)]
    # Output weights over the stable states: the yaw rate is state 1; the heading's increment is
    # A_d[0, 1:] times them (plus its own drive).
    weights = {0: ad[0, 1:], 1: np.eye(m)[0]}
    out: dict[int, np.ndarray] = {}
    for o in outputs:
        w = np.zeros((p, nsamp))
        for l in range(m):
            # Without num's leading zero (one sample of delay): drive[j] = s0 at j = 0, v[j - 1] after.
            c = weights[o] @ nums[l][:, 1:]
            if not np.any(c):
                continue
            drive = np.empty((p, nsamp))
            drive[:, 0] = s0[1 + l]
            drive[:, 1:] = v[:, 1 + l, :-1]
            for j, cj in enumerate(c):
                if cj != 0.0:
                    w[:, j:] += cj * drive[:, :nsamp - j]
        y = scipy.signal.lfilter([1.0], den, w, axis=-1)
        if o == 1:
            out[1] = y
        else:
            psi = np.empty((p, nsamp))
            psi[:, 0] = s0[0]
            np.cumsum(y[:, :-1] + v[:, 0, :-1], axis=-1, out=psi[:, 1:])
            psi[:, 1:] += s0[0][:, None]
            out[0] = psi
    return out
