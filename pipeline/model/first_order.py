"""The first-order response ``T y_dot + y = y_ss`` of one DOF after an input change, its
Jacobians and its closed-form estimate.

The fit stage (:mod:`pipeline.fit.first_order`) fits these by least squares; the segmenter
(:mod:`pipeline.segment.speed_events`) uses the closed form to judge whether a speed change looks
first order at all.
"""

from __future__ import annotations

import math

import numpy as np


def decay(t: np.ndarray, y0: float, T: float) -> np.ndarray:
    """Free first-order decay ``y0 exp(-t/T)``.

    Parameters
    ----------
    t : numpy.ndarray
        Time since the input was cut [s].
    y0 : float
        Value at ``t = 0`` [unit of y].
    T : float
        Time constant [s] (``m_eff / D``).
    """
    return y0 * np.exp(-np.asarray(t, float) / T)


def step_response(t: np.ndarray, y0: float, y_ss: float, T: float) -> np.ndarray:
    """First-order step response ``y_ss + (y0 - y_ss) exp(-t/T)``.

    Parameters
    ----------
    t : numpy.ndarray
        Time since the input change [s].
    y0 : float
        Value at ``t = 0`` [unit of y].
    y_ss : float
        Steady state [unit of y].
    T : float
        Time constant [s].
    """
    return y_ss + (y0 - y_ss) * np.exp(-np.asarray(t, float) / T)


def decay_jacobian(t: np.ndarray, y0: float, T: float) -> np.ndarray:
    """Jacobian of :func:`decay` with respect to ``(y0, T)``, shape (n, 2).

    Parameters
    ----------
    t, y0, T : numpy.ndarray, float, float
        As in :func:`decay`: time [s], initial value [unit of y], time constant [s].

    Returns
    -------
    numpy.ndarray
        Columns ``dy/dy0`` [-] and ``dy/dT`` [unit of y / s].
    """
    e = np.exp(-np.asarray(t, float) / T)
    return np.column_stack([e, y0 * e * t / T**2])


def step_jacobian(t: np.ndarray, y0: float, y_ss: float, T: float) -> np.ndarray:
    """Jacobian of :func:`step_response` with respect to ``(y0, y_ss, T)``, shape (n, 3).

    Parameters
    ----------
    t, y0, y_ss, T : numpy.ndarray, float, float, float
        As in :func:`step_response`: time [s], initial value and steady state [unit of y], time
        constant [s].

    Returns
    -------
    numpy.ndarray
        Columns ``dy/dy0``, ``dy/dy_ss`` [-] and ``dy/dT`` [unit of y / s].
    """
    e = np.exp(-np.asarray(t, float) / T)
    return np.column_stack([e, 1.0 - e, (y0 - y_ss) * e * t / T**2])


def guess_step(t: np.ndarray, y: np.ndarray) -> dict[str, float]:
    """Closed-form start for :func:`step_response` by integral regression.

    Integrating ``T y_dot = y_ss - y`` from the first sample ``t_a`` gives the linear relation
    ``y(t) = c0 + (y_ss/T) t - (1/T) S(t)`` with ``S(t) = int_{t_a}^t y dt``, so an ordinary linear
    regression of ``y`` on ``[1, t, S]`` yields ``T`` and ``y_ss`` without iteration, and the
    integral averages the noise down (Jacquelin 2009, "Regressions et equations integrales").

    Parameters
    ----------
    t, y : numpy.ndarray
        Time since the input change [s] and data.

    Returns
    -------
    dict
        ``y0``, ``y_ss`` [unit of y] and ``T`` [s].
    """
    t = np.asarray(t, float)
    y = np.asarray(y, float)
    duration = float(t[-1] - t[0])
    s = np.concatenate([[0.0], np.cumsum(0.5 * (y[1:] + y[:-1]) * np.diff(t))])
    c, *_ = np.linalg.lstsq(np.column_stack([np.ones_like(t), t, s]), y, rcond=None)
    if c[2] < 0 and math.isfinite(c[2]):
        T = -1.0 / c[2]
        y_ss = c[1] * T
        ya = c[0] + c[1] * t[0]
        y0 = y_ss + (ya - y_ss) * math.exp(min(t[0] / T, 50.0))
    else:
        # No decay towards a level: the length check downstream will report the segment as too short.
        tail = y[t >= t[0] + 0.9 * duration]
        T, y_ss, y0 = max(duration, 1e-9), float(np.mean(tail)), float(y[0])
    return {"y0": float(y0), "y_ss": float(y_ss), "T": float(T)}
