"""Kalman filter: Van Loan against numerical integration, the seed's matrices, observability, DARE, R."""

import math

import numpy as np
import pytest
import scipy.integrate
import scipy.linalg

from pipeline.autopilot.kalman import (DEFAULT_Q, continuous_noise_intensity, kalman_model, kalman_predict,
                                       kalman_update, observability, run_kalman_filter, sampled_noise_from_intensity,
                                       sampled_noise_variance, steady_state)
from pipeline.model import heading_model_matrices as continuous_model
from pipeline.model import van_loan
from pipeline.errors import AutopilotError
from pipeline.model.waves import WaveParams

K_SEED, T_SEED, TS = 0.1561, 72.4385, 0.1
WAVES_SEED = WaveParams(omega0=0.7823, lam=0.09, kw=0.0054)


def _integrated(a, b, e, q, h):
    """Ad, Bd, Ed, Qd by integrating the ODEs the matrix exponentials solve."""
    n = a.shape[0]
    bu = np.hstack([b, e])
    m = bu.shape[1]
    eqe = e @ q @ e.T

    def rhs(t, z):
        phi = z[: n * n].reshape(n, n)
        gam = z[n * n: n * n + n * m].reshape(n, m)
        p = z[n * n + n * m:].reshape(n, n)
        # Phi' = A Phi; Gamma' = Phi Bu (Gamma = int Phi ds Bu); P' = A P + P A^T + E Q E^T (P(0) = 0)
        return np.concatenate([(a @ phi).ravel(), (phi @ bu).ravel(), (a @ p + p @ a.T + eqe).ravel()])

    z0 = np.concatenate([np.eye(n).ravel(), np.zeros(n * m), np.zeros(n * n)])
    sol = scipy.integrate.solve_ivp(rhs, (0.0, h), z0, method="DOP853", rtol=1e-12, atol=1e-22)
    z = sol.y[:, -1]
    phi = z[: n * n].reshape(n, n)
    gam = z[n * n: n * n + n * m].reshape(n, m)
    p = z[n * n + n * m:].reshape(n, n)
    return phi, gam[:, : b.shape[1]], gam[:, b.shape[1]:], p


@pytest.mark.parametrize("h", [0.1, 1.0])
def test_van_loan_matches_numerical_integration(h):
    a, b, e, _ = continuous_model(K_SEED, T_SEED, WAVES_SEED)
    q = np.diag(DEFAULT_Q)
    ad, bd, ed, qd = van_loan(a, b, e, q, h)
    ad_i, bd_i, ed_i, qd_i = _integrated(a, b, e, q, h)
    np.testing.assert_allclose(ad, ad_i, rtol=1e-9, atol=1e-13)
    np.testing.assert_allclose(bd, bd_i, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(ed, ed_i, rtol=1e-9, atol=1e-15)
    # Qd spans 17 orders of magnitude (wave noise vs bias noise reaching psi), so compare each entry
    # relative to its own size, not the matrix norm.
    np.testing.assert_allclose(qd, qd_i, rtol=1e-7, atol=1e-24)
    assert np.all(np.linalg.eigvalsh(qd) > 0)


def test_ship_block_matches_the_seed_but_its_wave_block_does_not_match_lambda():
    m = kalman_model(K_SEED, T_SEED, WAVES_SEED, TS)
    # Seed eq. (5.3), ship rows: these are right.
    assert m.ad[2, 3] == pytest.approx(0.0999, abs=1e-4)
    assert m.ad[3, 3] == pytest.approx(0.9986, abs=1e-4)
    assert m.ad[3, 4] == pytest.approx(-2.153e-4, rel=1e-3)
    assert m.ad[2, 4] == pytest.approx(-1.076e-5, rel=2e-3)
    np.testing.assert_allclose(m.bd[2:4, 0], [1.077e-5, 2.153e-4], rtol=1e-3)
    np.testing.assert_allclose(m.ed[2:5, 1], [-3.590e-7, -1.0770e-5, 0.1], rtol=1e-3)
    # The seed's wave block [[0.9971, 0.0932], [-0.0570, 0.8659]] is not exp(A h) for lambda = 0.09 ...
    seed_wave = np.array([[0.9971, 0.0932], [-0.0570, 0.8659]])
    assert abs(m.ad[1, 1] - seed_wave[1, 1]) > 0.1
    # ... but it is for lambda = 0.9: a factor ten slipped in the seed's discretisation.
    m9 = kalman_model(K_SEED, T_SEED, WaveParams(0.7823, 0.9, 0.0054), TS)
    np.testing.assert_allclose(m9.ad[:2, :2], seed_wave, atol=2e-4)


def test_van_loan_qd_is_not_the_seeds_ed_q_ed():
    m = kalman_model(K_SEED, T_SEED, WAVES_SEED, TS)
    seed_qd = m.ed @ m.q @ m.ed.T
    assert np.linalg.matrix_rank(seed_qd) == 2
    assert np.all(np.linalg.eigvalsh(m.qd) > 0)  # bias noise reaches r and psi within the sample
    # E_d Q E_d^T ~ Q h^2 while Q_d ~ Q h: at 10 Hz the seed's wave noise is ten times too small.
    assert m.qd[1, 1] / seed_qd[1, 1] == pytest.approx(1.0 / TS, rel=0.05)


def test_observability_of_the_seeds_four_variants():
    obs = observability(K_SEED, T_SEED, WAVES_SEED)
    assert {k: (v["rank"], v["n"]) for k, v in obs.items()} == {
        "no disturbances": (2, 2), "current": (3, 3), "waves": (4, 4), "current and waves": (5, 5)}
    assert all(v["observable"] for v in obs.values())
    assert obs["current"]["states"] == ("psi", "r", "b")


def test_without_the_compass_seeing_psi_the_model_is_not_observable():
    # Sanity check of the rank test itself: measuring only psi_w leaves the ship unobservable.
    a, _, _, _ = continuous_model(K_SEED, T_SEED, WAVES_SEED)
    c = np.array([[0.0, 1.0, 0.0, 0.0, 0.0]])
    o = np.vstack([c @ np.linalg.matrix_power(a, k) for k in range(5)])
    assert np.linalg.matrix_rank(o) == 2


def test_filter_covariance_converges_to_the_dare_solution():
    m = kalman_model(K_SEED, T_SEED, WAVES_SEED, TS)
    run = run_kalman_filter(m, np.zeros(30000), np.zeros(30000))
    p_dare, p_post, gain = steady_state(m)
    scale = np.sqrt(np.outer(np.diag(p_dare), np.diag(p_dare)))
    np.testing.assert_allclose(run.p_prior_last / scale, p_dare / scale, atol=1e-6)
    np.testing.assert_allclose(run.gain[-1], gain, rtol=1e-5, atol=1e-12)
    np.testing.assert_allclose(run.p_post_diag[-1], np.diag(p_post), rtol=1e-5)
    # and it is the Riccati fixed point
    ad, c, qd, r = m.ad, m.c, m.qd, m.r
    rhs = ad @ p_dare @ ad.T - ad @ p_dare @ c.T @ np.linalg.inv(c @ p_dare @ c.T + r) @ c @ p_dare @ ad.T + qd
    np.testing.assert_allclose(rhs / scale, p_dare / scale, atol=1e-9)


def test_filter_separates_waves_and_estimates_bias_open_loop():
    from pipeline.model.waves import simulate_waves

    rng = np.random.default_rng(7)
    m = kalman_model(K_SEED, T_SEED, WAVES_SEED, TS, r=1e-6)
    n = 6000
    t = TS * np.arange(n)
    b_true = math.radians(2.0)
    delta = np.full(n, math.radians(5.0))
    # exact discrete ship with the rudder bias, no process noise
    x = np.zeros(5)
    x[4] = b_true
    psi = np.empty(n)
    for k in range(n):
        psi[k] = x[2]
        x = m.ad @ x + m.bd[:, 0] * delta[k]
    psi_w = simulate_waves(t, WAVES_SEED, rng)
    y = psi + psi_w + rng.standard_normal(n) * 1e-3
    run = run_kalman_filter(m, y, delta)
    late = slice(n // 2, n)
    assert np.sqrt(np.mean((run.x_post[late, 2] - psi[late]) ** 2)) < 0.2 * np.std(psi_w[late])
    assert abs(np.mean(run.x_post[late, 4]) - b_true) < math.radians(0.3)


def test_update_wraps_the_innovation():
    m = kalman_model(K_SEED, T_SEED, WAVES_SEED, TS)
    x = np.array([0.0, 0.0, math.pi - 0.01, 0.0, 0.0])
    x_post, p_post, _ = kalman_update(m, x, m.p0, -math.pi + 0.01)  # compass wrapped to the other side
    assert abs(x_post[2] - (math.pi - 0.01)) < 0.03
    np.testing.assert_allclose(p_post, p_post.T, atol=1e-15)
    x_pred, p_pred = kalman_predict(m, x_post, p_post, 0.0)
    np.testing.assert_allclose(p_pred, p_pred.T, atol=1e-15)


def test_sampled_noise_variance_and_its_relation_to_intensity():
    rng = np.random.default_rng(3)
    sd = math.radians(0.045)
    n = 4000
    drift = np.linspace(0.0, 0.01, n)  # a slow drift is not noise
    var = sampled_noise_variance(drift + sd * rng.standard_normal(n))
    assert abs(var - sd**2) < 3 * sd**2 * math.sqrt(2.0 / (n - 1))
    # Continuous white noise of intensity Rc averaged over h has variance Rc / h: simulate it with a
    # fine grid (variance Rc / dt per fine sample) averaged over each sample interval.
    rc, h, sub = 2e-7, 0.1, 100
    fine = rng.standard_normal((20000, sub)) * math.sqrt(rc / (h / sub))
    sampled = fine.mean(axis=1)
    assert np.var(sampled) == pytest.approx(sampled_noise_from_intensity(rc, h), rel=0.05)
    assert continuous_noise_intensity(sampled_noise_from_intensity(rc, h), h) == pytest.approx(rc)


@pytest.mark.parametrize("kwargs, match", [
    (dict(r=0.0), "compass noise variance R"),
    (dict(r=-1.0), "compass noise variance R"),
    (dict(q=(-1.0, 1e-6)), "process noise Q"),
    (dict(q=(1.0, 2.0, 3.0)), "process noise Q"),
    (dict(p0=(1.0, 1.0)), "initial covariance P0"),
    (dict(x0=np.zeros(3)), "initial state x0"),
])
def test_bad_filter_input(kwargs, match):
    with pytest.raises(AutopilotError, match=match):
        kalman_model(K_SEED, T_SEED, WAVES_SEED, TS, **kwargs)


def test_bad_model_and_records():
    with pytest.raises(AutopilotError, match="T > 0"):
        kalman_model(0.1, 0.0, WAVES_SEED, TS)
    with pytest.raises(AutopilotError, match="sample time"):
        kalman_model(K_SEED, T_SEED, WAVES_SEED, 0.0)
    with pytest.raises(AutopilotError, match="at least 10 samples"):
        sampled_noise_variance(np.zeros(3))
    with pytest.raises(AutopilotError, match="zero variance"):
        sampled_noise_variance(np.zeros(100))
    with pytest.raises(AutopilotError, match="equal length"):
        run_kalman_filter(kalman_model(K_SEED, T_SEED, WAVES_SEED, TS), np.zeros(5), np.zeros(4))
