"""HAC sandwich covariance (pipeline.fit.robust_covariance): coverage under AR(1) residuals."""

import numpy as np
import pytest

from pipeline.fit.robust_covariance import andrews_bandwidth, hac_covariance, pooled_lag1


def _ar1(rng, n, rho, sd):
    e = rng.normal(0, sd, n)
    x = np.empty(n)
    x[0] = e[0] / np.sqrt(1 - rho**2)
    for i in range(1, n):
        x[i] = rho * x[i - 1] + e[i]
    return x


def test_hac_covers_a_mean_under_ar1_noise_where_the_classic_covariance_does_not():
    # A slowly varying regressor (as a damping sensitivity is) and AR(1) noise with rho = 0.8:
    # the white-noise covariance is about 3x too small; the sandwich should cover near 95 %.
    rng = np.random.default_rng(3)
    n, reps, rho = 400, 300, 0.8
    x = np.linspace(0, 1, n)
    jac = -np.column_stack([np.ones(n), x])
    hit_hac, hit_classic = 0, 0
    for _ in range(reps):
        y = 1.0 + 2.0 * x + _ar1(rng, n, rho, 0.1)
        coef, *_ = np.linalg.lstsq(-jac, y, rcond=None)
        r = y + jac @ coef
        rob = hac_covariance(jac, r, np.zeros(n, int))
        se_h = np.sqrt(rob.covariance[1, 1])
        se_c = np.sqrt(rob.classic[1, 1])
        hit_hac += abs(coef[1] - 2.0) <= 1.96 * se_h
        hit_classic += abs(coef[1] - 2.0) <= 1.96 * se_c
    assert hit_classic / reps < 0.75
    assert 0.85 <= hit_hac / reps <= 0.99


def test_white_residuals_leave_the_covariance_at_the_classic_one():
    rng = np.random.default_rng(1)
    n = 2000
    jac = -np.column_stack([np.ones(n), rng.normal(size=n)])
    r = rng.normal(size=n)
    rob = hac_covariance(jac, r, np.repeat(np.arange(4), n // 4))
    assert abs(rob.rho) < 0.1
    assert np.allclose(rob.inflation, 1.0, atol=0.15)


def test_lags_do_not_cross_records_and_bandwidth_grows_with_rho():
    r = np.array([1.0, 1.0, -1.0, -1.0])
    assert pooled_lag1(r, np.array([0, 0, 1, 1])) == pytest.approx(0.5)
    assert pooled_lag1(r, np.array([0, 0, 0, 0])) == pytest.approx(0.25)
    assert andrews_bandwidth(0.0, 300) == 0
    assert andrews_bandwidth(0.5, 300) < andrews_bandwidth(0.9, 300) <= 150
