"""Second-order Nomoto segments pooled as vectors: K and T = T1 + T2 - T3 from one generalised least-squares mean.

When every Nomoto segment of a trial is fitted with the second order (K, T1 + T2, T1 T2, T3), the
first-order equivalent ``T = T1 + T2 - T3`` of each is the difference of two constants of 10-15 s that
its fit determines only together: a step's T scatters by 10-25 % between steps while its (T1 + T2, T3)
pair moves along their correlation. Averaging the per-segment T values (inverse-variance or random
effects, :func:`pipeline.fit.combine.combine`) loses that correlation. Here the segments' dynamic
vectors are combined by generalised least squares with their full covariances, and K and T are read
from the pooled vector (measured: PythonVehicleSimulator's Clarke83 ship, six commanded rudder steps,
seed 0: per-segment T 2.60-3.69 s, their random-effects mean 3.01 +- 0.68 s (+13 %); the pooled vector's
T 2.63 s, truth 2.66 s).

- The mean is the block-diagonal one (segments independent). Overlapping windows (consecutive rudder
  steps share the hold between them, correlation ``rho_ij`` of :func:`pipeline.fit.combine.overlap_correlation`)
  inflate its covariance by the design effect ``sum_ij rho_ij / k`` (the variance of an equally weighted
  mean of correlated values over that of independent ones). A generalised least-squares mean with the
  cross-covariances ``rho_ij C_i^(1/2) C_j^(1/2)`` was tried and dropped: with strongly correlated
  neighbours it weights segments negatively (the same Clarke83 steps: T 2.16 s, -19 %).
- Heterogeneity: the chi-square of the segment vectors about the pooled one (``4 (k - 1)`` degrees of
  freedom) tests whether they agree within their errors. Where they do not (p < ``CONSISTENCY_ALPHA``),
  the rule is the one :func:`pipeline.fit.combine.combine` applies to the first-order K and T, in its
  multivariate form: the between-segment covariance ``Psi`` by the matrix method of moments that
  generalises DerSimonian-Laird (:func:`pipeline.fit.combine.dersimonian_laird_psi`), and the
  random-effects prediction error ``g' (V + Psi) g`` of K or T (``g`` its gradient): a model error that
  differs between manoeuvres is not averaged down by their number. The mean stays the fixed-effect
  one, ``V`` its covariance under the random-effects model, ``A^-1 + A^-1 (sum W_i Psi W_i) A^-1``
  with ``A = sum W_i`` (Henmi & Copas 2010): the random-effects weights ``(C_i + Psi)^-1`` tend to
  equal weights as ``Psi`` grows, and so to the mean of the segments' own T, which is biased (below):
  PythonVehicleSimulator's Clarke83 ship, six commanded steps at 5 Hz, seeds 0-9, pooled T median
  +5.8 % (median absolute error 5.8 %) with those weights against +1.7 % (3.7 %) with the fixed-effect ones; the project's second-order ship
  (tests/test_fit_nomoto_structure.py) 2.97 s against 2.87 s, truth 2.70 s. A Birge-ratio scaling, used
  before, widened all four directions alike by ``sqrt(chi2 / dof)``: a spread in one direction is
  diluted over four, and on the Clarke83 ship at 2 Hz (seed 0, one step whose servo lag ran to zero)
  it gave T 3.35 +- 0.24 s against the truth 2.66 s (chi-square 67 on 20 dof).
- The vector chi-square's p-value is the estimate's ``consistency_p``. The per-segment T values are
  not tested for a spread (the rule of :func:`pipeline.fit.nomoto_quality.unsure_reasons` for
  combined scalars): a segment's own second-order T is a biased estimate (a nonlinear function of
  poorly separated constants; measured on the project's own linear second-order ship, six steps:
  per-segment T combined 3.22 +- 0.15 s, +19 %, the pooled vector's 2.86 +- 0.08 s, truth 2.70 s),
  so their spread about the pooled value is not heterogeneity; the heterogeneity of the vectors is in
  the random-effects error, and a material one shows there (relative standard error above
  ``UNSURE_RELATIVE_STDERR``).

References
----------
DerSimonian, R., Laird, N. (1986). Meta-analysis in clinical trials. Controlled Clinical Trials 7, 177-188.
Henmi, M., Copas, J. B. (2010). Confidence intervals for random effects meta-analysis and robustness to
publication bias. Statistics in Medicine 29, 2969-2983.
Jackson, D., White, I. R., Riley, R. D. (2013). A matrix-based method of moments for fitting the
multivariate random effects model in meta-analysis and meta-regression. Biometrical Journal 55, 231-245.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy import stats

from ..records import SegmentFit
from .combine import CONSISTENCY_ALPHA, dersimonian_laird_psi, overlap_correlation

#: Start of the note on a segment fitted jointly with others whose K, T and the other coefficients
#: are counted once, on the first segment of the joint fit
#: (:func:`pipeline.fit.nomoto_structure.joint_sinusoids`; read by :func:`is_joint_follower`).
JOINT_FOLLOWER = "fitted jointly with"
#: The second-order dynamic parameters pooled, in this order.
POOLED_PARAMS = ("K", "T12", "T1T2", "T3")
#: Start of the note on K and T read from the pooled vector (the unsure rules skip the per-segment spread).
POOLED_NOTE = "second-order Nomoto on all"
#: Gradient of ``T = T12 - T3`` and of K in the pooled vector.
_GRAD = {"K": np.array([1.0, 0.0, 0.0, 0.0]), "T": np.array([0.0, 1.0, 0.0, -1.0])}


@dataclass(frozen=True)
class PooledValue:
    """K or T read from the pooled vector.

    Attributes
    ----------
    value, stderr : float
        Value and standard error (the random-effects prediction error where the segments disagree)
        [1/s or s].
    p_value : float
        Chi-square p-value of the segment vectors about the pooled one.
    """

    value: float
    stderr: float
    p_value: float


@dataclass(frozen=True)
class PooledSecondOrder:
    """The generalised least-squares mean of second-order segment vectors.

    Attributes
    ----------
    values : dict
        ``K`` and ``T`` -> :class:`PooledValue`.
    psi : numpy.ndarray
        Between-segment covariance of (K, T1 + T2, T1 T2, T3) (zero while the segments agree within their
        errors) [their units squared].
    chi2, dof : float
        The vector chi-square and its degrees of freedom.
    n : int
        Segments pooled.
    note : str
        What was done, for the estimates' messages.
    """

    values: dict
    psi: np.ndarray
    chi2: float
    dof: int
    n: int
    note: str


def samples_window(sf: SegmentFit) -> tuple[float, float] | None:
    """Start and end [s, trial clock] of the samples a whole-record Nomoto fit used (None for other fits).

    A rudder step's window reaches back over the steady hold before it
    (:func:`pipeline.fit.nomoto_segment.rudder_step_lead_in`), which is the previous step's new level:
    consecutive steps share samples, and their combination treats them as correlated
    (:func:`pipeline.fit.combine.overlap_correlation`).

    Parameters
    ----------
    sf : SegmentFit
        A segment fit; its ``t`` is relative to the segment's start.
    """
    if not sf.model.startswith(("nomoto_oe", "nomoto_pem")) or sf.t is None or len(sf.t) < 2:
        return None
    t = np.asarray(sf.t, float)
    if not (math.isfinite(t[0]) and math.isfinite(t[-1])):
        return None
    return float(sf.segment.t_start + t[0]), float(sf.segment.t_start + t[-1])


def is_joint_follower(sf: SegmentFit) -> bool:
    """Whether ``sf`` is a segment of a joint fit whose coefficients are counted on another segment.

    Parameters
    ----------
    sf : SegmentFit
        A segment fit.
    """
    return sf.message.startswith(JOINT_FOLLOWER) or f"; {JOINT_FOLLOWER} " in sf.message


def _vector(sf: SegmentFit) -> tuple[np.ndarray, np.ndarray] | None:
    """The segment's (K, T12, T1T2, T3) and their covariance block (None when it has no usable one)."""
    names = list(getattr(sf, "param_names", None) or ())
    covariance = getattr(sf, "covariance", None)
    if not all(n in sf.params and n in names for n in POOLED_PARAMS) or covariance is None:
        return None
    idx = [names.index(n) for n in POOLED_PARAMS]
    cov = np.asarray(covariance, float)
    if cov.ndim != 2 or cov.shape[0] <= max(idx):
        return None
    c = cov[np.ix_(idx, idx)]
    x = np.array([sf.params[n] for n in POOLED_PARAMS], float)
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(c)) and np.all(np.diag(c) > 0)):
        return None
    return x, 0.5 * (c + c.T)


def pool_second_order(fits: Sequence[SegmentFit], min_segments: int = 2,
                      prediction: bool = True) -> PooledSecondOrder | None:
    """K and T from the generalised least-squares mean of second-order segment vectors (module doc).

    Parameters
    ----------
    fits : sequence of SegmentFit
        The successful Nomoto segment fits behind K and T.
    min_segments : int
        Fewest segments pooled (1: a single segment's own vector, for a group of steps,
        :func:`pipeline.fit.nomoto_quality.superposition_groups`).
    prediction : bool
        Where the segments disagree, add the between-segment spread to the error (the random-effects
        prediction error, as :func:`pipeline.fit.combine.combine` with ``prediction=True``).

    Returns
    -------
    PooledSecondOrder or None
        None unless there are ``min_segments`` or more and every one is a second-order whole-record
        fit with a usable covariance of (K, T12, T1T2, T3).
    """
    fits = [sf for sf in fits if not is_joint_follower(sf)]
    if len(fits) < max(min_segments, 1):
        return None
    vecs = [_vector(sf) for sf in fits]
    if any(v is None for v in vecs):
        return None
    k, p = len(vecs), len(POOLED_PARAMS)
    xs = np.array([v[0] for v in vecs])
    scale = np.maximum(np.abs(np.median(xs, axis=0)), 1e-12)
    covs = [v[1] / np.outer(scale, scale) for v in vecs]
    info = np.zeros((p, p))
    vec = np.zeros(p)
    try:
        invs = [np.linalg.pinv(c, rcond=1e-12, hermitian=True) for c in covs]
        for c_inv, x in zip(invs, xs / scale):
            info += c_inv
            vec += c_inv @ x
        cov = np.linalg.inv(info)
    except np.linalg.LinAlgError:
        return None
    theta = cov @ vec
    chi2 = float(sum((x - theta) @ c_inv @ (x - theta) for c_inv, x in zip(invs, xs / scale)))
    dof = p * (k - 1)
    p_value = float(stats.chi2.sf(chi2, dof)) if dof > 0 else math.nan
    rho = overlap_correlation([samples_window(sf) for sf in fits])
    deff = float(rho.sum()) / k
    psi = np.zeros((p, p))
    if dof > 0 and p_value < CONSISTENCY_ALPHA:
        psi = dersimonian_laird_psi(xs / scale, invs)
        # The fixed-effect mean's covariance under the random-effects model (Henmi & Copas 2010).
        cov = cov + cov @ sum(c_inv @ psi @ c_inv for c_inv in invs) @ cov
    s2 = np.outer(scale, scale)
    theta, cov_mean, psi = theta * scale, cov * s2 * deff, psi * s2
    cov_out = cov_mean + psi if prediction else cov_mean
    values = {name: PooledValue(float(g @ theta), math.sqrt(max(float(g @ cov_out @ g), 0.0)), p_value)
              for name, g in _GRAD.items()}
    n_pairs = int(np.sum(rho[np.triu_indices(k, 1)] > 0))
    if np.any(psi):
        spread = ", ".join(f"{name} {math.sqrt(max(float(g @ psi @ g), 0.0)):.3g}" for name, g in _GRAD.items())
        rule = (f"p = {p_value:.2g} < {CONSISTENCY_ALPHA}: the segments disagree, between-segment covariance by the "
                f"multivariate DerSimonian-Laird rule (spread {spread}), the mean's error under it"
                + (" plus the spread (random-effects prediction error: a model error common to every manoeuvre "
                   "is not averaged down)" if prediction else ""))
    else:
        rule = f"p = {p_value:.2g}: the segments agree within their errors"
    note = (f"{POOLED_NOTE} {k} segments: K and T = T1 + T2 - T3 read from the generalised "
            f"least-squares mean of their (K, T1 + T2, T1 T2, T3) with the full covariances (a segment's own T, "
            f"the difference of two correlated constants, scatters more than the vector it comes from)"
            + (f", {n_pairs} pair(s) of overlapping windows correlated" if n_pairs else "")
            + f"; vector chi-square {chi2:.3g} on {dof} dof, {rule}")
    return PooledSecondOrder(values, psi, chi2, dof, k, note)
