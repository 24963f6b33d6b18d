"""The free decay of a second-order DOF (roll, pitch after a release): ``A exp(-zeta wn t) cos(wd t + phase)
+ offset``, and its Jacobian. The fit stage (:mod:`pipeline.fit.second_order`) fits it by least squares.
"""

from __future__ import annotations

import math

import numpy as np


def damped_oscillation(t: np.ndarray, A: float, zeta: float, wn: float, phase: float, offset: float) -> np.ndarray:
    """Free decay ``A exp(-zeta wn t) cos(wd t + phase) + offset`` with ``wd = wn sqrt(1 - zeta^2)``.

    Parameters
    ----------
    t : numpy.ndarray
        Time since release [s].
    A : float
        Amplitude [rad or rad/s].
    zeta : float
        Damping ratio [-], 0 <= zeta < 1.
    wn : float
        Undamped natural frequency [rad/s].
    phase : float
        Phase [rad].
    offset : float
        Static offset [rad or rad/s].
    """
    t = np.asarray(t, float)
    wd = wn * math.sqrt(max(1.0 - zeta**2, 0.0))
    return A * np.exp(-zeta * wn * t) * np.cos(wd * t + phase) + offset


def damped_oscillation_jacobian(t: np.ndarray, A: float, zeta: float, wn: float, phase: float,
                                offset: float) -> np.ndarray:
    """Jacobian of :func:`damped_oscillation` with respect to ``(A, zeta, wn, phase, offset)``, shape (n, 5).

    Parameters
    ----------
    t, A, zeta, wn, phase, offset : numpy.ndarray, float, float, float, float, float
        As in :func:`damped_oscillation`; here ``1 - zeta^2`` is floored at 1e-12 so the derivative
        stays finite at ``zeta = 1`` (the offset's column is ones).

    Returns
    -------
    numpy.ndarray
        Columns in that order: derivatives with respect to ``A``, ``zeta``, ``wn``,
        ``phase`` and ``offset``.
    """
    t = np.asarray(t, float)
    root = math.sqrt(max(1.0 - zeta**2, 1e-12))
    wd = wn * root
    e = np.exp(-zeta * wn * t)
    c = np.cos(wd * t + phase)
    s = np.sin(wd * t + phase)
    # d wd / d zeta = -wn zeta / sqrt(1 - zeta^2), d wd / d wn = sqrt(1 - zeta^2)
    d_zeta = A * e * t * (-wn * c + s * wn * zeta / root)
    d_wn = -A * e * t * (zeta * c + root * s)
    return np.column_stack([e * c, d_zeta, d_wn, -A * e * s, np.ones_like(t)])
