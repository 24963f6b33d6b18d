"""Cramer-Rao lower bounds for the fits, for the same design and noise as the data.

For ``y = f(theta) + v`` with white Gaussian ``v`` of variance ``sigma^2`` the Fisher information is
``J^T J / sigma^2`` with ``J = df/dtheta`` at the true parameters, and no unbiased estimator beats
its inverse. For the prediction-error model ``y = G(q, theta) u + H(q) e`` the information of the
ship parameters is ``sum psi psi^T / lambda`` with ``psi = H^-1(q) dy_sim/dtheta`` and ``lambda`` the
innovation variance (Ljung 1999, sec. 9.3, eq. 9.29): the whitened sensitivities. In open loop it
does not couple to the noise-model parameters, so this is the bound for K, T, b and the initial
states whether the wave parameters are known or estimated (Ljung 1999, sec. 9.4).

References
----------
Ljung, L. (1999). System Identification: Theory for the User, 2nd ed., Prentice Hall, sec. 7.4, 9.3.
Kay, S. M. (1993). Fundamentals of Statistical Signal Processing: Estimation Theory, Prentice Hall,
ch. 3.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from pipeline.errors import FitError
from pipeline.model.waves import WaveParams
from pipeline.fit.first_order import decay_jacobian
from pipeline.fit.nomoto_problem import DYNAMIC_PARAMS, NomotoRecord, Problem, prepare, start_vector
from pipeline.fit.nomoto_pem import innovation_filter


def least_squares_crlb(jacobian: np.ndarray, noise_var: float) -> np.ndarray:
    """Cramer-Rao bound ``sigma^2 (J^T J)^-1`` for white Gaussian noise.

    Parameters
    ----------
    jacobian : numpy.ndarray, shape (n, p)
        Sensitivities of the noise-free model output at the true parameters.
    noise_var : float
        Noise variance [output unit^2].

    Returns
    -------
    numpy.ndarray, shape (p, p)
        Covariance bound.
    """
    j = np.asarray(jacobian, float)
    scale = np.linalg.norm(j, axis=0)
    if np.any(scale == 0):
        raise FitError("CRLB: a parameter does not affect the output (zero Jacobian column)")
    js = j / scale
    return np.linalg.inv(js.T @ js) / np.outer(scale, scale) * noise_var


def decay_crlb(t: np.ndarray, y0: float, T: float, noise_var: float) -> np.ndarray:
    """Bound on ``(y0, T)`` of ``y0 exp(-t/T)`` sampled at ``t`` with white noise (a coast-down).

    Parameters
    ----------
    t : numpy.ndarray
        Sample times from the input cut [s].
    y0 : float
        Initial velocity [m/s or rad/s].
    T : float
        Time constant [s].
    noise_var : float
        Velocity noise variance [(m/s)^2 or (rad/s)^2].
    """
    return least_squares_crlb(decay_jacobian(np.asarray(t, float), y0, T), noise_var)


def nomoto_crlb(designs: Sequence[NomotoRecord], truth: Mapping[str, float], initial: Sequence[Mapping[str, float]],
                noise_var: Mapping[str, float], order: int = 1, bias: bool = True,
                channels: Sequence[str] = ("psi",), waves: WaveParams | None = None) -> tuple[tuple[str, ...], np.ndarray]:
    """Cramer-Rao bound of the whole-record Nomoto fit for a given rudder design and noise.

    Parameters
    ----------
    designs : sequence of NomotoRecord
        Time grid and rudder of every record (the measured channels are not used; give any array
        of the right length, or None).
    truth : Mapping[str, float]
        ``K`` [1/s], ``T`` [s] (or ``T1``, ``T2``, ``T3``), ``b`` [rad].
    initial : sequence of Mapping[str, float]
        Per record ``psi0`` [rad], ``r0`` [rad/s] (and ``rdot0`` for order 2).
    noise_var : Mapping[str, float]
        White measurement-noise variance per channel (``psi`` [rad^2], ``r`` [(rad/s)^2]).
    order : int
        1 or 2.
    bias : bool
        Whether b is estimated (a parameter of the bound).
    channels : sequence of str
        Measured outputs.
    waves : WaveParams, optional
        Wave model on the compass: the bound is then the PEM one (whitened sensitivities).

    Returns
    -------
    names : tuple[str, ...]
        Parameter names, as :func:`pipeline.fit.nomoto_oe.fit_nomoto` names them.
    covariance : numpy.ndarray
        The bound.
    """
    channels = tuple(channels)
    recs = [NomotoRecord(d.t, d.delta, np.zeros(len(d.t)) if "psi" in channels else None,
                         np.zeros(len(d.t)) if "r" in channels else None, d.name) for d in designs]
    preps = [prepare(r, i, channels) for i, r in enumerate(recs)]
    if waves is not None:
        prob = Problem(preps, order, bias, channels, "waves", waves, noise_var["psi"])
    else:
        prob = Problem(preps, order, bias, channels, "white", None, None)
    dyn = [truth[n] for n in DYNAMIC_PARAMS[order]]
    ics = []
    for ini in initial:
        ic = ([ini.get("psi0", 0.0)] if "psi" in channels else []) + [ini.get("r0", 0.0)]
        ics.append(ic + ([ini.get("rdot0", 0.0)] if order == 2 else []))
    z = start_vector(prob, dyn, truth.get("b", 0.0), ics, ())
    # Noise-free data at the truth: the residual Jacobian is then exactly the (whitened) sensitivity.
    sims = [prob.simulate(z, i) for i in range(len(preps))]
    prob.recs = [type(p)(h=p.h, u=p.u, y={ch: sims[i][ch] for ch in channels}, mask=p.mask, duration=p.duration,
                         name=p.name) for i, p in enumerate(preps)]
    prob._sim_cache.clear()
    for ch in channels:
        if ch == "psi" and waves is not None:
            lam = innovation_filter(waves, noise_var["psi"], preps[0].h).innovation_var
        else:
            lam = noise_var[ch]
        prob.weights[ch] = 1.0 / np.sqrt(lam)
    jac = prob.jacobian(z)
    cov = least_squares_crlb(jac, 1.0)
    # Solver space (log T) -> SI.
    theta = prob.natural(z)
    d = np.where(prob.log_mask, theta, 1.0)
    return tuple(prob.names), cov * np.outer(d, d)
