"""Discrete Kalman filter for the heading autopilot: model, observability, Van Loan discretisation, filter.

Process model (the ship-autopilot seed's, Fossen 2021 sec. 13.3), state ``x = [xi_w, psi_w, psi, r, b]``::

    xi_w_dot  = psi_w
    psi_w_dot = -omega_0^2 xi_w - 2 lambda omega_0 psi_w + K_w w_w
    psi_dot   = r
    r_dot     = (-r + K (delta - b)) / T                 (pipeline.model.nomoto_rhs)
    b_dot     = w_b
    y         = psi + psi_w + v

so ``x_dot = A x + B delta + E w`` with ``w = [w_w, w_b]`` continuous white noise of intensity
``Q = diag(q_w, q_b)`` (``E[w(t) w(t')^T] = Q delta(t - t')``), and ``y[k] = C x(t_k) + v[k]`` with
``v[k]`` a *sampled* noise of variance ``R`` [rad^2].

Discretisation (Van Loan 1978), exact for a zero-order-held rudder::

    expm([[A, B, E], [0, 0, 0]] h)    = [[A_d, B_d, E_d], [0, I, 0]]
    expm([[-A, E Q E^T], [0, A^T]] h) = [[., F_12], [0, F_22]],   A_d = F_22^T,   Q_d = F_22^T F_12

``Q_d = int_0^h exp(A s) E Q E^T exp(A^T s) ds`` is the covariance of the state increment the noise
causes over one sample. The seed used ``E_d Q E_d^T`` instead, which treats ``w`` as a piecewise-constant
sequence of variance Q: it has the wrong units (Q is an intensity), is rank 2 instead of 5 (it
misses that bias noise reaches r and psi within the sample), and scales with h^2 instead of h.
``E_d`` is still given for completeness (it maps a zero-order-held *deterministic* w).

Measurement noise: ``R`` is the variance of the sampled compass noise, measured directly as the
variance of a record taken at rest (the seed's 5.5.b). A continuous white noise of intensity
``R_c`` [rad^2 s] seen through an ideal averaging (anti-alias) filter over one sample interval ``h``
has sample variance ``R = R_c / h``; conversely ``R_c = R h``. The seed measured the sampled variance
and then divided by h once more (``R = var / Ts``), which mixes the two: for 10 Hz it over-states R
tenfold (and in units of rad^2/s).

References
----------
Van Loan, C. F. (1978). Computing integrals involving the matrix exponential. IEEE Trans. Autom.
Control 23(3), 395-404.
Brown, R. G., Hwang, P. Y. C. (2012). Introduction to Random Signals and Applied Kalman Filtering,
4th ed., Wiley, sec. 3.9 (Van Loan's method), ch. 4 (the discrete filter, Joseph form).
Fossen, T. I. (2021). Handbook of Marine Craft Hydrodynamics and Motion Control, 2nd ed., Wiley.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from ..errors import AutopilotError
from ..geo import wrap_pi
from ..model import discretise
from ..model.nomoto import HEADING_MODEL_STATES, heading_model_matrices
from ..model.waves import WaveParams
from ..records import KalmanModel
from .defaults import DEFAULT_Q  # the default lives where the CLI's --help can read it

#: Filter states, in order.
KALMAN_STATES = HEADING_MODEL_STATES
#: Default initial a-priori covariance diagonal (the seed's hand-out) [rad^2 s^2, rad^2, rad^2, rad^2/s^2, rad^2].
DEFAULT_P0 = (1.0, 0.013, math.pi**2, 1.0, 2.5e-3)
#: Default sampled compass-noise variance [rad^2]: the course simulator's compass, 0.002 deg^2
#: (band-limited white noise Cov = 0.001 at Ts = 0.5 s, so Cov/Ts), which the seed measured as 6.08e-7 rad^2.
DEFAULT_R = 0.002 * (math.pi / 180.0) ** 2


# --------------------------------------------------------------------------- continuous model
def _checked_model(K: float, T: float, waves: WaveParams):
    """:func:`pipeline.model.nomoto.heading_model_matrices` after checking K and T."""
    if not (math.isfinite(K) and math.isfinite(T) and T > 0):
        raise AutopilotError(f"Nomoto model: expected finite K and T > 0, found K={K!r}, T={T!r}")
    return heading_model_matrices(K, T, waves)


#: The seed's four model variants (part IV): state indices kept from the 5-state model.
MODEL_VARIANTS = {
    "no disturbances": (2, 3),
    "current": (2, 3, 4),
    "waves": (0, 1, 2, 3),
    "current and waves": (0, 1, 2, 3, 4),
}


def observability_matrix(a: np.ndarray, c: np.ndarray) -> np.ndarray:
    """``[C; C A; ...; C A^(n-1)]``.

    Parameters
    ----------
    a : numpy.ndarray
        State matrix A (n x n).
    c : numpy.ndarray
        Output matrix C (m x n).

    Returns
    -------
    numpy.ndarray
        Observability matrix (n m x n); the pair is observable when its rank is n.
    """
    n = a.shape[0]
    rows = [c]
    for _ in range(n - 1):
        rows.append(rows[-1] @ a)
    return np.vstack(rows)


def observability(K: float, T: float, waves: WaveParams) -> dict[str, dict]:
    """Observability rank of each of the seed's four model variants.

    The variants drop states the seed's part IV switched off: without waves the compass sees
    ``psi`` only (``C = [1, 0, ...]``), without current the bias state is removed.

    Parameters
    ----------
    K, T : float
        Nomoto gain [1/s] and time constant [s].
    waves : WaveParams
        Wave model.

    Returns
    -------
    dict
        Variant name -> ``{"states", "rank", "n", "observable", "condition"}``; ``condition`` is the
        2-norm condition number of the observability matrix (large values: weakly observable).
    """
    a, _, _, c = _checked_model(K, T, waves)
    out = {}
    for name, keep in MODEL_VARIANTS.items():
        idx = np.array(keep)
        a_v = a[np.ix_(idx, idx)]
        c_v = c[:, idx]  # without the wave states the compass sees psi alone
        o = observability_matrix(a_v, c_v)
        sv = np.linalg.svd(o, compute_uv=False)
        rank = int(np.linalg.matrix_rank(o))
        out[name] = {"states": tuple(KALMAN_STATES[i] for i in keep), "rank": rank, "n": len(idx),
                     "observable": rank == len(idx),
                     "condition": float(sv[0] / sv[-1]) if sv[-1] > 0 else math.inf}
    return out


# --------------------------------------------------------------------------- the filter
def kalman_model(K: float, T: float, waves: WaveParams, ts: float, r: float = DEFAULT_R,
                 q: tuple[float, float] | np.ndarray = DEFAULT_Q,
                 p0: tuple[float, ...] | np.ndarray = DEFAULT_P0,
                 x0: np.ndarray | None = None) -> KalmanModel:
    """Build the discrete heading Kalman filter.

    Parameters
    ----------
    K, T : float
        Nomoto gain [1/s] and time constant [s].
    waves : WaveParams
        Wave model.
    ts : float
        Filter sample time [s].
    r : float
        Sampled compass-noise variance [rad^2] (:func:`sampled_noise_variance` of a still record).
    q : pair of float or 2x2 array
        Continuous intensities of ``(w_w, w_b)``; a pair is a diagonal. Default ``DEFAULT_Q``.
    p0 : 5 floats or 5x5 array
        Initial a-priori covariance; 5 floats are a diagonal. Default ``DEFAULT_P0``.
    x0 : numpy.ndarray, optional
        Initial a-priori state (default zeros).

    Returns
    -------
    KalmanModel
        Discrete model and tuning.

    Raises
    ------
    AutopilotError
        Non-positive ts or r, wrong shapes, non-PSD Q or P0.
    """
    if not (isinstance(r, (int, float)) and math.isfinite(r) and r > 0):
        raise AutopilotError(f"compass noise variance R: expected a positive number [rad^2], found {r!r}")
    qm = np.asarray(q, float)
    qm = np.diag(qm) if qm.shape == (2,) else qm
    if qm.shape != (2, 2) or not np.all(np.isfinite(qm)) or np.any(np.linalg.eigvalsh(0.5 * (qm + qm.T)) < 0):
        raise AutopilotError(f"process noise Q: expected 2 non-negative intensities (w_w, w_b) or a 2x2 PSD "
                             f"matrix, found {np.asarray(q).tolist()!r}")
    pm = np.asarray(p0, float)
    pm = np.diag(pm) if pm.shape == (5,) else pm
    if pm.shape != (5, 5) or not np.all(np.isfinite(pm)) or np.any(np.linalg.eigvalsh(0.5 * (pm + pm.T)) < 0):
        raise AutopilotError(f"initial covariance P0: expected 5 non-negative variances or a 5x5 PSD matrix, "
                             f"found {np.asarray(p0).tolist()!r}")
    xm = np.zeros(5) if x0 is None else np.asarray(x0, float).copy()
    if xm.shape != (5,) or not np.all(np.isfinite(xm)):
        raise AutopilotError(f"initial state x0: expected 5 finite numbers {list(KALMAN_STATES)}, found {x0!r}")
    a, b, e, c = _checked_model(K, T, waves)
    if not (isinstance(ts, (int, float)) and math.isfinite(ts) and ts > 0):
        raise AutopilotError(f"sample time: expected a positive number [s], found {ts!r}")
    ad, bd, ed, qd = discretise.van_loan(a, b, e, qm, ts)
    return KalmanModel(ts=float(ts), ad=ad, bd=bd, ed=ed, c=c, qd=qd, r=float(r), p0=pm.copy(), x0=xm,
                       a=a, b=b, e=e, q=qm.copy())


def kalman_update(model: KalmanModel, x_prior: np.ndarray, p_prior: np.ndarray, y: float
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Measurement update with one compass sample (Joseph form).

    Parameters
    ----------
    model : KalmanModel
    x_prior : numpy.ndarray, shape (5,)
        A-priori state.
    p_prior : numpy.ndarray, shape (5, 5)
        A-priori covariance.
    y : float
        Compass heading [rad]; the innovation is wrapped to [-pi, pi) so a compass that wraps at
        +-180 deg does not kick the filter.

    Returns
    -------
    x_post, p_post, gain : numpy.ndarray
        A-posteriori state and covariance, and the Kalman gain (5,).
    """
    c = model.c[0]
    pc = p_prior @ c
    s = float(c @ pc) + model.r
    gain = pc / s
    innov = float(wrap_pi(y - c @ x_prior))
    x_post = x_prior + gain * innov
    ikc = np.eye(5) - np.outer(gain, c)
    # Joseph form: stays symmetric positive definite in floating point (Brown & Hwang, eq. 4.2.18).
    p_post = ikc @ p_prior @ ikc.T + model.r * np.outer(gain, gain)
    return x_post, p_post, gain


def kalman_predict(model: KalmanModel, x_post: np.ndarray, p_post: np.ndarray, u: float
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Time update to the next sample with the rudder angle held over the interval.

    Parameters
    ----------
    model : KalmanModel
    x_post : numpy.ndarray, shape (5,)
        A-posteriori state.
    p_post : numpy.ndarray, shape (5, 5)
        A-posteriori covariance.
    u : float
        Rudder angle applied until the next sample [rad].

    Returns
    -------
    x_prior, p_prior : numpy.ndarray
        A-priori state and (symmetrised) covariance at the next sample.
    """
    x = model.ad @ x_post + model.bd[:, 0] * u
    p = model.ad @ p_post @ model.ad.T + model.qd
    return x, 0.5 * (p + p.T)


@dataclass(frozen=True)
class KalmanRun:
    """A filter pass over a record.

    Attributes
    ----------
    x_post : numpy.ndarray, shape (N, 5)
        A-posteriori estimates ``[xi_w, psi_w, psi, r, b]``.
    p_post_diag : numpy.ndarray, shape (N, 5)
        Diagonal of the a-posteriori covariance.
    gain : numpy.ndarray, shape (N, 5)
        Kalman gains.
    p_prior_last : numpy.ndarray, shape (5, 5)
        A-priori covariance after the last sample (converges to the DARE solution).
    """

    x_post: np.ndarray
    p_post_diag: np.ndarray
    gain: np.ndarray
    p_prior_last: np.ndarray


def run_kalman_filter(model: KalmanModel, y: np.ndarray, u: np.ndarray) -> KalmanRun:
    """Filter a compass record ``y`` [rad] with the applied rudder ``u`` [rad], one sample per ``ts``.

    Parameters
    ----------
    model : KalmanModel
    y : numpy.ndarray, shape (N,)
        Compass samples [rad].
    u : numpy.ndarray, shape (N,)
        Rudder angle applied from each sample to the next [rad].

    Returns
    -------
    KalmanRun
        Estimates, covariances and gains.
    """
    y = np.asarray(y, float)
    u = np.asarray(u, float)
    if y.shape != u.shape or y.ndim != 1:
        raise AutopilotError(f"Kalman filter: expected compass and rudder series of equal length, "
                             f"found shapes {y.shape} and {u.shape}")
    n = len(y)
    xs = np.empty((n, 5))
    pd_ = np.empty((n, 5))
    gs = np.empty((n, 5))
    x, p = model.x0.copy(), model.p0.copy()
    for k in range(n):
        xk, pk, g = kalman_update(model, x, p, y[k])
        xs[k], pd_[k], gs[k] = xk, np.diag(pk), g
        x, p = kalman_predict(model, xk, pk, u[k])
    return KalmanRun(x_post=xs, p_post_diag=pd_, gain=gs, p_prior_last=p)


def steady_state(model: KalmanModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stationary a-priori and a-posteriori covariance and gain, from the discrete Riccati equation.

    ``P = A_d P A_d^T - A_d P C^T (C P C^T + R)^-1 C P A_d^T + Q_d`` is the dual of the control
    DARE, so ``scipy.linalg.solve_discrete_are(A_d^T, C^T, Q_d, R)`` solves it.

    Parameters
    ----------
    model : KalmanModel

    Returns
    -------
    p_prior, p_post : numpy.ndarray, shape (5, 5)
    gain : numpy.ndarray, shape (5,)
    """
    p = scipy.linalg.solve_discrete_are(model.ad.T, model.c.T, model.qd, np.array([[model.r]]))
    _, p_post, gain = kalman_update(model, model.x0, p, 0.0)
    return p, p_post, gain


# --------------------------------------------------------------------------- measurement noise
def sampled_noise_variance(psi_still: np.ndarray) -> float:
    """Variance of the sampled compass noise from a heading record taken at rest [rad^2].

    The record is detrended (a linear fit removed) so that a slow drift of the vessel or the sensor
    is not counted as noise. This *is* the discrete filter's R; no division by the sample time.

    Parameters
    ----------
    psi_still : numpy.ndarray
        Compass heading at rest, no rudder, no waves [rad], at the filter's sample rate.

    Returns
    -------
    float
        Sample variance [rad^2].

    Raises
    ------
    AutopilotError
        Fewer than 10 samples, non-finite values, or zero variance.
    """
    y = np.unwrap(np.asarray(psi_still, float))
    if y.ndim != 1 or len(y) < 10:
        raise AutopilotError(f"still compass record: expected at least 10 samples, found {y.size}")
    if not np.all(np.isfinite(y)):
        raise AutopilotError("still compass record: expected finite headings, found NaN/inf")
    k = np.arange(len(y))
    resid = y - np.polyval(np.polyfit(k, y, 1), k)
    var = float(np.var(resid, ddof=2))
    if var <= 0:
        raise AutopilotError("still compass record: expected measurement noise, found a noiseless heading "
                             "(zero variance); give --noise-std-deg instead")
    return var


def continuous_noise_intensity(r: float, ts: float) -> float:
    """Continuous-time intensity [rad^2 s] equivalent to a sampled variance ``r`` [rad^2] at ``ts`` [s]: ``r ts``.

    Parameters
    ----------
    r : float
        Variance of the sampled measurement noise [rad^2].
    ts : float
        Sample time [s].
    """
    return float(r) * float(ts)


def sampled_noise_from_intensity(rc: float, ts: float) -> float:
    """Sampled variance [rad^2] of continuous white noise of intensity ``rc`` [rad^2 s] at ``ts`` [s]: ``rc / ts``.

    The inverse of :func:`continuous_noise_intensity`.

    Parameters
    ----------
    rc : float
        Intensity of the continuous white noise [rad^2 s].
    ts : float
        Sample time [s].
    """
    return float(rc) / float(ts)
