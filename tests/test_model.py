"""The shared right-hand sides against systems with known answers (python-control style).

5-DOF: surge coast-down u0 exp(-D/m t), roll free decay with omega_n = sqrt(G/I) and
zeta = D / (2 sqrt(G I)); numpy and casadi evaluations agree; Nomoto step K delta (1 - exp(-t/T));
the wave model's sampled variance and spectrum match its stationary variance and PSD.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import casadi as ca
import numpy as np
import pytest
import scipy.linalg
import scipy.signal

from pipeline.model import (INPUTS_5DOF, NOMOTO_STATES, STATES_5DOF, NomotoParams, Vessel5DofParams,
                            integrate_rk4, nomoto_rhs, params_from_vessel, rk4_chunk_integrator, vessel5dof_rhs)
from pipeline.model.waves import WaveParams, simulate_waves, wave_matrices, wave_psd, wave_rhs
from pipeline.errors import ConfigError
from pipeline.vessel import load_vessel, parse_vessel

from conftest import AAUSHIP  # noqa: E402 - the vessel, loaded once per session
IX = {name: i for i, name in enumerate(STATES_5DOF)}


def _x0(**values):
    x = np.zeros(len(STATES_5DOF))
    for k, v in values.items():
        x[IX[k]] = v
    return x


# --------------------------------------------------------------------------- 5-DOF, single DOFs
def test_surge_coast_down_is_exponential():
    params = params_from_vessel(AAUSHIP)
    m, d = 13.0, 2.86
    t = np.arange(0.0, 30.0 + 1e-9, 0.05)
    x = integrate_rk4(vessel5dof_rhs, _x0(u=1.5), t, np.zeros((len(t), 5)), params)
    np.testing.assert_allclose(x[:, IX["u"]], 1.5 * np.exp(-d / m * t), rtol=1e-7, atol=1e-12)
    # Straight line north at psi = 0: x_n is the integral of u, nothing else moves.
    np.testing.assert_allclose(x[:, IX["x_n"]], 1.5 * m / d * (1 - np.exp(-d / m * t)), rtol=1e-6, atol=1e-9)
    others = [IX[k] for k in ("v", "p", "q", "r", "y_e", "phi", "theta", "psi")]
    assert np.all(x[:, others] == 0.0)


def test_surge_step_reaches_force_over_damping():
    params = params_from_vessel(AAUSHIP)
    t = np.arange(0.0, 40.0, 0.05)
    u = np.zeros((len(t), 5))
    u[:, 0] = 4.29
    x = integrate_rk4(vessel5dof_rhs, _x0(), t, u, params)
    np.testing.assert_allclose(x[:, 0], 4.29 / 2.86 * (1 - np.exp(-2.86 / 13.0 * t)), rtol=1e-6, atol=1e-9)


def _peaks_and_crossings(t, y):
    """Times of zero up/down crossings (linear interpolation) and values of the extrema."""
    s = np.sign(y)
    i = np.flatnonzero(s[:-1] * s[1:] < 0)
    tz = t[i] - y[i] * (t[i + 1] - t[i]) / (y[i + 1] - y[i])
    ext = [np.max(np.abs(y[a:b + 1])) for a, b in zip(i[:-1], i[1:])]
    return tz, np.array(ext)


@pytest.mark.parametrize("dof, angle, i_vel", [("roll", "phi", 2), ("pitch", "theta", 3)])
def test_free_decay_frequency_and_damping(dof, angle, i_vel):
    params = params_from_vessel(AAUSHIP)
    inertia = AAUSHIP.mass_matrix()[i_vel, i_vel]
    g = AAUSHIP.restoring[dof]
    d = AAUSHIP.damping[i_vel, i_vel]
    wn_true = np.sqrt(g / inertia)
    zeta_true = d / (2 * np.sqrt(g * inertia))
    t = np.arange(0.0, 6.0, 0.001)
    x = integrate_rk4(vessel5dof_rhs, _x0(**{angle: 0.01}), t, np.zeros((len(t), 5)), params)
    y = x[:, IX[angle]]
    # Measure, do not just compare curves: damped period from zero crossings, zeta from the
    # logarithmic decrement of successive half-period extrema.
    tz, ext = _peaks_and_crossings(t, y)
    assert len(tz) >= 6
    wd = np.pi / np.mean(np.diff(tz))
    delta = np.mean(np.log(ext[:-1] / ext[1:])) * 2  # per full period
    zeta = delta / np.sqrt(4 * np.pi**2 + delta**2)
    wn = wd / np.sqrt(1 - zeta**2)
    assert wn == pytest.approx(wn_true, rel=2e-4)
    assert zeta == pytest.approx(zeta_true, rel=5e-3)
    # ... and the whole curve is the textbook solution.
    wd_true = wn_true * np.sqrt(1 - zeta_true**2)
    ref = 0.01 * np.exp(-zeta_true * wn_true * t) * (np.cos(wd_true * t)
                                                     + zeta_true / np.sqrt(1 - zeta_true**2) * np.sin(wd_true * t))
    np.testing.assert_allclose(y, ref, rtol=0, atol=1e-9)


def test_params_from_vessel_needs_damping():
    hull = parse_vessel({"name": "hull", "rigid_body": {"mass": 13.0, "inertia": [1.0, 1.0, 1.0]}})
    with pytest.raises(ConfigError, match=r"hull: expected a \[damping\] matrix or diagonal to simulate, found none"):
        params_from_vessel(hull)
    d = np.diag([1.0, 2.0, 3.0, 4.0, 5.0])
    np.testing.assert_array_equal(params_from_vessel(hull, D=d).D, d)


# --------------------------------------------------------------------------- numpy vs casadi
def _coupled_params(rng):
    """A vessel with every term the 5-DOF model has: CG offset, added mass, full D, |x|x, current."""
    v = parse_vessel({"name": "x", "rigid_body": {"mass": 13.0, "inertia": [0.0654, 1.089, 1.107],
                                                   "cg": [0.05, -0.02, 0.04]},
                      "added_mass": {"surge": 1.2, "sway": 5.0, "yaw": 0.3},
                      "restoring": {"roll": 6.97, "pitch": 131.8}})
    d = np.diag([2.86, 32.5, 0.1094, 7.203, 0.26285]) + 0.05 * rng.standard_normal((5, 5))
    return Vessel5DofParams(M=v.mass_matrix(), D=d, G=v.restoring_matrix(), D2=np.array([0.8, 3.0, 0.01, 0.2, 0.05]),
                            current=np.array([0.3, -0.2]))


def test_vessel5dof_numpy_and_casadi_agree():
    rng = np.random.default_rng(7)
    params = _coupled_params(rng)
    xs, us = ca.SX.sym("x", 10), ca.SX.sym("u", 5)
    f = ca.Function("f", [xs, us], [vessel5dof_rhs(0.0, xs, us, params)])
    for _ in range(20):
        x = rng.normal(0, [1, 0.3, 0.5, 0.3, 0.4, 50, 50, 0.4, 0.2, 3.0])
        u = rng.normal(0, [5, 5, 0.5, 1, 0.3])
        num = vessel5dof_rhs(0.0, x, u, params)
        sym = np.asarray(f(x, u)).ravel()
        assert num.shape == (10,)
        np.testing.assert_allclose(sym, num, rtol=1e-12, atol=1e-12)


def test_compiled_chunks_integrate_like_integrate_rk4():
    """The simulator's compiled RK4 (chunks of 64 steps; 150 samples: two full chunks and a short one)
    gives integrate_rk4's states and the right-hand side's derivatives, to rounding."""
    rng = np.random.default_rng(11)
    params = _coupled_params(rng)
    h, n = 0.05, 150
    t = np.arange(n) * h
    u = np.repeat(rng.normal(0, [5, 5, 0.5, 1, 0.3], size=(15, 5)), 10, axis=0)  # held inputs
    x0 = _x0(u=1.0, phi=0.2, psi=0.5)
    integrate = rk4_chunk_integrator(vessel5dof_rhs, params, 10, 5, h, chunk=64)
    xs, xdots, x_end = integrate(x0, u)
    ref = integrate_rk4(vessel5dof_rhs, x0, np.append(t, n * h), np.vstack([u, u[-1:]]), params)
    np.testing.assert_allclose(xs, ref[:n], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(x_end, ref[n], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(xdots, [vessel5dof_rhs(0.0, x, uk, params) for x, uk in zip(ref[:n], u)],
                               rtol=1e-12, atol=1e-12)
    assert np.max(np.abs(xs[-1] - xs[0])) > 0.1  # the vessel moved: the comparison is not of a state at rest


def test_vessel5dof_casadi_jacobian_is_minus_minv_d_at_rest():
    params = _coupled_params(np.random.default_rng(3))
    xs, us = ca.SX.sym("x", 10), ca.SX.sym("u", 5)
    jac = ca.Function("j", [xs, us], [ca.jacobian(vessel5dof_rhs(0.0, xs, us, params), xs)])
    a = np.asarray(jac(np.zeros(10), np.zeros(5)))
    # Linearised at rest (|x|x terms vanish): nu_dot = -M^-1 D nu - M^-1 G eta.
    np.testing.assert_allclose(a[:5, :5], -np.linalg.solve(params.M, params.D), rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(a[:5, 7:9], -np.linalg.solve(params.M, params.G)[:, 2:4], rtol=1e-12, atol=1e-14)


def test_nomoto_numpy_and_casadi_agree():
    rng = np.random.default_rng(11)
    p = NomotoParams(K=0.156, T=72.4, b=0.02, d2=3.0)
    xs, us = ca.SX.sym("x", 2), ca.SX.sym("u", 1)
    f = ca.Function("f", [xs, us], [nomoto_rhs(0.0, xs, us, p)])
    for _ in range(20):
        x, u = rng.normal(0, [3.0, 0.05]), rng.normal(0, [0.3])
        np.testing.assert_allclose(np.asarray(f(x, u)).ravel(), nomoto_rhs(0.0, x, u, p), rtol=1e-13, atol=1e-15)


# --------------------------------------------------------------------------- Nomoto
@pytest.mark.parametrize("K, T, delta, b", [(0.156, 72.4, 0.1745, 0.0), (1.712, 4.21, -0.1, 0.0),
                                             (0.5, 10.0, 0.2, 0.05)])
def test_nomoto_step_response(K, T, delta, b):
    p = NomotoParams(K=K, T=T, b=b)
    t = np.arange(0.0, 6 * T, T / 200)
    x = integrate_rk4(nomoto_rhs, np.zeros(2), t, np.full((len(t), 1), delta), p)
    gain = K * (delta - b)
    np.testing.assert_allclose(x[:, 1], gain * (1 - np.exp(-t / T)), rtol=1e-7, atol=1e-12)
    np.testing.assert_allclose(x[:, 0], gain * (t - T * (1 - np.exp(-t / T))), rtol=1e-6, atol=1e-10)
    assert NOMOTO_STATES == ("psi", "r")


def test_nomoto_quadratic_damping_lowers_steady_rate():
    K, T, delta, d2 = 0.5, 5.0, 0.2, 20.0
    t = np.arange(0.0, 150.0, 0.05)  # 30 T: exp(-30) is far below the tolerance
    u = np.full((len(t), 1), delta)
    x_lin = integrate_rk4(nomoto_rhs, np.zeros(2), t, u, NomotoParams(K, T))
    x_nl = integrate_rk4(nomoto_rhs, np.zeros(2), t, u, NomotoParams(K, T, d2=d2))
    # r + d2 r^2 = K delta at steady state
    r_ss = (-1 + np.sqrt(1 + 4 * d2 * K * delta)) / (2 * d2)
    assert x_nl[-1, 1] == pytest.approx(r_ss, rel=1e-6)
    assert x_lin[-1, 1] == pytest.approx(K * delta, rel=1e-6)


# --------------------------------------------------------------------------- waves
WAVES = WaveParams(omega0=0.8, lam=0.1, kw=2 * 0.1 * 0.8 * 0.05)


def _stationary_variance(params):
    a, e, c = wave_matrices(params)
    p = scipy.linalg.solve_continuous_lyapunov(a, -e @ e.T)
    return float((c @ p @ c.T)[0, 0])


def test_wave_stationary_variance_closed_form():
    # Var psi_w = K_w^2 / (4 lambda omega_0) for H(s) = K_w s / (s^2 + 2 lambda omega_0 s + omega_0^2)
    assert _stationary_variance(WAVES) == pytest.approx(WAVES.kw**2 / (4 * WAVES.lam * WAVES.omega0), rel=1e-10)
    # ... which is the integral of the two-sided PSD over omega / (2 pi).
    w = np.linspace(0.0, 400.0, 4_000_001)
    var = np.trapezoid(wave_psd(w, WAVES), w) / np.pi
    assert var == pytest.approx(_stationary_variance(WAVES), rel=1e-3)


def test_wave_rhs_matches_state_space():
    a, e, c = wave_matrices(WAVES)
    x, w = np.array([0.3, -0.1]), np.array([0.7])
    np.testing.assert_allclose(wave_rhs(0.0, x, w, WAVES), a @ x + e @ w, rtol=1e-14)


@pytest.fixture(scope="module")
def wave_record():
    fs = 5.0
    t = np.arange(0.0, 40_000.0, 1 / fs)
    return fs, simulate_waves(t, WAVES, np.random.default_rng(2024))


def test_wave_sample_variance_matches_stationary(wave_record):
    _, psi_w = wave_record
    var = _stationary_variance(WAVES)
    # Correlation time 1/(lambda omega_0) = 12.5 s over 40 000 s: the variance estimate has a
    # relative standard deviation of about 5%; 15% is three of them.
    assert np.var(psi_w) == pytest.approx(var, rel=0.15)
    assert abs(np.mean(psi_w)) < 4 * np.sqrt(var / (40_000 * WAVES.lam * WAVES.omega0 / 2))


def test_wave_psd_matches_welch(wave_record):
    fs, psi_w = wave_record
    f, pxx = scipy.signal.welch(psi_w, fs=fs, nperseg=4096)
    # welch is one-sided per Hz; wave_psd is |H(j omega)|^2 per unit-intensity white noise:
    # var = int_0^inf P_welch df = (1/pi) int_0^inf |H|^2 d omega  ->  P_welch(f) = 2 |H(j 2 pi f)|^2.
    model = 2 * wave_psd(2 * np.pi * f, WAVES)
    band = model > 0.1 * model.max()
    ratio = pxx[band] / model[band]
    assert band.sum() > 20
    # About 2 * 40000 / 819 = 97 averaged segments: each bin has ~12% relative scatter.
    assert np.mean(ratio) == pytest.approx(1.0, abs=0.06)
    assert np.all(np.abs(ratio - 1) < 0.5)
    assert f[np.argmax(pxx)] == pytest.approx(WAVES.omega0 / (2 * np.pi), abs=2 * fs / 4096)
    # Far above the peak the spectrum falls as K_w^2 / omega^2; the exactly sampled record has that
    # continuous spectrum folded about Nyquist: S_d(f) = sum_k S_c(f + k fs).
    hi = (f > 1.0) & (f < 2.4)
    k = np.arange(-200, 201)[:, None]
    aliased = (2 * wave_psd(2 * np.pi * (f[hi][None, :] + k * fs), WAVES)).sum(axis=0)
    assert np.mean(pxx[hi] / aliased) == pytest.approx(1.0, abs=0.05)
    assert np.mean(pxx[hi] / model[hi]) > 1.15  # aliasing is visible: the comparison can tell


def test_wave_record_starts_stationary():
    # An ensemble of first samples has the stationary variance: no transient from x = 0.
    rng = np.random.default_rng(5)
    first = np.array([simulate_waves(np.array([0.0, 0.2]), WAVES, rng)[0] for _ in range(500)])
    var = _stationary_variance(WAVES)
    # Sample variance of 500 normals: relative std sqrt(2/500) = 6.3%. Starting from rest would
    # give exactly zero.
    assert np.var(first) == pytest.approx(var, rel=0.25)


def test_waves_are_seeded():
    t = np.arange(0.0, 100.0, 0.1)
    a = simulate_waves(t, WAVES, np.random.default_rng(1))
    b = simulate_waves(t, WAVES, np.random.default_rng(1))
    c = simulate_waves(t, WAVES, np.random.default_rng(2))
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)


def test_state_and_input_names():
    assert STATES_5DOF == ("u", "v", "p", "q", "r", "x_n", "y_e", "phi", "theta", "psi")
    assert INPUTS_5DOF == ("tau_x", "tau_y", "tau_k", "tau_m", "tau_n")
    # A heading state in the 5-DOF vector follows r through the Euler kinematics.
    params = replace(params_from_vessel(AAUSHIP))
    xdot = vessel5dof_rhs(0.0, _x0(r=0.2, u=1.0, psi=np.pi / 2), np.zeros(5), params)
    assert xdot[IX["psi"]] == pytest.approx(0.2)
    assert xdot[IX["x_n"]] == pytest.approx(0.0, abs=1e-15) and xdot[IX["y_e"]] == pytest.approx(1.0)
