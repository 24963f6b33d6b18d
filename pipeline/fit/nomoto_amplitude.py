"""K at zero rudder amplitude: the rudder-amplitude model fitted across a trial's rudder steps.

A linear Nomoto K holds for one rudder amplitude when the ship's steady turn rate is not linear in the
rudder (a rudder force that saturates, PythonVehicleSimulator's Clarke83 ``sin 2 delta``: -2.0 % at
10 deg, -0.5 % at 5 deg; a speed that settles lower in harder turns, its tanker at 25 m). The model of
:func:`pipeline.model.nomoto.rudder_secant_factor`, ``K(delta) = K0 (1 + a delta^2)``, a Taylor series of
the rudder's odd effect, gives each step the gain ``K0 (1 + a x)`` with ``x = d1^2 + d1 d2 + d2^2`` its
squared amplitude (:func:`pipeline.model.nomoto.step_amplitude_sq`, from the levels the segmenter measured
before and after it). Across steps of different amplitudes the steps' K lie on a line in ``x``
(:func:`amplitude_line`, weighted least squares whose covariance holds the overlapping windows'
correlation of :func:`pipeline.fit.combine.overlap_correlation` (a sandwich) and is scaled by the line's
Birge ratio when it misfits); its intercept is ``K0``, the linearisation, with the extrapolation's error.

``a`` is kept only when the data demand it: the slope's two-sided t-test at ``AMPLITUDE_ALPHA`` (t
distribution on the line's degrees of freedom when the Birge ratio scales the errors, normal otherwise).
Otherwise K stays the combination of the steps (the constant model), and the note says the amplitude
test did not reject it. Where every step has one amplitude (``x`` spread below ``MIN_SPREAD``) ``a`` is
not identified and K stays as it is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy import stats

from ..model.nomoto import step_amplitude_sq
from ..records import SegmentFit
from .combine import overlap_correlation
from .nomoto_pool import samples_window

#: Note head of K read at zero rudder amplitude.
AMPLITUDE_K = "K at zero rudder amplitude"
#: Note head of the constant model kept.
AMPLITUDE_NOT_KEPT = "rudder-amplitude model not kept"
#: Two-sided significance level of the amplitude slope that keeps ``a``.
AMPLITUDE_ALPHA = 0.05
#: Largest over smallest squared amplitude of the steps needed to identify ``a`` [-].
MIN_SPREAD = 1.5
#: Difference between the zero-amplitude K and the constant model's, relative to the latter, above which a
#: K whose amplitude slope is not significant is unsure [-] (the data can neither keep nor rule out a
#: curvature that matters).
AMPLITUDE_UNDECIDED = 0.01
#: ... and by more than this many standard errors of the difference (the data lean towards the curvature;
#: a K0 whose extrapolation error dwarfs the gap says nothing: a linear ship's steps, K0 +- 6.5 %).
AMPLITUDE_LEAN = 1.0


@dataclass(frozen=True)
class AmplitudeLine:
    """The steps' K against their squared amplitude (:func:`amplitude_line`).

    Attributes
    ----------
    k0, se_k0 : float
        Intercept ``K0`` (the linearisation) and its standard error [1/s].
    a, se_a : float
        Curvature ``a`` = slope / ``K0`` and its error (delta method) [1/rad^2].
    t, p : float
        t of the slope and its two-sided p-value.
    birge : float
        Birge ratio applied to the errors (at least 1).
    dof : int
        Degrees of freedom of the line (steps - 2).
    mean, se_mean : float
        The constant model's weighted mean and error (its own Birge ratio, the same sandwich) [1/s].
    x : numpy.ndarray
        The steps' squared amplitudes [rad^2].
    kept : bool
        ``p < AMPLITUDE_ALPHA``: ``a`` kept and ``K0`` the value.
    """

    k0: float
    se_k0: float
    a: float
    se_a: float
    t: float
    p: float
    birge: float
    dof: int
    mean: float
    se_mean: float
    x: np.ndarray
    kept: bool


def _wls(design: np.ndarray, y: np.ndarray, se: np.ndarray, rho: np.ndarray
         ) -> tuple[np.ndarray, np.ndarray, float, int]:
    """Weighted least squares: coefficients, their covariance, Birge ratio (at least 1) and dof.

    The weights are the inverse variances; the covariance is the sandwich under the correlation ``rho`` of
    the values (``(X'WX)^-1 X'W C W X (X'WX)^-1``, ``C = D rho D``), scaled by the square of the Birge
    ratio of the residuals (their chi-square under the weights over the dof, at least 1).
    """
    w = np.diag(1.0 / se**2)
    bread = np.linalg.inv(design.T @ w @ design)
    beta = bread @ design.T @ w @ y
    res = y - design @ beta
    dof = y.size - design.shape[1]
    birge = math.sqrt(max(float(res @ w @ res) / dof, 1.0)) if dof > 0 else 1.0
    meat = design.T @ w @ (rho * np.outer(se, se)) @ w @ design
    return beta, bread @ meat @ bread * birge**2, birge, dof


def amplitude_line(values: Sequence[float], stderrs: Sequence[float], x: Sequence[float],
                   windows: Sequence[tuple[float, float] | None] | None = None) -> AmplitudeLine | None:
    """``K = K0 (1 + a x)`` fitted to the steps' K (module docstring); None where ``a`` is not identified.

    Parameters
    ----------
    values, stderrs : sequence of float
        The steps' K and standard errors [1/s].
    x : sequence of float
        Their squared amplitudes ``d1^2 + d1 d2 + d2^2`` [rad^2].
    windows : sequence of (float, float) or None, optional
        Each step's samples [s, trial clock], for the correlation of overlapping windows.

    Returns
    -------
    AmplitudeLine or None
        None with fewer than three usable steps or an amplitude spread below ``MIN_SPREAD``.
    """
    y = np.asarray(values, float)
    se = np.asarray(stderrs, float)
    xx = np.asarray(x, float)
    ok = np.isfinite(y) & np.isfinite(se) & (se > 0) & np.isfinite(xx) & (xx > 0)
    if ok.sum() < 3 or not xx[ok].max() >= MIN_SPREAD * xx[ok].min():
        return None
    idx = np.flatnonzero(ok)
    rho = (overlap_correlation([windows[i] for i in idx]) if windows is not None else np.eye(idx.size))
    # Weighted least squares, the overlapping windows' correlation in the covariance only (a sandwich): the
    # overlap correlation is a stated approximation, which in the weights would move the extrapolated
    # intercept with it.
    y, xx, s = y[ok], xx[ok], se[ok]
    try:
        beta, c, birge, dof = _wls(np.column_stack([np.ones_like(xx), xx]), y, s, rho)
        m, cm, _, _ = _wls(np.ones((xx.size, 1)), y, s, rho)
    except np.linalg.LinAlgError:
        return None
    k0, slope = float(beta[0]), float(beta[1])
    se_k0, se_s = math.sqrt(max(c[0, 0], 0.0)), math.sqrt(max(c[1, 1], 0.0))
    if not (k0 != 0 and se_s > 0 and math.isfinite(k0)):
        return None
    t = slope / se_s
    p = float(2 * (stats.t.sf(abs(t), dof) if birge > 1.0 else stats.norm.sf(abs(t))))
    a = slope / k0
    # d(s / k0) = ds / k0 - s dk0 / k0^2
    g = np.array([-slope / k0**2, 1.0 / k0])
    se_a = math.sqrt(max(float(g @ c @ g), 0.0))
    return AmplitudeLine(k0=k0, se_k0=se_k0, a=a, se_a=se_a, t=t, p=p, birge=birge, dof=dof, mean=float(m[0]),
                         se_mean=math.sqrt(max(float(cm[0, 0]), 0.0)), x=xx, kept=bool(p < AMPLITUDE_ALPHA))


def step_line(fits: Sequence[SegmentFit]) -> AmplitudeLine | None:
    """:func:`amplitude_line` of the K of a trial's rudder-step fits (None unless every fit is a rudder step).

    Parameters
    ----------
    fits : sequence of SegmentFit
        Successful Nomoto segment fits (their segments' ``input_before`` and ``input_after`` [rad]).
    """
    if len(fits) < 3 or any(f.segment.kind != "rudder_step" for f in fits):
        return None
    values = [f.params.get("K", math.nan) for f in fits]
    stderrs = [f.stderr.get("K", math.nan) for f in fits]
    x = [step_amplitude_sq(getattr(f.segment, "input_before", math.nan), getattr(f.segment, "input_after", math.nan))
         for f in fits]
    return amplitude_line(values, stderrs, x, [samples_window(f) if hasattr(f, "model") else None for f in fits])


def amplitude_note(line: AmplitudeLine, unit: str = "1/s") -> str:
    """The note of a line: ``K0`` and ``a`` where kept, or why the constant model stays.

    Parameters
    ----------
    line : AmplitudeLine
        The fitted line.
    unit : str
        K's unit.
    """
    amps = f"{math.degrees(math.sqrt(line.x.min())):.3g} to {math.degrees(math.sqrt(line.x.max())):.3g} deg"
    test = f"slope t = {line.t:+.2f}, p = {line.p:.2g}, Birge ratio {line.birge:.3g} on {line.dof} dof"
    if line.kept:
        return (f"{AMPLITUDE_K}: K = {line.k0:.6g} +- {line.se_k0:.3g} {unit} (K0 of K(delta) = K0 (1 + a delta^2) "
                f"fitted across {line.x.size} steps of {amps}, a = {line.a:.3g} +- {line.se_a:.2g} 1/rad^2, {test}; "
                f"the steps' constant K {line.mean:.6g} +- {line.se_mean:.3g})")
    return (f"{AMPLITUDE_NOT_KEPT}: across {line.x.size} steps of {amps} the slope of K on the squared "
            f"amplitude is not significant ({test}, level {AMPLITUDE_ALPHA:g}); K0 would be {line.k0:.4g} +- "
            f"{line.se_k0:.2g} {unit}")


def undecided_reason(line: AmplitudeLine, unit: str = "1/s") -> str:
    """Why a constant K kept by the slope test is unsure ('' when it is not, or the line was kept).

    The constant model kept whose K lies more than ``AMPLITUDE_UNDECIDED`` of it and ``AMPLITUDE_LEAN``
    standard errors of the difference from the line's ``K0``: the test could not decide a difference that
    matters. The same test judges the steps' own K and their steady levels' secants (measured:
    PythonVehicleSimulator's Clarke83 steps re-timed with waves, seed 1: the secants' constant K -1.6 %
    with its interval missing, marked success before this test read them).

    Parameters
    ----------
    line : AmplitudeLine
        The fitted line.
    unit : str
        K's unit.
    """
    if line.kept or line.mean == 0:
        return ""
    gap = abs(line.k0 - line.mean) / abs(line.mean)
    # The difference's error (nested estimators, Hausman's form, at least the constant's).
    sd = math.sqrt(max(line.se_k0**2 - line.se_mean**2, line.se_mean**2))
    if not (gap > AMPLITUDE_UNDECIDED and abs(line.k0 - line.mean) > AMPLITUDE_LEAN * sd):
        return ""
    return (f"K may change with the rudder amplitude: the steps' constant K {line.mean:.4g} and the "
            f"zero-amplitude K0 {line.k0:.4g} +- {line.se_k0:.2g} {unit} differ by {gap:.1%} (above "
            f"{AMPLITUDE_UNDECIDED:.0%}, {abs(line.k0 - line.mean) / sd:.1f} times the difference's error), and "
            f"the slope test cannot decide between them (p = {line.p:.2g})")
