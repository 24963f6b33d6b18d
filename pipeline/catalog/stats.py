"""Comparisons across trials: two trials coefficient by coefficient, and one coefficient's trend.

Compare: for each coefficient identified in both trials, ``d = b - a``, ``se = sqrt(se_a^2 +
se_b^2)`` (the trials are independent recordings), ``z = d / se`` and the two-sided p-value of the
normal distribution. Testing many coefficients at once inflates false alarms, so the flag "beyond
uncertainty" uses Holm's step-down correction (Holm 1979), which keeps the family-wise error rate
at ``alpha`` over all coefficients compared.

Trend: a weighted straight line ``y = a + b x`` through the trials of one vessel (weights
``1/se^2``), with ``x`` the log date in days when every trial has one, else the trial's position in
name order. When the points scatter more than their standard errors say (reduced chi-square > 1),
the covariance is scaled by it (Birge ratio), so the drift's uncertainty covers trial-to-trial
variation the single-trial errors miss. The drift is significant when the two-sided t-test
(``n - 2`` degrees of freedom) on ``b`` gives p < ``alpha``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import stats as st

from .errors import CatalogError
from .store import Catalog

#: Family-wise error rate of the compare flags and the trend test.
ALPHA = 0.05


def holm(p_values: np.ndarray, alpha: float = ALPHA) -> np.ndarray:
    """Holm's step-down test: which hypotheses are rejected at family-wise error rate ``alpha``.

    Parameters
    ----------
    p_values : numpy.ndarray
        p-values of the individual tests (NaN counts as not rejected).
    alpha : float
        Family-wise error rate.

    Returns
    -------
    numpy.ndarray
        Boolean, True where rejected.
    """
    p = np.asarray(p_values, float)
    valid = np.flatnonzero(np.isfinite(p))
    reject = np.zeros(p.shape, bool)
    m = len(valid)
    for rank, i in enumerate(valid[np.argsort(p[valid], kind="stable")]):
        if p[i] > alpha / (m - rank):
            break
        reject[i] = True
    return reject


def compare_trials(cat: Catalog, ref_a: str, ref_b: str, alpha: float = ALPHA) -> tuple[pd.DataFrame, str]:
    """Compare two trials coefficient by coefficient.

    Parameters
    ----------
    cat : Catalog
        Open catalogue.
    ref_a, ref_b : str
        Trial names or ids (:meth:`Catalog.resolve`); differences are ``b - a``.
    alpha : float
        Family-wise error rate of the Holm-corrected flags.

    Returns
    -------
    (pandas.DataFrame, str)
        One row per coefficient present in either trial: ``a``, ``se_a``, ``b``, ``se_b``,
        ``diff``, ``se_diff``, ``z``, ``p``, ``beyond`` (Holm-corrected), ``rel_change`` and a
        ``note`` where a coefficient is missing in one trial; and the text of the correction used.
    """
    ta, tb = cat.resolve(ref_a), cat.resolve(ref_b)
    for t in (ta, tb):
        if t["status"] != "ok":
            raise CatalogError(f"trial {t['name']} ({t['trial_id']}): expected a processed trial, found one that "
                               f"failed: {t['error']}")
    ca = cat.coefficients(ta["trial_id"]).set_index("name")
    cb = cat.coefficients(tb["trial_id"]).set_index("name")
    names = list(ca.index) + [n for n in cb.index if n not in ca.index]
    rows = []
    for n in names:
        a = ca.loc[n] if n in ca.index else None
        b = cb.loc[n] if n in cb.index else None
        usable = [x is not None and bool(x["success"]) and _finite(x["value"]) and _finite(x["stderr"]) for x in (a, b)]
        row = {"coefficient": n, "unit": (a if a is not None else b)["unit"],
               "a": a["value"] if usable[0] else math.nan, "se_a": a["stderr"] if usable[0] else math.nan,
               "b": b["value"] if usable[1] else math.nan, "se_b": b["stderr"] if usable[1] else math.nan}
        if all(usable):
            d = row["b"] - row["a"]
            se = math.hypot(row["se_a"], row["se_b"])
            z = d / se if se > 0 else math.nan
            row.update(diff=d, se_diff=se, z=z, p=2 * st.norm.sf(abs(z)) if math.isfinite(z) else math.nan,
                       rel_change=d / abs(row["a"]) if row["a"] != 0 else math.nan, note="")
        else:
            missing = [lab for lab, u in zip(("A", "B"), usable) if not u]
            row.update(diff=math.nan, se_diff=math.nan, z=math.nan, p=math.nan, rel_change=math.nan,
                       note=f"not identified in trial {' and '.join(missing)}")
        rows.append(row)
    df = pd.DataFrame(rows)
    df["beyond"] = holm(df["p"].to_numpy(), alpha) if not df.empty else []
    m = int(np.isfinite(df["p"]).sum()) if not df.empty else 0
    text = (f"A = {ta['name']} ({ta['trial_id']}), B = {tb['name']} ({tb['trial_id']}); diff = B - A, "
            f"se = sqrt(se_A^2 + se_B^2), z = diff/se, two-sided normal p; 'beyond' = change beyond the combined "
            f"uncertainty after Holm's correction over the {m} coefficients compared (family-wise error rate {alpha:g})")
    return df, text


def _finite(x) -> bool:
    try:
        return math.isfinite(float(x))
    except (TypeError, ValueError):
        return False


@dataclass(frozen=True)
class Trend:
    """A coefficient's straight-line drift over the trials of one vessel.

    Attributes
    ----------
    coefficient, vessel, unit : str
        What was fitted.
    x_label : str
        What ``x`` is (``days since the first trial`` or ``trial number in name order``).
    x_unit : str
        Unit of ``x`` for the drift (``day`` or ``trial``).
    points : pandas.DataFrame
        The trials: ``name``, ``trial_id``, ``x``, ``value``, ``stderr``, ``report_dir``.
    intercept, slope : float
        ``a`` and ``b`` [unit, unit per x]; NaN with fewer than 3 trials.
    slope_se : float
        Standard error of ``b`` (scaled by the Birge ratio when the scatter exceeds the errors).
    rel_slope, rel_slope_se : float
        ``b`` and its error relative to the weighted mean |value| [1 per x].
    p_value : float
        Two-sided t-test of ``b = 0``, ``n - 2`` degrees of freedom.
    chi2_red : float
        Reduced chi-square of the weighted fit.
    significant : bool
        ``p_value < alpha``.
    note : str
        Why no drift is given, or what the scale factor was.
    """

    coefficient: str
    vessel: str
    unit: str
    x_label: str
    x_unit: str
    points: pd.DataFrame
    intercept: float = math.nan
    slope: float = math.nan
    slope_se: float = math.nan
    rel_slope: float = math.nan
    rel_slope_se: float = math.nan
    p_value: float = math.nan
    chi2_red: float = math.nan
    significant: bool = False
    note: str = ""


def fit_drift(x: np.ndarray, y: np.ndarray, se: np.ndarray) -> tuple[float, float, float, float, float]:
    """Weighted straight line through ``(x, y)`` with standard errors ``se``.

    Parameters
    ----------
    x : numpy.ndarray
        Abscissae (at least 3 distinct values).
    y : numpy.ndarray
        Values.
    se : numpy.ndarray
        Standard errors of ``y`` (positive).

    Returns
    -------
    (float, float, float, float, float)
        Intercept, slope, slope standard error (Birge-scaled when reduced chi-square > 1), p-value
        of the slope's t-test, reduced chi-square.
    """
    w = 1.0 / np.asarray(se, float) ** 2
    A = np.column_stack([np.ones_like(x), x])
    cov = np.linalg.inv(A.T @ (A * w[:, None]))
    beta = cov @ (A.T @ (w * y))
    resid = y - A @ beta
    dof = len(x) - 2
    chi2_red = float(np.sum(w * resid**2) / dof) if dof > 0 else math.nan
    scale = max(chi2_red, 1.0) if math.isfinite(chi2_red) else 1.0
    slope_se = float(math.sqrt(cov[1, 1] * scale))
    t = beta[1] / slope_se if slope_se > 0 else math.inf
    p = float(2 * st.t.sf(abs(t), dof)) if dof > 0 else math.nan
    return float(beta[0]), float(beta[1]), slope_se, p, chi2_red


def coefficient_trend(cat: Catalog, coefficient: str, vessel: str | None = None,
                      alpha: float = ALPHA) -> list[Trend]:
    """Trend of one coefficient over the trials of each vessel (or of one vessel).

    Parameters
    ----------
    cat : Catalog
        Open catalogue.
    coefficient : str
        Coefficient name.
    vessel : str, optional
        Only this vessel.
    alpha : float
        Significance level of the drift test.

    Returns
    -------
    list[Trend]
        One per vessel that has the coefficient in at least one trial.

    Raises
    ------
    CatalogError
        No trial has the coefficient.
    """
    hist = cat.coefficient_history(coefficient, vessel)
    if hist.empty:
        known = cat.query("SELECT DISTINCT name FROM coefficients ORDER BY name")["name"].tolist()
        raise CatalogError(f"trend: expected a coefficient catalogued for {vessel or 'any vessel'}, found no "
                           f"{coefficient!r}; coefficients: {', '.join(known) or 'none'}")
    out = []
    for vname, g in hist.groupby("vessel_name", sort=True, dropna=False):
        # One point per trial (same files): the newest processing; an old version's rows stay catalogued.
        g = g.sort_values("processed_at").groupby("files_hash", as_index=False).tail(1)
        ok = g[g["success"].astype(bool) & g["value"].notna() & (g["stderr"] > 0)].copy()
        dated = ok["started_utc"].notna().all() and len(ok) > 0
        if dated:
            t = pd.to_datetime(ok["started_utc"], utc=True)
            ok["x"] = (t - t.min()).dt.total_seconds() / 86400.0
            ok = ok.sort_values(["x", "name"])
            label, x_unit = "days since the first trial (log clock)", "day"
        else:
            ok = ok.sort_values("name", key=lambda s: s.map(_natural_key))
            ok["x"] = np.arange(len(ok), dtype=float)
            label, x_unit = "trial number in name order (not every trial has a log date)", "trial"
        pts = ok[["name", "trial_id", "x", "value", "stderr", "report_dir"]].reset_index(drop=True)
        unit = str(g["unit"].iloc[0])
        base = dict(coefficient=coefficient, vessel=str(vname), unit=unit, x_label=label, x_unit=x_unit, points=pts)
        if len(pts) < 3 or pts["x"].nunique() < 3:
            out.append(Trend(**base, note=f"no drift fitted: {len(pts)} trial(s) with the coefficient identified, "
                                          f"need 3 or more at 3 distinct x"))
            continue
        a, b, b_se, p, chi2 = fit_drift(pts["x"].to_numpy(), pts["value"].to_numpy(), pts["stderr"].to_numpy())
        w = 1 / pts["stderr"].to_numpy() ** 2
        mean = abs(float(np.sum(w * pts["value"]) / np.sum(w)))
        note = (f"covariance scaled by reduced chi-square {chi2:.3g} (scatter beyond the single-trial errors)"
                if chi2 > 1 else f"reduced chi-square {chi2:.3g} (scatter within the single-trial errors)")
        out.append(Trend(**base, intercept=a, slope=b, slope_se=b_se, rel_slope=b / mean if mean else math.nan,
                         rel_slope_se=b_se / mean if mean else math.nan, p_value=p, chi2_red=chi2,
                         significant=bool(p < alpha), note=note))
    return out


def _natural_key(name: str):
    import re

    return tuple(int(s) if s.isdigit() else s for s in re.split(r"(\d+)", str(name)))


def plot_trend(trend: Trend, path=None):
    """Plot a trend: the trials with error bars (1 sigma) and the fitted drift with its 95% band.

    Parameters
    ----------
    trend : Trend
        From :func:`coefficient_trend`.
    path : str or Path, optional
        PNG to write (atomically); None returns the figure without saving.

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pts = trend.points
    fig, ax = plt.subplots(figsize=(6.4, 3.6), dpi=100)
    ax.errorbar(pts["x"], pts["value"], yerr=pts["stderr"], fmt="o", ms=4, capsize=3, label="trial (±1 std. error)")
    if math.isfinite(trend.slope):
        xs = np.linspace(pts["x"].min(), pts["x"].max(), 50)
        ax.plot(xs, trend.intercept + trend.slope * xs, "-", color="C3",
                label=f"drift {trend.slope:.3g} ± {trend.slope_se:.2g} {trend.unit} per {trend.x_unit} "
                      f"(p = {trend.p_value:.2g})")
        # 95% band of the slope only, pivoting about the weighted centre, as a visual of the drift error.
        w = 1 / pts["stderr"].to_numpy() ** 2
        xc = float(np.sum(w * pts["x"]) / np.sum(w))
        yc = trend.intercept + trend.slope * xc
        q = st.t.ppf(0.975, max(len(pts) - 2, 1))
        for sgn in (-1, 1):
            ax.plot(xs, yc + (trend.slope + sgn * q * trend.slope_se) * (xs - xc), ":", color="C3", lw=1)
    ax.set_xlabel(trend.x_label)
    ax.set_ylabel(f"{trend.coefficient} [{trend.unit}]")
    ax.set_title(f"{trend.vessel}: {trend.coefficient}" + (" — significant drift" if trend.significant else ""))
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    if path is not None:
        from ..atomic import atomic_path

        with atomic_path(path) as tmp:
            fig.savefig(tmp, format="png")
        plt.close(fig)
    return fig
