"""Which damping coefficients a trial determines, from the Fisher information of its own data.

At the estimate the Fisher information of the grey-box output error is ``F = J^T J / sigma^2``
(Ljung 1999, sec. 7.4 and 9.2); its inverse is the Cramer-Rao covariance. Three readings of it say
what the trial cannot determine, instead of printing a number for it:

- **Relative standard error.** ``sqrt((s^2 F^-1)_ii) / max(|theta_i|, scale_i)`` above
  ``MAX_RELATIVE_STD`` (50%). ``scale_i`` is the coefficient's natural size: its own start value
  for a diagonal term, a tenth of the geometric mean of the two diagonal terms it links for a coupled
  one (``0.1 sqrt(D_ii D_jj)``, the units match). A coupling that is truly near zero is then
  reported as determined (near zero) rather than as a huge relative error of a tiny number.
- **Near-null directions.** Eigen-decomposition of the scaled Fisher matrix ``S F S``
  (``S = diag(max(|theta_i|, scale_i))``): an eigenvector whose standard deviation
  ``sqrt(s^2/lambda)`` exceeds ``MAX_RELATIVE_STD`` is a combination of coefficients the data do not
  see; every coefficient loading on it by more than ``MIN_LOADING`` is not determined, and is named
  with its partners. (The linearised marginal error of such a coefficient can still look
  acceptable when the fit has wandered along the flat direction.)
- **Correlation.** ``|corr_ij| > MAX_CORRELATION`` (0.95): the pair is separable only through the
  small difference in how it acts on the data. A long zig-zag trial separates ``N_r`` and ``Y_r``
  at a correlation of 0.995 with errors below 2%, so correlation alone does not fail a coefficient:
  a correlated pair whose errors pass is reported with a warning, one that fails is called not
  separable.

Each coefficient maps to the manoeuvre that excites it (``MANOEUVRES``), so a failed coefficient's
message says what to run next.

References
----------
Ljung, L. (1999). *System Identification: Theory for the User*, 2nd ed. Prentice Hall.
Fossen, T. I. (2021). *Handbook of Marine Craft Hydrodynamics and Motion Control*, 2nd ed. Wiley.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

#: Standard error above which a coefficient (or an eigen-direction) is not determined, as a
#: fraction of ``max(|value|, scale)``.
MAX_RELATIVE_STD = 0.5
#: Correlation above which a pair is flagged.
MAX_CORRELATION = 0.95
#: Loading above which a coefficient is named with a near-null direction.
MIN_LOADING = 0.3

#: Coefficient -> the manoeuvre that determines it (what must move, and what must be logged).
MANOEUVRES: Mapping[str, str] = {
    "X_u": "a surge step and coast-down (thrust held 5 time constants, then cut)",
    "Y_v": "a sway step and coast-down with the tunnel thrusters (tau_y logged, sway velocity v measured)",
    "K_p": "roll free decays (heel the hull 15-20 deg and release; phi or p logged)",
    "M_q": "pitch free decays (trim the hull 5 deg and release; theta or q logged)",
    "N_r": "a yaw step and coast-down (tau_n) or +-10 deg rudder steps held 6 time constants",
    "Y_r": "a 20/20 zig-zag or rudder steps at speed with the sway velocity v logged (GNSS course and heading)",
    "N_v": ("a sway step with the tunnel thrusters (yaw rate logged), or a 20/20 zig-zag at speed: sway "
            "velocity that is not just a copy of the yaw rate"),
    "K_v": "a sway step with the tunnel thrusters with roll (phi or p) logged",
    "K_r": "rudder steps or a turning circle at speed with roll (phi or p) logged (the heel in a steady turn)",
    "Y_p": "roll free decays or a roll sinusoid with the sway velocity v logged",
    "N_p": "roll free decays or a roll sinusoid with the yaw rate r logged",
}


@dataclass(frozen=True)
class CoefficientStatus:
    """What the Fisher information says about one coefficient.

    Attributes
    ----------
    name : str
        Coefficient.
    identified : bool
        Determined by this trial.
    relative_std : float
        Standard error over ``max(|value|, scale)`` [-]; ``inf`` when not determined at all.
    correlated_with : tuple[tuple[str, float], ...]
        Partners with ``|corr| > MAX_CORRELATION`` and the correlation.
    near_null : tuple[str, ...]
        The other coefficients of a near-null direction it belongs to (empty if none).
    reasons : tuple[str, ...]
        Why it is not determined, or the warnings on a determined one.
    manoeuvre : str
        The manoeuvre that determines it.
    """

    name: str
    identified: bool
    relative_std: float
    correlated_with: tuple[tuple[str, float], ...] = ()
    near_null: tuple[str, ...] = ()
    reasons: tuple[str, ...] = ()
    manoeuvre: str = ""

    @property
    def message(self) -> str:
        """One sentence for the Estimate: why not identified and what to run, or the warnings."""
        if self.identified:
            return "; ".join(self.reasons)
        why = "; ".join(self.reasons) or "the Fisher information of this trial does not determine it"
        return f"{self.name} not identified by this trial: {why}; to determine it run {self.manoeuvre}"


@dataclass(frozen=True)
class Identifiability:
    """Eigen-analysis of the Fisher information of one fit.

    Attributes
    ----------
    names : tuple[str, ...]
        Coefficients, in Fisher order.
    scales : numpy.ndarray
        ``max(|value|, scale)`` per coefficient [unit of each].
    eigenvalues : numpy.ndarray
        Eigenvalues of the scaled Fisher matrix ``S F S / s^2``, ascending [-].
    eigenvectors : numpy.ndarray
        Columns: the matching unit eigenvectors in scaled coordinates.
    correlation : numpy.ndarray
        Correlation matrix (NaN where a standard error is infinite).
    status : Mapping[str, CoefficientStatus]
        Per coefficient.
    near_null : tuple[tuple[str, ...], ...]
        Coefficients of each near-null direction.
    """

    names: tuple[str, ...]
    scales: np.ndarray
    eigenvalues: np.ndarray
    eigenvectors: np.ndarray
    correlation: np.ndarray
    status: Mapping[str, CoefficientStatus] = field(default_factory=dict)
    near_null: tuple[tuple[str, ...], ...] = ()

    @property
    def not_identified(self) -> tuple[str, ...]:
        """Coefficients the trial does not determine."""
        return tuple(n for n in self.names if not self.status[n].identified)


def analyse_identifiability(names: Sequence[str], values: np.ndarray, fisher: np.ndarray, scales: np.ndarray,
                            s2: float = 1.0, max_relative_std: float = MAX_RELATIVE_STD,
                            max_correlation: float = MAX_CORRELATION) -> Identifiability:
    """Decide which coefficients a fit determines.

    Parameters
    ----------
    names : sequence of str
        Coefficient names (``MANOEUVRES`` keys for the manoeuvre advice).
    values : numpy.ndarray
        Estimates [unit of each].
    fisher : numpy.ndarray
        Fisher information ``J^T J / sigma^2`` of the values [1/(unit_i unit_j)].
    scales : numpy.ndarray
        Natural size of each coefficient [unit of each] (see the module notes).
    s2 : float
        Residual variance factor (weighted RSS / dof); standard errors are ``sqrt(s2 F^-1)``.
    max_relative_std : float
        Threshold on the standard error relative to ``max(|value|, scale)``.
    max_correlation : float
        Threshold on ``|corr|``.

    Returns
    -------
    Identifiability
    """
    names = tuple(names)
    values = np.asarray(values, float)
    size = np.maximum(np.abs(values), np.abs(np.asarray(scales, float)))
    size = np.where(size > 0, size, 1.0)
    fs = np.asarray(fisher, float) * np.outer(size, size) / max(s2, 1e-300)
    fs = 0.5 * (fs + fs.T)
    lam, vec = np.linalg.eigh(fs)
    top = float(lam.max(initial=0.0))
    # An eigenvalue at round-off level is a direction with no information at all.
    zero = lam <= max(top, 1e-300) * 1e-12
    with np.errstate(divide="ignore"):
        dir_std = np.where(zero, np.inf, 1.0 / np.sqrt(np.where(zero, 1.0, lam)))
    weak = dir_std > max_relative_std
    cov = (vec[:, ~zero] / lam[~zero]) @ vec[:, ~zero].T
    rel = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    undetermined = np.any(np.abs(vec[:, zero]) > 1e-6, axis=1) if zero.any() else np.zeros(len(names), bool)
    rel = np.where(undetermined, np.inf, rel)
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(rel, rel)
    corr[undetermined, :] = np.nan
    corr[:, undetermined] = np.nan

    groups = []
    member_of: dict[str, list[str]] = {n: [] for n in names}
    for j in np.flatnonzero(weak):
        who = tuple(names[i] for i in np.flatnonzero(np.abs(vec[:, j]) > MIN_LOADING))
        if len(who) == 0:
            who = (names[int(np.argmax(np.abs(vec[:, j])))],)
        groups.append(who)
        for n in who:
            member_of[n] += [m for m in who if m != n and m not in member_of[n]]

    status = {}
    for i, n in enumerate(names):
        partners = tuple((names[j], float(corr[i, j])) for j in range(len(names))
                         if j != i and math.isfinite(corr[i, j]) and abs(corr[i, j]) > max_correlation)
        in_null = any(n in g for g in groups)
        ok = bool(math.isfinite(rel[i]) and rel[i] <= max_relative_std and not in_null)
        reasons = []
        if not math.isfinite(rel[i]):
            reasons.append("the data carry no information on it (a zero eigenvalue of the Fisher matrix)")
        elif rel[i] > max_relative_std:
            reasons.append(f"its standard error is {rel[i]:.0%} of its size (limit {max_relative_std:.0%})")
        if in_null and member_of[n]:
            reasons.append(f"it moves with {', '.join(member_of[n])} along a direction the data do not see "
                           f"(near-null eigenvector of the Fisher matrix)")
        elif in_null and not ok:
            reasons.append("it lies along a near-null eigenvector of the Fisher matrix")
        if partners:
            pair = ", ".join(f"{m} (corr {c:+.3f})" for m, c in partners)
            reasons.append(f"not separable from {pair}" if not ok else f"strongly correlated with {pair}: "
                           f"separated by this trial, but a shorter or noisier one would not separate them")
        status[n] = CoefficientStatus(name=n, identified=ok, relative_std=float(rel[i]), correlated_with=partners,
                                      near_null=tuple(member_of[n]), reasons=tuple(reasons),
                                      manoeuvre=MANOEUVRES.get(n, "a manoeuvre that excites it"))
    return Identifiability(names=names, scales=size, eigenvalues=lam, eigenvectors=vec, correlation=corr,
                           status=status, near_null=tuple(groups))
