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


def rk4_chunk_integrator(rhs: Callable, params, n_states: int, n_inputs: int, h: float,
                         chunk: int = 256) -> Callable:
    """Compiled RK4 over chunks of samples, for a loop that cannot hand the whole input history to one call.

    The simulator's closed loop (commands that depend on the state, actuator effects) knows the
    inputs only a stretch at a time. :func:`integrate_rk4` evaluates the numpy right-hand side four
    times per step from Python (about 130 us a step for the 10-state vessel; 47 000 steps on the
    AAUSHIP sea-trial day). Here the right-hand side (any model of this package: they all accept
    casadi symbols) is traced once and its RK4 step accumulated over ``chunk`` samples in casadi's
    virtual machine, so a stretch of inputs costs one call. Same equations and the same RK4 as
    :func:`integrate_rk4`; the results agree with it to rounding (tests/test_model.py).

    Parameters
    ----------
    rhs : callable
        ``f(t, x, u, params)`` of a time-invariant model, accepting casadi symbols.
    params : object
        Model parameters passed through to ``rhs`` (numbers: they are compiled in).
    n_states, n_inputs : int
        Sizes of ``x`` and ``u``.
    h : float
        Step [s].
    chunk : int
        Most samples per compiled call; longer stretches take several calls.

    Returns
    -------
    callable
        ``integrate(x0, u) -> (x, x_dot, x_end)`` for inputs ``u`` of shape (N, n_inputs), each held
        over one step: the states at the N samples (``x[0] = x0``), the derivatives there, and the
        state one step after the last sample.
    """
    import casadi as ca

    x = ca.SX.sym("x", n_states)
    u = ca.SX.sym("u", n_inputs)
    k1 = rhs(0.0, x, u, params)
    k2 = rhs(0.0, x + h / 2 * k1, u, params)
    k3 = rhs(0.0, x + h / 2 * k2, u, params)
    k4 = rhs(0.0, x + h * k3, u, params)
    step = ca.Function("rk4_step", [x, u], [x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4), k1])
    compiled: dict[int, ca.Function] = {}

    def accumulated(m: int) -> ca.Function:
        # One function per stretch length: a zig-zag's ticks are all one length, the rest a chunk or
        # a manoeuvre's last stretch.
        if m not in compiled:
            compiled[m] = step.mapaccum(f"rk4_{m}", m)
        return compiled[m]

    def integrate(x0: np.ndarray, u_rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        u_rows = np.asarray(u_rows, float).reshape(-1, n_inputs)
        n = len(u_rows)
        xs = np.empty((n, n_states))
        xdots = np.empty((n, n_states))
        xk = np.asarray(x0, float)
        for a in range(0, n, chunk):
            part = u_rows[a:a + chunk]
            m = len(part)
            nxt, der = accumulated(m)(xk, part.T)
            nxt, der = np.asarray(nxt), np.asarray(der)
            xs[a] = xk
            xs[a + 1:a + m] = nxt[:, :m - 1].T
            xdots[a:a + m] = der[:, :m].T
            xk = nxt[:, m - 1].copy()
        return xs, xdots, xk

    return integrate
