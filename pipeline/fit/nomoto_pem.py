"""Wave and measurement-noise model for the Nomoto prediction-error fit (Ljung 1999, ch. 7).

The ship-autopilot seed's augmented model (its eq. 1) is, with ``x = [xi_w, psi_w, psi, r, b]``::

    xi_w_dot  = psi_w
    psi_w_dot = -omega_0^2 xi_w - 2 lambda omega_0 psi_w + K_w w_w
    psi_dot   = r
    r_dot     = (-r + K (delta - b)) / T
    b_dot     = w_b
    y         = psi + psi_w + v

In the identification the bias is a constant parameter (``w_b = 0``) and the ship's initial state
is a parameter too, so the Nomoto block carries no process noise. The steady-state Kalman filter of
the augmented model then decouples: the Nomoto block is deterministic (its error covariance is
zero, so is its gain) and the filter reduces to

    e[k] = H^-1(q) (y[k] - y_sim[k])

where ``y_sim`` is the exact zero-order-hold simulation of the Nomoto model
(:mod:`pipeline.fit.nomoto_oe`) and ``H^-1`` is the steady-state innovations filter of the wave
model plus white measurement noise, built here. ``e`` are the Kalman-filter innovations; the PEM
criterion is ``sum e^2`` (Ljung 1999, eq. 7.12, Box-Jenkins structure). The wave parameters may be
estimated with K and T, or held fixed from a PSD fit. :func:`kalman_innovations` is the plain
time-varying filter of the full augmented model; the tests check that its innovations converge to
those of the decoupled form.

Noise parameters: only the ratio of the wave intensity ``K_w^2`` to the measurement-noise variance
``R`` shapes the filter (the gain is invariant to a common scale), so the fit estimates
``omega_0``, ``lambda`` and ``K_w / sqrt(R)``; the innovation variance then gives ``R`` and ``K_w``
separately (:func:`noise_from_ratio`). The filter's initial wave state is concentrated out of
the criterion (:func:`whiten_profiled`).

References
----------
Ljung, L. (1999). System Identification: Theory for the User, 2nd ed., Prentice Hall, ch. 4, 7, 9.
de Jong, P. (1991). The diffuse Kalman filter. Annals of Statistics 19(2), 1073-1083.
Fossen, T. I. (2021). Handbook of Marine Craft Hydrodynamics and Motion Control, 2nd ed., Wiley,
sec. 10.2.4 (wave-response model).
Van Loan, C. F. (1978). Computing integrals involving the matrix exponential. IEEE Trans. Autom.
Control 23(3), 395-404.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.signal

from ..errors import FitError
from ..model.discretise import expm_small, noise_integral_fast
from ..model.nomoto import HEADING_MODEL_STATES
from ..model.waves import WaveParams, wave_matrices

#: States of the seed's augmented model, in order (:data:`pipeline.model.nomoto.HEADING_MODEL_STATES`).
AUGMENTED_STATES = HEADING_MODEL_STATES
#: The augmented model is :func:`pipeline.model.nomoto.heading_model_matrices` (not redefined here);
#: the exponential :func:`pipeline.model.discretise.expm_small` (re-exported here for existing callers).
__all__ = ["AUGMENTED_STATES", "InnovationFilter", "dare_filter_2x2", "expm_small",
           "guess_wave_noise", "initial_state_response", "innovation_filter", "kalman_innovations",
           "noise_from_ratio", "wave_discrete", "wave_std", "whiten", "whiten_profiled"]
def _inv2(m: np.ndarray) -> np.ndarray:
    det = m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0]
    return np.array([[m[1, 1], -m[0, 1]], [-m[1, 0], m[0, 0]]]) / det


def dare_filter_2x2(ad: np.ndarray, c: np.ndarray, qd: np.ndarray, noise_var: float,
                    tol: float = 1e-13, max_iter: int = 60) -> np.ndarray:
    """A-priori covariance of the steady-state Kalman filter of a 2-state, 1-output model.

    Solves ``P = A P A^T - A P C^T (C P C^T + R)^-1 C P A^T + Q`` by the structure-preserving
    doubling algorithm (Chu, Fan, Lin & Wang 2004), which converges quadratically, with closed-form
    2x2 inverses (no LAPACK call; see :func:`pipeline.model.discretise.expm_small` for why). The tests check it against
    :func:`scipy.linalg.solve_discrete_are`.

    Parameters
    ----------
    ad : numpy.ndarray, shape (2, 2)
        Discrete system matrix.
    c : numpy.ndarray, shape (1, 2)
        Output row.
    qd : numpy.ndarray, shape (2, 2)
        Process-noise covariance per sample.
    noise_var : float
        Measurement-noise variance ``R``.
    tol : float
        Relative change of ``P`` at which the doubling stops.
    max_iter : int
        Doubling steps (each squares the horizon: 60 is far beyond any use).
    """
    # Control-form DARE with A = Ad^T, B = C^T: A0 = A, G0 = B R^-1 B^T, H0 = Q.
    a = ad.T.copy()
    g = c.T @ c / noise_var
    hh = np.array(qd, float)
    eye = np.eye(2)
    for _ in range(max_iter):
        w = _inv2(eye + g @ hh)
        a_new = a @ w @ a
        g_new = g + a @ w @ g @ a.T
        h_new = hh + a.T @ hh @ w @ a
        done = np.abs(h_new - hh).max() <= tol * max(np.abs(h_new).max(), 1e-300)
        a, g, hh = a_new, g_new, h_new
        if done:
            break
    else:
        raise FitError("innovation filter: the Riccati doubling did not converge (wave damping not positive?)")
    return 0.5 * (hh + hh.T)


@dataclass(frozen=True)
class InnovationFilter:
    """Steady-state Kalman predictor of the wave model plus white measurement noise.

    Attributes
    ----------
    ad, qd : numpy.ndarray, shape (2, 2)
        Discrete wave model and its process-noise covariance per sample [rad^2] (Van Loan).
    c : numpy.ndarray, shape (1, 2)
        Output row (``psi_w``).
    gain : numpy.ndarray, shape (2, 1)
        Predictor gain ``L = A P C^T (C P C^T + R)^-1`` [-].
    p : numpy.ndarray, shape (2, 2)
        A-priori error covariance of the steady-state filter [rad^2].
    innovation_var : float
        ``C P C^T + R`` [rad^2]: the variance of the innovations when the model is right.
    noise_var : float
        ``R`` the filter was built with [rad^2 per sample].
    num, den : numpy.ndarray
        ``H^-1(q)`` as a transfer function (monic ``den``), for :func:`scipy.signal.lfilter`.
    """

    ad: np.ndarray
    qd: np.ndarray
    c: np.ndarray
    gain: np.ndarray
    p: np.ndarray
    innovation_var: float
    noise_var: float
    num: np.ndarray
    den: np.ndarray


#: Above this ``lambda omega_0 h`` the wave noise integral is taken from the stationary covariance
#: (below it, Van Loan's block, whose growing exponential is at most e^0.5 there, keeps the digits).
VAN_LOAN_MAX_DECAY = 0.5


def wave_discrete(waves: WaveParams, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact discretisation of the wave model: ``(A_d, Q_d)`` for sample time ``h`` (Van Loan 1978).

    Parameters
    ----------
    waves : WaveParams
        omega_0 [rad/s], lambda [-], K_w [rad s^-1/2] (unit-intensity driving noise).
    h : float
        Sample time [s].

    Returns
    -------
    ad : numpy.ndarray, shape (2, 2)
        ``exp(A_w h)``.
    qd : numpy.ndarray, shape (2, 2)
        ``int_0^h exp(A_w s) E E^T exp(A_w^T s) ds`` [rad^2].
    """
    a, e, _ = wave_matrices(waves)
    decay = waves.lam * waves.omega0 * h
    if not decay > VAN_LOAN_MAX_DECAY:
        return noise_integral_fast(a, e @ e.T, h)
    # Van Loan's block holds exp(+lambda omega_0 h), which overflows for a fast-decaying wave
    # model (the solver may try one); for a stable A_w the same integral is
    # Q_d = P - A_d P A_d^T with P the stationary covariance (A P + P A^T + E E^T = 0):
    # P = diag(K_w^2 / (4 lambda omega_0^3), K_w^2 / (4 lambda omega_0)), no growing exponential.
    ad = expm_small(a * h)
    w0, kw2 = waves.omega0, waves.kw**2
    p = np.diag([kw2 / (4.0 * waves.lam * w0**3), kw2 / (4.0 * waves.lam * w0)])
    qd = p - ad @ p @ ad.T
    return ad, 0.5 * (qd + qd.T)


def innovation_filter(waves: WaveParams, noise_var: float, h: float) -> InnovationFilter:
    """Steady-state innovations filter ``H^-1(q)`` of ``psi_w + v`` (Kalman predictor form).

    Parameters
    ----------
    waves : WaveParams
        Wave model; ``kw = 0`` gives ``H^-1 = 1`` (white noise only).
    noise_var : float
        Variance of the sampled measurement noise ``v`` [rad^2] (> 0).
    h : float
        Sample time [s].

    Returns
    -------
    InnovationFilter

    Raises
    ------
    FitError
        Non-positive noise variance or sample time, or a Riccati equation without a stabilising
        solution (wave damping not positive).
    """
    if not (noise_var > 0 and h > 0):
        raise FitError(f"innovation filter: expected noise_var > 0 and h > 0, found {noise_var}, {h}")
    if not (waves.omega0 > 0 and waves.lam > 0):
        raise FitError(f"innovation filter: expected omega0 > 0 and lambda > 0, found {waves.omega0}, {waves.lam}")
    ad, qd = wave_discrete(waves, h)
    c = np.array([[0.0, 1.0]])
    p = dare_filter_2x2(ad, c, qd, noise_var)
    s = float((c @ p @ c.T)[0, 0] + noise_var)
    gain = ad @ p @ c.T / s
    # x_hat[k+1] = F x_hat[k] + L w[k], e[k] = w[k] - C x_hat[k] with F = A - L C, so
    # H^-1(z) = 1 - C (zI - F)^-1 L = (det(zI - F) - C adj(zI - F) L) / det(zI - F).
    f = ad - gain @ c
    den = np.array([1.0, -(f[0, 0] + f[1, 1]), f[0, 0] * f[1, 1] - f[0, 1] * f[1, 0]])
    adj1 = np.eye(2)                                  # coefficient of z in adj(zI - F)
    adj0 = np.array([[-f[1, 1], f[0, 1]], [f[1, 0], -f[0, 0]]])
    cl1 = float((c @ adj1 @ gain)[0, 0])
    cl0 = float((c @ adj0 @ gain)[0, 0])
    num = np.array([1.0, den[1] - cl1, den[2] - cl0])
    return InnovationFilter(ad=ad, qd=qd, c=c, gain=gain, p=p, innovation_var=s, noise_var=float(noise_var),
                            num=num, den=den)


def whiten(filt: InnovationFilter, w: np.ndarray) -> np.ndarray:
    """Innovations ``e = H^-1(q) w`` of an output-error sequence ``w = y - y_sim`` [rad].

    The filter starts from ``x_hat = 0``, as a steady-state Kalman filter started without prior
    information on the waves would; its transient lasts a few wave periods.

    Parameters
    ----------
    filt : InnovationFilter
        From :func:`innovation_filter`.
    w : numpy.ndarray
        Output error on a uniform grid [rad].
    """
    return scipy.signal.lfilter(filt.num, filt.den, np.asarray(w, float))


def initial_state_response(filt: InnovationFilter, n: int) -> np.ndarray:
    """Innovations caused by a unit error in the filter's initial wave state, shape (n, 2).

    With ``x_hat[0] = x0`` instead of 0 the innovations change by ``-C F^k x0``,
    ``F = A - L C``. Column ``j`` is that response for ``x0 = e_j``; the sequence obeys the
    characteristic recursion of ``F``, so it is a second-order IIR filter's impulse response.

    Parameters
    ----------
    filt : InnovationFilter
        From :func:`innovation_filter`.
    n : int
        Samples.
    """
    f = filt.ad - filt.gain @ filt.c
    a1, a2 = -(f[0, 0] + f[1, 1]), f[0, 0] * f[1, 1] - f[0, 1] * f[1, 0]
    impulse = np.zeros(n)
    impulse[0] = 1.0
    out = np.empty((n, 2))
    c = filt.c.ravel()
    for j in range(2):
        s0 = -c[j]
        s1 = -float(c @ f[:, j])
        out[:, j] = scipy.signal.lfilter([s0, s1 + a1 * s0], [1.0, a1, a2], impulse)
    return out


def whiten_profiled(filt: InnovationFilter, w: np.ndarray, phi: np.ndarray | None = None) -> np.ndarray:
    """Innovations with the initial wave state concentrated out (diffuse initialisation).

    The filter's initial wave state is unknown (the record starts in a sea already running); its
    influence on the innovations, ``-C F^k x0``, decays with the filter's slowest pole (a few
    hundred samples for the seed's waves). Started from ``x0 = 0`` those early innovations are too
    large and leak into the initial-condition and ship parameters, which makes the errors larger
    than the Jacobian covariance says. Here ``x0`` is chosen by linear least squares at every
    evaluation (a variable projection; cf. the diffuse Kalman filter of de Jong 1991), which
    costs two filtered impulses and a 2x2 solve.

    Parameters
    ----------
    filt : InnovationFilter
        From :func:`innovation_filter`.
    w : numpy.ndarray
        Output error ``y - y_sim`` [rad], uniformly sampled without gaps.
    phi : numpy.ndarray, optional
        :func:`initial_state_response` for ``len(w)`` samples (computed when omitted).

    Returns
    -------
    numpy.ndarray
        Innovations [rad].
    """
    e0 = whiten(filt, w)
    phi = initial_state_response(filt, e0.size) if phi is None else phi
    g = phi.T @ phi
    rhs = phi.T @ e0
    det = g[0, 0] * g[1, 1] - g[0, 1] * g[1, 0]
    if not det > 1e-300:
        return e0
    x0 = np.array([g[1, 1] * rhs[0] - g[0, 1] * rhs[1], g[0, 0] * rhs[1] - g[1, 0] * rhs[0]]) / det
    return e0 - phi @ x0


def noise_from_ratio(omega0: float, lam: float, ratio: float, innovation_var: float,
                     h: float) -> tuple[WaveParams, float]:
    """``(WaveParams, R)`` from the shape parameters and the observed innovation variance.

    With ``R = 1`` the filter's innovation variance is ``s1 = C P1 C^T + 1``; every covariance
    scales with ``R``, so ``R = innovation_var / s1`` and ``K_w = ratio sqrt(R)``.

    Parameters
    ----------
    omega0, lam : float
        Peak frequency [rad/s] and relative damping [-].
    ratio : float
        ``K_w / sqrt(R)`` [s^-1/2].
    innovation_var : float
        Mean square of the innovations [rad^2].
    h : float
        Sample time [s].

    Returns
    -------
    waves : WaveParams
        With ``kw`` [rad s^-1/2].
    noise_var : float
        Measurement-noise variance per sample [rad^2].
    """
    unit = innovation_filter(WaveParams(omega0, lam, ratio), 1.0, h)
    r = innovation_var / unit.innovation_var
    return WaveParams(omega0=float(omega0), lam=float(lam), kw=float(ratio * math.sqrt(r))), float(r)


def wave_std(waves: WaveParams) -> float:
    """Stationary standard deviation of ``psi_w`` [rad]: ``K_w / sqrt(4 lambda omega_0)``.

    Parameters
    ----------
    waves : WaveParams
        Wave model (``kw`` for unit-intensity driving noise).
    """
    return float(waves.kw / math.sqrt(4.0 * waves.lam * waves.omega0))


def guess_wave_noise(w: np.ndarray, fs: float, noise_std: float) -> tuple[float, float, float]:
    """Start values ``(omega_0, lambda, K_w / sqrt(R))`` from an output-error sequence.

    ``omega_0`` is the peak of a Welch periodogram above ten record-frequencies (below that the
    residual is dominated by model error, not by waves); ``lambda`` starts at 0.1 (the seed's
    0.09); ``K_w`` from the variance left after the white noise: ``var(psi_w) = K_w^2 / (4 lambda
    omega_0)``.

    Parameters
    ----------
    w : numpy.ndarray
        Output error ``y - y_sim`` [rad] on a uniform grid.
    fs : float
        Sample rate [Hz].
    noise_std : float
        Standard deviation of the white measurement noise [rad] (e.g. from second differences).
    """
    w = np.asarray(w, float)
    w = w[np.isfinite(w)]
    n = w.size
    nper = int(min(n, 4096))
    f, pxx = scipy.signal.welch(w - w.mean(), fs=fs, nperseg=nper, detrend="linear")
    omega = 2 * np.pi * f
    low = 10 * 2 * np.pi * fs / max(n, 1)
    band = (omega > max(low, 0.05)) & (omega < 0.8 * np.pi * fs)
    omega0 = float(omega[band][np.argmax(pxx[band])]) if band.any() else 0.8
    lam = 0.1
    sv = noise_std if (math.isfinite(noise_std) and noise_std > 0) else 1e-3 * float(np.std(w) + 1e-12)
    var_w = max(float(np.var(w)) - sv**2, 0.01 * sv**2)
    kw = math.sqrt(var_w * 4 * lam * omega0)
    return omega0, lam, kw / sv


def kalman_innovations(ad: np.ndarray, bd: np.ndarray, c: np.ndarray, qd: np.ndarray, noise_var: float,
                       x0: np.ndarray, p0: np.ndarray, u: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Innovations of the time-varying Kalman filter (reference implementation, one output).

    ``x[k+1] = A x[k] + B u[k] + w[k]``, ``cov w = Q``; ``y[k] = C x[k] + v[k]``, ``var v = R``.
    A non-finite ``y[k]`` skips the update (innovation NaN).

    Parameters
    ----------
    ad, bd, c, qd : numpy.ndarray
        Discrete model (``bd`` shape (n, 1)) and process-noise covariance.
    noise_var : float
        ``R`` [output unit^2].
    x0, p0 : numpy.ndarray
        Prior mean and covariance of ``x[0]``.
    u, y : numpy.ndarray, shape (N,)
        Input and measurements.

    Returns
    -------
    e : numpy.ndarray, shape (N,)
        Innovations ``y[k] - C x[k|k-1]``.
    s : numpy.ndarray, shape (N,)
        Their variances ``C P C^T + R``.
    """
    x = np.array(x0, float)
    p = np.array(p0, float)
    n = len(y)
    e = np.full(n, np.nan)
    s = np.full(n, np.nan)
    for k in range(n):
        sk = float((c @ p @ c.T)[0, 0]) + noise_var
        s[k] = sk
        if np.isfinite(y[k]):
            e[k] = y[k] - float((c @ x)[0])
            g = p @ c.T / sk
            x = x + (g * e[k]).ravel()
            p = p - g @ c @ p
        x = ad @ x + bd.ravel() * u[k]
        p = ad @ p @ ad.T + qd
    return e, s
