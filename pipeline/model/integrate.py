"""Fixed-step Runge-Kutta integration with zero-order-hold inputs."""

from __future__ import annotations

from typing import Callable

import numpy as np


def integrate_rk4(rhs: Callable, x0: np.ndarray, t: np.ndarray, u: np.ndarray, params,
                  substeps: int = 1) -> np.ndarray:
    """Integrate ``x_dot = rhs(t, x, u, params)`` on the grid ``t`` with RK4.

    The input is held constant over each interval ``[t[k], t[k+1])`` (zero-order hold), as a
    digital actuator command is.

    Parameters
    ----------
    rhs : callable
        ``f(t, x, u, params)`` returning the state derivative.
    x0 : numpy.ndarray, shape (n,)
        Initial state.
    t : numpy.ndarray, shape (N,)
        Output times [s], increasing.
    u : numpy.ndarray, shape (N, m)
        Input samples, held over each interval.
    params : object
        Model parameters passed through to ``rhs``.
    substeps : int
        RK4 steps per interval (for stiff-ish DOFs such as roll at coarse sampling).

    Returns
    -------
    numpy.ndarray, shape (N, n)
        State at each time in ``t``.
    """
    t = np.asarray(t, float)
    u = np.asarray(u, float).reshape(len(t), -1)
    x = np.empty((len(t), len(x0)))
    x[0] = xk = np.asarray(x0, float)
    for k in range(len(t) - 1):
        h = (t[k + 1] - t[k]) / substeps
        uk = u[k]
        tk = t[k]
        for _ in range(substeps):
            k1 = rhs(tk, xk, uk, params)
            k2 = rhs(tk + h / 2, xk + h / 2 * k1, uk, params)
            k3 = rhs(tk + h / 2, xk + h / 2 * k2, uk, params)
            k4 = rhs(tk + h, xk + h * k3, uk, params)
            xk = xk + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            tk = tk + h
        x[k + 1] = xk
    return x
