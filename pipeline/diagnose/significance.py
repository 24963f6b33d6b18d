"""Is a candidate's held-out improvement beyond what noise alone produces?

Test (held-out F test with an effective sample size): for each output channel of the DOF, with
``SSE0`` and ``SSE1`` the held-out weighted sums of squares of the baseline and of the candidate,
``p`` the parameters the candidate adds, and ``n_eff = n (1 - rho) / (1 + rho)`` the number of
samples corrected for the lag-1 autocorrelation ``rho`` of the candidate's residual (Bartlett 1946;
a residual that is still a slow model error counts as few independent samples)::

    F = ((SSE0 - SSE1) / p) / (SSE1 / (n_eff - p)),    p_value = 1 - F_cdf(F; p, n_eff - p)

The candidate is significant when the smallest p-value over the channels, times the number of
channels, is below ``ALPHA``; when that still holds (below ``ALPHA_ROBUST``) with the fold that
favours the candidate most left out, so one fold whose training set happened to pin a gain badly
cannot make a verdict; when the DOF's held-out gap shrinks by at least ``MIN_SHRINK`` percent;
and when the error it explains, ``sqrt(gap_before^2 - gap_after^2)``, is at least ``MIN_EXPLAINED`` of
the channel scale. The last is practical significance: at low sensor noise a sub-sample timing
mismatch of the logger is statistically visible, but a model error of a few tenths of a percent of
the signal is no sim-to-real gap worth naming. Held-out residuals already punish overfitting (an extra parameter fitted to noise makes
the held-out error larger, so F < 0); the thresholds only guard against chance improvements.

Calibration: the thresholds are set so that clean simulated trials (no effect; several vessels,
noise levels and seeds) give a verdict other than null in at most 5% of trials. Reproduce with::

    .venv/bin/python benchmarks/diagnose.py --calibrate

which prints, for the clean trials, the largest ``-log10 p`` and shrink of any candidate per trial
and the false-positive rate at the constants below.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np
import scipy.stats

from .gridfit import GridData

#: Family-wise p-value threshold per candidate and DOF (calibrated, see module docstring).
ALPHA = 1e-4
#: p-value threshold once the candidate's most favourable fold is left out (robustness).
ALPHA_ROBUST = 1e-3
#: Smallest held-out shrink [%] of the DOF gap for a candidate to count (calibrated).
MIN_SHRINK = 10.0
#: Smallest normalised RMS error the effect must explain [-] (0.3% of the channel's scale).
MIN_EXPLAINED = 0.003


@dataclass(frozen=True)
class ChannelScore:
    """Held-out comparison of one output channel.

    Attributes
    ----------
    channel : str
        Channel name.
    n : int
        Held-out samples.
    gap_before, gap_after : float
        Held-out RMS simulation error in units of the channel's white-noise level at the analysis
        step, baseline and candidate [-] (1 = only sensor noise left).
    explained : float
        ``sqrt(e0^2 - e1^2)`` of the RMS errors over the channel's scale [-] (negative when worse).
    rho : float
        Lag-1 autocorrelation of the candidate's held-out residual [-].
    n_eff : float
        Effective number of independent samples.
    f_stat, p_value : float
        F statistic and its p-value (NaN when it cannot be computed).
    """

    channel: str
    n: int
    gap_before: float
    gap_after: float
    explained: float
    rho: float
    n_eff: float
    f_stat: float
    p_value: float


@dataclass(frozen=True)
class Score:
    """A candidate's held-out score in one DOF.

    Attributes
    ----------
    gap_before, gap_after : float
        DOF gap: RMS over its channels of the noise-normalised held-out gaps [-].
    shrink : float
        ``100 (1 - gap_after / gap_before)`` [%].
    p_value : float
        Bonferroni-corrected smallest channel p-value.
    significant : bool
        ``p_value < ALPHA``, ``shrink >= MIN_SHRINK`` and ``explained >= MIN_EXPLAINED``.
    channels : tuple[ChannelScore, ...]
        Per-channel detail.
    gain : float
        Reduction of the sum of squared channel gaps (the candidate's share of the trial gap,
        a log-likelihood ratio in noise units).
    explained : float
        Largest scale-normalised RMS error explained in any channel [-].
    p_robust : float
        The p-value with the candidate's most favourable fold left out (NaN with one fold).
    """

    gap_before: float
    gap_after: float
    shrink: float
    p_value: float
    significant: bool
    channels: tuple[ChannelScore, ...]
    gain: float
    explained: float
    p_robust: float = float("nan")


def heldout_residuals(data: GridData, outputs: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Scale-weighted held-out residual rows per output key (``"y"``, ``"angle"``), NaN off-window.

    Parameters
    ----------
    data : GridData
        Measured data.
    outputs : Mapping[str, numpy.ndarray]
        Model outputs.
    """
    out = {"y": np.where(data.mask, (data.y - outputs["y"]) * data.w_y, np.nan)}
    if data.angle is not None and "angle" in outputs:
        am = data.mask & np.isfinite(data.angle)
        out["angle"] = np.where(am, (data.angle - outputs["angle"]) * data.w_angle, np.nan)
    return out


def noise_units(data: GridData) -> dict[str, float]:
    """Noise level of each output key in the scale-weighted residual's units.

    Parameters
    ----------
    data : GridData
        Measured data.
    """
    out = {"y": data.sigma_y * data.w_y}
    if data.angle is not None:
        out["angle"] = data.sigma_angle * data.w_angle
    return {k: (v if np.isfinite(v) and v > 0 else float("nan")) for k, v in out.items()}


def lag1(resid: np.ndarray) -> float:
    """Lag-1 autocorrelation of residual rows, pooled within windows [-].

    Parameters
    ----------
    resid : numpy.ndarray
        Residual rows (W, n), NaN outside windows.
    """
    a, b = resid[:, :-1], resid[:, 1:]
    ok = np.isfinite(a) & np.isfinite(b)
    den = np.nansum(np.where(np.isfinite(resid), resid**2, 0.0))
    if den <= 0:
        return 0.0
    return float(np.sum(np.where(ok, a * b, 0.0)) / den)


def channel_score(name: str, e0: np.ndarray, e1: np.ndarray, p: int, n_windows: int, noise: float) -> ChannelScore:
    """Held-out F test of one channel.

    Parameters
    ----------
    name : str
        Channel name.
    e0, e1 : numpy.ndarray
        Scale-weighted residual rows of the baseline and of the candidate.
    p : int
        Parameters the candidate adds.
    n_windows : int
        Windows (the least number of independent samples).
    noise : float
        Noise level in the residuals' units (NaN: gaps stay scale-normalised).
    """
    ok = np.isfinite(e0) & np.isfinite(e1)
    n = int(ok.sum())
    if n == 0:
        return ChannelScore(name, 0, np.nan, np.nan, np.nan, np.nan, np.nan, np.nan, np.nan)
    sse0 = float(np.sum(e0[ok] ** 2))
    sse1 = float(np.sum(e1[ok] ** 2))
    rho = float(np.clip(lag1(np.where(ok, e1, np.nan)), 0.0, 0.999))
    n_eff = float(np.clip(n * (1 - rho) / (1 + rho), max(n_windows, p + 2), n))
    r0, r1 = np.sqrt(sse0 / n), np.sqrt(sse1 / n)
    # Without a usable noise estimate the scale-normalised error stands in for the gap.
    unit = noise if np.isfinite(noise) and noise > 0 else 1.0
    diff = r0**2 - r1**2
    explained = float(np.sign(diff) * np.sqrt(abs(diff)))
    if sse1 <= 0 or n_eff <= p + 1:
        return ChannelScore(name, n, r0 / unit, r1 / unit, explained, rho, n_eff, np.nan, np.nan)
    f = ((sse0 - sse1) / p) / (sse1 / (n_eff - p))
    pv = float(scipy.stats.f.sf(f, p, n_eff - p)) if f > 0 else 1.0
    return ChannelScore(name, n, r0 / unit, r1 / unit, explained, rho, n_eff, float(f), pv)


def _pvalue(chans: tuple[ChannelScore, ...]) -> float:
    pvals = np.array([c.p_value for c in chans], float)
    return float(min(np.nanmin(pvals) * len(chans), 1.0)) if np.isfinite(pvals).any() else 1.0


def score(data: GridData, base: Mapping[str, np.ndarray], cand: Mapping[str, np.ndarray], p: int,
          names: Mapping[str, str], folds: np.ndarray | None = None) -> Score:
    """Score a candidate against the baseline on held-out outputs.

    Parameters
    ----------
    data : GridData
        Measured data.
    base, cand : Mapping[str, numpy.ndarray]
        Held-out outputs of the baseline and the candidate.
    p : int
        Parameters the candidate adds.
    names : Mapping[str, str]
        Output key -> channel name (``{"y": "r", "angle": "psi"}``).
    folds : numpy.ndarray, optional
        Fold of each window, for the robustness check (skipped when None).

    Returns
    -------
    Score
    """
    r0 = heldout_residuals(data, base)
    r1 = heldout_residuals(data, cand)
    noise = noise_units(data)
    nw = data.y.shape[0]
    keys = [k for k in r0 if k in r1]
    chans = tuple(channel_score(names[k], r0[k], r1[k], max(p, 1), nw, noise[k]) for k in keys)
    g0 = np.array([c.gap_before for c in chans])
    g1 = np.array([c.gap_after for c in chans])
    gb = float(np.sqrt(np.nanmean(g0**2)))
    ga = float(np.sqrt(np.nanmean(g1**2)))
    shrink = 100.0 * (1.0 - ga / gb) if gb > 0 else 0.0
    pv = _pvalue(chans)
    explained = float(np.nanmax([c.explained for c in chans])) if chans else float("nan")
    p_rob = float("nan")
    if folds is not None and folds.max() >= 1:
        # The fold with the largest improvement (noise units) is left out and the test redone.
        gains = np.zeros(int(folds.max()) + 1)
        for k in keys:
            u = noise[k] if np.isfinite(noise[k]) else 1.0
            d = np.where(np.isfinite(r0[k]) & np.isfinite(r1[k]), (r0[k] ** 2 - r1[k] ** 2) / u**2, 0.0).sum(axis=1)
            np.add.at(gains, folds, d)
        keep = folds != int(np.argmax(gains))
        rest = tuple(channel_score(names[k], np.where(keep[:, None], r0[k], np.nan),
                                   np.where(keep[:, None], r1[k], np.nan), max(p, 1), int(keep.sum()), noise[k])
                     for k in keys)
        p_rob = _pvalue(rest)
    robust = not (p_rob >= ALPHA_ROBUST)  # NaN (one fold) passes
    sig = bool(pv < ALPHA and robust and shrink >= MIN_SHRINK and explained >= MIN_EXPLAINED)
    return Score(gb, ga, float(shrink), pv, sig, chans, float(np.nansum(g0**2 - g1**2)), explained, p_rob)
