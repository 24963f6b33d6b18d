"""Whole-record Nomoto identification: continuous-time output-error (OE) and prediction-error (PEM)
fits of K and T (or the second-order T1, T2, T3) with a rudder bias (Nomoto et al. 1957; Ljung 1999).

Model (first order, :func:`pipeline.model.nomoto_rhs`)::

    psi_dot = r,    T r_dot + r = K (delta - b)

or second order (:func:`nomoto2_rhs`; Fossen 2021, sec. 7.2)::

    r / (delta - b) = K (1 + T3 s) / ((1 + T1 s)(1 + T2 s))

The continuous model is discretised exactly for a zero-order-hold rudder, per candidate parameter
vector, with the matrix exponential of the augmented matrix ``[[A, B], [0, 0]] h`` (Van Loan
1978; :func:`zoh_discretise`), and simulated over the whole record (steps, zig-zags, sinusoids or
closed-loop data: only the measured rudder is used). The ship's initial heading and yaw rate are
parameters of every record.

Noise models (``noise=``):

- ``"white"``: output error. Residuals ``y - y_sim`` per channel, weighted by the inverse of their
  estimated variance (the maximum-likelihood weighting for independent white channels).
- ``"waves"``: prediction error. The compass residual is passed through the steady-state Kalman
  innovations filter of the seed's second-order wave model plus white measurement noise
  (:mod:`pipeline.fit.nomoto_pem`), and ``sum e^2`` is minimised over K, T, b, the initial states
  and the wave parameters (omega_0, lambda, K_w/sqrt(R)) -- or with the wave parameters held from
  a PSD fit (``waves=WaveParams(...)``). Open-loop OE stays consistent under coloured noise but
  is inefficient and its white-noise error bars are wrong; with the right noise model the PEM
  estimate reaches the Cramer-Rao bound and its Jacobian covariance is right (Ljung 1999,
  sec. 9.3). In closed loop (an autopilot steering on the wave-contaminated compass) the direct
  method is consistent only with a correct noise model, so OE may be biased there and the PEM
  is not (Ljung 1999, sec. 13.4).
- ``"auto"``: OE first; if its compass residuals fail the whiteness test
  (:func:`pipeline.fit.residual_tests.residual_test`), the wave PEM, kept when its BIC is lower.

The yaw rate ``r`` (gyro) is used when given; it is modelled without the wave component (as the
seed and the simulator do), so a gyro that sees the wave-induced yaw is better left out
(``channels=("psi",)``).

Uncertainty: the Gauss-Newton covariance ``(J^T W J)^-1`` of the weighted residuals (finite
differences of the exact simulation: central for K, T and the noise parameters, one-sided and
exact for the initial states and the bias, in which the residual is linear), scaled by
``RSS/(n - p)``; for the PEM this is the asymptotic covariance of Ljung (1999, sec. 9.3). The
residuals of every record and channel get the whiteness and input cross-correlation tests of
:mod:`pipeline.fit.residual_tests`.

References
----------
Nomoto, K., Taguchi, T., Honda, K., Hirano, S. (1957). On the steering qualities of ships.
International Shipbuilding Progress 4, 354-370.
Ljung, L. (1999). System Identification: Theory for the User, 2nd ed., Prentice Hall.
Fossen, T. I. (2021). Handbook of Marine Craft Hydrodynamics and Motion Control, 2nd ed., Wiley,
sec. 7.2 (Nomoto models) and 10.2.4 (wave model).
Van Loan, C. F. (1978). Computing integrals involving the matrix exponential. IEEE Trans. Autom.
Control 23(3), 395-404.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Mapping, Sequence

import numpy as np
import scipy.signal
from scipy import optimize
from scipy.integrate import cumulative_trapezoid

from ..errors import FitError
from ..model._backend import ops
from ..model.waves import WaveParams
from ..records import Segment, SegmentFit, Trial
from .data import noise_sigma, pick_channel, segment_label
from .nomoto_pem import (InnovationFilter, expm_small, guess_wave_noise, initial_state_response, innovation_filter,
                         noise_from_ratio, whiten_profiled)
from .residual_tests import ResidualTest, residual_test
from .segment_fit import MAX_RELATIVE_STDERR

#: Dynamic parameter names per model order.
DYNAMIC_PARAMS: Mapping[int, tuple[str, ...]] = {1: ("K", "T"), 2: ("K", "T1", "T2", "T3")}
#: Wave/noise parameters of the PEM (estimated on a log scale).
NOISE_PARAMS = ("omega0", "lambda", "kw_ratio")
NOISE_MODELS = ("auto", "white", "waves")
#: Fewest samples a record must have.
MIN_SAMPLES = 50
#: Relative jitter of the sample spacing accepted as uniform.
UNIFORM_TOLERANCE = 1e-3
# The residual is linear in these (initial states, and the bias through the input delta - b).
_LINEAR_KINDS = frozenset({"b", "psi0", "r0", "rdot0"})
# Floors of the finite-difference steps per parameter kind (step = 1e-6 max(|x|, floor)).
_FD_FLOOR = {"K": 1e-3, "T": 1.0, "T1": 1.0, "T2": 1.0, "T3": 1.0, "b": 1e-2, "psi0": 1e-2, "r0": 1e-3,
             "rdot0": 1e-4, "log": 10.0}


# --------------------------------------------------------------------------- models
@dataclass(frozen=True)
class Nomoto2Params:
    """Parameters of :func:`nomoto2_rhs` (second-order Nomoto model).

    Attributes
    ----------
    K : float
        Gain [1/s].
    T1, T2 : float
        Time constants of the poles [s] (``T1 >= T2`` by convention).
    T3 : float
        Time constant of the zero [s].
    b : float
        Rudder bias [rad].
    """

    K: float
    T1: float
    T2: float
    T3: float
    b: float = 0.0


def _nomoto2_coefficients(K: float, T1: float, T2: float, T3: float) -> tuple[float, float, float, float]:
    # r (s^2 + a1 s + a0) = (b1 s + b0) (delta - b)
    a1 = (T1 + T2) / (T1 * T2)
    a0 = 1.0 / (T1 * T2)
    return a1, a0, K * T3 / (T1 * T2), K / (T1 * T2)


def nomoto2_rhs(t, x, u, params: Nomoto2Params):
    """Right-hand side ``f(t, x, u, params)`` of the second-order Nomoto model.

    Observable canonical form of ``r/(delta - b) = K (1 + T3 s) / ((1 + T1 s)(1 + T2 s))``::

        psi_dot = r
        r_dot   = -a1 r + x2 + b1 (delta - b)
        x2_dot  = -a0 r + b0 (delta - b)

    with ``a1 = (T1 + T2)/(T1 T2)``, ``a0 = 1/(T1 T2)``, ``b1 = K T3/(T1 T2)``, ``b0 = K/(T1 T2)``.

    Parameters
    ----------
    t : float
        Time [s] (unused; time-invariant).
    x : array_like, shape (3,)
        ``[psi, r, x2]`` [rad, rad/s, rad/s^2]; ``x2 = r_dot + a1 r - b1 (delta - b)``.
    u : array_like, shape (1,)
        ``[delta]`` [rad].
    params : Nomoto2Params
        K [1/s], T1, T2, T3 [s], b [rad].

    Returns
    -------
    array_like, shape (3,)
        ``[psi_dot, r_dot, x2_dot]``.
    """
    o = ops(x)
    a1, a0, b1, b0 = _nomoto2_coefficients(params.K, params.T1, params.T2, params.T3)
    v = u[0] - params.b
    return o.stack([x[1], -a1 * x[1] + x[2] + b1 * v, -a0 * x[1] + b0 * v])


def nomoto_matrices(order: int, dyn: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """Continuous ``(A, B)`` of the Nomoto model for the input ``delta - b``; state 0 is psi.

    Parameters
    ----------
    order : int
        1 (``dyn = (K, T)``, states ``[psi, r]``) or 2 (``dyn = (K, T1, T2, T3)``, states
        ``[psi, r, x2]`` of :func:`nomoto2_rhs`).
    dyn : sequence of float
        Dynamic parameters [1/s, s, ...].
    """
    if order == 1:
        K, T = dyn
        return np.array([[0.0, 1.0], [0.0, -1.0 / T]]), np.array([[0.0], [K / T]])
    if order == 2:
        a1, a0, b1, b0 = _nomoto2_coefficients(*dyn)
        a = np.array([[0.0, 1.0, 0.0], [0.0, -a1, 1.0], [0.0, -a0, 0.0]])
        return a, np.array([[0.0], [b1], [b0]])
    raise FitError(f"Nomoto model order: expected 1 or 2, found {order!r}")


def zoh_discretise(a: np.ndarray, b: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretisation ``(A_d, B_d)`` (Van Loan 1978).

    ``exp([[A, B], [0, 0]] h) = [[A_d, B_d], [0, I]]``: the same matrices as
    :func:`scipy.signal.cont2discrete` with ``method="zoh"`` (the tests compare them); the
    exponential is :func:`pipeline.fit.nomoto_pem.expm_small`, which is cheap enough to call for
    every candidate parameter vector of a fit.

    Parameters
    ----------
    a : numpy.ndarray, shape (n, n)
        Continuous system matrix [1/s].
    b : numpy.ndarray, shape (n, m)
        Continuous input matrix.
    h : float
        Sample time [s].
    """
    a = np.asarray(a, float)
    b = np.asarray(b, float).reshape(a.shape[0], -1)
    n, m = b.shape
    big = np.zeros((n + m, n + m))
    big[:n, :n] = a
    big[:n, n:] = b
    ex = expm_small(big * h)
    return ex[:n, :n], ex[:n, n:]


def _state_tf(ad: np.ndarray, bd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Transfer functions ``(zI - A)^-1 B`` to every state: numerators (n, n+1) and denominator."""
    n = ad.shape[0]
    bd = np.asarray(bd, float).reshape(n)
    if n == 1:
        return np.array([[0.0, bd[0]]]), np.array([1.0, -ad[0, 0]])
    if n == 2:
        # (zI - A)^-1 = adj(zI - A) / det(zI - A), written out (no LAPACK in the inner loop).
        a = ad
        den = np.array([1.0, -(a[0, 0] + a[1, 1]), a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]])
        num = np.array([[0.0, bd[0], -a[1, 1] * bd[0] + a[0, 1] * bd[1]],
                        [0.0, bd[1], a[1, 0] * bd[0] - a[0, 0] * bd[1]]])
        return num, den
    num, den = scipy.signal.ss2tf(ad, bd.reshape(n, 1), np.eye(n), np.zeros((n, 1)))
    return np.asarray(num, float), np.asarray(den, float)


def _stable_states(ad: np.ndarray, bd: np.ndarray, x0: np.ndarray, u: np.ndarray) -> np.ndarray:
    """States of ``x[k+1] = A x[k] + B u[k]``, ``x[0] = x0`` (A stable), by IIR filtering.

    Each state is a linear filter of the input (plus the free response to ``x0``), so
    :func:`scipy.signal.lfilter` runs the recursion in compiled code: the cost of a candidate
    parameter vector is a few microseconds per sample, not a Python loop.
    """
    n = ad.shape[0]
    out = np.empty((u.size, n))
    num, den = _state_tf(ad, bd)
    impulse = np.zeros(u.size + 1)
    impulse[0] = 1.0
    if np.any(x0):
        num0, _ = _state_tf(ad, x0)
    for i in range(n):
        out[:, i] = scipy.signal.lfilter(num[i], den, u)
        if np.any(x0):
            # Impulse at k = 0 through B = x0 gives A^(k-1) x0 at k >= 1: shift by one sample.
            out[:, i] += scipy.signal.lfilter(num0[i], den, impulse)[1:]
    return out


def simulate_zoh(ad: np.ndarray, bd: np.ndarray, x0: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Exact sampled response of a Nomoto model (state 0 = heading, the integral of the rest).

    ``x[k+1] = A_d x[k] + B_d u[k]`` with ``A_d[0, 0] = 1`` and ``A_d[1:, 0] = 0``: the heading is
    accumulated from the stable yaw dynamics by a running sum, which avoids putting the marginally
    stable integrator pole inside a transfer-function recursion.

    Parameters
    ----------
    ad, bd : numpy.ndarray
        Discrete model from :func:`zoh_discretise` (``bd`` one column).
    x0 : numpy.ndarray, shape (n,)
        Initial state.
    u : numpy.ndarray, shape (N,)
        Input held over each sample interval (``delta - b``) [rad].

    Returns
    -------
    numpy.ndarray, shape (N, n)
        States at the sample times.
    """
    u = np.asarray(u, float)
    x0 = np.asarray(x0, float)
    bd = np.asarray(bd, float).reshape(-1)
    xr = _stable_states(ad[1:, 1:], bd[1:], x0[1:], u)
    inc = xr @ ad[0, 1:] + bd[0] * u
    psi = np.empty(u.size)
    psi[0] = x0[0]
    psi[1:] = x0[0] + np.cumsum(inc[:-1])
    return np.column_stack([psi, xr])


# --------------------------------------------------------------------------- records and results
@dataclass(frozen=True)
class NomotoRecord:
    """One uniformly sampled record for a whole-record Nomoto fit.

    Attributes
    ----------
    t : numpy.ndarray
        Sample times [s], uniform.
    delta : numpy.ndarray
        Rudder angle [rad], held over each sample interval (zero-order hold), finite.
    psi : numpy.ndarray or None
        Compass heading [rad] (wrapped or not; unwrapped inside). NaN marks a missing sample.
    r : numpy.ndarray or None
        Yaw rate [rad/s], if logged.
    name : str
        For messages.
    """

    t: np.ndarray
    delta: np.ndarray
    psi: np.ndarray | None = None
    r: np.ndarray | None = None
    name: str = ""


@dataclass(frozen=True)
class NomotoFit:
    """Result of :func:`fit_nomoto` (lmfit-style: values, errors, covariance, criteria, checks).

    Attributes
    ----------
    order : int
        1 or 2.
    noise_model : str
        ``white`` (OE) or ``waves`` (PEM with the wave model).
    names : tuple[str, ...]
        Parameter names in covariance order: ``K``, ``T`` (or ``T1``, ``T2``, ``T3``), ``b`` (if
        estimated), per record ``psi0``/``r0`` (``[i]`` suffix for several records), and for the PEM
        the estimated ones of ``omega0`` [rad/s], ``lambda`` [-], ``kw_ratio`` [s^-1/2].
    values, stderr : numpy.ndarray
        Estimates and standard errors in SI units (NaN errors when the covariance is singular).
    covariance : numpy.ndarray
        Parameter covariance.
    waves : WaveParams or None
        Wave model used (estimated or fixed), K_w in rad s^-1/2.
    noise_var : Mapping[str, float]
        Variance of the white measurement noise per channel [rad^2, (rad/s)^2].
    innovation_var : Mapping[str, float]
        Mean square of the weighted residuals' channel (innovations for the PEM) [SI^2].
    y_fit : tuple[Mapping[str, numpy.ndarray], ...]
        Simulated noise-free output per record and channel.
    residuals : tuple[Mapping[str, numpy.ndarray], ...]
        Residuals per record and channel (``y - y_sim`` for OE, innovations for PEM).
    n : int
        Residuals used.
    neg2loglik : float
        ``-2 log L`` of the Gaussian innovations with the variances concentrated out.
    aic, bic : float
        ``-2 log L + 2p`` and ``-2 log L + p ln n``.
    converged : bool
        Solver convergence.
    at_bound : tuple[str, ...]
        Parameters outside their plausible range (time constants between a tenth of a sample and
        100 record lengths, |b| < pi/2, omega_0 between the record and the Nyquist frequency, ...);
        the solver itself is unbounded.
    residual_tests : tuple[ResidualTest, ...]
        Whiteness and input cross-correlation per record and channel (Ljung 1999, sec. 16.6).
    message : str
        What is doubtful (coloured residuals, ranges, singular covariance) and what was chosen.
    channels : tuple[str, ...]
        Channels fitted (``psi``, ``r``).
    timings : Mapping[str, float]
        Wall time of the fit [s] (``total_s``).
    """

    order: int
    noise_model: str
    names: tuple[str, ...]
    values: np.ndarray
    stderr: np.ndarray
    covariance: np.ndarray
    waves: WaveParams | None
    noise_var: Mapping[str, float]
    innovation_var: Mapping[str, float]
    y_fit: tuple[Mapping[str, np.ndarray], ...]
    residuals: tuple[Mapping[str, np.ndarray], ...]
    n: int
    neg2loglik: float
    aic: float
    bic: float
    converged: bool
    at_bound: tuple[str, ...]
    residual_tests: tuple[ResidualTest, ...] = ()
    message: str = ""
    channels: tuple[str, ...] = ("psi",)
    timings: Mapping[str, float] = field(default_factory=dict)

    def value(self, name: str) -> float:
        """Estimate of one parameter [SI].

        Parameters
        ----------
        name : str
            One of ``names``.
        """
        return float(self.values[self.names.index(name)])

    def error(self, name: str) -> float:
        """Standard error of one parameter [SI].

        Parameters
        ----------
        name : str
            One of ``names``.
        """
        return float(self.stderr[self.names.index(name)])

    @property
    def K(self) -> float:
        """Nomoto gain [1/s]."""
        return self.value("K")

    @property
    def T(self) -> float:
        """Nomoto time constant [s]; for order 2 the equivalent ``T1 + T2 - T3``."""
        if self.order == 1:
            return self.value("T")
        return self.value("T1") + self.value("T2") - self.value("T3")

    @property
    def b(self) -> float:
        """Rudder bias [rad] (0 when not estimated)."""
        return self.value("b") if "b" in self.names else 0.0

    @property
    def success(self) -> bool:
        """Converged, no parameter on a bound and a finite covariance."""
        return self.converged and not self.at_bound and bool(np.all(np.isfinite(self.stderr)))


# --------------------------------------------------------------------------- preparation
@dataclass(frozen=True)
class _Prepared:
    h: float
    u: np.ndarray
    y: Mapping[str, np.ndarray]
    mask: Mapping[str, np.ndarray]
    duration: float
    name: str


def _unwrap(psi: np.ndarray) -> np.ndarray:
    out = np.array(psi, float)
    ok = np.isfinite(out)
    out[ok] = np.unwrap(out[ok])
    return out


def _prepare(rec: NomotoRecord, i: int, channels: Sequence[str]) -> _Prepared:
    name = rec.name or f"record {i}"
    t = np.asarray(rec.t, float)
    u = np.asarray(rec.delta, float)
    if t.ndim != 1 or t.size < MIN_SAMPLES:
        raise FitError(f"{name}: expected at least {MIN_SAMPLES} samples, found {t.size}")
    if u.shape != t.shape:
        raise FitError(f"{name}: expected delta with {t.size} samples like t, found shape {u.shape}")
    if not np.all(np.isfinite(u)):
        raise FitError(f"{name}: expected a finite rudder angle on every sample (the model is driven by it), "
                       f"found {int((~np.isfinite(u)).sum())} non-finite samples")
    dt = np.diff(t)
    h = float(np.median(dt))
    if not (h > 0 and np.all(np.abs(dt - h) <= UNIFORM_TOLERANCE * h)):
        raise FitError(f"{name}: expected uniform, increasing sample times, found spacings "
                       f"{float(dt.min()):.4g}..{float(dt.max()):.4g} s")
    ys, masks = {}, {}
    for ch in channels:
        raw = rec.psi if ch == "psi" else rec.r
        if raw is None:
            raise FitError(f"{name}: channel {ch!r} requested but not given")
        y = np.asarray(raw, float)
        if y.shape != t.shape:
            raise FitError(f"{name}: expected {ch} with {t.size} samples like t, found shape {y.shape}")
        y = _unwrap(y) if ch == "psi" else y
        m = np.isfinite(y)
        if m.sum() < MIN_SAMPLES:
            raise FitError(f"{name}: expected at least {MIN_SAMPLES} finite {ch} samples, found {int(m.sum())}")
        ys[ch], masks[ch] = np.where(m, y, 0.0), m
    return _Prepared(h=h, u=u, y=ys, mask=masks, duration=float(t[-1] - t[0]), name=name)


# --------------------------------------------------------------------------- start values
def guess_nomoto(t: np.ndarray, delta: np.ndarray, psi: np.ndarray, bias: bool = True) -> dict[str, float]:
    """Closed-form start for the first-order model by integral regression on the heading.

    Integrating ``T psi_ddot + psi_dot = K (delta - b)`` twice from 0 to t::

        int psi = -T psi(t) + T psi0 + (T r0 + psi0) t + K int int delta - (K b / 2) t^2

    is linear in ``(-T, T psi0, T r0 + psi0, K, -K b/2)``; the integrals average the noise, so
    a least-squares solve gives usable starts even under waves.

    Parameters
    ----------
    t : numpy.ndarray
        Uniform sample times [s].
    delta : numpy.ndarray
        Rudder angle [rad].
    psi : numpy.ndarray
        Heading [rad] (unwrapped, finite).
    bias : bool
        Include the rudder bias term.

    Returns
    -------
    dict
        ``K`` [1/s], ``T`` [s], ``b`` [rad], ``psi0`` [rad], ``r0`` [rad/s].
    """
    t = np.asarray(t, float) - float(t[0])
    psi = np.asarray(psi, float)
    delta = np.asarray(delta, float)
    h = float(t[1] - t[0])
    # The ZOH input integrated exactly: int delta is piecewise linear between samples.
    i1 = np.concatenate([[0.0], np.cumsum(delta[:-1]) * h])
    i2 = cumulative_trapezoid(i1, t, initial=0.0)
    ipsi = cumulative_trapezoid(psi, t, initial=0.0)
    cols = [psi, np.ones_like(t), t, i2] + ([t**2] if bias else [])
    c, *_ = np.linalg.lstsq(np.column_stack(cols), ipsi, rcond=None)
    T, K = -float(c[0]), float(c[3])
    duration = float(t[-1])
    if not (math.isfinite(T) and 2 * h < T < 50 * duration) or K == 0 or not math.isfinite(K):
        # Fall back to a mid-range time constant and the gain that fits best with it.
        T = max(duration / 5, 10 * h)
        cols = [np.ones_like(t), t, i2] + ([t**2] if bias else [])
        c2, *_ = np.linalg.lstsq(np.column_stack(cols), ipsi + T * psi, rcond=None)
        K = float(c2[2])
        c = np.array([-T, c2[0], c2[1], c2[2]] + ([c2[3]] if bias else []))
    psi0 = float(c[1]) / T
    r0 = (float(c[2]) - psi0) / T
    b = -2.0 * float(c[4]) / K if bias and K != 0 else 0.0
    return {"K": K, "T": T, "b": b if math.isfinite(b) else 0.0, "psi0": psi0, "r0": r0}


# --------------------------------------------------------------------------- the problem
class _Problem:
    """Residuals of the OE/PEM criterion over several records, with caches for the FD Jacobian."""

    def __init__(self, recs: Sequence[_Prepared], order: int, bias: bool, channels: tuple[str, ...],
                 noise: str, fixed_waves: WaveParams | None, fixed_noise_var: float | None):
        self.recs = recs
        self.order = order
        self.bias = bias
        self.channels = channels
        self.noise = noise
        self.fixed_waves = fixed_waves
        self.fixed_noise_var = fixed_noise_var
        dyn = list(DYNAMIC_PARAMS[order])
        self.names: list[str] = dyn + (["b"] if bias else [])
        self.kinds: list[str] = list(self.names)
        self.ic_names = (["psi0"] if "psi" in channels else []) + ["r0"] + (["rdot0"] if order == 2 else [])
        self.ic_index: list[list[int]] = []
        for i in range(len(recs)):
            idx = []
            for nm in self.ic_names:
                idx.append(len(self.names))
                self.names.append(nm if len(recs) == 1 else f"{nm}[{i}]")
                self.kinds.append(nm)
            self.ic_index.append(idx)
        self.noise_index: list[int] = []
        self.noise_free: tuple[str, ...] = ()
        if noise == "waves":
            self.noise_free = NOISE_PARAMS if fixed_waves is None else (
                ("kw_ratio",) if fixed_noise_var is None else ())
            for nm in self.noise_free:
                self.noise_index.append(len(self.names))
                self.names.append(nm)
                self.kinds.append("log")
        self.n_dyn = len(dyn)
        # Time constants and noise parameters are positive: the solver works on their logarithms.
        self.log_mask = np.array([k in ("T", "T1", "T2", "T3", "log") for k in self.kinds])
        self.weights = {ch: 1.0 for ch in channels}
        self._sim_cache: dict = {}
        self._filt_cache: dict = {}
        self._phi_cache: dict = {}

    # -- pieces
    def natural(self, z: np.ndarray) -> np.ndarray:
        """SI parameter values from the solver's vector (logarithms of the positive ones)."""
        return np.where(self.log_mask, np.exp(np.clip(z, -60.0, 60.0)), z)

    def solver_vector(self, theta: np.ndarray) -> np.ndarray:
        """The solver's vector from SI values."""
        theta = np.asarray(theta, float)
        return np.where(self.log_mask, np.log(np.where(self.log_mask, theta, 1.0)), theta)

    def _noise_params(self, z: np.ndarray) -> tuple[float, float, float]:
        vals = dict(zip(self.noise_free, self.natural(z)[self.noise_index]))
        fw = self.fixed_waves
        omega0 = vals.get("omega0", fw.omega0 if fw else math.nan)
        lam = vals.get("lambda", fw.lam if fw else math.nan)
        if "kw_ratio" in vals:
            ratio = vals["kw_ratio"]
        else:
            ratio = fw.kw / math.sqrt(self.fixed_noise_var)
        return omega0, lam, ratio

    def _filter(self, x: np.ndarray, h: float) -> InnovationFilter | None:
        if self.noise != "waves":
            return None
        omega0, lam, ratio = self._noise_params(x)
        key = (omega0, lam, ratio, h)
        f = self._filt_cache.get(key)
        if f is None:
            if len(self._filt_cache) > 64:
                self._filt_cache.clear()
            f = innovation_filter(WaveParams(omega0, lam, ratio), 1.0, h)
            self._filt_cache[key] = f
        return f

    def _phi(self, filt: InnovationFilter, h: float, n: int) -> np.ndarray:
        key = (filt.num.tobytes(), filt.gain.tobytes(), h, n)
        phi = self._phi_cache.get(key)
        if phi is None:
            if len(self._phi_cache) > 64:
                self._phi_cache.clear()
            phi = initial_state_response(filt, n)
            self._phi_cache[key] = phi
        return phi

    def simulate(self, z: np.ndarray, i: int) -> dict[str, np.ndarray]:
        """Noise-free outputs of record ``i`` at the solver vector ``z``."""
        rec = self.recs[i]
        x = self.natural(z)
        dyn = tuple(float(v) for v in x[: self.n_dyn])
        b = float(x[self.n_dyn]) if self.bias else 0.0
        icd = {nm: float(x[j]) for nm, j in zip(self.ic_names, self.ic_index[i])}
        psi0 = icd.pop("psi0", 0.0)
        # The initial heading only shifts psi: it is added after the cached simulation, so a
        # finite-difference step in psi0 costs no new simulation.
        key = (i, dyn, b, tuple(icd.values()))
        out = self._sim_cache.get(key)
        if out is None:
            a, bm = nomoto_matrices(self.order, dyn)
            ad, bd = zoh_discretise(a, bm, rec.h)
            x0 = np.zeros(a.shape[0])
            x0[1] = icd["r0"]
            if self.order == 2:
                a1, _, b1, _ = _nomoto2_coefficients(*dyn)
                # x2 from the initial yaw acceleration: x2 = r_dot + a1 r - b1 (delta - b).
                x0[2] = icd["rdot0"] + a1 * icd["r0"] - b1 * (rec.u[0] - b)
            states = simulate_zoh(ad, bd, x0, rec.u - b)
            out = {"psi": states[:, 0], "r": states[:, 1]}
            if len(self._sim_cache) > 256:
                self._sim_cache.clear()
            self._sim_cache[key] = out
        return {"psi": out["psi"] + psi0, "r": out["r"]} if psi0 else out

    def channel_residuals(self, x: np.ndarray) -> list[dict[str, np.ndarray]]:
        """Unweighted residuals per record and channel (masked samples removed)."""
        res = []
        for i, rec in enumerate(self.recs):
            sim = self.simulate(x, i)
            filt = self._filter(x, rec.h)
            per = {}
            for ch in self.channels:
                w = rec.y[ch] - sim[ch]
                m = rec.mask[ch]
                if ch == "psi" and filt is not None:
                    if m.all():
                        e = whiten_profiled(filt, w, self._phi(filt, rec.h, w.size))
                    else:
                        e = _whiten_with_gaps(filt, w, m)
                    per[ch] = e[m]
                else:
                    per[ch] = w[m]
            res.append(per)
        return res

    def residual(self, x: np.ndarray) -> np.ndarray:
        parts = []
        for per in self.channel_residuals(x):
            for ch in self.channels:
                parts.append(per[ch] * self.weights[ch])
        return np.concatenate(parts)

    def fd_steps(self, x: np.ndarray) -> np.ndarray:
        floor = np.array([1.0 if lg else _FD_FLOOR.get(k, 1e-3) for k, lg in zip(self.kinds, self.log_mask)])
        return 1e-6 * np.maximum(np.abs(x), floor)

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """Central differences for K, T and the noise parameters; one-sided for the parameters the
        residual is linear in (initial states, bias), where a forward difference is exact."""
        steps = self.fd_steps(x)
        base = None
        cols = []
        for j, s in enumerate(steps):
            xp = np.array(x, float)
            if self.kinds[j] in _LINEAR_KINDS:
                if base is None:
                    base = self.residual(x)
                s = 1e3 * s   # exact for a linear map: a larger step only lowers the rounding error
                xp[j] += s
                cols.append((self.residual(xp) - base) / s)
                continue
            xm = np.array(x, float)
            xp[j] += s
            xm[j] -= s
            cols.append((self.residual(xp) - self.residual(xm)) / (2 * s))
        return np.column_stack(cols)


def _whiten_with_gaps(filt: InnovationFilter, w: np.ndarray, mask: np.ndarray) -> np.ndarray:
    # A missing compass sample is a Kalman step without update: predict only. Rare (segments do
    # not span gaps), so the plain loop is good enough.
    a, l, c = filt.ad, filt.gain.ravel(), filt.c.ravel()
    xh = np.zeros(2)
    e = np.zeros(w.size)
    for k in range(w.size):
        if mask[k]:
            e[k] = w[k] - c @ xh
            xh = a @ xh + l * e[k]
        else:
            xh = a @ xh
    return e


# --------------------------------------------------------------------------- the fit
def _ranges(prob: _Problem) -> tuple[np.ndarray, np.ndarray]:
    """Plausible SI ranges; an estimate outside is reported (the solver itself is unbounded)."""
    h = min(r.h for r in prob.recs)
    dur = max(r.duration for r in prob.recs)
    lo = np.full(len(prob.names), -np.inf)
    hi = np.full(len(prob.names), np.inf)
    for j, k in enumerate(prob.kinds):
        if k in ("T", "T1", "T2", "T3"):
            lo[j], hi[j] = 0.1 * h, 100.0 * dur
        elif k == "b":
            lo[j], hi[j] = -math.pi / 2, math.pi / 2
    for nm, j in zip(prob.noise_free, prob.noise_index):
        if nm == "omega0":
            lo[j], hi[j] = 2 * math.pi / dur, math.pi / h
        elif nm == "lambda":
            lo[j], hi[j] = 1e-3, 5.0
        else:
            lo[j], hi[j] = 1e-8, 1e8
    return lo, hi


def _solve(prob: _Problem, z0: np.ndarray, max_nfev: int) -> optimize.OptimizeResult:
    # MINPACK's Levenberg-Marquardt: positivity comes from the log parameters, and its QR is its
    # own code, so a tall Jacobian costs no threaded LAPACK call per iteration.
    return optimize.least_squares(prob.residual, z0, jac=prob.jacobian, method="lm", x_scale="jac",
                                  max_nfev=max_nfev, xtol=1e-10, ftol=1e-10, gtol=1e-10)


def _reweighted_solve(prob: _Problem, x0: np.ndarray, max_nfev: int) -> optimize.OptimizeResult:
    """Solve, re-estimating the per-channel variances (maximum likelihood for unknown variances)."""
    def update_weights(x: np.ndarray) -> None:
        per = prob.channel_residuals(x)
        for ch in prob.channels:
            e = np.concatenate([p[ch] for p in per])
            ms = float(np.mean(e**2))
            prob.weights[ch] = 1.0 / math.sqrt(ms) if ms > 0 else 1.0

    update_weights(x0)
    res = _solve(prob, x0, max_nfev)
    # One channel: the weight is only a scale, the solution does not depend on it.
    for _ in range(4 if len(prob.channels) > 1 else 0):
        old = dict(prob.weights)
        update_weights(res.x)
        if all(abs(prob.weights[c] / old[c] - 1.0) < 1e-3 for c in prob.channels):
            break
        res = _solve(prob, res.x, max_nfev)
    update_weights(res.x)
    return res


def _start_vector(prob: _Problem, dyn: Sequence[float], b: float, ics: Sequence[Sequence[float]],
                  noise0: Sequence[float]) -> np.ndarray:
    """Solver vector from SI start values."""
    x = np.ones(len(prob.names))
    x[: prob.n_dyn] = dyn
    if prob.bias:
        x[prob.n_dyn] = b
    for idx, ic in zip(prob.ic_index, ics):
        x[idx] = ic
    if prob.noise_index:
        x[prob.noise_index] = np.asarray(noise0, float)
    return prob.solver_vector(x)


def _normal_covariance(jac: np.ndarray, s2: float) -> tuple[np.ndarray, str]:
    """``(J^T J)^-1 s^2`` through the column-scaled normal matrix (p x p eigen-decomposition).

    Same result as the SVD of :func:`pipeline.fit.least_squares.fit_least_squares` for the
    well-conditioned problems here, without a threaded LAPACK call on the tall Jacobian.
    """
    p = jac.shape[1]
    scale = np.linalg.norm(jac, axis=0)
    if not np.all(np.isfinite(jac)) or np.any(scale == 0):
        return np.full((p, p), np.nan), "Jacobian has a zero or non-finite column: a parameter does not affect the fit"
    js = jac / scale
    w, v = np.linalg.eigh(js.T @ js)
    # cond(J)^2 above 1e12 is where the normal equations lose the digits the errors need.
    if w[0] <= w[-1] * 1e-12:
        return np.full((p, p), np.nan), (f"Jacobian is near-singular (condition number "
                                         f"{math.sqrt(w[-1] / max(w[0], 1e-300)):.1e}): parameters not separable")
    inv = (v / w) @ v.T
    return inv / np.outer(scale, scale) * s2, ""


def _finish(prob: _Problem, res: optimize.OptimizeResult, messages: list[str]) -> NomotoFit:
    x = res.x
    names = tuple(prob.names)
    p = x.size
    resid = prob.residual(x)
    n = resid.size
    rss = float(resid @ resid)
    jac = prob.jacobian(x)
    cov, why = (_normal_covariance(jac, rss / (n - p)) if n > p
                else (np.full((p, p), np.nan), "no degrees of freedom"))
    if why:
        messages.append(why)
    # Solver space -> SI: d theta / d z = theta for the log parameters (delta method).
    values = prob.natural(x)
    d = np.where(prob.log_mask, values, 1.0)
    cov = cov * np.outer(d, d)
    stderr = np.sqrt(np.clip(np.diag(cov), 0.0, None)) if not why else np.full(p, np.nan)
    lo, hi = _ranges(prob)
    at_bound = tuple(nm for nm, v, a, b in zip(names, values, lo, hi) if not a < v < b)
    if at_bound:
        messages.append(f"parameter(s) {', '.join(at_bound)} outside the plausible range "
                        f"({', '.join(f'{a:.3g}..{b:.3g}' for nm, a, b in zip(names, lo, hi) if nm in at_bound)})")
    if res.status <= 0:
        messages.append(f"solver did not converge: {res.message}")
    per = prob.channel_residuals(x)
    inn_var, neg2 = {}, 0.0
    for ch in prob.channels:
        e = np.concatenate([q[ch] for q in per])
        inn_var[ch] = float(np.mean(e**2))
        neg2 += e.size * (math.log(2 * math.pi * inn_var[ch]) + 1.0) if inn_var[ch] > 0 else -math.inf
    waves, noise_var = None, {}
    h0 = prob.recs[0].h
    if prob.noise == "waves":
        omega0, lam, ratio = prob._noise_params(x)
        if prob.fixed_noise_var is not None and prob.fixed_waves is not None:
            waves, r = prob.fixed_waves, prob.fixed_noise_var
        else:
            waves, r = noise_from_ratio(omega0, lam, ratio, inn_var["psi"], h0)
        noise_var["psi"] = r
    elif "psi" in prob.channels:
        noise_var["psi"] = inn_var["psi"]
    if "r" in prob.channels:
        noise_var["r"] = inn_var["r"]
    y_fit, residuals, tests = [], [], []
    for i, rec in enumerate(prob.recs):
        sim = prob.simulate(x, i)
        y_fit.append({ch: sim[ch] for ch in prob.channels})
        full = {}
        for ch in prob.channels:
            e = np.full(rec.u.size, np.nan)
            e[rec.mask[ch]] = per[i][ch]
            full[ch] = e
            tests.append(residual_test(e, {"delta": rec.u}, f"{rec.name} {ch}"))
        residuals.append(full)
    messages += [tst.message for tst in tests if tst.message]
    model = "OE" if prob.noise == "white" else "PEM (wave noise model)"
    messages.insert(0, f"{model}, order {prob.order}, {len(prob.recs)} record(s), channels {'+'.join(prob.channels)}")
    return NomotoFit(order=prob.order, noise_model=prob.noise, names=names, values=values, stderr=stderr,
                     covariance=cov, waves=waves, noise_var=noise_var, innovation_var=inn_var,
                     y_fit=tuple(y_fit), residuals=tuple(residuals), n=n, neg2loglik=neg2,
                     aic=neg2 + 2 * p, bic=neg2 + p * math.log(n), converged=res.status > 0,
                     at_bound=at_bound, residual_tests=tuple(tests), message="; ".join(messages),
                     channels=prob.channels)


def _first_order_start(preps: Sequence[_Prepared], bias: bool,
                       channels: tuple[str, ...]) -> tuple[list[float], float, list[list[float]]]:
    gs = []
    for prep in preps:
        t = np.arange(prep.u.size) * prep.h
        if "psi" in prep.y:
            m = prep.mask["psi"]
            psi = np.interp(t, t[m], prep.y["psi"][m])
            gs.append(guess_nomoto(t, prep.u, psi, bias))
        else:
            # Yaw rate only: integrate it into a heading and use the same regression.
            m = prep.mask["r"]
            r = np.interp(t, t[m], prep.y["r"][m])
            gs.append(guess_nomoto(t, prep.u, cumulative_trapezoid(r, t, initial=0.0), bias))
    K = float(np.median([g["K"] for g in gs]))
    T = float(np.median([g["T"] for g in gs]))
    b = float(np.mean([g["b"] for g in gs])) if bias else 0.0
    ics = []
    for g, prep in zip(gs, preps):
        ic = []
        if "psi" in channels:
            ic.append(g["psi0"])
        ic.append(g["r0"])
        ics.append(ic)
    return [K, T], b, ics


def fit_nomoto(records: NomotoRecord | Sequence[NomotoRecord], order: int = 1, noise: str = "auto",
               waves: WaveParams | None = None, noise_var: float | None = None, bias: bool = True,
               channels: Sequence[str] | None = None, start: Mapping[str, float] | None = None,
               max_nfev: int = 100) -> NomotoFit:
    """Fit the Nomoto model to whole records by output error or prediction error.

    Parameters
    ----------
    records : NomotoRecord or sequence of NomotoRecord
        One or more records of the same ship; K, T (T1..T3), b and the wave model are shared,
        the initial heading and yaw rate are per record.
    order : int
        1 (K, T) or 2 (K, T1, T2, T3).
    noise : str
        ``"white"`` (OE), ``"waves"`` (PEM with the wave model) or ``"auto"`` (see module doc).
    waves : WaveParams, optional
        Hold omega_0 and lambda (and K_w, if ``noise_var`` is given too) fixed, e.g. from a PSD fit
        (``kw`` in this package's convention, :mod:`pipeline.model.waves`). Implies the PEM for
        ``noise="auto"``.
    noise_var : float, optional
        Compass noise variance per sample [rad^2], with ``waves``: the noise model is then fully
        known and only the ship is estimated.
    bias : bool
        Estimate the rudder bias b [rad].
    channels : sequence of str, optional
        Outputs to fit: ``"psi"`` and/or ``"r"``; default every one given in all records.
    start : Mapping[str, float], optional
        Start values by parameter name (``K``, ``T``, ``T1``...), overriding the closed-form guess.
    max_nfev : int
        Maximum function evaluations per solver call.

    Returns
    -------
    NomotoFit

    Raises
    ------
    FitError
        Bad records (non-uniform time, missing channels, non-finite rudder), an unknown order or
        noise model, or waves asked for without a compass channel.
    """
    t_start = time.perf_counter()
    recs = [records] if isinstance(records, NomotoRecord) else list(records)
    if not recs:
        raise FitError("fit_nomoto: expected at least one record, found none")
    if order not in DYNAMIC_PARAMS:
        raise FitError(f"fit_nomoto: expected order 1 or 2, found {order!r}")
    if noise not in NOISE_MODELS:
        raise FitError(f"fit_nomoto: expected noise in {NOISE_MODELS}, found {noise!r}")
    if channels is None:
        channels = tuple(ch for ch in ("psi", "r") if all(getattr(r, ch) is not None for r in recs))
    channels = tuple(channels)
    if not channels or any(ch not in ("psi", "r") for ch in channels):
        raise FitError(f"fit_nomoto: expected channels among ('psi', 'r'), found {channels or 'none'}")
    if noise == "waves" and "psi" not in channels:
        raise FitError("fit_nomoto: the wave noise model acts on the compass: expected channel 'psi', found "
                       f"{channels}")
    if noise_var is not None and waves is None:
        raise FitError("fit_nomoto: noise_var is only used with fixed waves; give waves=WaveParams(...) too")
    if noise_var is not None and not noise_var > 0:
        raise FitError(f"fit_nomoto: expected noise_var > 0 [rad^2], found {noise_var}")
    preps = [_prepare(r, i, channels) for i, r in enumerate(recs)]
    start = dict(start or {})

    # White-noise OE first: it starts the PEM, and it is the answer when the residuals are white.
    (K0, T0), b0, ics = _first_order_start(preps, bias, channels)
    K0, T0, b0 = start.get("K", K0), start.get("T", T0), start.get("b", b0)
    if order == 2:
        ics = [ic + [0.0] for ic in ics]
        candidates = [[K0, start.get("T1", 1.1 * T0), start.get("T2", 0.1 * T0), start.get("T3", 0.2 * T0)],
                      [K0, T0, 0.05 * T0, 0.15 * T0], [K0, 1.5 * T0, 0.2 * T0, 0.7 * T0]]
    else:
        candidates = [[K0, T0], [K0, 0.3 * T0], [K0, 3.0 * T0]]
    best = None
    for dyn in candidates:
        prob = _Problem(preps, order, bias, channels, "white", None, None)
        res = _reweighted_solve(prob, _start_vector(prob, dyn, b0, ics, ()), max_nfev)
        if best is None or res.cost < best[1].cost:
            best = (prob, res)
        # A first-order fit that converged inside the plausible ranges needs no other start; the
        # second-order one can stop in a local minimum, so every start is tried.
        if order == 1 and _plausible(*best):
            break
    prob, res = best
    oe = _finish(prob, res, [])
    if noise == "white" or (noise == "auto" and waves is None and _psi_white(oe)):
        note = "compass residuals white: OE kept" if noise == "auto" else ""
        return _timed(_with_message(oe, note), t_start)

    # PEM: the ship starts from the OE estimate, the noise from the OE compass residual's spectrum.
    theta = prob.natural(res.x)
    dyn = list(theta[: prob.n_dyn])
    b = float(theta[prob.n_dyn]) if bias else 0.0
    icl = [list(theta[idx]) for idx in prob.ic_index]
    h = preps[0].h
    w = np.concatenate([p.y["psi"][p.mask["psi"]] - oe.y_fit[i]["psi"][p.mask["psi"]] for i, p in enumerate(preps)])
    sv = noise_sigma(np.concatenate([p.y["psi"][p.mask["psi"]] for p in preps]))
    omega0, lam, ratio = guess_wave_noise(w, 1.0 / h, sv)
    if waves is not None:
        omega0, lam = waves.omega0, waves.lam
        ratio = waves.kw / (math.sqrt(noise_var) if noise_var is not None else max(sv, 1e-12))
    pem_prob = _Problem(preps, order, bias, channels, "waves", waves, noise_var)
    noise0 = [dict(zip(NOISE_PARAMS, (omega0, lam, ratio)))[nm] for nm in pem_prob.noise_free]
    pem_res = _reweighted_solve(pem_prob, _start_vector(pem_prob, dyn, b, icl, noise0), max_nfev)
    pem = _finish(pem_prob, pem_res, [])
    if noise == "auto" and waves is None:
        if pem.bic >= oe.bic:
            return _timed(_with_message(oe, f"compass residuals coloured but the wave PEM does not lower the BIC "
                                            f"({pem.bic:.1f} >= {oe.bic:.1f}): OE kept"), t_start)
        pem = _with_message(pem, f"OE compass residuals coloured; wave PEM chosen (BIC {pem.bic:.1f} < "
                                 f"{oe.bic:.1f})")
    return _timed(pem, t_start)


def _plausible(prob: _Problem, res: optimize.OptimizeResult) -> bool:
    lo, hi = _ranges(prob)
    theta = prob.natural(res.x)
    return bool(res.status > 0 and np.all((theta > lo) & (theta < hi)))


def _psi_white(fit: NomotoFit) -> bool:
    tests = [t for t in fit.residual_tests if t.name.endswith(" psi")]
    return all(t.white for t in tests)


def _with_message(fit: NomotoFit, note: str) -> NomotoFit:
    if not note:
        return fit
    return replace(fit, message="; ".join(m for m in (fit.message, note) if m))


def _timed(fit: NomotoFit, t_start: float) -> NomotoFit:
    return replace(fit, timings={"total_s": time.perf_counter() - t_start})


def fit_nomoto_oe(records: NomotoRecord | Sequence[NomotoRecord], order: int = 1, bias: bool = True,
                  channels: Sequence[str] | None = None) -> NomotoFit:
    """Output-error fit (white measurement noise); see :func:`fit_nomoto`.

    Parameters
    ----------
    records : NomotoRecord or sequence of NomotoRecord
        Records of one ship.
    order : int
        1 or 2.
    bias : bool
        Estimate the rudder bias.
    channels : sequence of str, optional
        ``"psi"`` and/or ``"r"``.
    """
    return fit_nomoto(records, order=order, noise="white", bias=bias, channels=channels)


def fit_nomoto_pem(records: NomotoRecord | Sequence[NomotoRecord], order: int = 1, bias: bool = True,
                   waves: WaveParams | None = None, noise_var: float | None = None,
                   channels: Sequence[str] | None = None) -> NomotoFit:
    """Prediction-error fit with the wave noise model (Kalman innovations); see :func:`fit_nomoto`.

    Parameters
    ----------
    records : NomotoRecord or sequence of NomotoRecord
        Records of one ship.
    order : int
        1 or 2.
    bias : bool
        Estimate the rudder bias.
    waves : WaveParams, optional
        Fixed wave shape (and K_w with ``noise_var``), e.g. from a PSD fit; estimated when omitted.
    noise_var : float, optional
        Fixed compass noise variance [rad^2] (with ``waves``).
    channels : sequence of str, optional
        ``"psi"`` and/or ``"r"``.
    """
    return fit_nomoto(records, order=order, noise="waves", waves=waves, noise_var=noise_var, bias=bias,
                      channels=channels)


# --------------------------------------------------------------------------- fit stage
#: Segment kinds the whole-record fit serves in :func:`pipeline.fit.fit_trial`.
WHOLE_RECORD_KINDS = ("zigzag", "sinusoid")
#: Parameters whose relative standard error decides ``success``.
KEY_PARAMS = ("K", "T")


def fit_nomoto_segment(trial: Trial, segment: Segment) -> SegmentFit:
    """Whole-record Nomoto fit (:func:`fit_nomoto`, ``noise="auto"``) of a zig-zag or sinusoid segment.

    The compass heading ``psi`` and, when logged, the yaw rate ``r`` are fitted against the
    logged rudder ``delta`` (zero-order hold on the trial clock). K, T and the rudder bias b are
    reported; the OE result is kept when its compass residuals are white, the wave PEM otherwise.

    Parameters
    ----------
    trial : Trial
        Trial with ``delta`` and ``psi`` and/or ``r``.
    segment : Segment
        A ``zigzag`` or ``sinusoid`` segment in yaw.

    Returns
    -------
    SegmentFit
        Model ``nomoto_oe`` or ``nomoto_pem``, channel ``psi`` (``r`` without a compass), with
        parameters ``K`` [1/s], ``T`` [s], ``b`` [rad], ``psi0`` [rad], ``r0`` [rad/s] and for the
        PEM ``omega0`` [rad/s], ``lambda`` [-], ``kw_ratio`` [s^-1/2]; ``y_fit`` is the simulated
        heading.

    Raises
    ------
    FitError
        Wrong DOF, missing channels, gaps in the rudder, too few samples.
    """
    where = segment_label(segment)
    if segment.dof != "yaw":
        raise FitError(f"{where}: expected a {segment.kind} in yaw, found DOF {segment.dof!r}")
    u_ch = segment.input_channel or "delta"
    if u_ch != "delta":
        raise FitError(f"{where}: expected the rudder (delta) as input, found {u_ch!r}")
    pick_channel(trial, segment, ["delta"])
    channels = tuple(ch for ch in ("psi", "r") if trial.has(ch))
    if not channels:
        pick_channel(trial, segment, ["psi", "r"])
    rows = trial.window(segment.t_start, segment.t_end)
    t = rows["t"].to_numpy(dtype=float)
    delta = rows["delta"].to_numpy(dtype=float)
    if t.size < MIN_SAMPLES:
        raise FitError(f"{where}: expected at least {MIN_SAMPLES} samples, found {t.size}")
    if not np.all(np.isfinite(delta)):
        raise FitError(f"{where}: expected a logged rudder on every sample, found {int((~np.isfinite(delta)).sum())} gaps")
    rec = NomotoRecord(t=t, delta=delta, psi=rows["psi"].to_numpy(dtype=float) if "psi" in channels else None,
                       r=rows["r"].to_numpy(dtype=float) if "r" in channels else None, name=where)
    fit = fit_nomoto(rec, noise="auto", channels=channels)
    main = channels[0]
    model = "nomoto_oe" if fit.noise_model == "white" else "nomoto_pem"
    fail = []
    if not fit.converged:
        fail.append("solver did not converge")
    if fit.at_bound:
        fail.append(f"parameter(s) {', '.join(fit.at_bound)} outside the plausible range")
    if not np.all(np.isfinite(fit.stderr)):
        fail.append("covariance not computed")
    for name in KEY_PARAMS:
        v, se = fit.value(name), fit.error(name)
        if math.isfinite(se) and abs(se) > MAX_RELATIVE_STDERR * abs(v):
            fail.append(f"{name} = {v:.4g} +- {se:.2g} has a relative standard error above "
                        f"{MAX_RELATIVE_STDERR:.0%}: not identified")
    notes = [fit.message]
    if segment.kind == "zigzag" and not all(t.independent for t in fit.residual_tests):
        notes.append("a zig-zag switches the rudder on the heading, so residuals that lead the rudder "
                     "(negative lags) are the expected feedback, not a model error")
    y = rec.psi if main == "psi" else rec.r
    y = _unwrap(y) if main == "psi" else np.asarray(y, float)
    e = fit.residuals[0][main]
    rmse = float(np.sqrt(np.nanmean(e**2)))
    return SegmentFit(segment=segment, model=model, channel=main, param_names=fit.names,
                      params={n: float(v) for n, v in zip(fit.names, fit.values)},
                      stderr={n: float(s) for n, s in zip(fit.names, fit.stderr)},
                      covariance=fit.covariance, t=t - segment.t_start, y=y, y_fit=fit.y_fit[0][main], rmse=rmse,
                      aic=fit.aic, bic=fit.bic, success=not fail, message="; ".join(fail + notes))
