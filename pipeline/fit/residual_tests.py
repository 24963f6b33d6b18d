"""Residual analysis of a fitted model, as MATLAB's ``resid`` does it (Ljung 1999, sec. 16.6).

Two questions are asked of the prediction errors ``e = y - y_model`` of a fit:

- **Whiteness.** Is ``e`` white? The normalised autocorrelation ``rho_e(k) = R_e(k) / R_e(0)``
  of a white sequence of length ``N`` is asymptotically normal with variance ``1/N``, so about 95%
  of the lags ``1..M`` lie within ``+-1.96/sqrt(N)``. The Ljung-Box statistic
  ``Q = N (N + 2) sum_{k=1}^{M} rho_e(k)^2 / (N - k)`` is chi-square with ``M`` degrees of freedom
  (Ljung & Box 1978). Coloured residuals mean unmodelled dynamics, waves or a filtered sensor:
  the estimate may still be fine, but the white-noise covariance behind its error bar is too small.
- **Independence of the input.** Is ``e`` uncorrelated with the input? The normalised
  cross-correlation ``rho_eu(k)`` has variance ``P/N`` with ``P = sum_k rho_e(k) rho_u(k)``
  (Ljung 1999, eq. 16.64), which is ``1`` for white ``e``; that band is reported per lag, as
  ``resid`` draws it. The lags of a coloured input (a step, a zig-zag) are strongly correlated with
  each other, so the decision is made on the input prewhitened by a least-squares AR model
  (Box & Jenkins 1976, sec. 11.2): then ``N sum_k rho_(e u~)(k)^2`` over ``k = -M..M`` is
  chi-square with ``2M + 1`` degrees of freedom for a white residual independent of the input. A
  significant ``rho_eu(k)`` at ``k >= 0`` means part of the response to the input is not in the
  model (a wrong gain, a delay, a missing coupling); at ``k < 0`` it points at feedback (a
  helmsman or autopilot closing the loop).

Whiteness fails when the Ljung-Box p-value is below ``alpha`` (default 1%) or when more lags fall
outside the 95% band than a binomial count allows at ``alpha``; independence fails when the
prewhitened chi-square p-value is below ``alpha``.

References
----------
Ljung, L. (1999). *System Identification: Theory for the User*, 2nd ed., sec. 16.6. Prentice Hall.
Ljung, G. M. & Box, G. E. P. (1978). On a measure of lack of fit in time series models.
*Biometrika* 65(2), 297-303.
Box, G. E. P. & Jenkins, G. M. (1976). *Time Series Analysis: Forecasting and Control*. Holden-Day.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np
from scipy import linalg, stats

from ..errors import FitError
from ..records import SegmentFit, Trial

#: Two-sided 95% quantile of the normal distribution: the band drawn by ``resid``.
BAND_Z = 1.959963984540054
#: Significance of the whiteness and independence decisions.
ALPHA = 0.01
#: Default number of lags (MATLAB's ``resid`` uses 25).
MAX_LAG = 25
#: Fewest residuals a test is run on.
MIN_SAMPLES = 30


@dataclass(frozen=True)
class ResidualTest:
    """Result of :func:`residual_test` on one residual sequence.

    Attributes
    ----------
    name : str
        What was tested (segment label, channel).
    n : int
        Residuals used.
    max_lag : int
        Lags tested, ``M``.
    autocorrelation : numpy.ndarray, shape (M + 1,)
        ``rho_e(0..M)`` [-]; ``rho_e(0) = 1``.
    band : float
        ``1.96/sqrt(N)``: the 95% band of a white sequence [-].
    outside : int
        Lags ``1..M`` with ``|rho_e(k)| > band``.
    ljung_box_q, ljung_box_p : float
        Ljung-Box statistic and its chi-square p-value on ``M`` degrees of freedom.
    cross_correlation : Mapping[str, numpy.ndarray]
        ``rho_eu(-M..M)`` per input channel [-] (inputs that are constant over the record are left out).
    cross_band : Mapping[str, float]
        ``1.96 sqrt(P/N)`` per input.
    cross_outside : Mapping[str, int]
        Lags outside the band per input.
    cross_p : Mapping[str, float]
        p-value of the prewhitened chi-square independence test per input.
    white : bool
        Whiteness not rejected at ``ALPHA``.
    independent : bool
        Independence of every input not rejected at ``ALPHA`` (True when no input varies).
    message : str
        Empty when both pass; otherwise what failed and what it means.
    """

    name: str
    n: int
    max_lag: int
    autocorrelation: np.ndarray
    band: float
    outside: int
    ljung_box_q: float
    ljung_box_p: float
    cross_correlation: Mapping[str, np.ndarray] = field(default_factory=dict)
    cross_band: Mapping[str, float] = field(default_factory=dict)
    cross_outside: Mapping[str, int] = field(default_factory=dict)
    cross_p: Mapping[str, float] = field(default_factory=dict)
    white: bool = True
    independent: bool = True
    message: str = ""

    @property
    def passed(self) -> bool:
        """Both whiteness and input independence hold."""
        return self.white and self.independent


def autocorrelation(e: np.ndarray, max_lag: int) -> np.ndarray:
    """Normalised sample autocorrelation ``rho(0..max_lag)`` of a mean-removed sequence [-].

    Uses the biased estimator ``R(k) = (1/N) sum e_t e_{t+k}`` (as ``resid`` and the Ljung-Box test
    assume), computed by FFT.

    Parameters
    ----------
    e : numpy.ndarray
        Sequence in time order.
    max_lag : int
        Largest lag.
    """
    e = np.asarray(e, float) - np.mean(e)
    n = e.size
    size = 1 << int(math.ceil(math.log2(2 * n)))
    f = np.fft.rfft(e, size)
    r = np.fft.irfft(f * np.conj(f), size)[: max_lag + 1]
    return r / r[0] if r[0] > 0 else np.zeros(max_lag + 1)


def cross_correlation(e: np.ndarray, u: np.ndarray, max_lag: int) -> np.ndarray:
    """Normalised cross-correlation ``rho_eu(k)``, ``k = -max_lag..max_lag`` [-].

    ``rho_eu(k) = R_eu(k) / sqrt(R_e(0) R_u(0))`` with ``R_eu(k) = (1/N) sum_t e_(t+k) u_t``: a
    positive lag compares the residual with an *earlier* input (the causal direction).

    Parameters
    ----------
    e, u : numpy.ndarray
        Residual and input, same length, time order.
    max_lag : int
        Largest lag.
    """
    e = np.asarray(e, float) - np.mean(e)
    u = np.asarray(u, float) - np.mean(u)
    n = e.size
    den = math.sqrt(float(e @ e) * float(u @ u))
    out = np.zeros(2 * max_lag + 1)
    if den == 0:
        return out
    for j, k in enumerate(range(-max_lag, max_lag + 1)):
        out[j] = float(e[k:] @ u[: n - k]) if k >= 0 else float(e[: n + k] @ u[-k:])
    return out / den


#: Largest AR order of the input prewhitening filter.
MAX_AR_ORDER = 10


def prewhiten(u: np.ndarray, order: int = MAX_AR_ORDER) -> np.ndarray:
    """Innovations of an AR(``order``) model of ``u`` (mean removed), length ``N - order``.

    The AR coefficients solve the Yule-Walker equations (a Toeplitz system in the sample
    autocorrelation), which is as good as least squares for the long records tested here and
    much cheaper.

    Parameters
    ----------
    u : numpy.ndarray
        Input sequence in time order.
    order : int
        AR order (clipped to ``N/10``).

    Returns
    -------
    numpy.ndarray
        ``u_t - sum_i a_i u_(t-i)`` for ``t = order..N-1``; the input itself (mean removed) when too
        short for an AR model.
    """
    u = np.asarray(u, float) - np.mean(u)
    p = int(min(order, u.size // 10))
    if p < 1 or not np.any(u):
        return u
    rho = autocorrelation(u, p)
    try:
        # A tiny ridge keeps the Toeplitz system regular for an input that is nearly deterministic.
        a = linalg.solve_toeplitz((rho[:p] + np.r_[1e-9, np.zeros(p - 1)], rho[:p]), rho[1: p + 1])
    except (np.linalg.LinAlgError, ValueError):
        return u
    lags = np.column_stack([u[p - i - 1: u.size - i - 1] for i in range(p)])
    return u[p:] - lags @ a


def _binomial_reject(outside: int, lags: int, alpha: float) -> bool:
    # Under the null each lag falls outside the 95% band with probability 0.05 (independently, to
    # first order): more than the binomial (1 - alpha) quantile is too many to be chance.
    return outside > 0 and float(stats.binom.sf(outside - 1, lags, 0.05)) < alpha


def residual_test(residuals: np.ndarray, inputs: Mapping[str, np.ndarray] | None = None, name: str = "",
                  max_lag: int = MAX_LAG, alpha: float = ALPHA) -> ResidualTest:
    """Whiteness and input cross-correlation tests of one residual sequence (``resid``).

    Parameters
    ----------
    residuals : numpy.ndarray
        Prediction errors in time order, uniformly sampled [unit of the output]; non-finite values
        are dropped (with their input samples).
    inputs : Mapping[str, numpy.ndarray], optional
        Input channels on the same samples [SI]; constant ones are skipped.
    name : str
        What is tested, for the message.
    max_lag : int
        Lags ``M`` (clipped to ``N/4``).
    alpha : float
        Significance level of the decisions.

    Returns
    -------
    ResidualTest
        With ``white``/``independent`` flags and a message that says what failed.

    Raises
    ------
    FitError
        An input does not have one sample per residual.
    """
    e = np.asarray(residuals, float)
    ok = np.isfinite(e)
    ins = {k: np.asarray(v, float) for k, v in (inputs or {}).items()}
    for ch, v in ins.items():
        if v.shape != e.shape:
            raise FitError(f"{name or 'residual test'}: expected input {ch!r} with {e.size} samples like the "
                           f"residuals, found shape {v.shape}")
        ok &= np.isfinite(v)
    e = e[ok]
    n = e.size
    if n < MIN_SAMPLES:
        return ResidualTest(name=name, n=n, max_lag=0, autocorrelation=np.ones(1), band=math.nan, outside=0,
                            ljung_box_q=math.nan, ljung_box_p=math.nan, white=True, independent=True,
                            message=f"{name}: residual tests not run: expected at least {MIN_SAMPLES} "
                                    f"residuals, found {n}")
    m = int(max(1, min(max_lag, n // 4)))
    rho = autocorrelation(e, m)
    band = BAND_Z / math.sqrt(n)
    outside = int(np.sum(np.abs(rho[1:]) > band))
    k = np.arange(1, m + 1)
    q = float(n * (n + 2) * np.sum(rho[1:] ** 2 / (n - k)))
    p = float(stats.chi2.sf(q, m))
    white = not (p < alpha or _binomial_reject(outside, m, alpha))

    xc, xb, xo, xp = {}, {}, {}, {}
    for ch, u in ins.items():
        u = u[ok]
        if np.ptp(u) == 0:
            continue
        rho_u = autocorrelation(u, m)
        # P = sum_{k=-M}^{M} rho_e(k) rho_u(k): both autocorrelations are even.
        big_p = float(rho[0] * rho_u[0] + 2 * np.sum(rho[1:] * rho_u[1:]))
        b = BAND_Z * math.sqrt(max(big_p, 1e-12) / n)
        c = cross_correlation(e, u, m)
        xc[ch], xb[ch], xo[ch] = c, b, int(np.sum(np.abs(c) > b))
        uw = prewhiten(u)
        if np.ptp(uw) == 0:
            continue
        cw = cross_correlation(e[e.size - uw.size:], uw, m)
        xp[ch] = float(stats.chi2.sf(uw.size * float(cw @ cw), 2 * m + 1))
    independent = all(p_u >= alpha for p_u in xp.values())

    parts = []
    label = f"{name}: " if name else ""
    if not white:
        parts.append(f"{label}residuals are not white (Ljung-Box Q = {q:.3g} on {m} lags, p = {p:.2g}; "
                     f"{outside} of {m} autocorrelation lags outside +-{band:.3f}): unmodelled dynamics or "
                     f"coloured noise, so the standard errors are too small")
    for ch, p_u in xp.items():
        if p_u < alpha:
            lag = int(np.argmax(np.abs(xc[ch]))) - m
            parts.append(f"{label}residuals correlate with input {ch} (prewhitened chi-square p = {p_u:.2g}; "
                         f"{xo[ch]} of {2 * m + 1} lags outside +-{xb[ch]:.3f}, largest at lag {lag}): part of "
                         f"the response to {ch} is not in the model" + (" (negative lag: feedback)" if lag < 0 else ""))
    return ResidualTest(name=name, n=n, max_lag=m, autocorrelation=rho, band=band, outside=outside,
                        ljung_box_q=q, ljung_box_p=p, cross_correlation=xc, cross_band=xb, cross_outside=xo, cross_p=xp,
                        white=white, independent=independent, message="; ".join(parts))


def segment_fit_residual_test(fit: SegmentFit, trial: Trial | None = None, max_lag: int = MAX_LAG,
                              alpha: float = ALPHA) -> ResidualTest:
    """:func:`residual_test` of a :class:`~pipeline.records.SegmentFit` (``y - y_fit``).

    Parameters
    ----------
    fit : SegmentFit
        A fitted segment (a failed one without residuals gives a not-run result).
    trial : Trial, optional
        The trial, to read the segment's input channel on the fit's samples for the
        cross-correlation test (inputs constant over the segment are skipped).
    max_lag : int
        Lags.
    alpha : float
        Significance level.
    """
    from .data import segment_label

    name = f"{segment_label(fit.segment)} {fit.channel}".strip()
    e = np.asarray(fit.y, float) - np.asarray(fit.y_fit, float)
    inputs: dict[str, np.ndarray] = {}
    ch = fit.segment.input_channel
    if trial is not None and ch and trial.has(ch) and e.size:
        t = trial.t
        u = trial.data[ch].to_numpy(dtype=float)
        # The fit's samples are trial samples; nearest-sample lookup keeps them aligned.
        idx = np.clip(np.searchsorted(t, np.asarray(fit.t) + fit.segment.t_start - 1e-9), 0, t.size - 1)
        inputs[ch] = u[idx]
    return residual_test(e, inputs, name, max_lag, alpha)
