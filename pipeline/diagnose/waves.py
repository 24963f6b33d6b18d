"""The ``waves`` candidate: a second-order wave-band disturbance on a model's output.

Waves add a narrow-band, zero-mean motion to what the sensors see (Fossen 2021, sec. 10.2.4):

    y = y_model + y_w,     y_w(s) = K_w s / (s^2 + 2 lambda omega_0 s + omega_0^2) w(s)

A deterministic simulation cannot predict a random sea, so the candidate is judged the way a
wave-filtering autopilot uses it: the residual spectrum of the baseline on the training windows
(an autoregressive estimate, which short windows support) is fitted with
``S(omega) = N0 (1 + 2 rho cos(omega dt)) + A / omega^2 + S_w(omega)`` (sensor noise, leakage of
low-frequency model error, waves), and on held-out windows the wave part is separated by the
fixed-interval Kalman smoother of that spectrum (:func:`smooth_waves`; away from the window ends the
non-causal Wiener smoother ``G = S_w / S``, Wiener 1949). If there are no waves, ``S_w`` fits to
nearly nothing and the held-out gap does not move; the significance test decides what "nearly" means.

The sensor noise is not white on the analysis grid: a trapezoidal block mean shares its end
sample with the next block (lag-1 correlation ``1 / (4 m - 2)``, one half at one sample per step),
and a sensor logged slower than the trial rate and interpolated (GNSS-derived velocities) is
low-pass. ``rho`` in ``[-1/2, 1/2]`` (the spectrum of any first-order moving average) takes that
smooth colouring, so that a wave is a resolved peak above it and not a broad hump that mimics the
noise's own shape.

PSD convention: one-sided per rad/s, ``var = integral_0^inf S(omega) d omega`` [unit^2 s/rad].

The Kalman filter and Rauch-Tung-Striebel smoother are written here rather than taken from a
library (statsmodels' state-space models, filterpy): the candidate smooths every window of a DOF side
by side, hundreds of short rows with NaN gaps that share one covariance path, inside a likelihood
search run for each fold; those libraries filter one series at a time (not timed against them).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import scipy.optimize
import scipy.stats

from ..fit.nomoto_pem import wave_discrete
from ..model.waves import WaveParams
from ..model.waves import wave_psd as model_wave_psd

#: Lowest wave frequency searched, in units of 1/T of the DOF: below that the residual holds the
#: model's own low-frequency error, which a wave model must not be allowed to soak up.
BAND_LO_T = 2.5
#: Absolute bounds of the search band [rad/s] (swell to short chop).
BAND_ABS = (0.2, 12.0)
#: A fitted peak closer than this factor to a band edge is leakage, not a wave.
EDGE_MARGIN = 1.15
#: Smallest peak height of the wave PSD over the background (noise + leakage) at omega_0.
PEAK_RATIO = 3.0
#: Bounds of the lag-1 correlation of the background noise (any MA(1) spectrum).
RHO_BOUNDS = (-0.5, 0.5)
#: Relative damping bounds of the wave spectrum (Fossen: 0.05-0.2 for sea states).
LAMBDA_BOUNDS = (0.02, 0.8)


@dataclass(frozen=True)
class WaveSpectrum:
    """A fitted residual spectrum.

    Attributes
    ----------
    omega0 : float
        Peak wave frequency [rad/s] (NaN when no spectrum could be fitted).
    lam : float
        Relative damping lambda [-].
    sigma : float
        Standard deviation of the wave component [unit of the channel].
    n0 : float
        White-noise level [unit^2 s/rad].
    a_lf : float
        Low-frequency leakage ``A`` in ``A / omega^2`` [unit^2 rad/s].
    band : tuple[float, float]
        Band searched [rad/s].
    rho : float
        Lag-1 correlation of the background noise [-]: it is ``N0 (1 + 2 rho cos(omega dt))``.
    dt : float
        Sample step of the spectrum [s] (with ``rho``).
    m : int
        Trial samples per sample of the rows (their trapezoidal block means share an end sample:
        the noise model of :func:`smooth_waves`).
    """

    omega0: float
    lam: float
    sigma: float
    n0: float
    a_lf: float
    band: tuple[float, float]
    rho: float = 0.0
    dt: float = 0.0
    m: int = 1

    def background(self, omega: np.ndarray) -> np.ndarray:
        """Noise plus leakage PSD at ``omega`` [rad/s].

        Parameters
        ----------
        omega : numpy.ndarray
            Frequencies [rad/s].
        """
        w = np.maximum(np.asarray(omega, float), 1e-9)
        return self.n0 * (1.0 + 2.0 * self.rho * np.cos(w * self.dt)) + self.a_lf / w**2

    def parts(self, omega: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Wave PSD and the rest (noise + leakage) at ``omega`` [rad/s].

        Parameters
        ----------
        omega : numpy.ndarray
            Frequencies [rad/s].
        """
        w = np.maximum(np.asarray(omega, float), 1e-9)
        if not np.isfinite(self.omega0) or self.sigma <= 0:
            return np.zeros_like(w), self.background(w)
        return wave_psd(w, self.omega0, self.lam, self.sigma), self.background(w)


def kw_for_variance(omega0: float, lam: float, sigma: float) -> float:
    """Gain ``K_w`` of :class:`pipeline.model.waves.WaveParams` whose one-sided spectrum
    ``K_w^2 shape(omega)`` holds the variance ``sigma^2`` (the conversion between the model's
    spectrum and a residual's measured variance).

    ``shape = omega^2 / ((omega0^2 - omega^2)^2 + (2 lam omega0 omega)^2)`` integrates to
    ``pi / (4 lam omega0)`` over ``(0, inf)``, so ``K_w^2 = 4 lam omega0 sigma^2 / pi``.

    Parameters
    ----------
    omega0 : float
        Peak frequency [rad/s].
    lam : float
        Relative damping [-].
    sigma : float
        Standard deviation of the wave component [unit].
    """
    kw = np.sqrt(4.0 * lam * omega0 / np.pi) * sigma
    return float(kw) if np.ndim(kw) == 0 else kw


def wave_psd(omega: np.ndarray, omega0: float, lam: float, sigma: float) -> np.ndarray:
    """One-sided PSD [unit^2 s/rad] of the wave model (:func:`pipeline.model.waves.wave_psd`, the
    project's one convention) scaled to the variance ``sigma^2`` (:func:`kw_for_variance`).

    Parameters
    ----------
    omega : numpy.ndarray
        Frequencies [rad/s].
    omega0 : float
        Peak frequency [rad/s].
    lam : float
        Relative damping [-].
    sigma : float
        Standard deviation of the wave component [unit].
    """
    return model_wave_psd(omega, WaveParams(omega0=omega0, lam=lam, kw=kw_for_variance(omega0, lam, sigma)))


def search_band(t_const: float, dt: float) -> tuple[float, float]:
    """Wave frequencies [rad/s] searched for a DOF of time constant ``t_const`` sampled at ``dt``.

    Parameters
    ----------
    t_const : float
        The DOF's time constant [s].
    dt : float
        Analysis step [s].
    """
    lo = max(BAND_ABS[0], BAND_LO_T / max(t_const, 1e-9))
    hi = min(BAND_ABS[1], 0.8 * np.pi / dt)
    return float(lo), float(hi)


#: Order of the autoregressive spectral estimate (one resonant pair, low-frequency drift, slack).
AR_ORDER = 8


def residual_psd(resid: np.ndarray, dt: float, omega_lo: float, n_omega: int = 256
                 ) -> tuple[np.ndarray, np.ndarray, int]:
    """Autoregressive PSD [unit^2 s/rad] of residual rows (NaN-padded windows), pooled.

    An AR model fitted by least squares on lagged samples of every window (each detrended
    linearly) resolves a wave peak from windows far shorter than a Welch segment would need
    (Burg 1967 and Akaike 1969 for parametric spectra); ``S = sigma_e^2 dt / (pi |A(e^{i omega dt})|^2)``.

    Parameters
    ----------
    resid : numpy.ndarray
        Residual rows (W, n), NaN outside windows.
    dt : float
        Step [s].
    omega_lo : float
        Lowest frequency of interest [rad/s].
    n_omega : int
        Frequencies evaluated.

    Returns
    -------
    omega, psd, samples
        Frequencies in ``(omega_lo / 2, pi / dt)`` [rad/s], PSD, and the samples used (0 when
        there were too few).
    """
    p = AR_ORDER
    rows, targets = [], []
    for row in resid:
        x = row[np.isfinite(row)]
        if len(x) < 3 * p:
            continue
        tt = np.arange(len(x))
        x = x - np.polyval(np.polyfit(tt, x, 1), tt)
        lagged = np.lib.stride_tricks.sliding_window_view(x, p + 1)
        rows.append(lagged[:, :p][:, ::-1])
        targets.append(lagged[:, p])
    if not rows:
        return np.zeros(0), np.zeros(0), 0
    a = np.concatenate(rows)
    b = np.concatenate(targets)
    if len(b) < 10 * p:
        return np.zeros(0), np.zeros(0), 0
    coef, *_ = np.linalg.lstsq(a, b, rcond=None)
    e = b - np.einsum("ij,j->i", a, coef)
    var = float(np.mean(e**2))
    omega = np.linspace(max(omega_lo / 2, 1e-3), np.pi / dt, n_omega)
    z = np.exp(-1j * np.outer(omega * dt, np.arange(1, p + 1)))
    den = np.abs(1 - z @ coef) ** 2
    return omega, var * dt / np.pi / den, int(len(b))


def fit_residual_spectrum(resid: np.ndarray, dt: float, band: tuple[float, float]) -> WaveSpectrum:
    """Fit ``N0 (1 + 2 rho cos(omega dt)) + A / omega^2 + S_w`` to the residual PSD in ``band``
    (log least squares).

    Parameters
    ----------
    resid : numpy.ndarray, shape (W, n)
        Baseline residuals per window (NaN outside windows) [unit].
    dt : float
        Sample step [s].
    band : tuple[float, float]
        Wave frequencies searched [rad/s].

    Returns
    -------
    WaveSpectrum
        ``sigma = 0`` when the data cannot support a fit (too short, too few frequencies).
    """
    lo, hi = band
    omega, psd, segs = residual_psd(resid, dt, lo)
    null = WaveSpectrum(np.nan, np.nan, 0.0, float(np.median(psd)) if len(psd) else 0.0, 0.0, band)
    if segs == 0:
        return null
    sel = (omega >= lo / 1.5) & (omega <= hi) & (psd > 0)
    if sel.sum() < 16:
        return null
    w = omega[sel]
    s = psd[sel]
    logs = np.log(s)
    n0_0 = float(np.percentile(s, 20))
    a0 = max(float(np.min(s * w**2)) * 0.5, 1e-30)

    cos_w = np.cos(w * dt)

    def model(x: np.ndarray) -> np.ndarray:
        # x is (6,) or (6, B): a batch of parameter vectors evaluated at once (the Jacobian's).
        x = x[..., None]
        n0, a, om, lam, sig, rho = np.exp(x[0]), np.exp(x[1]), np.exp(x[2]), x[3], np.exp(x[4]), x[5]
        return n0 * (1.0 + 2.0 * rho * cos_w) + a / w**2 + wave_psd(w, om, lam, sig)

    def resid_fn(x: np.ndarray) -> np.ndarray:
        return np.log(model(x)) - logs

    def jac_fn(x: np.ndarray) -> np.ndarray:
        # Forward differences, all six perturbed vectors in one vectorised evaluation.
        h = 1e-7 * np.maximum(np.abs(x), 1.0)
        batch = x[:, None] + np.diag(h)
        f0 = np.log(model(x))
        return ((np.log(model(batch)) - f0) / h[:, None]).T

    best = None
    # rho stops just short of +-1/2, where the background reaches zero at one end of the band.
    lb = [np.log(n0_0) - 12, np.log(a0) - 20, np.log(lo), LAMBDA_BOUNDS[0], np.log(1e-12) + 0.5 * np.log(n0_0 * hi),
          RHO_BOUNDS[0] * 0.98]
    ub = [np.log(n0_0) + 12, np.log(a0) + 20, np.log(hi), LAMBDA_BOUNDS[1], 0.5 * np.log(np.sum(s) * hi) + 5,
          RHO_BOUNDS[1] * 0.98]
    inb = (w >= lo) & (w <= hi)
    # Start at the strongest whitened peaks in the band and at a few spread frequencies.
    peaks = list(w[inb][np.argsort(s[inb])[-3:]]) if inb.any() else []
    starts = sorted(set(float(np.clip(om, lo, hi)) for om in
                        peaks + list(np.exp(np.linspace(np.log(lo), np.log(hi), 4)))))
    for om in starts:
        excess = max(float(np.interp(om, w, s)) - n0_0, n0_0 * 0.1)
        sig0 = np.sqrt(excess * np.pi / (4 * 0.15 * om) * 1.0)
        x0 = np.array([np.log(n0_0), np.log(a0), np.log(om), 0.15, np.log(max(sig0, 1e-15)), 0.0])
        x0 = np.clip(x0, np.array(lb) + 1e-6, np.array(ub) - 1e-6)
        try:
            sol = scipy.optimize.least_squares(resid_fn, x0, jac=jac_fn, bounds=(lb, ub), max_nfev=200)
        except ValueError:
            continue
        if best is None or sol.cost < best.cost:
            best = sol
    if best is None:
        return null
    x = best.x
    om, lam_, sig = float(np.exp(x[2])), float(x[3]), float(np.exp(x[4]))
    rest_spec = WaveSpectrum(om, lam_, sig, float(np.exp(x[0])), float(np.exp(x[1])), band, float(x[5]), dt)
    sw, rest = wave_psd(np.array([om]), om, lam_, sig)[0], float(rest_spec.background(np.array([om]))[0])
    # A wave is a resolved peak inside the band: not a spectrum rising toward the band's low edge
    # (that is the model's own low-frequency error) and clearly above the background.
    if om < lo * EDGE_MARGIN or om > hi / EDGE_MARGIN or sw < PEAK_RATIO * rest:
        return null
    return rest_spec


#: Prior variance of a window's drift level and slope, in units of the rows' variance (a diffuse
#: prior: each window's own line is estimated from its data alone).
DIFFUSE = 1e6
#: States of the smoother's model: wave ``xi_w, psi_w``, drift level and slope, and the two shared
#: end samples of a trapezoidal block mean (:func:`_state_space`).
N_STATES = 6


def smooth_waves(resid: np.ndarray, dt: float, spec: WaveSpectrum) -> np.ndarray:
    """Wave component of residual rows by the fixed-interval Kalman smoother of the fitted spectrum.

    Each row (a window) is modelled as three parts (Fossen 2021, sec. 10.2.4 for the wave states)::

        r_k = psi_w(t_k) + l(t_k) + v_k,   psi_w: the second-order wave model (omega0, lambda, sigma),
        l_dot = s + eta,  s_dot = 0:       the low-frequency model error, a random walk of intensity
                                           pi A (the spectrum's A / omega^2) on a line,
        v_k:                               sensor noise of variance pi N0 / dt in a trapezoidal mean
                                           of m samples (lag-1 correlation 1 / (4 m - 2)),

    with the wave started in its stationary distribution and the line's level and slope diffuse
    (each window's own), and the wave states are estimated with the Rauch-Tung-Striebel smoother
    (Rauch, Tung and Striebel 1965), every window side by side. Far from the window ends this is
    the non-causal Wiener smoother ``G = S_w / (S_w + rest)`` of the same spectrum; at the ends it
    needs no mirroring. The smoother that came before (the FFT of each row, mirrored about a line
    through its end samples) left the wave's value at both window ends in that line and never
    returned it: a quarter of the wave's RMS stayed in the residual (randomised seed 34 r006:
    0.0145 rad of a 0.057 rad wave, against 0.0023 rad with this smoother and the background of
    :func:`refine_background`).

    Parameters
    ----------
    resid : numpy.ndarray, shape (W, n)
        Residuals (NaN outside windows and at missing samples) [unit].
    dt : float
        Sample step [s].
    spec : WaveSpectrum
        Fitted spectrum.

    Returns
    -------
    numpy.ndarray, shape (W, n)
        Estimated wave component (NaN where ``resid`` is; 0 in a row with fewer than 4 samples).
    """
    ok = np.isfinite(resid)
    if not np.isfinite(spec.omega0) or spec.sigma <= 0 or resid.size == 0:
        return np.where(ok, 0.0, np.nan)
    n_rows, n = resid.shape
    f, q, h, r, p0 = _state_space(resid, dt, spec)
    x_f, p_f, x_p, p_p, _ = _kalman_filter(resid, f, q, h, r, p0, keep=True)
    wave = np.zeros((n_rows, n))
    xs = x_f[-1]
    wave[:, -1] = xs[:, 1]
    for k in range(n - 2, -1, -1):
        # Smoother gain C = P_f F^T P_p(k+1)^-1, from one batched solve (P symmetric).
        c = np.swapaxes(np.linalg.solve(p_p[k + 1], f @ p_f[k]), 1, 2)
        xs = x_f[k] + np.einsum("...ij,...j->...i", c, xs - x_p[k + 1])
        wave[:, k] = xs[:, 1]
    wave[ok.sum(axis=1) < 4] = 0.0
    return np.where(ok, wave, np.nan)


def _kalman_filter(resid: np.ndarray, f: np.ndarray, q: np.ndarray, h: np.ndarray, r: float, p0: np.ndarray,
                   keep: bool = False) -> tuple:
    """Kalman filter of every row side by side (model of :func:`_state_space`).

    Rows measured at every sample up to their end (the usual window) share one covariance path,
    computed once; a row with a gap inside it gets its own (batched with the other such rows).

    Returns ``(x_f, p_f, x_p, p_p, loglik)``: filtered and predicted states per column, shape
    ``(n, W, states)``, and covariances, shape ``(n, W, states, states)`` or ``(n, 1, states,
    states)`` when every row shares the path (None unless ``keep``), and the Gaussian
    log-likelihood of the rows' innovations [-].
    """
    ok = np.isfinite(resid)
    ends = ok.shape[1] - np.argmax(ok[:, ::-1], axis=1)
    ends[~ok.any(axis=1)] = 0
    regular = ok.sum(axis=1) == ends
    if regular.all():
        return _filter_rows(resid, f, q, h, r, p0, keep, shared=True)
    out_r = _filter_rows(resid[regular], f, q, h, r, p0, keep, shared=True)
    out_i = _filter_rows(resid[~regular], f, q, h, r, p0, keep, shared=False)
    if not keep:
        return None, None, None, None, out_r[4] + out_i[4]
    n, ns = resid.shape[1], len(h)
    merged = []
    for k, full in ((0, False), (1, True), (2, False), (3, True)):
        shape = (n, len(resid), ns, ns) if full else (n, len(resid), ns)
        arr = np.zeros(shape)
        arr[:, regular] = out_r[k] if not full else np.broadcast_to(out_r[k], (n, int(regular.sum()), ns, ns))
        arr[:, ~regular] = out_i[k]
        merged.append(arr)
    return (*merged, out_r[4] + out_i[4])


def _filter_rows(resid: np.ndarray, f: np.ndarray, q: np.ndarray, h: np.ndarray, r: float, p0: np.ndarray,
                 keep: bool, shared: bool) -> tuple:
    """:func:`_kalman_filter` of rows that all share one covariance path (``shared``: every row
    measured at each sample up to its end) or each with its own."""
    n_rows, n = resid.shape
    ns = len(h)
    nc = 1 if shared else n_rows
    x_f = np.zeros((n, n_rows, ns)) if keep else None
    x_p = np.zeros((n, n_rows, ns)) if keep else None
    p_f = np.zeros((n, nc, ns, ns)) if keep else None
    p_p = np.zeros((n, nc, ns, ns)) if keep else None
    x = np.zeros((n_rows, ns))
    p = np.broadcast_to(p0, (nc, ns, ns)).copy()
    loglik = 0.0
    for k in range(n):
        if k > 0:
            x = x @ f.T
            p = f @ p @ f.T + q
        if keep:
            x_p[k], p_p[k] = x, p
        z = resid[:, k]
        has = np.isfinite(z)
        if has.any():
            ph = p @ h
            s = ph @ h + r
            nu = np.where(has, z - x @ h, 0.0)
            gain = ph / s[:, None]
            x = x + np.where(has[:, None], gain, 0.0) * nu[:, None]
            if shared:
                p = p - gain[:, :, None] * ph[:, None, :]
            else:
                p = p - np.where(has[:, None, None], gain[:, :, None] * ph[:, None, :], 0.0)
            p = 0.5 * (p + np.swapaxes(p, 1, 2))
            loglik -= 0.5 * float(np.sum(np.where(has, np.log(np.broadcast_to(s, has.shape)) + nu**2 / s, 0.0)))
        if keep:
            x_f[k], p_f[k] = x, p
    return x_f, p_f, x_p, p_p, loglik


def _state_space(resid: np.ndarray, dt: float, spec: WaveSpectrum
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, np.ndarray]:
    """State-space model of :func:`smooth_waves`: transition ``F``, process noise ``Q``, output row
    ``H``, measurement noise variance ``R`` and initial covariance ``P0``.

    States ``[xi_w, psi_w, l, s, u_k, u_k+1]``: the wave (:mod:`pipeline.model.waves`; none when
    ``spec.sigma`` is 0), the drift's level and slope, and the sensor noise of the block's two end
    samples. A trapezoidal mean of ``m`` samples (:func:`pipeline.diagnose.problem.block_average`)
    of white noise of variance ``s^2`` is ``a_k + u_k + u_k+1``: its inner samples ``a_k`` (variance
    ``(m - 1) s^2 / m^2``, independent) and half of each end sample (``u``, variance ``s^2 / (4 m^2)``),
    which the next block shares; the block's variance ``R_b = (m - 1/2) s^2 / m^2`` is ``pi N0 / dt``.
    """
    f = np.zeros((N_STATES, N_STATES))
    q = np.zeros((N_STATES, N_STATES))
    p0 = np.zeros((N_STATES, N_STATES))
    if np.isfinite(spec.omega0) and spec.sigma > 0:
        # The wave model driven by unit-intensity white noise has stationary variance K^2 / (4 lambda omega0).
        kw = spec.sigma * np.sqrt(4.0 * spec.lam * spec.omega0)
        ad, qd = wave_discrete(WaveParams(omega0=spec.omega0, lam=spec.lam, kw=kw), dt)
        f[:2, :2], q[:2, :2] = ad, qd
        p0[:2, :2] = np.diag([spec.sigma**2 / spec.omega0**2, spec.sigma**2])
    f[2:4, 2:4] = [[1.0, dt], [0.0, 1.0]]
    # A one-sided PSD A / omega^2 [unit^2 s/rad] is a random walk of intensity pi A [unit^2/s].
    q[2, 2] = np.pi * spec.a_lf * dt
    m = max(int(spec.m), 1)
    r_block = np.pi * spec.n0 / dt
    r_end = r_block / (4.0 * m - 2.0)
    f[4, 5] = 1.0
    q[5, 5] = r_end
    p0[4, 4] = p0[5, 5] = r_end
    h = np.array([0.0, 1.0, 1.0, 0.0, 1.0, 1.0])
    # The inner samples' share; a small floor keeps the update defined at m = 1 (no inner sample).
    r = float(r_block * (m - 1.0) / (m - 0.5) + 1e-6 * r_block + 1e-12 * (spec.sigma**2 + 1e-30))
    scale = float(np.nanvar(resid)) + spec.sigma**2 + r_block
    span = resid.shape[1] * dt
    p0[2, 2] = DIFFUSE * scale
    p0[3, 3] = DIFFUSE * scale / span**2
    return f, q, h, r, p0


def _loglik(resid: np.ndarray, dt: float, spec: WaveSpectrum) -> float:
    """Log-likelihood of the rows under :func:`_state_space` [-]."""
    return _kalman_filter(resid, *_state_space(resid, dt, spec))[4]


def _best_background(resid: np.ndarray, dt: float, spec: WaveSpectrum, a0: float, r0: float
                     ) -> tuple[WaveSpectrum, float]:
    """``spec`` with the drift level ``A`` and the noise variance ``R_b`` of the largest likelihood,
    and that log-likelihood: a pattern search in ``log A`` and ``log R_b`` from ``(a0, r0)``, steps
    of :data:`SEARCH_STEP` decades halved down to :data:`SEARCH_TOL` (Hooke and Jeeves 1961), each
    within :data:`SEARCH_RANGE` decades of its start, at most :data:`SEARCH_PASSES` filter passes."""
    def at(a: float, r: float) -> WaveSpectrum:
        return replace(spec, a_lf=float(a), n0=float(r * dt / np.pi))

    lo, hi = 10.0 ** -SEARCH_RANGE, 10.0 ** SEARCH_RANGE
    a, r = a0, r0
    best = _loglik(resid, dt, at(a, r))
    step, passes = SEARCH_STEP, 1
    while step >= SEARCH_TOL and passes < SEARCH_PASSES:
        moved = False
        for ta, tr in ((a * 10**step, r), (a / 10**step, r), (a, r * 10**step), (a, r / 10**step)):
            if not (lo <= ta / a0 <= hi and lo <= tr / r0 <= hi):
                continue
            v = _loglik(resid, dt, at(ta, tr))
            passes += 1
            if v > best:
                best, a, r, moved = v, ta, tr, True
                break
        if not moved:
            step /= 2.0
    return at(a, r), best


#: First and last step of :func:`_best_background` [decades], its range about the start
#: [decades] and its most filter passes.
SEARCH_STEP, SEARCH_TOL, SEARCH_RANGE, SEARCH_PASSES = 1.0, 0.1, 3.0, 30
#: Level of the likelihood-ratio test of a wave against the background alone.
WAVE_ALPHA = 1e-4


def refine_background(resid: np.ndarray, dt: float, spec: WaveSpectrum, noise: float = float("nan"),
                      m: int = 1) -> WaveSpectrum:
    """The spectrum with its background (``A`` and ``N0``) set by maximum likelihood of the
    smoother's model on the rows (the wave's ``omega0``, ``lambda``, ``sigma`` kept), or no wave
    when the likelihood-ratio test does not find one.

    The log least-squares fit of the autoregressive spectrum sets the background poorly under a
    strong wave: the AR estimate smears the wave peak to low frequencies, which the fit reads as
    model error (randomised seed 34 r006: at 0.2 rad/s 200 times the PSD of the residual without the
    wave), and where the wave's high-frequency tail lies above the sensor noise everywhere, ``N0``
    fits to nothing; with ``A`` that large the smoother gives the drift much of the wave. And its
    peak test (:data:`PEAK_RATIO`) is no test: on a clean twin-thruster trial logged at 8.3 Hz
    (randomised seed 28 r006) the residual's own colour (a trapezoidal mean of one sample is a
    two-sample average: lag-1 correlation 1/2) fitted as a broad wave at 4.1 rad/s, and a smoother,
    which removes whatever share of the noise lies under a wave spectrum, takes part of the sensor
    noise with it: the candidate took 17.8 % of the yaw gap (with the Kalman smoother and no test,
    the heading's held-out gap went from 1.03 to 0.72 noise units, below the noise itself).

    Here the background is the maximum-likelihood one (:func:`_best_background`) with the wave and
    without it, the noise's block colour in both (:func:`_state_space`), and the wave is kept only
    when twice the log-likelihood ratio exceeds the chi-square quantile of its three parameters at
    :data:`WAVE_ALPHA` (Wilks 1938; the wave's parameters come from the spectrum fit, not the
    likelihood's maximum, so the test is conservative).

    Parameters
    ----------
    resid : numpy.ndarray, shape (W, n)
        Training residual rows (NaN outside windows) [unit].
    dt : float
        Sample step [s].
    spec : WaveSpectrum
        Fitted spectrum (returned unchanged without a wave).
    noise : float
        The channel's white noise on the grid (standard deviation of a block mean) [unit]; NaN when
        unknown.
    m : int
        Trial samples per block of the rows.

    Returns
    -------
    WaveSpectrum
        With ``m`` set; the null spectrum (``sigma = 0``) when the test finds no wave.
    """
    spec = replace(spec, m=int(max(m, 1)))
    if not np.isfinite(spec.omega0) or spec.sigma <= 0 or not np.isfinite(resid).any():
        return spec
    r0 = max(np.pi * spec.n0 / dt, noise**2 if np.isfinite(noise) else 0.0, 1e-6 * spec.sigma**2)
    a0 = max(spec.a_lf, 1e-12 * spec.sigma**2)
    with_wave, ll1 = _best_background(resid, dt, spec, a0, r0)
    null = replace(spec, sigma=0.0)
    # The background alone starts where it fits the rows' variance: its noise at the wave's and
    # the noise's variance together.
    _, ll0 = _best_background(resid, dt, null, a0, r0 + spec.sigma**2)
    _, ll0b = _best_background(resid, dt, null, with_wave.a_lf, np.pi * with_wave.n0 / dt)
    if 2.0 * (ll1 - max(ll0, ll0b)) < scipy.stats.chi2.isf(WAVE_ALPHA, 3):
        return WaveSpectrum(np.nan, np.nan, 0.0, spec.n0, spec.a_lf, spec.band, spec.rho, spec.dt, spec.m)
    return with_wave
