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
and the false-positive rate at the constants (defined in :mod:`pipeline.fit.heldout_test`, which
holds the rule so that model-structure selection in the fit stage uses the same one).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from ..fit.heldout_test import (ALPHA, ALPHA_ROBUST, MIN_EXPLAINED, MIN_SHRINK,  # noqa: F401 (re-exported)
                                ChannelScore, channel_score, is_significant, lag1)
from .gridfit import GridData


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
    sig = is_significant(pv, p_rob, shrink, explained)
    return Score(gb, ga, float(shrink), pv, sig, chans, float(np.nansum(g0**2 - g1**2)), explained, p_rob)
