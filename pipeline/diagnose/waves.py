"""The ``waves`` candidate: a second-order wave-band disturbance on a model's output.

Waves add a narrow-band, zero-mean motion to what the sensors see (Fossen 2021, sec. 10.2.4):

    y = y_model + y_w,     y_w(s) = K_w s / (s^2 + 2 lambda omega_0 s + omega_0^2) w(s)

A deterministic simulation cannot predict a random sea, so the candidate is judged the way a
wave-filtering autopilot uses it: the residual spectrum of the baseline on the training windows
(an autoregressive estimate, which short windows support) is fitted with
``S(omega) = N0 (1 + 2 rho cos(omega dt)) + A / omega^2 + S_w(omega)`` (sensor noise, leakage of
low-frequency model error, waves), and on held-out windows the wave part is separated by the non-causal Wiener
smoother ``G = S_w / S`` (Wiener 1949). If there are no waves, ``S_w`` fits to nearly nothing and
the held-out gap does not move; the significance test decides what "nearly" means.

The sensor noise is not white on the analysis grid: a trapezoidal block mean shares its end
sample with the next block (lag-1 correlation ``1 / (4 m - 2)``, one half at one sample per step),
and a sensor logged slower than the trial rate and interpolated (GNSS-derived velocities) is
low-pass. ``rho`` in ``[-1/2, 1/2]`` (the spectrum of any first-order moving average) takes that
smooth colouring, so that a wave is a resolved peak above it and not a broad hump that mimics the
noise's own shape.

PSD convention: one-sided per rad/s, ``var = integral_0^inf S(omega) d omega`` [unit^2 s/rad].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.optimize
import scipy.signal

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
    """

    omega0: float
    lam: float
    sigma: float
    n0: float
    a_lf: float
    band: tuple[float, float]
    rho: float = 0.0
    dt: float = 0.0

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


def smooth_waves(resid: np.ndarray, dt: float, spec: WaveSpectrum) -> np.ndarray:
    """Wave component of residual rows by the Wiener smoother ``G = S_w / (S_w + rest)``.

    Each row is mirrored at both ends before the FFT so the smoother has no edge jumps.

    Parameters
    ----------
    resid : numpy.ndarray, shape (W, n)
        Residuals (NaN outside windows) [unit].
    dt : float
        Sample step [s].
    spec : WaveSpectrum
        Fitted spectrum.

    Returns
    -------
    numpy.ndarray, shape (W, n)
        Estimated wave component (NaN where ``resid`` is).
    """
    out = np.full_like(resid, np.nan)
    if not np.isfinite(spec.omega0) or spec.sigma <= 0:
        return np.where(np.isfinite(resid), 0.0, np.nan)
    for k, row in enumerate(resid):
        ok = np.isfinite(row)
        if ok.sum() < 4:
            out[k] = np.where(ok, 0.0, np.nan)
            continue
        idx = np.flatnonzero(ok)
        x = row[idx[0]:idx[-1] + 1].copy()
        bad = ~np.isfinite(x)
        if bad.any():
            x[bad] = np.interp(np.flatnonzero(bad), np.flatnonzero(~bad), x[~bad])
        lin = np.linspace(x[0], x[-1], len(x))
        xd = x - lin  # the ends meet, so the mirrored signal has no jump either
        ext = np.concatenate([-xd[::-1], xd, -xd[::-1]])
        nfft = int(2 ** np.ceil(np.log2(len(ext))))
        spec_x = np.fft.rfft(ext, nfft)
        omega = 2 * np.pi * np.fft.rfftfreq(nfft, dt)
        sw, rest = spec.parts(omega)
        g = sw / np.maximum(sw + rest, 1e-300)
        g[0] = 0.0
        wave = np.fft.irfft(spec_x * g, nfft)[len(x):2 * len(x)]
        out[k, idx[0]:idx[-1] + 1] = wave
        out[k, ~ok] = np.nan
    return out
