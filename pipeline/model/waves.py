"""Second-order linear wave-response model (Fossen 2021, sec. 10.2.4; the ship-autopilot seed).

    psi_w(s) / w_w(s) = K_w s / (s^2 + 2 lambda omega_0 s + omega_0^2)

in state space with ``xi_w_dot = psi_w`` and
``psi_w_dot = -omega_0^2 xi_w - 2 lambda omega_0 psi_w + K_w w_w``, ``w_w`` unit-intensity white noise.
The wave-induced heading ``psi_w`` adds to the measured compass heading.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from ._backend import ops

WAVE_STATES = ("xi_w", "psi_w")


@dataclass(frozen=True)
class WaveParams:
    """Parameters of the wave-response model.

    Attributes
    ----------
    omega0 : float
        Dominating (peak) wave frequency [rad/s].
    lam : float
        Relative damping lambda [-].
    kw : float
        Gain K_w [rad s^-1/2 per unit white noise]; ``K_w = 2 lambda omega_0 sigma``.
    """

    omega0: float
    lam: float
    kw: float


def wave_matrices(params: WaveParams) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """State-space ``(A_w, E_w, C_w)`` of the wave model: x_dot = A_w x + E_w w, psi_w = C_w x.

    Parameters
    ----------
    params : WaveParams
        Peak frequency ``omega0`` [rad/s], damping ``lam`` [-] and gain ``kw``.

    Returns
    -------
    a, e, c : numpy.ndarray
        ``A_w`` (2x2), ``E_w`` (2x1) and ``C_w`` (1x2), state order ``WAVE_STATES``
        (Fossen 2021, sec. 10.2.4).
    """
    w0, lam = params.omega0, params.lam
    a = np.array([[0.0, 1.0], [-w0**2, -2 * lam * w0]])
    e = np.array([[0.0], [params.kw]])
    c = np.array([[0.0, 1.0]])
    return a, e, c


def wave_rhs(t, x, u, params: WaveParams):
    """Right-hand side ``f(t, x, u, params)`` with ``u = [w_w]`` the driving noise sample.

    Parameters
    ----------
    t : float
        Time [s]; unused (the model is time-invariant), kept for the common signature.
    x : array_like or casadi.SX
        State ``[xi_w, psi_w]`` [rad s, rad]; a casadi symbol gives a casadi expression.
    u : array_like or casadi.SX
        ``[w_w]``, the unit-intensity white-noise sample [-].
    params : WaveParams
        Wave model.

    Returns
    -------
    numpy.ndarray or casadi.SX
        ``[xi_w_dot, psi_w_dot]`` [rad, rad/s].
    """
    o = ops(x)
    w0, lam = params.omega0, params.lam
    return o.stack([x[1], -w0**2 * x[0] - 2 * lam * w0 * x[1] + params.kw * u[0]])


def wave_psd(omega: np.ndarray, params: WaveParams) -> np.ndarray:
    """Power spectral density |H(j omega)|^2 of psi_w for unit-intensity white noise [rad^2 s].

    ``P(omega) = |H(j omega)|^2 = K_w^2 omega^2 / ((omega_0^2 - omega^2)^2 + (2 lambda omega_0 omega)^2)``.

    Parameters
    ----------
    omega : array_like
        Frequencies [rad/s].
    params : WaveParams
        Wave model.
    """
    w = np.asarray(omega, float)
    w0, lam = params.omega0, params.lam
    return params.kw**2 * w**2 / ((w0**2 - w**2) ** 2 + (2 * lam * w0 * w) ** 2)


def simulate_waves(t: np.ndarray, params: WaveParams, rng: np.random.Generator) -> np.ndarray:
    """Sample psi_w [rad] on the uniform grid ``t`` exactly (Van Loan discretisation of the noise).

    Parameters
    ----------
    t : numpy.ndarray
        Uniform time grid [s].
    params : WaveParams
        Wave model.
    rng : numpy.random.Generator
        Seeded generator.

    Returns
    -------
    numpy.ndarray
        Wave-induced heading psi_w(t) [rad].
    """
    if len(t) < 2:
        return np.zeros(len(t))
    h = float(t[1] - t[0])
    a, e, c = wave_matrices(params)
    n = a.shape[0]
    # Van Loan (1978): exp([[-A, E E^T], [0, A^T]] h) gives Ad and Qd exactly.
    big = np.zeros((2 * n, 2 * n))
    big[:n, :n] = -a
    big[:n, n:] = e @ e.T
    big[n:, n:] = a.T
    ex = scipy.linalg.expm(big * h)
    ad = ex[n:, n:].T
    qd = ad @ ex[:n, n:]
    qd = 0.5 * (qd + qd.T)
    lq = np.linalg.cholesky(qd + 1e-18 * np.eye(n))
    # Start in the stationary distribution so there is no transient: P = Ad P Ad^T + Qd.
    p_stat = scipy.linalg.solve_discrete_lyapunov(ad, qd)
    x = np.linalg.cholesky(p_stat + 1e-18 * np.eye(n)) @ rng.standard_normal(n)
    out = np.empty(len(t))
    noise = rng.standard_normal((len(t), n))
    for k in range(len(t)):
        out[k] = (c @ x)[0]
        x = ad @ x + lq @ noise[k]
    return out
