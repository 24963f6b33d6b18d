"""The held-out significance rule shared by model-structure selection (:mod:`pipeline.fit.structure`)
and the gap diagnosis (:mod:`pipeline.diagnose.significance`, whose docstring gives the derivation and
the calibration).

A richer model (candidate) beats a baseline on held-out data when, per output channel, the held-out
F test with an effective sample size ``n_eff = n (1 - rho) / (1 + rho)`` (Bartlett 1946)::

    F = ((SSE0 - SSE1) / p) / (SSE1 / (n_eff - p)),    p_value = 1 - F_cdf(F; p, n_eff - p)

gives a Bonferroni-corrected p-value below ``ALPHA``, still below ``ALPHA_ROBUST`` with the most
favourable fold left out, the held-out gap shrinks by at least ``MIN_SHRINK`` percent, and the error
explained is at least ``MIN_EXPLAINED`` of the channel scale (:func:`is_significant`). The rule lives
in the fit stage so that both stages use one definition without the fit importing a later stage.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.stats

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


def heldout_gain(name: str, e0: np.ndarray, e1: np.ndarray, fold_of: np.ndarray, n_folds: int,
                 noise: float) -> tuple[ChannelScore, float, float]:
    """The held-out F test of a larger model over folds, its gap shrink, and the robust p-value.

    Parameters
    ----------
    name : str
        Channel name.
    e0, e1 : numpy.ndarray
        Held-out residual rows of the baseline and of the larger model (NaN outside the test data).
    fold_of : numpy.ndarray
        Fold index of each row.
    n_folds : int
        Folds.
    noise : float
        Noise level in the residuals' units.

    Returns
    -------
    score : ChannelScore
        :func:`channel_score` over every row (the larger model adds one parameter).
    shrink : float
        Held-out gap reduction [%].
    p_robust : float
        The same test without the fold the larger model gains most on (NaN with one fold).
    """
    cs = channel_score(name, e0, e1, 1, e0.shape[0], noise)
    shrink = 100.0 * (1.0 - cs.gap_after / cs.gap_before) if cs.gap_before > 0 else 0.0
    gains = np.zeros(n_folds)
    np.add.at(gains, fold_of, np.nansum(e0**2 - e1**2, axis=1))
    keep = fold_of != int(np.argmax(gains))
    p_rob = np.nan
    if n_folds > 1 and keep.any():
        p_rob = channel_score(name, e0[keep], e1[keep], 1, int(keep.sum()), noise).p_value
    return cs, shrink, float(p_rob)


def is_significant(p_value: float, p_robust: float, shrink: float, explained: float) -> bool:
    """The rule's verdict from its four numbers (module docstring).

    Parameters
    ----------
    p_value : float
        Bonferroni-corrected smallest channel p-value.
    p_robust : float
        The same with the most favourable fold left out (NaN with one fold: passes).
    shrink : float
        Held-out gap reduction [%].
    explained : float
        Scale-normalised RMS error explained [-].
    """
    robust = not (p_robust >= ALPHA_ROBUST)  # NaN (one fold) passes
    return bool(p_value < ALPHA and robust and shrink >= MIN_SHRINK and explained >= MIN_EXPLAINED)
