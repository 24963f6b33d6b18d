"""Wave-response model from a heading record: Welch PSD and a least-squares fit of the spectrum.

The wave-induced heading is modelled as the output of a second-order filter driven by white noise
(Fossen 2021, sec. 10.2.4; :mod:`pipeline.model.waves`)::

    psi_w(s) = K_w s / (s^2 + 2 lambda omega_0 s + omega_0^2) w_w(s)

with ``w_w`` of unit intensity, ``E[w_w(t) w_w(t')] = delta(t - t')``. Its power spectral density is

    P(omega) = |H(j omega)|^2 = K_w^2 omega^2 / ((omega_0^2 - omega^2)^2 + (2 lambda omega_0 omega)^2)

whose maximum is exactly at ``omega = omega_0`` with value ``sigma^2 = K_w^2 / (2 lambda omega_0)^2``,
so ``K_w = 2 lambda omega_0 sigma`` (sigma^2 is the peak of the PSD).

PSD convention (the ship-autopilot seed mixes them; this module states its own)
-------------------------------------------------------------------------------
All angles are radians. ``P`` is the *two-sided* PSD in the angular-frequency convention,
``var(psi_w) = (1 / 2 pi) * integral_{-inf}^{inf} P(omega) d omega`` [rad^2 s]. From scipy's one-sided
Welch estimate ``G(f)`` [rad^2/Hz], ``P(omega = 2 pi f) = G(f) / 2``. This is the convention of
:func:`pipeline.model.waves.wave_psd` and of :func:`pipeline.model.waves.simulate_waves`, so a model
fitted here, simulated there and put in the Kalman filter's process noise has the variance of the
record it came from.

The TTK4115 course (and the seed) plot ``G(f) / (2 pi)`` instead, a one-sided density per rad/s
that is ``pi`` times smaller, and fit ``|H|^2`` to it. Their sigma and K_w are therefore ``sqrt(pi)``
times smaller than ours for the same record (``COURSE_SCALE``); :func:`wave_fit_to_dict` reports both. Fitting
``|H|^2`` to ``G / (2 pi)`` but simulating with unit-intensity noise would under-state the waves'
variance by a factor pi.

References
----------
Fossen, T. I. (2021). Handbook of Marine Craft Hydrodynamics and Motion Control, 2nd ed., Wiley,
sec. 10.2.4 (linear wave-response approximation).
Welch, P. D. (1967). The use of the fast Fourier transform for the estimation of power spectra.
IEEE Trans. Audio Electroacoust. 15(2), 70-73.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, fields, replace
from pathlib import Path

import numpy as np

from ..errors import AutopilotError
from ..records import FitResult, WaveFit, fit_result_from_arrays, parameter_unit
from ..model.waves import WaveParams, wave_psd

#: Factor from our sigma and K_w to the course's (``G/(2 pi)`` one-sided per rad/s convention).
COURSE_SCALE = 1.0 / math.sqrt(math.pi)
#: Fewest samples a record may have for a Welch estimate with a usable resolution.
MIN_SAMPLES = 512
#: Longest default Welch segment [samples] (the course's 4096 at 10 Hz: 0.0024 Hz resolution).
MAX_NPERSEG = 4096


@dataclass(frozen=True)
class HeadingRecord:
    """A wave-induced heading record on a uniform clock.

    Attributes
    ----------
    t : numpy.ndarray
        Uniform sample times [s].
    psi : numpy.ndarray
        Heading (wave-induced part) [rad].
    fs : float
        Sample rate [Hz].
    source : str
        File and variable or column read.
    notes : tuple[str, ...]
        What was done to the record (unit conversion, resampling of irregular samples).
    """

    t: np.ndarray
    psi: np.ndarray
    fs: float
    source: str = ""
    notes: tuple[str, ...] = ()


def wave_params(fit: WaveFit) -> WaveParams:
    """The fitted wave model as :class:`pipeline.model.waves.WaveParams` (module convention).

    Parameters
    ----------
    fit : WaveFit
        A wave-spectrum fit; its ``omega0`` [rad/s], ``lam`` [-] and ``kw`` [rad s^-1/2].
    """
    return WaveParams(omega0=fit.value("omega0"), lam=fit.value("lam"), kw=fit.value("kw"))


def course_sigma(fit: WaveFit) -> float:
    """sigma of ``fit`` in the course's ``G/(2 pi)`` convention [rad s^1/2] (compare with the seed).

    Parameters
    ----------
    fit : WaveFit
        A wave-spectrum fit (``statistics["sigma"]``, module convention).
    """
    return fit.statistics["sigma"] * COURSE_SCALE


def course_kw(fit: WaveFit) -> float:
    """K_w of ``fit`` in the course's convention [rad s^-1/2] (compare with the seed's 0.0054).

    Parameters
    ----------
    fit : WaveFit
        A wave-spectrum fit (module convention).
    """
    return fit.value("kw") * COURSE_SCALE


def wave_fit_to_dict(fit: WaveFit) -> dict:
    """JSON-ready summary of a wave fit (what ``vesselid waves`` writes): every parameter as
    ``{"value", "stderr", "unit"}`` plus the conventions and fit details.

    Parameters
    ----------
    fit : WaveFit
        A wave-spectrum fit.
    """

    def entry(name, unit):
        return {"value": _json_num(fit.value(name)), "stderr": _json_num(fit.stderr(name)), "unit": unit}

    st = fit.statistics
    return {
        "omega0": entry("omega0", "rad/s"),
        "lambda": entry("lam", "1"),
        "kw": entry("kw", "rad s^-1/2"),
        "sigma": {"value": _json_num(st["sigma"]), "stderr": _json_num(st["sigma_se"]), "unit": "rad s^1/2"},
        "convention": ("P(omega) = |H(j omega)|^2 for unit-intensity w_w: two-sided PSD, "
                       "var = (1/2pi) int P d omega, P = G_welch(f)/2 [rad^2 s]; "
                       "sigma^2 = max P = P(omega0); kw = 2 lambda omega0 sigma"),
        "course_convention": {
            "sigma": _json_num(course_sigma(fit)), "kw": _json_num(course_kw(fit)),
            "note": "TTK4115/seed convention G_welch(f)/(2 pi): sigma and kw divided by sqrt(pi)",
        },
        "welch_peak": {"omega": _json_num(fit.peak_omega), "psd": _json_num(fit.peak_psd),
                       "sigma_course": _json_num(math.sqrt(fit.peak_psd) * COURSE_SCALE)},
        "band": [float(fit.band[0]), float(fit.band[1])],
        "fs": float(fit.fs), "nperseg": int(fit.nperseg), "n_samples": int(fit.n_samples),
        "rel_residual_std": _json_num(st["rel_residual_std"]),
        "expected_rel_std": _json_num(st["expected_rel_std"]),
        "success": bool(fit.success), "message": fit.message,
    }


def _json_num(x: float) -> float | None:
    return float(x) if x is not None and math.isfinite(x) else None


# --------------------------------------------------------------------------- PSD
def default_nperseg(n: int) -> int:
    """Welch segment length: the largest power of two with at least 8 segments, at most 4096.

    Parameters
    ----------
    n : int
        Record length [samples].

    Returns
    -------
    int
        Segment length [samples].
    """
    if n < MIN_SAMPLES:
        raise AutopilotError(f"wave record: expected at least {MIN_SAMPLES} samples, found {n}")
    return int(min(MAX_NPERSEG, 2 ** int(math.floor(math.log2(n / 8)))))


def welch_psd(psi_w: np.ndarray, fs: float, nperseg: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Welch estimate of the wave-heading PSD in this module's convention.

    Parameters
    ----------
    psi_w : numpy.ndarray
        Wave-induced heading on a uniform clock [rad].
    fs : float
        Sample rate [Hz].
    nperseg : int, optional
        Segment length [samples]; :func:`default_nperseg` if omitted. Hann window, 50 % overlap,
        linear detrend per segment.

    Returns
    -------
    omega : numpy.ndarray
        Angular frequency [rad/s].
    psd : numpy.ndarray
        Two-sided PSD ``P(omega) = G(f) / 2`` [rad^2 s] (see module docstring).
    """
    import scipy.signal  # lazy: scipy.signal costs a second at CLI start-up

    y = np.asarray(psi_w, float)
    nps = default_nperseg(len(y)) if nperseg is None else int(nperseg)
    if nps < 16 or nps > len(y):
        raise AutopilotError(f"wave record: expected 16 <= nperseg <= {len(y)} samples, found {nps}")
    f, g = scipy.signal.welch(y, fs=fs, window="hann", nperseg=nps, noverlap=nps // 2,
                              detrend="linear", scaling="density", return_onesided=True)
    return 2.0 * np.pi * f, 0.5 * g


def _bin_correlation(n: int, nperseg: int, max_lag: int = 8) -> np.ndarray:
    """Correlation of Welch PSD estimates k bins apart for a Gaussian record [-].

    For one segment the periodogram values at two bins are correlated by ``|W2(k)|^2 / W2(0)^2`` with
    ``W2`` the DFT of the squared window (Hann: 0.44 at one bin); with 50 % overlap the products of
    neighbouring segments add ``|C1(k)|^2`` terms, ``C1`` the DFT of ``w[n] w[n + D]``, raising the
    one-bin correlation to about 0.52. Neighbouring bins are therefore far from independent, and a
    covariance that assumed they were would be about 1.4 times too optimistic.
    """
    import scipy.signal  # lazy: scipy.signal costs a second at CLI start-up

    step = nperseg // 2
    k_seg = max(1 + (n - nperseg) // step, 1)
    w = scipy.signal.get_window("hann", nperseg)
    c0 = np.abs(np.fft.fft(w**2)[: max_lag + 1]) ** 2
    total = c0.copy()
    for j in range(1, k_seg):
        lag = j * step
        if lag >= nperseg:
            break
        prod = np.zeros(nperseg)
        prod[: nperseg - lag] = w[:-lag] * w[lag:]
        total += 2.0 * (1.0 - j / k_seg) * np.abs(np.fft.fft(prod)[: max_lag + 1]) ** 2
    return total / total[0]


def _welch_relative_std(n: int, nperseg: int) -> float:
    """Relative standard deviation of a Welch PSD bin for a Gaussian record (Welch 1967, eq. 10)."""
    import scipy.signal  # lazy: scipy.signal costs a second at CLI start-up

    step = nperseg // 2
    k = 1 + (n - nperseg) // step
    w = scipy.signal.get_window("hann", nperseg)
    norm = float(np.sum(w**2))
    total = 1.0
    for j in range(1, k):
        lag = j * step
        if lag >= nperseg:
            break
        rho = float(np.sum(w[:-lag] * w[lag:])) / norm
        total += 2.0 * (1.0 - j / k) * rho**2
    return math.sqrt(total / k)


# --------------------------------------------------------------------------- model and guess
def wave_autocovariance(tau: np.ndarray, params: WaveParams) -> np.ndarray:
    """Autocovariance of psi_w for unit-intensity w_w [rad^2].

    ``R(tau) = K_w^2 / (4 lambda omega_0) exp(-lambda omega_0 |tau|) (cos(omega_d tau) - lambda omega_0 /
    omega_d sin(omega_d |tau|))`` with ``omega_d = omega_0 sqrt(1 - lambda^2)``; for lambda > 1 cos and
    sin become cosh and sinh, and lambda = 1 is the limit ``exp(-omega_0 tau) (1 - omega_0 tau)``.

    Parameters
    ----------
    tau : numpy.ndarray
        Lags [s].
    params : WaveParams

    Returns
    -------
    numpy.ndarray
        R(tau) [rad^2].
    """
    tau = np.abs(np.asarray(tau, float))
    w0, lam, kw = params.omega0, params.lam, params.kw
    a = lam * w0
    var = kw**2 / (4.0 * lam * w0)
    if abs(1.0 - lam) < 1e-9:
        return var * np.exp(-a * tau) * (1.0 - a * tau)
    if lam < 1.0:
        wd = w0 * math.sqrt(1.0 - lam**2)
        return var * np.exp(-a * tau) * (np.cos(wd * tau) - a / wd * np.sin(wd * tau))
    # Over-damped: cosh and sinh written as two decaying exponentials, which cannot overflow.
    beta = w0 * math.sqrt(lam**2 - 1.0)
    return 0.5 * var * ((1.0 - a / beta) * np.exp(-(a - beta) * tau) + (1.0 + a / beta) * np.exp(-(a + beta) * tau))


def expected_welch_psd(params: WaveParams, fs: float, nperseg: int) -> tuple[np.ndarray, np.ndarray]:
    """What the Welch estimate of :func:`welch_psd` converges to for the sampled wave model.

    ``E[P_j] = 1 / (fs sum w^2) sum_k c_w(k) R(k / fs) exp(-i 2 pi j k / N)``, with ``c_w`` the Hann
    window's autocorrelation. Unlike ``|H(j omega)|^2`` this includes the window's smoothing of the
    peak (which widens it: lambda would come out biased high with short segments) and aliasing. The
    per-segment linear detrend is neglected (it only touches the lowest bins).

    Parameters
    ----------
    params : WaveParams
    fs : float
        Sample rate [Hz].
    nperseg : int
        Welch segment length [samples].

    Returns
    -------
    omega : numpy.ndarray
        Welch frequencies [rad/s].
    psd : numpy.ndarray
        Expected PSD, two-sided omega convention [rad^2 s].
    """
    import scipy.signal  # lazy: scipy.signal costs a second at CLI start-up

    n = int(nperseg)
    w = scipy.signal.get_window("hann", n)
    cw = np.correlate(w, w, mode="full")[n - 1:]  # lags 0 .. n-1
    g = cw * wave_autocovariance(np.arange(n) / fs, params)
    # Fold negative lags onto the DFT's period: lag -m is lag n - m.
    s = g.copy()
    s[1:] += g[1:][::-1]
    psd = np.fft.rfft(s).real / (fs * float(np.sum(w**2)))
    return 2.0 * np.pi * np.fft.rfftfreq(n, 1.0 / fs), psd


def guess_wave_params(omega: np.ndarray, psd: np.ndarray) -> WaveParams:
    """Closed-form start: omega_0 at the PSD peak, lambda from the half-power width, K_w = 2 lambda omega_0 sigma.

    For a lightly damped second-order peak the half-power points are ``omega_0 (1 -+ lambda)``, so the
    full width at half maximum is about ``2 lambda omega_0``.

    Parameters
    ----------
    omega : numpy.ndarray
        Frequencies [rad/s], increasing.
    psd : numpy.ndarray
        PSD in this module's convention [rad^2 s].

    Returns
    -------
    WaveParams
        Start values.
    """
    i = int(np.argmax(psd))
    w0 = float(omega[i])
    peak = float(psd[i])
    half = peak / 2.0
    lo = i
    while lo > 0 and psd[lo] > half:
        lo -= 1
    hi = i
    while hi < len(psd) - 1 and psd[hi] > half:
        hi += 1
    width = float(omega[hi] - omega[lo])
    lam = float(np.clip(width / (2.0 * w0), 0.01, 1.0)) if w0 > 0 else 0.1
    return WaveParams(omega0=w0, lam=lam, kw=2.0 * lam * w0 * math.sqrt(peak))


# --------------------------------------------------------------------------- fit
def fit_wave_spectrum(psi_w: np.ndarray, fs: float, nperseg: int | None = None,
                      band: tuple[float, float] | None = None) -> WaveFit:
    """Fit omega_0, lambda and K_w of the second-order wave model to the Welch PSD of a record.

    Ordinary least squares on the PSD itself (not its logarithm) over a band around the peak, as
    Fossen fits the linear approximation to a wave spectrum: the energetic band is what the Kalman
    filter has to remove, and a real sea's spectrum falls off faster than omega^-2 above the peak, so
    the tails would otherwise pull the fit. The model compared with the estimate is what Welch's
    method measures for the sampled model (:func:`expected_welch_psd`: ``|H|^2`` smoothed by the
    window, with aliasing), so lambda is not biased high by short segments. The covariance is a
    sandwich estimate that uses the Welch estimate's statistics: bin variance proportional to
    ``P^2`` (scale from the residuals near the peak, never below Welch's own) and the window's
    bin-to-bin correlation.

    Parameters
    ----------
    psi_w : numpy.ndarray
        Wave-induced heading on a uniform clock [rad]. A heading record with steering in it may be
        used if the steering is slow compared with the waves and ``band`` excludes it.
    fs : float
        Sample rate [Hz].
    nperseg : int, optional
        Welch segment length [samples]; default :func:`default_nperseg`.
    band : tuple of float, optional
        ``(low, high)`` frequencies fitted [rad/s]. Default ``[omega_p / 3, 3 omega_p]`` around the
        largest Welch bin ``omega_p`` above the two lowest bins.

    Returns
    -------
    WaveFit
        A :class:`~pipeline.records.FitResult` of ``omega0``, ``lam``, ``kw`` (values, standard errors,
        units, covariance, success, message, provenance; ``sigma``, ``sigma_se`` and the misfit
        measures in ``statistics``) with the Welch PSD it was fitted to.

    Raises
    ------
    AutopilotError
        Too short, non-finite or constant record; empty band; too few bins in the band.

    References
    ----------
    Fossen (2021), sec. 10.2.4; Welch (1967).
    """
    import scipy.optimize  # lazy, as scipy.signal

    y = np.asarray(psi_w, float)
    if y.ndim != 1:
        raise AutopilotError(f"wave record: expected a 1-D heading series, found shape {y.shape}")
    if not math.isfinite(fs) or fs <= 0:
        raise AutopilotError(f"wave record: expected a positive sample rate [Hz], found {fs!r}")
    if not np.all(np.isfinite(y)):
        raise AutopilotError(f"wave record: expected finite headings, found {int(np.sum(~np.isfinite(y)))} NaN/inf")
    nps = default_nperseg(len(y)) if nperseg is None else int(nperseg)
    if np.ptp(y) == 0.0:
        raise AutopilotError("wave record: expected a varying heading, found a constant series")
    omega, psd = welch_psd(y, fs, nps)

    if band is None:
        usable = np.arange(len(omega)) >= 2  # DC and the first bin hold the detrend residue and drift
        i_p = int(np.flatnonzero(usable)[np.argmax(psd[usable])])
        band = (omega[i_p] / 3.0, min(3.0 * omega[i_p], omega[-1]))
    lo, hi = float(band[0]), float(band[1])
    if not (math.isfinite(lo) and math.isfinite(hi) and 0 <= lo < hi):
        raise AutopilotError(f"wave fit band: expected 0 <= low < high [rad/s], found {band!r}")
    sel = (omega >= lo) & (omega <= hi) & (omega > 0)
    n = int(sel.sum())
    if n < 8:
        raise AutopilotError(f"wave fit band [{lo:.3g}, {hi:.3g}] rad/s: expected at least 8 Welch bins, "
                             f"found {n} (resolution {omega[1]:.3g} rad/s); use a longer record or a wider band")
    w_b, p_b = omega[sel], psd[sel]
    i_peak = int(np.argmax(p_b))
    start = guess_wave_params(w_b, p_b)
    scale = float(p_b[i_peak])
    theta0 = np.array([start.omega0, start.lam, start.kw])

    def model_of(theta):
        return expected_welch_psd(WaveParams(*theta), fs, nps)[1][sel]

    def jacobian(theta):
        # Central differences with relative steps: the expected Welch PSD has no handy closed form.
        cols = []
        for i in range(3):
            step = np.zeros(3)
            step[i] = 1e-6 * theta[i]
            cols.append((model_of(theta + step) - model_of(theta - step)) / (2 * step[i]))
        return np.column_stack(cols)

    res = scipy.optimize.least_squares(lambda th: (model_of(th) - p_b) / scale, theta0,
                                       jac=lambda th: jacobian(th) / scale, x_scale=theta0,
                                       bounds=([1e-6, 1e-4, 1e-12], [np.pi * fs, 10.0, np.inf]),
                                       xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=500)
    theta = res.x
    model, jmat = model_of(theta), jacobian(theta)
    rel = (p_b - model) / model
    # The relative scatter c is estimated where the fit draws its information: the bins within a
    # factor ten of the model's peak. The tails barely move an OLS fit on the linear PSD, and on a
    # real sea their misfit (the spectrum falls faster than omega^-2) would otherwise inflate the
    # errors of the peak parameters tenfold. A residual-based (HAC) meat is no alternative: the few
    # peak bins have high leverage, their residuals are shrunk, and it under-states the errors by
    # about a factor two in Monte Carlo.
    core = model >= 0.1 * model.max()
    if int(core.sum()) < 8:
        core = np.ones(n, bool)
    c_fit = float(np.sum(rel[core] ** 2) / max(int(core.sum()) - 3, 1))
    expected = _welch_relative_std(len(y), nps)
    # A record cannot be better known than the Welch statistics allow: the core has few effectively
    # independent bins, so a lucky small scatter would otherwise give a standard error several times
    # too small.
    c = max(c_fit, expected**2)
    # Sandwich covariance for OLS with Cov(P_i, P_j) = c P_i P_j rho_|i-j| (Welch bins are
    # heteroscedastic and correlated).
    rho = _bin_correlation(len(y), nps)
    idx = np.arange(n)
    lag = np.abs(idx[:, None] - idx[None, :])
    r_mat = np.where(lag < len(rho), rho[np.minimum(lag, len(rho) - 1)], 0.0)
    sigma_mat = c * np.outer(model, model) * r_mat
    messages = []
    try:
        jtj_inv = np.linalg.inv(jmat.T @ jmat)
        cov = jtj_inv @ jmat.T @ sigma_mat @ jmat @ jtj_inv
        se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    except np.linalg.LinAlgError:
        cov = np.full((3, 3), np.nan)
        se = np.full(3, np.nan)
        messages.append("standard errors not computed: the Jacobian is singular (the band does not "
                        "constrain all three parameters)")
    w0, lam, kw = (float(v) for v in theta)
    sigma = kw / (2.0 * lam * w0)
    grad = np.array([-sigma / w0, -sigma / lam, 1.0 / (2.0 * lam * w0)])
    sigma_se = float(math.sqrt(max(grad @ cov @ grad, 0.0))) if np.all(np.isfinite(cov)) else math.nan
    rel_std = math.sqrt(c_fit)
    success = bool(res.success) and lo <= w0 <= hi and lam < 1.0
    if not res.success:
        messages.append(f"optimiser did not converge: {res.message}")
    if not lo <= w0 <= hi:
        messages.append(f"fitted omega0 = {w0:.4g} rad/s lies outside the band [{lo:.4g}, {hi:.4g}] rad/s")
    if lam >= 1.0:
        messages.append(f"fitted lambda = {lam:.3g} >= 1: no resonant peak; the record is not wave-like")
    if rel_std > 2.0 * expected:
        messages.append(f"the second-order model misses the spectrum's shape: relative residual scatter "
                        f"{rel_std:.3g} vs {expected:.3g} expected from the Welch estimate alone; standard "
                        f"errors include this misfit but not the choice of band")
    band_rel = math.sqrt(float(np.mean(rel**2)))
    if band_rel > 3.0 * expected and rel_std <= 2.0 * expected:
        messages.append(f"away from the peak the record departs from the second-order shape (relative "
                        f"residual RMS {band_rel:.3g} over the whole band vs {expected:.3g} expected): the "
                        f"model describes the energetic band only")
    names = ("omega0", "lam", "kw")
    fr = fit_result_from_arrays(
        "wave_spectrum", names, theta, se, cov, {n: parameter_unit(n) for n in names}, success=success,
        message="; ".join(messages), ndata=int(np.size(omega)),
        provenance={"fitter": "pipeline.autopilot.waves_fit.fit_wave_spectrum",
                    "data": f"Welch PSD of {len(y)} samples at {float(fs):g} Hz (nperseg {nps}), "
                            f"band {lo:g}-{hi:g} rad/s",
                    "covariance": "sandwich estimate for least squares on the Welch PSD (bin variance "
                                  "proportional to P^2, the window's bin-to-bin correlation)"},
        statistics={"sigma": float(sigma), "sigma_se": float(sigma_se), "rel_residual_std": float(rel_std),
                    "expected_rel_std": float(expected)})
    return WaveFit(**{f.name: getattr(fr, f.name) for f in fields(FitResult)},
                   omega=omega, psd=psd, band=(lo, hi), peak_omega=float(w_b[i_peak]), peak_psd=float(p_b[i_peak]),
                   fs=float(fs), nperseg=nps, n_samples=len(y))


def fit_wave_record(record: HeadingRecord, nperseg: int | None = None,
                    band: tuple[float, float] | None = None) -> WaveFit:
    """:func:`fit_wave_spectrum` on a :class:`HeadingRecord`; the record's notes join the message.

    Parameters
    ----------
    record : HeadingRecord
        Uniformly sampled wave-induced heading [rad].
    nperseg : int, optional
        Welch segment length [samples].
    band : tuple of float, optional
        Fit band [rad/s].

    Returns
    -------
    WaveFit
        The fit.
    """
    fit = fit_wave_spectrum(record.psi, record.fs, nperseg=nperseg, band=band)
    if record.notes:
        msg = "; ".join([fit.message, *record.notes]) if fit.message else "; ".join(record.notes)
        fit = replace(fit, message=msg)
    return fit


# --------------------------------------------------------------------------- reading records
def uniform_record(t: np.ndarray, psi: np.ndarray, source: str = "", notes: tuple[str, ...] = ()) -> HeadingRecord:
    """Put a heading series on a uniform clock at its median sample interval.

    Variable-step solver output (the course's ``wave.mat`` is irregular near t = 0) is linearly
    interpolated; a Welch estimate needs a uniform clock.

    Parameters
    ----------
    t : numpy.ndarray
        Sample times [s], strictly increasing.
    psi : numpy.ndarray
        Heading [rad].
    source : str
        Where it came from.
    notes : tuple of str
        Notes to carry.

    Returns
    -------
    HeadingRecord
        Uniformly sampled record.

    Raises
    ------
    AutopilotError
        Lengths differ, non-finite values, non-increasing time, too few samples.
    """
    t = np.asarray(t, float)
    psi = np.asarray(psi, float)
    where = source or "wave record"
    if t.shape != psi.shape or t.ndim != 1:
        raise AutopilotError(f"{where}: expected time and heading of equal length, found {t.shape} and {psi.shape}")
    if len(t) < MIN_SAMPLES:
        raise AutopilotError(f"{where}: expected at least {MIN_SAMPLES} samples, found {len(t)}")
    bad = ~(np.isfinite(t) & np.isfinite(psi))
    if bad.any():
        raise AutopilotError(f"{where}: expected finite numbers, found {int(bad.sum())} NaN/inf samples "
                             f"(first at index {int(np.argmax(bad))})")
    dt = np.diff(t)
    if np.any(dt <= 0):
        k = int(np.argmax(dt <= 0))
        raise AutopilotError(f"{where}: expected strictly increasing time, found t[{k + 1}] = {t[k + 1]!r} "
                             f"after t[{k}] = {t[k]!r}")
    h = float(np.median(dt))
    irregular = int(np.sum(np.abs(dt - h) > 1e-6 * h))
    notes = tuple(notes)
    if irregular:
        tu = t[0] + h * np.arange(int(math.floor((t[-1] - t[0]) / h + 1e-9)) + 1)
        psi = np.interp(tu, t, psi)
        t = tu
        notes += (f"{irregular} irregular sample intervals: resampled by linear interpolation at the median "
                  f"interval {h:.6g} s",)
    return HeadingRecord(t=t, psi=psi, fs=1.0 / h, source=source, notes=notes)


_CSV_TIME = ("t", "t_s", "time")
_CSV_VALUES = ("psi_w", "psi_w_rad", "psi_w_deg", "psi", "psi_rad", "psi_deg")


def read_heading_record(path: str | Path, column: str | None = None, unit: str | None = None) -> HeadingRecord:
    """Read a wave-induced heading record from CSV or MATLAB ``.mat``.

    Parameters
    ----------
    path : str or Path
        ``.csv`` with a header row, a time column (``t``, ``t_s`` or ``time`` [s]) and a heading
        column; or ``.mat`` holding a ``2 x N`` array (row 1 time [s], row 2 heading) as the course's
        ``wave.mat`` variable ``psi_w``, or a 1-D heading with a ``t`` variable.
    column : str, optional
        CSV column or MAT variable. Default: the first of ``psi_w, psi_w_rad, psi_w_deg, psi, psi_rad,
        psi_deg`` present (CSV) or ``psi_w`` (MAT).
    unit : {"rad", "deg"}, optional
        Unit of the heading. Default: ``deg`` for names ending in ``_deg`` and for MAT files (the
        course stores degrees), else ``rad`` (the canonical CSV is SI).

    Returns
    -------
    HeadingRecord
        Heading [rad] on a uniform clock.

    Raises
    ------
    AutopilotError
        Missing file, column or variable; unreadable or non-numeric content; bad time axis.
    """
    p = Path(path)
    if unit not in (None, "rad", "deg"):
        raise AutopilotError(f"heading unit: expected 'rad' or 'deg', found {unit!r}")
    if not p.is_file():
        raise AutopilotError(f"{p}: expected a heading record file, found no such file")
    suffix = p.suffix.lower()
    if suffix == ".mat":
        t, values, name, default_unit = _read_mat(p, column)
    elif suffix in (".csv", ".txt"):
        t, values, name, default_unit = _read_csv(p, column)
    else:
        raise AutopilotError(f"{p}: expected a .csv or .mat heading record, found suffix {p.suffix!r}")
    use = unit or default_unit
    notes = ()
    if use == "deg":
        values = np.deg2rad(values)
        notes = (f"{name} read in degrees and converted to radians",)
    return uniform_record(t, values, source=f"{p}:{name}", notes=notes)


def _read_mat(p: Path, column: str | None) -> tuple[np.ndarray, np.ndarray, str, str]:
    import scipy.io  # lazy, as scipy.signal
    try:
        mat = scipy.io.loadmat(str(p))
    except NotImplementedError:
        raise AutopilotError(f"{p}: expected a MATLAB v5/v7 .mat file, found v7.3 (HDF5); save with -v7") from None
    except Exception as exc:  # scipy raises ValueError/TypeError/OSError for corrupt files
        raise AutopilotError(f"{p}: expected a readable .mat file, found: {exc}") from None
    names = sorted(k for k in mat if not k.startswith("__"))
    name = column or "psi_w"
    if name not in mat:
        raise AutopilotError(f"{p}: expected variable {name!r}, found {names}")
    arr = np.asarray(mat[name], dtype=float)
    if arr.ndim == 2 and arr.shape[0] == 2 and arr.shape[1] > 2:
        return arr[0], arr[1], name, "deg"
    if arr.ndim == 2 and arr.shape[1] == 2 and arr.shape[0] > 2:
        return arr[:, 0], arr[:, 1], name, "deg"
    flat = arr.ravel()
    if "t" in mat and np.asarray(mat["t"]).size == flat.size:
        return np.asarray(mat["t"], float).ravel(), flat, name, "deg"
    raise AutopilotError(f"{p}: expected {name!r} as 2 x N [time; heading] or a 1-D heading with a 't' "
                         f"variable of the same length, found shape {arr.shape} and variables {names}")


def _read_csv(p: Path, column: str | None) -> tuple[np.ndarray, np.ndarray, str, str]:
    with open(p, newline="") as fh:
        reader = csv.reader(fh)
        try:
            header = [h.strip() for h in next(reader)]
        except StopIteration:
            raise AutopilotError(f"{p}: expected a header row, found an empty file") from None
        rows = [r for r in reader if r and any(c.strip() for c in r)]
    tcol = next((c for c in _CSV_TIME if c in header), None)
    if tcol is None:
        raise AutopilotError(f"{p}: expected a time column {list(_CSV_TIME)}, found {header}")
    vcol = column or next((c for c in _CSV_VALUES if c in header), None)
    if vcol is None or vcol not in header:
        want = [column] if column else list(_CSV_VALUES)
        raise AutopilotError(f"{p}: expected a heading column {want}, found {header}")
    if not rows:
        raise AutopilotError(f"{p}: expected data rows after the header, found none")
    it, iv = header.index(tcol), header.index(vcol)
    t = np.empty(len(rows))
    v = np.empty(len(rows))
    for k, r in enumerate(rows):
        try:
            t[k] = float(r[it])
            v[k] = float(r[iv])
        except (IndexError, ValueError):
            raise AutopilotError(f"{p}: expected numbers in columns {tcol!r} and {vcol!r}, found {r!r} "
                                 f"on data row {k + 1}") from None
    return t, v, vcol, "deg" if vcol.endswith("_deg") else "rad"


def model_psd(omega: np.ndarray, fit: WaveFit) -> np.ndarray:
    """The fitted model's PSD at ``omega`` [rad^2 s] (module convention), for plots.

    Parameters
    ----------
    omega : numpy.ndarray
        Frequencies [rad/s].
    fit : WaveFit
        The fit; :func:`wave_params` of it goes to :func:`pipeline.model.waves.wave_psd`.
    """
    return wave_psd(omega, wave_params(fit))
