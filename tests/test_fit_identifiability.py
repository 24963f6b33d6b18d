"""Identifiability from the Fisher information (pipeline.fit.identifiability): relative standard
error, near-null eigen-directions and correlations decide what a trial determines, and every
coefficient maps to the manoeuvre that would determine it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pipeline.fit.greybox import COEFFICIENTS, covariance_from_fisher
from pipeline.fit.identifiability import MANOEUVRES, analyse_identifiability


def _fisher_from_jacobian(jac: np.ndarray, sigma: float = 1.0) -> np.ndarray:
    return jac.T @ jac / sigma**2


def test_well_determined_coefficients_pass():
    rng = np.random.default_rng(1)
    jac = rng.normal(size=(500, 3))
    fisher = _fisher_from_jacobian(jac, 0.1)
    ident = analyse_identifiability(("Y_v", "N_r", "Y_r"), np.array([-32.5, -0.26, -0.09]), fisher,
                                    np.array([32.5, 0.26, 0.29]))
    assert ident.not_identified == ()
    assert all(st.identified and st.relative_std < 0.05 for st in ident.status.values())
    assert ident.eigenvalues.shape == (3,) and np.all(np.diff(ident.eigenvalues) >= 0)


def test_pair_the_data_see_only_as_a_sum_is_flagged_with_its_partner_and_manoeuvre():
    # The response depends on N_v + Y_r only (columns equal): a near-null direction N_v - Y_r.
    rng = np.random.default_rng(2)
    col = rng.normal(size=400)
    jac = np.column_stack([col, col * (1 + 1e-4 * rng.normal(size=400)), rng.normal(size=400)])
    ident = analyse_identifiability(("N_v", "Y_r", "N_r"), np.array([-0.9, -0.1, -0.26]),
                                    _fisher_from_jacobian(jac, 0.05), np.array([0.3, 0.3, 0.26]))
    assert set(ident.not_identified) == {"N_v", "Y_r"}
    st = ident.status["N_v"]
    assert not st.identified and st.near_null == ("Y_r",)
    assert st.correlated_with and st.correlated_with[0][0] == "Y_r" and abs(st.correlated_with[0][1]) > 0.95
    msg = st.message
    assert msg.startswith("N_v not identified by this trial")
    assert "Y_r" in msg and "near-null" in msg and "zig-zag" in msg
    assert ident.status["N_r"].identified
    assert any(set(g) == {"N_v", "Y_r"} for g in ident.near_null)


def test_coefficient_without_information_has_infinite_error():
    jac = np.column_stack([np.ones(100), np.zeros(100)])
    ident = analyse_identifiability(("K_p", "K_v"), np.array([-0.11, 0.0]), _fisher_from_jacobian(jac),
                                    np.array([0.11, 0.19]))
    st = ident.status["K_v"]
    assert not st.identified and math.isinf(st.relative_std)
    assert "no information" in st.message and "roll" in st.manoeuvre
    cov, se = covariance_from_fisher(_fisher_from_jacobian(jac))
    assert math.isinf(se[1]) and math.isfinite(se[0]) and se[0] == pytest.approx(0.1)


def test_a_coupling_near_zero_is_determined_against_its_natural_size():
    # Y_r = 0.001 +- 0.005: 500% of its value, but 2% of 0.1 sqrt(Y_v N_r): determined (near zero).
    fisher = np.diag([1 / 0.05**2, 1 / 0.005**2])
    ident = analyse_identifiability(("Y_v", "Y_r"), np.array([-32.5, 0.001]), fisher, np.array([32.5, 0.29]))
    assert ident.status["Y_r"].identified and ident.status["Y_r"].relative_std == pytest.approx(0.005 / 0.29)


def test_residual_variance_scales_the_errors():
    fisher = np.diag([1 / 0.1**2])
    lo = analyse_identifiability(("N_r",), np.array([-0.26]), fisher, np.array([0.26]), s2=1.0)
    hi = analyse_identifiability(("N_r",), np.array([-0.26]), fisher, np.array([0.26]), s2=16.0)
    assert lo.status["N_r"].identified and not hi.status["N_r"].identified
    assert hi.status["N_r"].relative_std == pytest.approx(4 * lo.status["N_r"].relative_std)


def test_strong_but_resolved_correlation_is_a_warning_not_a_failure():
    # corr 0.99 with both errors small: a long zig-zag separates N_r and Y_r this way.
    cov = np.array([[1.0, 0.99], [0.99, 1.0]]) * 1e-8
    ident = analyse_identifiability(("N_r", "Y_r"), np.array([-0.26, -0.09]), np.linalg.inv(cov),
                                    np.array([0.26, 0.29]))
    st = ident.status["Y_r"]
    assert st.identified and st.correlated_with and "strongly correlated" in st.message


def test_every_coefficient_has_a_manoeuvre():
    for name in list(COEFFICIENTS) + ["X_u", "M_q"]:
        assert name in MANOEUVRES and MANOEUVRES[name]
