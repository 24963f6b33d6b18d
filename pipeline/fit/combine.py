"""Combine per-segment values of one coefficient into an :class:`~pipeline.records.Estimate`.

Inverse-variance weighted mean ``x = sum(w_i x_i) / sum(w_i)``, ``w_i = 1/se_i^2``, standard error
``1/sqrt(sum w_i)``. The chi-square ``Q = sum w_i (x_i - x)^2`` with ``k - 1`` degrees of freedom tests
whether the segments agree within their errors.

When they do not (p < ``CONSISTENCY_ALPHA``), the segments are read as draws from a spread of
values (a model-structure error that differs between manoeuvres, not noise): the DerSimonian-Laird
random-effects combination estimates that spread, ``tau^2 = max(0, (Q - (k - 1)) / (S1 - S2/S1))``
with ``S1 = sum w_i``, ``S2 = sum w_i^2``, and weights each segment by ``1/(se_i^2 + tau^2)``; the
standard error ``1/sqrt(sum 1/(se_i^2 + tau^2))`` then holds the spread (DerSimonian & Laird 1986).
Its 95% interval is normal. (A Birge-scaled error with a t interval of ``k - 1`` degrees of freedom,
used before, gave a 12.7-sigma interval for two segments: wide enough to look right by accident.)
The coverage of this rule on independent-simulator data is measured by benchmarks/independent.py.

The 95% interval is Student's t with the fit's residual degrees of freedom for a single segment and
normal for a combination.

Segments whose fits used overlapping sample windows (consecutive rudder steps share the steady hold
between them: the hold is the first step's new level and the second step's lead-in) are not
independent: their inverse-variance mean gets the error of a weighted mean of correlated values, with the
correlation of :func:`overlap_correlation`, and the chi-square uses the same covariance.

References
----------
DerSimonian, R., Laird, N. (1986). Meta-analysis in clinical trials. Controlled Clinical Trials 7, 177-188.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy import stats

from ..records import Estimate
from .least_squares import confidence_interval
from .segment_fit import MAX_RELATIVE_STDERR

#: p-value below which repeated segments are called inconsistent.
CONSISTENCY_ALPHA = 0.01


@dataclass(frozen=True)
class Contribution:
    """One segment's value of a coefficient.

    Attributes
    ----------
    value, stderr : float
        Value and standard error [unit of the coefficient].
    source : str
        Segment label, for messages.
    dof : float
        Residual degrees of freedom of the fit (for a single-segment t interval).
    ok : bool
        False when the segment fit failed; the value is then not combined.
    reason : str
        Why the segment is not usable.
    window : tuple of float, optional
        Start and end [s, trial clock] of the samples the fit used; fits whose windows overlap share
        samples, and their values are combined as correlated (:func:`overlap_correlation`).
    """

    value: float
    stderr: float
    source: str
    dof: float = math.inf
    ok: bool = True
    reason: str = ""
    window: tuple[float, float] | None = None


def overlap_correlation(windows: Sequence[tuple[float, float] | None]) -> np.ndarray:
    """Correlation of estimates from sample windows that overlap: ``|W_i & W_j| / sqrt(|W_i| |W_j|)`` [-].

    The correlation of two means over windows of white samples that share ``|W_i & W_j|`` of them;
    a stated approximation for fitted coefficients (measured on rudder steps whose windows share the
    steady hold between them: per-step K errors correlated +0.23 within a day, where fitted as
    independent the combined K's z spread 1.5 over 12 seeds). Windows that are None or do not
    overlap give 0.

    Parameters
    ----------
    windows : sequence of (float, float) or None
        Start and end of each window [s].
    """
    k = len(windows)
    rho = np.eye(k)
    for i in range(k):
        for j in range(i + 1, k):
            a, b = windows[i], windows[j]
            if a is None or b is None:
                continue
            la, lb = a[1] - a[0], b[1] - b[0]
            shared = min(a[1], b[1]) - max(a[0], b[0])
            if la > 0 and lb > 0 and shared > 0:
                rho[i, j] = rho[j, i] = min(shared / math.sqrt(la * lb), 1.0)
    return rho


def failed_estimate(name: str, unit: str, method: str, message: str) -> Estimate:
    """An :class:`Estimate` that was not identified, with the reason.

    Parameters
    ----------
    name, unit, method : str
        Coefficient name, SI unit and method description.
    message : str
        Why it was not identified.
    """
    return Estimate(name=name, value=math.nan, stderr=math.nan, ci95=(math.nan, math.nan), unit=unit,
                    n_segments=0, method=method, success=False, message=message)


def combine(name: str, unit: str, method: str, contributions: Sequence[Contribution],
            notes: Sequence[str] = (), prediction: bool = False) -> Estimate:
    """Inverse-variance weighted mean of the usable contributions, with a consistency test.

    Parameters
    ----------
    name : str
        Coefficient name (``X_u``, ``K_nomoto``, ...).
    unit : str
        SI unit.
    method : str
        How the per-segment values were obtained (the combination rule is appended).
    contributions : sequence of Contribution
        Per-segment values; those with ``ok=False`` or no finite standard error are left out and
        named in the message.
    notes : sequence of str
        Further remarks for the message (a model mismatch, a missing config value).
    prediction : bool
        When the segments disagree, report the random-effects *prediction* error
        ``sqrt(se_re^2 + tau^2)`` (Higgins, Thompson & Spiegelhalter 2009) instead of the error of
        the random-effects mean: the coefficient sought (a linear model's K at small rudder, say) is
        then read as one more draw from the spread the manoeuvres show, whose common part is not
        averaged down by their number (:func:`prediction_stderr`). Measured on PythonVehicleSimulator's
        ships (benchmarks/independent.py; 56 estimates of K or T marked success that carried the spread,
        mostly steps, at 1 and 5 Hz): where the segments scatter about the truth it over-states the error (|z| at most 1.22
        with it, 2.01 without; the frigate's steps' errors 2.3 times wider with it), but where a bias is common
        to every manoeuvre it is what holds the truth (the tanker at 20 m, measured-rudder steps with waves,
        seed 3: K -2.0 %, z -1.22 with it, -2.01 without, the interval missing): kept for that.

    Returns
    -------
    Estimate
        ``success=False`` when no segment is usable or the combined relative standard error exceeds
        ``MAX_RELATIVE_STDERR``.
    """
    usable = [c.ok and math.isfinite(c.value) and math.isfinite(c.stderr) and c.stderr > 0
              for c in contributions]
    used = [c for c, u in zip(contributions, usable) if u]
    left_out = [f"{c.source} left out: {c.reason or 'no finite standard error'}"
                for c, u in zip(contributions, usable) if not u]
    messages = list(notes)
    if not used:
        return failed_estimate(name, unit, method,
                               "; ".join(["not identified: no usable segment"] + left_out + messages))
    x = np.array([c.value for c in used])
    w = 1.0 / np.array([c.stderr for c in used]) ** 2
    k = len(used)
    mean = float(w @ x / w.sum())
    se = float(1.0 / math.sqrt(w.sum()))
    p_value = math.nan
    rho = overlap_correlation([c.window for c in used])
    if k > 1 and np.any(rho[~np.eye(k, dtype=bool)] > 0):
        return _combine_correlated(name, unit, method, used, rho, messages, left_out, prediction)
    if k == 1:
        ci = confidence_interval(mean, se, used[0].dof)
        rule = "single segment"
    else:
        chi2 = float(w @ (x - mean) ** 2)
        p_value = float(stats.chi2.sf(chi2, k - 1))
        rule = f"inverse-variance mean of {k} segments"
        if p_value < CONSISTENCY_ALPHA:
            tau2 = dersimonian_laird_tau2(chi2, w)
            w_re = 1.0 / (1.0 / w + tau2)
            mean = float(w_re @ x / w_re.sum())
            se = float(1.0 / math.sqrt(w_re.sum()))
            se, suffix = note_disagreement(messages, chi2, k, p_value, tau2, unit, se, prediction)
            rule = f"DerSimonian-Laird random-effects mean of {k} segments{suffix}"
            ci = confidence_interval(mean, se, math.inf)
        else:
            ci = confidence_interval(mean, se, math.inf)
    return combined_estimate(name, unit, method, rule, mean, se, ci, p_value, x, messages + left_out)


def dersimonian_laird_tau2(chi2: float, w: np.ndarray) -> float:
    """Between-segment variance ``tau^2`` by DerSimonian and Laird's moment estimator [unit^2].

    Parameters
    ----------
    chi2 : float
        Cochran's Q of the values about their inverse-variance mean.
    w : numpy.ndarray
        Inverse-variance weights ``1/se_i^2`` [1/unit^2].
    """
    s1, s2 = float(w.sum()), float((w**2).sum())
    return max(0.0, (chi2 - (w.size - 1)) / (s1 - s2 / s1))


def dersimonian_laird_psi(values: np.ndarray, weights: Sequence[np.ndarray]) -> np.ndarray:
    """Between-segment covariance ``Psi`` of vector values by the matrix method of moments [unit^2].

    The multivariate form of :func:`dersimonian_laird_tau2` (Jackson, White & Riley 2013): with the
    segments' weight matrices ``W_i = C_i^-1``, ``A = sum W_i``, the fixed-effect mean
    ``m = A^-1 sum W_i x_i`` and ``Q = sum W_i (x_i - m)(x_i - m)'``, whose expectation is
    ``(k - 1) I + (A - sum W_i A^-1 W_i) Psi``,

        ``Psi = (A - sum W_i A^-1 W_i)^-1 (Q - (k - 1) I)``,

    made symmetric and truncated to its non-negative eigenvalues. For one parameter it is
    DerSimonian and Laird's ``tau^2`` exactly.

    Parameters
    ----------
    values : numpy.ndarray
        ``(k, p)`` segment vectors [unit].
    weights : sequence of numpy.ndarray
        Their ``(p, p)`` weight matrices (inverse covariances) [1/unit^2].

    Returns
    -------
    numpy.ndarray
        ``(p, p)`` positive semi-definite ``Psi``.

    References
    ----------
    Jackson, D., White, I. R., Riley, R. D. (2013). A matrix-based method of moments for fitting the
    multivariate random effects model in meta-analysis and meta-regression. Biometrical Journal 55, 231-245.
    """
    x = np.atleast_2d(np.asarray(values, float))
    k, p = x.shape
    w = [np.atleast_2d(np.asarray(wi, float)) for wi in weights]
    a = sum(w)
    a_inv = np.linalg.inv(a)
    mean = a_inv @ sum(wi @ xi for wi, xi in zip(w, x))
    q = sum(wi @ np.outer(xi - mean, xi - mean) for wi, xi in zip(w, x))
    b = a - sum(wi @ a_inv @ wi for wi in w)
    psi = np.linalg.solve(b, q - (k - 1) * np.eye(p))
    ev, vec = np.linalg.eigh(0.5 * (psi + psi.T))
    return (vec * np.maximum(ev, 0.0)) @ vec.T


def note_disagreement(messages: list[str], chi2: float, k: int, p_value: float, tau2: float, unit: str,
                      se_re: float, prediction: bool) -> tuple[float, str]:
    """Put the "segments disagree" note first in ``messages``; the reported error and a rule suffix.

    Parameters
    ----------
    messages : list of str
        The combination's notes (changed in place).
    chi2, p_value : float
        The consistency test on ``k - 1`` degrees of freedom.
    k : int
        Segments combined.
    tau2 : float
        Between-segment variance [unit^2].
    unit : str
        Unit of the values.
    se_re : float
        Standard error of the random-effects mean [unit].
    prediction : bool
        Report the prediction error instead (:func:`prediction_stderr`).

    Returns
    -------
    float
        The standard error to report [unit].
    str
        ``", prediction error"`` when the prediction error is reported, else ``""``.
    """
    messages.insert(0, f"segments disagree (chi2 = {chi2:.3g} on {k - 1} dof, p = {p_value:.2g} "
                       f"< {CONSISTENCY_ALPHA}): random-effects combination, between-segment spread "
                       f"tau = {math.sqrt(tau2):.3g} {unit} added to every segment's error")
    if not prediction:
        return se_re, ""
    se, note = prediction_stderr(se_re, tau2, unit)
    messages.insert(1, note)
    return se, ", prediction error"


def prediction_stderr(se_re: float, tau2: float, unit: str) -> tuple[float, str]:
    """The random-effects prediction error ``sqrt(se_re^2 + tau^2)`` and the note saying why.

    Segments that disagree beyond their errors show a model error that differs between manoeuvres;
    its part common to all of them biases every segment alike and is not averaged down by their
    number. Reading the sought value as one more draw from the spread (the 95 % prediction interval
    of Higgins, Thompson & Spiegelhalter 2009, normal here) keeps that part in the error.

    Parameters
    ----------
    se_re : float
        Standard error of the random-effects mean.
    tau2 : float
        Between-segment variance.
    unit : str
        Unit for the note.

    References
    ----------
    Higgins, J. P. T., Thompson, S. G., Spiegelhalter, D. J. (2009). A re-evaluation of random-effects
    meta-analysis. J. R. Stat. Soc. A 172, 137-159.
    """
    se = math.sqrt(se_re**2 + tau2)
    return se, (f"standard error {se_re:.4g} -> {se:.4g} {unit} with the between-segment spread (random-effects "
                f"prediction error: a model error common to every manoeuvre is not averaged down)")


def _combine_correlated(name: str, unit: str, method: str, used: Sequence[Contribution], rho: np.ndarray,
                        messages: list[str], left_out: list[str], prediction: bool = False) -> Estimate:
    """:func:`combine` for values whose windows overlap: the inverse-variance mean with its correlated error.

    ``C = diag(se) R diag(se)`` with ``R`` from :func:`overlap_correlation`; mean ``w' x / sum w``
    with ``w = 1/se^2`` (always inside the values' range, unlike full GLS weights), variance
    ``w' C w / (sum w)^2``, ``Q = (x - m)' C^-1 (x - m)`` on ``k - 1`` degrees of freedom. When ``Q`` says the segments disagree, the DerSimonian-Laird spread ``tau^2``
    (from the diagonal weights) is added to the diagonal of ``C`` and the mean taken again.
    """
    x = np.array([c.value for c in used])
    sd = np.array([c.stderr for c in used])
    k = len(used)
    cov = rho * np.outer(sd, sd)

    def gls(c: np.ndarray) -> tuple[float, float, np.ndarray]:
        # Inverse-variance weights from the diagonal (a mean inside the values' range, which full
        # GLS weights do not promise when correlated values have unequal errors), and the variance
        # of that weighted mean under the correlated covariance: w' C w / (sum w)^2.
        w = 1.0 / np.diag(c)
        var = float(w @ c @ w) / float(w.sum()) ** 2
        return float(w @ x) / float(w.sum()), math.sqrt(var), np.linalg.pinv(c)

    mean, se, cinv = gls(cov)
    chi2 = float((x - mean) @ cinv @ (x - mean))
    p_value = float(stats.chi2.sf(chi2, k - 1))
    n_pairs = int(np.sum(np.triu(rho, 1) > 0))
    note = (f"{n_pairs} pair(s) of segments share samples (overlapping windows, correlation up to "
            f"{float(np.max(np.triu(rho, 1))):.2f} from the shared share of their samples): "
            f"inverse-variance mean with the correlated error")
    rule = f"inverse-variance mean of {k} segments, overlapping windows correlated"
    if p_value < CONSISTENCY_ALPHA:
        tau2 = dersimonian_laird_tau2(chi2, 1.0 / sd**2)
        mean, se, _ = gls(cov + tau2 * np.eye(k))
        se, suffix = note_disagreement(messages, chi2, k, p_value, tau2, unit, se, prediction)
        rule = f"random-effects mean of {k} segments, overlapping windows correlated{suffix}"
    messages.append(note)
    ci = confidence_interval(mean, se, math.inf)
    return combined_estimate(name, unit, method, rule, mean, se, ci, p_value, x, messages + left_out)



def combined_estimate(name: str, unit: str, method: str, rule: str, mean: float, se: float,
                      ci: tuple[float, float], p_value: float, values: Sequence[float],
                      messages: list[str]) -> Estimate:
    """The :class:`Estimate` of a combination, not identified when its relative error is too large.

    Parameters
    ----------
    name, unit, method : str
        Coefficient name, SI unit and how each segment's value was fitted.
    rule : str
        How the segments were combined.
    mean, se : float
        Combined value and its standard error [unit].
    ci : tuple of float
        95 % confidence interval [unit].
    p_value : float
        Consistency test of the segments' values (NaN: one segment).
    values : sequence of float
        Every segment's value [unit].
    messages : list of str
        Notes, in order; a "not identified" note is put first when it applies.

    Returns
    -------
    Estimate
    """
    success = True
    if abs(se) > MAX_RELATIVE_STDERR * abs(mean):
        success = False
        messages = [f"relative standard error {se / abs(mean) if mean else math.inf:.0%} above "
                    f"{MAX_RELATIVE_STDERR:.0%}: not identified"] + list(messages)
    return Estimate(name=name, value=mean, stderr=se, ci95=ci, unit=unit, n_segments=len(values),
                    method=f"{method}; {rule}", success=success, message="; ".join(messages),
                    consistency_p=p_value, per_segment=tuple(float(v) for v in values))


#: Combination rules :func:`combination_rules` computes (the first is the one :func:`combine` uses).
COMBINATION_RULES = ("dersimonian_laird", "fixed_effect", "birge_ratio", "hartung_knapp", "dl_prediction")


def combination_rules(values: Sequence[float], stderrs: Sequence[float], dof: float = math.inf
                      ) -> dict[str, tuple[float, float, tuple[float, float]]]:
    """Several stated rules for combining per-segment values, for measuring their coverage side by side.

    - ``dersimonian_laird``: what :func:`combine` reports by default (inverse-variance mean while the
      segments agree, chi-square p >= ``CONSISTENCY_ALPHA``; else the DerSimonian-Laird random-effects
      mean), normal 95 % interval (Student's t with ``dof`` for one segment).
    - ``fixed_effect``: inverse-variance mean and error, normal interval, whatever the spread.
    - ``birge_ratio``: the inverse-variance mean with its error times ``max(1, sqrt(Q / (k - 1)))``
      (the Birge ratio), normal interval.
    - ``hartung_knapp``: the DerSimonian-Laird mean with the Hartung-Knapp(-Sidik-Jonkman) variance
      ``sum w_i (x_i - x)^2 / ((k - 1) sum w_i)`` (random-effects weights) and a t interval with
      ``k - 1`` degrees of freedom (Hartung & Knapp 2001); the fixed-effect rule for one segment.
    - ``dl_prediction``: ``dersimonian_laird`` with, when the segments disagree, the prediction error
      ``sqrt(se_re^2 + tau^2)`` (:func:`prediction_stderr`): what :func:`combine` reports with
      ``prediction=True`` (the Nomoto K and T) for segments whose windows do not overlap.

    Parameters
    ----------
    values, stderrs : sequence of float
        Per-segment values and standard errors (finite, positive errors only are used).
    dof : float
        Residual degrees of freedom of a single segment's fit.

    Returns
    -------
    dict
        Rule name -> ``(value, stderr, (lo, hi))``; empty when no segment is usable.

    References
    ----------
    Birge, R. T. (1932). The calculation of errors by the method of least squares. Phys. Rev. 40, 207-227.
    Hartung, J., Knapp, G. (2001). On tests of the overall treatment effect in meta-analysis with
    normally distributed responses. Statistics in Medicine 20, 1771-1782.
    """
    x = np.asarray(values, float)
    s = np.asarray(stderrs, float)
    ok = np.isfinite(x) & np.isfinite(s) & (s > 0)
    x, s = x[ok], s[ok]
    k = x.size
    if k == 0:
        return {}
    w = 1.0 / s**2
    mean = float(w @ x / w.sum())
    se = float(1.0 / math.sqrt(w.sum()))
    if k == 1:
        one = (mean, se, confidence_interval(mean, se, dof))
        return {name: one for name in COMBINATION_RULES}
    z = float(stats.norm.ppf(0.975))
    q = float(w @ (x - mean) ** 2)
    out = {"fixed_effect": (mean, se, (mean - z * se, mean + z * se))}
    birge = se * max(1.0, math.sqrt(q / (k - 1)))
    out["birge_ratio"] = (mean, birge, (mean - z * birge, mean + z * birge))
    tau2 = dersimonian_laird_tau2(q, w)
    w_re = 1.0 / (1.0 / w + tau2)
    m_re = float(w_re @ x / w_re.sum())
    se_re = float(1.0 / math.sqrt(w_re.sum()))
    p_value = float(stats.chi2.sf(q, k - 1))
    out["dersimonian_laird"] = ((m_re, se_re, (m_re - z * se_re, m_re + z * se_re)) if p_value < CONSISTENCY_ALPHA
                                else out["fixed_effect"])
    se_pr = math.sqrt(se_re**2 + tau2)
    out["dl_prediction"] = ((m_re, se_pr, (m_re - z * se_pr, m_re + z * se_pr)) if p_value < CONSISTENCY_ALPHA
                            else out["fixed_effect"])
    se_hk = math.sqrt(float(w_re @ (x - m_re) ** 2) / ((k - 1) * w_re.sum()))
    tq = float(stats.t.ppf(0.975, k - 1))
    out["hartung_knapp"] = (m_re, se_hk, (m_re - tq * se_hk, m_re + tq * se_hk))
    return {name: out[name] for name in COMBINATION_RULES}
