"""Damping coefficients derived from fitted model parameters, with first-order (delta-method)
propagation of the parameter covariance: ``var f(p) = g^T C g`` with ``g = df/dp``.

Single-DOF relations (Fossen 2021, sec. 6.4; DOF order u v p q r):

- first order:  ``D_ii = m_eff / T``;  ``se_D = m_eff se_T / T^2``
- step gain:    ``D_ii = delta_tau / (y_ss - y0)`` when the input is the DOF's generalised force
- free decay:   ``D_ii = 2 zeta wn I_eff``; ``wn`` is checked against ``sqrt(C / I_eff)``

``m_eff`` and ``I_eff`` are the diagonal of ``M = M_RB + M_A`` from the vessel config.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ..records import SegmentFit


def propagate(gradient: Sequence[float], covariance: np.ndarray) -> float:
    """Standard error of ``f(p)`` from its gradient and the covariance of ``p`` (delta method).

    Parameters
    ----------
    gradient : sequence of float
        ``df/dp`` at the estimate.
    covariance : numpy.ndarray
        Covariance of ``p``.

    Returns
    -------
    float
        ``sqrt(g^T C g)``; NaN when the covariance is not finite.
    """
    g = np.asarray(gradient, float)
    c = np.asarray(covariance, float)
    if not np.all(np.isfinite(c)):
        return math.nan
    return float(math.sqrt(max(float(g @ c @ g), 0.0)))


def sub_covariance(fit: SegmentFit, names: Sequence[str]) -> np.ndarray:
    """Covariance block of the parameters ``names`` of a segment fit.

    Parameters
    ----------
    fit : SegmentFit
        The segment fit; its ``param_names`` give the covariance order.
    names : Sequence[str]
        Parameters wanted, in the order of the returned block (``ValueError`` when one is not
        a parameter of the fit).

    Returns
    -------
    numpy.ndarray
        ``len(names) x len(names)`` covariance [products of the parameters' units].
    """
    idx = [fit.param_names.index(n) for n in names]
    return np.asarray(fit.covariance, float)[np.ix_(idx, idx)]


def damping_from_time_constant(m_eff: float, T: float, se_T: float) -> tuple[float, float]:
    """Linear damping ``D = m_eff / T`` of a first-order DOF.

    Parameters
    ----------
    m_eff : float
        Effective mass or inertia ``M[i, i]`` [kg or kg m^2].
    T : float
        Time constant [s].
    se_T : float
        Standard error of ``T`` [s].

    Returns
    -------
    tuple[float, float]
        ``D`` and its standard error [kg/s or kg m^2/s], positive.
    """
    return m_eff / T, m_eff * se_T / T**2


def damping_from_decay(inertia: float, fit: SegmentFit) -> tuple[float, float]:
    """Linear damping ``D = 2 zeta wn I_eff`` of a free decay.

    Parameters
    ----------
    inertia : float
        Effective inertia ``I_eff`` [kg m^2].
    fit : SegmentFit
        A ``damped_oscillation`` fit (``zeta``, ``wn`` and their covariance).

    Returns
    -------
    tuple[float, float]
        ``D`` and its standard error [kg m^2/s], positive; the zeta-wn correlation is included.
    """
    zeta, wn = fit.params["zeta"], fit.params["wn"]
    grad = [2 * wn * inertia, 2 * zeta * inertia]
    return 2 * zeta * wn * inertia, propagate(grad, sub_covariance(fit, ("zeta", "wn")))


def natural_frequency_ratio(fit: SegmentFit, restoring: float, inertia: float) -> tuple[float, float]:
    """Fitted ``wn`` over the config's ``sqrt(C / I_eff)`` [-].

    Parameters
    ----------
    fit : SegmentFit
        A ``damped_oscillation`` fit.
    restoring : float
        Restoring stiffness ``C`` [N m/rad].
    inertia : float
        Effective inertia ``I_eff`` [kg m^2].

    Returns
    -------
    tuple[float, float]
        Ratio and standard error; 1 when the config's mass and restoring agree with the data.
    """
    wn_cfg = math.sqrt(restoring / inertia)
    return fit.params["wn"] / wn_cfg, fit.stderr["wn"] / wn_cfg


def step_gain(fit: SegmentFit, input_before: float, input_after: float, formulation: str) -> tuple[float, float]:
    """Input gain of a first-order step [unit of y per unit of input].

    ``change``: ``(y_ss - y0) / (input_after - input_before)`` (steady before the step);
    ``level``: ``y_ss / input_after`` (no offset). See :func:`pipeline.fit.data.gain_formulation`.
    The gain is ``1 / D`` when the input is the DOF's generalised force.

    Parameters
    ----------
    fit : SegmentFit
        A ``first_order_step`` fit.
    input_before, input_after : float
        Input levels [SI unit of the input].
    formulation : str
        ``change`` or ``level``.

    Returns
    -------
    tuple[float, float]
        Gain and standard error.
    """
    cov = sub_covariance(fit, ("y0", "y_ss"))
    y0, y_ss = fit.params["y0"], fit.params["y_ss"]
    if formulation == "level":
        return y_ss / input_after, propagate([0.0, 1.0 / input_after], cov)
    du = input_after - input_before
    return (y_ss - y0) / du, propagate([-1.0 / du, 1.0 / du], cov)


def damping_from_gain(fit: SegmentFit, input_before: float, input_after: float,
                      formulation: str) -> tuple[float, float]:
    """Gain-based damping ``D = 1 / gain`` of a first-order step in the DOF's generalised force.

    Parameters
    ----------
    fit : SegmentFit
        A ``first_order_step`` fit.
    input_before, input_after : float
        Force or moment before and after the step [N or N m].
    formulation : str
        ``change`` or ``level`` (see :func:`step_gain`).

    Returns
    -------
    tuple[float, float]
        ``D`` and standard error [kg/s or kg m^2/s]; ``se_D = se_gain / gain^2``.
    """
    gain, se = step_gain(fit, input_before, input_after, formulation)
    return 1.0 / gain, se / gain**2
