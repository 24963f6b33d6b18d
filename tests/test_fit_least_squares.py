"""The shared least-squares helper (covariance, intervals, residual whiteness) and the combination
of repeated segments."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from pipeline.fit import Contribution, combine, confidence_interval, fit_least_squares
from pipeline.fit.least_squares import lag1_autocorrelation


def _line(t, p):
    return p[0] + p[1] * t


def _line_jac(t, p):
    return np.column_stack([np.ones_like(t), t])


def test_covariance_equals_ordinary_least_squares_formula():
    rng = np.random.default_rng(1)
    t = np.linspace(0, 10, 50)
    y = 1.0 + 0.5 * t + rng.normal(0, 0.2, t.size)
    res = fit_least_squares(_line, _line_jac, t, y, [0.0, 0.0], ("a", "b"))
    x = np.column_stack([np.ones_like(t), t])
    beta, rss, *_ = np.linalg.lstsq(x, y, rcond=None)
    s2 = float(rss[0]) / (t.size - 2)
    assert res.values == pytest.approx(beta, rel=1e-6)
    assert res.covariance == pytest.approx(np.linalg.inv(x.T @ x) * s2, rel=1e-6)
    assert res.stderr == pytest.approx(np.sqrt(np.diag(res.covariance)))
    assert res.dof == 48 and res.converged and res.at_bound == ()
    assert res.aic == pytest.approx(50 * math.log(res.rss / 50) + 4)
    assert res.bic == pytest.approx(50 * math.log(res.rss / 50) + 2 * math.log(50))


def test_bound_hit_is_reported():
    t = np.linspace(0, 1, 20)
    res = fit_least_squares(_line, _line_jac, t, 2.0 + t, [0.0, 0.0], ("a", "b"), [-np.inf, -np.inf], [1.0, np.inf])
    assert res.at_bound == ("a",)


def test_singular_jacobian_gives_nan_stderr_and_says_why():
    t = np.linspace(0, 1, 20)
    res = fit_least_squares(lambda tt, p: (p[0] + p[1]) * tt, lambda tt, p: np.column_stack([tt, tt]),
                            t, 2 * t, [0.5, 0.5], ("a", "b"))
    assert np.isnan(res.stderr).all() and "singular" in res.message


def test_confidence_interval_uses_student_t():
    lo, hi = confidence_interval(10.0, 1.0, 5)
    assert hi - 10.0 == pytest.approx(stats.t.ppf(0.975, 5))
    lo, hi = confidence_interval(10.0, 1.0, math.inf)
    assert hi - 10.0 == pytest.approx(1.959964, rel=1e-6)
    assert all(math.isnan(v) for v in confidence_interval(1.0, math.nan, 5))


def test_lag1_autocorrelation_of_white_and_ar1_noise():
    rng = np.random.default_rng(2)
    w = rng.normal(size=20000)
    assert abs(lag1_autocorrelation(w)) < 0.03
    e = np.zeros_like(w)
    for k in range(1, w.size):
        e[k] = 0.8 * e[k - 1] + w[k]
    assert lag1_autocorrelation(e) == pytest.approx(0.8, abs=0.03)


def test_combine_inverse_variance_mean():
    est = combine("X_u", "kg/s", "m", [Contribution(-2.9, 0.1, "a"), Contribution(-2.8, 0.2, "b")])
    w = np.array([100.0, 25.0])
    assert est.value == pytest.approx((w @ [-2.9, -2.8]) / w.sum())
    assert est.stderr == pytest.approx(1 / math.sqrt(w.sum()))
    chi2 = float(w @ (np.array([-2.9, -2.8]) - est.value) ** 2)
    assert est.consistency_p == pytest.approx(stats.chi2.sf(chi2, 1))
    assert est.n_segments == 2 and est.per_segment == (-2.9, -2.8) and est.success


def test_combine_uses_random_effects_when_inconsistent():
    values = [1.0, 2.0, 1.5]
    est = combine("T", "s", "m", [Contribution(v, 0.05, str(i)) for i, v in enumerate(values)])
    w = np.full(3, 400.0)
    chi2 = float(w @ (np.array(values) - 1.5) ** 2)
    assert est.consistency_p < 0.01
    # DerSimonian-Laird: tau^2 = (Q - (k - 1)) / (S1 - S2/S1), weights 1/(se^2 + tau^2).
    tau2 = (chi2 - 2) / (w.sum() - (w**2).sum() / w.sum())
    assert est.stderr == pytest.approx(math.sqrt((0.05**2 + tau2) / 3))
    assert "random-effects" in est.message and "DerSimonian-Laird" in est.method
    assert est.ci95[1] - est.value == pytest.approx(stats.norm.ppf(0.975) * est.stderr)


def test_combine_leaves_out_failed_segments_and_names_them():
    est = combine("T", "s", "m", [Contribution(4.5, 0.1, "good"),
                                   Contribution(math.nan, math.nan, "bad", ok=False, reason="too short")])
    assert est.n_segments == 1 and est.value == 4.5 and "bad left out: too short" in est.message
    none = combine("T", "s", "m", [Contribution(math.nan, math.nan, "bad", ok=False, reason="too short")])
    assert not none.success and math.isnan(none.value) and "no usable segment" in none.message


def test_combine_fails_a_poorly_determined_value():
    est = combine("N_r", "kg m^2/s", "m", [Contribution(-0.2, 0.15, "a")])
    assert not est.success and "relative standard error" in est.message
