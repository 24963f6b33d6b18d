"""Roll and pitch free decays (damped oscillation): recovery, log-decrement guess, wn check."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from pipeline.errors import FitError
from pipeline.fit import fit_trial, guess_damped_oscillation
from pipeline.fit.second_order import damped_oscillation, damped_oscillation_jacobian, fit_free_decay
from pipeline.records import Segment, Segments, Trial
from pipeline.vessel import parse_vessel

I_ROLL, C_ROLL, D_ROLL = 0.0654, 6.97, 0.1094
I_PITCH, C_PITCH, D_PITCH = 1.089, 131.8, 7.203
AAUSHIP = {"name": "aauship", "rigid_body": {"mass": 13.0, "inertia": [I_ROLL, I_PITCH, 1.107]},
           "restoring": {"roll": C_ROLL, "pitch": C_PITCH}}


def decay_truth(inertia, c, d):
    wn = math.sqrt(c / inertia)
    zeta = d / (2 * math.sqrt(c * inertia))
    return wn, zeta


def free_decay_trial(seed, inertia=I_ROLL, c=C_ROLL, d=D_ROLL, angle0=math.radians(10), noise_deg=0.2,
                     fs=100.0, t_release=1.0, length=11.0, channel="phi", offset=0.0):
    """Held at angle0, released from rest at t_release: exact solution of I x'' + d x' + c x = 0."""
    rng = np.random.default_rng(seed)
    wn, zeta = decay_truth(inertia, c, d)
    wd = wn * math.sqrt(1 - zeta**2)
    t = np.arange(0.0, length, 1.0 / fs)
    s = np.clip(t - t_release, 0.0, None)
    e = np.exp(-zeta * wn * s)
    x = angle0 * e * (np.cos(wd * s) + zeta * wn / wd * np.sin(wd * s))
    rate = -angle0 * wn**2 / wd * e * np.sin(wd * s)
    y = (x if channel in ("phi", "theta") else rate) + offset
    y = y + rng.normal(0.0, math.radians(noise_deg), t.size)
    return Trial("decay", pd.DataFrame({"t": t, channel: y}), fs)


def roll_segment(t_start=1.0, t_end=11.0, dof="roll"):
    return Segment("free_decay", dof, t_start, t_end)


def test_roll_decay_recovers_K_p_wn_and_zeta():
    fits = fit_trial(free_decay_trial(seed=1), Segments("roll", (roll_segment(),)), parse_vessel(AAUSHIP))
    wn, zeta = decay_truth(I_ROLL, C_ROLL, D_ROLL)
    est = fits.estimates
    for name, truth, tol in (("K_p", -D_ROLL, 0.003), ("wn_roll", wn, 0.03), ("zeta_roll", zeta, 0.002),
                             ("wn_ratio_roll", 1.0, 0.003)):
        e = est[name]
        assert e.success, (name, e.message)
        assert abs(e.value - truth) < 3 * e.stderr, (name, e.value, truth, e.stderr)
        assert abs(e.value - truth) < tol, name
    assert est["K_p"].unit == "kg m^2/s" and est["wn_roll"].unit == "rad/s"
    assert "mismatch" not in est["K_p"].message
    assert fits.damping_matrix[2, 2] == pytest.approx(D_ROLL, abs=0.003)
    sf = fits.segment_fits[0]
    assert sf.success and sf.model == "damped_oscillation" and sf.channel == "phi"
    assert "log-decrement guess" in sf.message
    # K_p = -2 zeta wn I with the zeta-wn covariance (delta method).
    g = np.array([2 * sf.params["wn"] * I_ROLL, 2 * sf.params["zeta"] * I_ROLL])
    c = sf.covariance[1:3, 1:3]
    assert est["K_p"].stderr == pytest.approx(math.sqrt(g @ c @ g), rel=1e-9)


def test_log_decrement_guess_is_close_to_truth():
    trial = free_decay_trial(seed=2)
    w = trial.window(1.0, 11.0)
    g = guess_damped_oscillation(w["t"].to_numpy() - 1.0, w["phi"].to_numpy())
    wn, zeta = decay_truth(I_ROLL, C_ROLL, D_ROLL)
    assert g["wn"] == pytest.approx(wn, rel=0.01)
    assert g["zeta"] == pytest.approx(zeta, rel=0.10)
    assert g["log_decrement"] == pytest.approx(2 * math.pi * zeta / math.sqrt(1 - zeta**2), rel=0.10)
    assert g["A"] == pytest.approx(math.radians(10), rel=0.10)


def test_guess_is_exact_on_noiseless_decay_with_offset():
    t = np.arange(0, 8, 0.01)
    y = damped_oscillation(t, 0.2, 0.05, 4.0, 0.3, 0.02)
    g = guess_damped_oscillation(t, y)
    assert g["wn"] == pytest.approx(4.0, rel=1e-3) and g["zeta"] == pytest.approx(0.05, rel=0.02)
    assert g["offset"] == pytest.approx(0.02, abs=1e-3)


def test_analytic_jacobian_matches_finite_differences():
    t = np.linspace(0, 3, 200)
    p = np.array([0.2, 0.1, 6.0, 0.4, 0.01])
    jac = damped_oscillation_jacobian(t, *p)
    for i in range(5):
        h = np.zeros(5)
        h[i] = 1e-6
        num = (damped_oscillation(t, *(p + h)) - damped_oscillation(t, *(p - h))) / 2e-6
        assert np.allclose(jac[:, i], num, atol=1e-6)


def test_pitch_wn_mismatch_over_ten_percent_is_flagged():
    # The water's restoring is 30% stiffer than the config says.
    trial = free_decay_trial(seed=3, inertia=I_PITCH, c=1.3 * C_PITCH, d=D_PITCH, angle0=math.radians(5),
                             noise_deg=0.02, length=5.0, channel="theta")
    fits = fit_trial(trial, Segments("pitch", (roll_segment(1.0, 5.0, "pitch"),)), parse_vessel(AAUSHIP))
    ratio, m_q = fits.estimates["wn_ratio_pitch"], fits.estimates["M_q"]
    assert ratio.value == pytest.approx(math.sqrt(1.3), rel=0.01)
    assert "mismatch > 10%" in m_q.message and "mismatch > 10%" in ratio.message
    wn, zeta = decay_truth(I_PITCH, 1.3 * C_PITCH, D_PITCH)
    assert abs(m_q.value + D_PITCH) < 3 * m_q.stderr and fits.damping_matrix[3, 3] == pytest.approx(D_PITCH, rel=0.03)


def test_roll_rate_is_fitted_when_angle_is_missing():
    trial = free_decay_trial(seed=4, channel="p", noise_deg=1.0)  # 1 deg/s rate noise
    fits = fit_trial(trial, Segments("roll", (roll_segment(),)), parse_vessel(AAUSHIP))
    wn, zeta = decay_truth(I_ROLL, C_ROLL, D_ROLL)
    assert fits.segment_fits[0].channel == "p"
    z = fits.estimates["zeta_roll"]
    assert abs(z.value - zeta) < 3 * z.stderr and abs(z.value - zeta) < 0.004


def test_static_heel_offset_is_absorbed():
    trial = free_decay_trial(seed=5, offset=math.radians(2))
    sf = fit_free_decay(trial, roll_segment())
    assert sf.params["offset"] == pytest.approx(math.radians(2), abs=math.radians(0.05))
    assert sf.params["A"] > 0 and -math.pi <= sf.params["phase"] <= math.pi


def test_half_period_segment_raises_naming_expected_and_found():
    trial = free_decay_trial(seed=6)
    with pytest.raises(FitError) as err:
        fit_free_decay(trial, roll_segment(1.0, 1.4))  # less than one period (0.61 s)
    msg = str(err.value)
    assert "free_decay roll" in msg and "expected at least 3 alternating extrema" in msg and "found" in msg


def test_too_few_samples_raises():
    with pytest.raises(FitError, match="expected at least 15 samples.*found 11 samples"):
        fit_free_decay(free_decay_trial(seed=7), roll_segment(1.0, 1.1))


def test_missing_restoring_is_noted_not_failed():
    doc = {k: v for k, v in AAUSHIP.items() if k != "restoring"}
    fits = fit_trial(free_decay_trial(seed=8), Segments("roll", (roll_segment(),)), parse_vessel(doc))
    assert fits.estimates["K_p"].success and "restoring.roll not in vessel config" in fits.estimates["K_p"].message
    assert "wn_ratio_roll" not in fits.estimates


def test_free_decay_in_yaw_is_refused():
    trial = free_decay_trial(seed=9)
    fits = fit_trial(trial, Segments("x", (roll_segment(dof="yaw"),)), parse_vessel(AAUSHIP))
    assert not fits.segment_fits[0].success and "expected a free_decay in roll or pitch" in fits.segment_fits[0].message


def test_heavily_damped_one_second_pitch_decay_uses_the_release_as_first_extremum():
    # zeta = 0.3: after the release only two turning points stand above the noise.
    trial = free_decay_trial(seed=10, inertia=I_PITCH, c=C_PITCH, d=D_PITCH, angle0=math.radians(6),
                             noise_deg=0.1, length=3.0, channel="theta")
    fits = fit_trial(trial, Segments("pitch", (roll_segment(1.0, 1.96, "pitch"),)), parse_vessel(AAUSHIP))
    m_q = fits.estimates["M_q"]
    assert m_q.success, m_q.message
    assert abs(m_q.value + D_PITCH) < 3 * m_q.stderr and abs(m_q.value + D_PITCH) < 0.3


def test_roll_decay_logged_at_5_hz_is_fitted_from_linear_prediction():
    # A 1.64 Hz roll logged at 5 Hz: three samples per period, no clean extrema; 24 samples.
    trial = free_decay_trial(seed=11, fs=5.0, t_release=0.0, length=4.8)
    with pytest.raises(FitError):
        from pipeline.fit.second_order import _guess_from_extrema
        _guess_from_extrema(trial.data["t"].to_numpy(), trial.data["phi"].to_numpy())
    fits = fit_trial(trial, Segments("roll", (roll_segment(0.0, 4.8),)), parse_vessel(AAUSHIP))
    k_p = fits.estimates["K_p"]
    assert k_p.success, k_p.message
    assert abs(k_p.value + D_ROLL) < 3 * k_p.stderr and abs(k_p.value + D_ROLL) < 0.01


def test_roll_decay_aliased_by_a_slow_log_is_refused_with_the_rates():
    # Logged at 2 Hz, a 1.64 Hz roll shows as a clean 0.36 Hz damped cosine: the samples alone
    # cannot tell; the config's sqrt(C/I_eff) can.
    trial = free_decay_trial(seed=12, fs=2.0, t_release=0.0, length=30.0, d=D_ROLL / 8, noise_deg=0.05)
    fits = fit_trial(trial, Segments("roll", (roll_segment(0.0, 30.0),)), parse_vessel(AAUSHIP))
    for name in ("K_p", "wn_roll", "zeta_roll"):
        est = fits.estimates[name]
        assert not est.success, (name, est.value)
    assert "alias" in fits.estimates["K_p"].message and "2 Hz" in fits.estimates["K_p"].message


def test_linear_prediction_refuses_noise_and_unresolved_swings():
    from pipeline.fit.second_order import guess_by_linear_prediction
    rng = np.random.default_rng(13)
    t = np.arange(0.0, 8.0, 0.2)
    with pytest.raises(FitError):
        guess_by_linear_prediction(t, rng.normal(0.0, 0.01, t.size))
    g = guess_by_linear_prediction(t, 0.2 * np.exp(-0.3 * t) * np.cos(2 * math.pi * 1.0 * t + 0.4) + 0.01)
    assert g["wn"] == pytest.approx(math.hypot(2 * math.pi, 0.3), rel=1e-6)
    assert g["zeta"] == pytest.approx(0.3 / math.hypot(2 * math.pi, 0.3), rel=1e-6)
    with pytest.raises(FitError, match="samples per period"):
        guess_by_linear_prediction(t, 0.2 * np.exp(-0.3 * t) * np.cos(2 * math.pi * 2.2 * t))
