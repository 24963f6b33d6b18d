"""First-order model ``T y_dot = -y + f(t)`` sampled exactly on a grid of block means.

With ``a = exp(-dt/T)`` the exact zero-order-hold recursion and the exact mean of ``y`` over step
``k`` (what a block average of the measurements estimates) are

    y_{k+1} = a y_k + (1 - a) f_k,      y_bar_k = c1 y_k + (1 - c1) f_k,      c1 = T (1 - a) / dt,

and the block means of its integral (a heading integrated from a yaw rate) follow in closed form.
This is the same first-order system as :func:`pipeline.model.nomoto.nomoto_rhs` (Nomoto 1957;
Fossen 2021, sec. 7.2) in the form the diagnosis' variable-projection fits need: linear in the
forcing and the initial state for a given ``T``.
"""

from __future__ import annotations

import numpy as np
import scipy.signal


def coefficients(t_const: float, dt: float) -> tuple[float, float]:
    """``a = exp(-dt/T)`` and ``c1 = T (1 - a) / dt`` of the exact ZOH recursion.

    Parameters
    ----------
    t_const : float
        Time constant T [s].
    dt : float
        Analysis step [s].
    """
    x = dt / t_const
    a = float(np.exp(-x))
    c1 = float(-np.expm1(-x) / x)
    return a, c1


def effective_forcing(f: np.ndarray, t_const: float, dt: float, m: int) -> tuple[np.ndarray, np.ndarray]:
    """State and block-mean forcing of one regressor for time constant ``t_const`` [s].

    A (W, n) regressor is constant over each step: both are the regressor itself. For (3, W, n)
    moments of a held input (sample ``j`` of ``m``, each ``h = dt/m`` long) the exact weights are
    ``b^(m-1-j)`` for the state at the step's end and ``1 - c_h b^(m-1-j)`` for the step's mean,
    with ``b = exp(-h/T)`` and ``c_h = T (1 - b) / h``; they are expanded to second order in ``h/T``
    and normalised so that a constant input is reproduced exactly.

    Parameters
    ----------
    f : numpy.ndarray
        Regressor, (W, n) or (3, W, n) moments.
    t_const : float
        Time constant [s].
    dt : float
        Analysis step [s].
    m : int
        Trial samples per step.

    Returns
    -------
    f_state, f_mean : numpy.ndarray
        (W, n) each.
    """
    if f.ndim == 2:
        return f, f
    x = dt / m / t_const
    lag1 = m * (m - 1) / 2.0
    lag2 = (m - 1) * m * (2 * m - 1) / 6.0
    taylor = f[0] - x * f[1] + 0.5 * x * x * f[2]
    ones = m - x * lag1 + 0.5 * x * x * lag2
    f_state = taylor / ones
    ch = -np.expm1(-x) / x if x > 0 else 1.0
    f_mean = (f[0] - ch * taylor) / (m - ch * ones) if m > 1 else f[0]
    return f_state, f_mean


def zero_state(f_state: np.ndarray, f_mean: np.ndarray, a: float, c1: float) -> tuple[np.ndarray, np.ndarray]:
    """Response from rest: block means ``c1 s_k + (1 - c1) f_mean_k`` and the states ``s_k`` at the
    step starts, with ``s_{k+1} = a s_k + (1 - a) f_state_k``.

    Parameters
    ----------
    f_state, f_mean : numpy.ndarray
        Forcing for the state update and for the step means (..., n).
    a, c1 : float
        Coefficients of :func:`coefficients`.
    """
    s = scipy.signal.lfilter([0.0, 1.0 - a], [1.0, -a], f_state, axis=-1)
    return c1 * s + (1.0 - c1) * f_mean, s


def free_response(n: int, a: float, c1: float) -> np.ndarray:
    """Block-mean response to a unit initial state: ``c1 a^k`` (n,).

    Parameters
    ----------
    n : int
        Steps.
    a, c1 : float
        Coefficients of :func:`coefficients`.
    """
    return c1 * a ** np.arange(n)


def integrate_blocks(ybar: np.ndarray, dt: float, within: np.ndarray | None = None) -> np.ndarray:
    """Block means of the integral of a signal whose block means are ``ybar`` (..., n) [SI s].

    ``psi_bar_k = dt sum_{j<k} ybar_j + w_k``: the increments are exact; ``w_k`` is the mean of the
    integral within step ``k``, exact when given (:func:`within_block`), else the trapezoid
    ``dt ybar_k / 2``.

    Parameters
    ----------
    ybar : numpy.ndarray
        Block means of the signal (..., n).
    dt : float
        Step [s].
    within : numpy.ndarray, optional
        Within-step means of the integral (..., n) [SI s].
    """
    c = np.cumsum(ybar, axis=-1) - ybar
    return dt * c + (0.5 * dt * ybar if within is None else within)


def within_block(y_start: np.ndarray, f_mean: np.ndarray, t_const: float, dt: float) -> np.ndarray:
    """Mean over step k of the integral of y from the step's start [SI s]: exact for a first-order
    response from ``y_start`` under constant forcing ``f_mean``.

    ``(1/dt) int_0^dt int_0^s y = f dt / 2 + (y_k - f) T (1 - c1)``.

    Parameters
    ----------
    y_start : numpy.ndarray
        State at each step's start [SI].
    f_mean : numpy.ndarray or float
        Forcing over the step [SI].
    t_const : float
        Time constant [s].
    dt : float
        Step [s].
    """
    _, c1 = coefficients(t_const, dt)
    return f_mean * dt / 2 + (y_start - f_mean) * t_const * (1 - c1)
