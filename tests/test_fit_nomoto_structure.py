"""The Nomoto models written once, the discretisation, the rudder servo, measured-rudder segmentation,
and the whole-record segment fit that estimates the servo and chooses the model order."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
import scipy.linalg
import scipy.signal

from pipeline.fit.nomoto_oe import NomotoRecord, fit_nomoto
from pipeline.fit.nomoto_segment import fit_nomoto_window, structure_note
from pipeline.model import discretise
from pipeline.model.nomoto import (ORDER2_SUM_PRODUCT, Nomoto2Params, NomotoParams, nomoto2_rhs, nomoto_matrices,
                                   nomoto_rhs, pole_time_constants, servo_response)
from pipeline.records import Segment, Trial
from pipeline.segment import detect_segments
from pipeline.segment.rudder import classify_changes, find_holds, is_command_like, is_servo_command, zigzag_runs

K_TRUE, T_TRUE = 0.15, 20.0
H = 0.2


# --------------------------------------------------------------------------- model and discretisation
def test_zoh_matches_scipy_and_fast_path():
    a, b = nomoto_matrices(1, (K_TRUE, T_TRUE))
    ad, bd, *_ = scipy.signal.cont2discrete((a, b, np.eye(2), np.zeros((2, 1))), H, method="zoh")
    for f in (discretise.zoh, discretise.zoh_fast):
        ad2, bd2 = f(a, b, H)
        np.testing.assert_allclose(ad2, ad, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(bd2, bd, rtol=1e-12, atol=1e-15)
    m = np.array([[0.3, -2.0], [1.5, -0.7]]) * 7
    np.testing.assert_allclose(discretise.expm_small(m), scipy.linalg.expm(m), rtol=1e-12)


def test_noise_integral_against_quadrature():
    a = np.array([[0.0, 1.0], [-0.5, -0.3]])
    g = np.diag([0.0, 2.0])
    _, qd = discretise.noise_integral(a, g, 0.5)
    s = np.linspace(0, 0.5, 2001)
    vals = np.array([scipy.linalg.expm(a * x) @ g @ scipy.linalg.expm(a * x).T for x in s])
    np.testing.assert_allclose(qd, np.trapezoid(vals, s, axis=0), rtol=1e-5, atol=1e-9)
    np.testing.assert_allclose(discretise.noise_integral_fast(a, g, 0.5)[1], qd, rtol=1e-12)


def test_second_order_forms_agree():
    K, T1, T2, T3 = 0.1, 12.0, 3.0, 5.0
    a2, b2 = nomoto_matrices(2, (K, T1, T2, T3))
    a3, b3 = nomoto_matrices(ORDER2_SUM_PRODUCT, (K, T1 + T2, T1 * T2, T3))
    np.testing.assert_allclose(a2, a3)
    np.testing.assert_allclose(b2, b3)
    assert pole_time_constants(T1 + T2, T1 * T2) == pytest.approx((T1, T2))
    assert pole_time_constants(10.0, 60.0) is None  # complex pair
    x = np.array([0.0, 0.01, 0.002])
    np.testing.assert_allclose(nomoto2_rhs(0, x, [0.1], Nomoto2Params(K, T1, T2, T3)), a2 @ x + b2[:, 0] * 0.1)
    assert Nomoto2Params(K, T1, T2, T3).T_equivalent == pytest.approx(T1 + T2 - T3)


def test_norrbin_term():
    r = 0.05
    xd = nomoto_rhs(0, np.array([0.0, r]), [0.1], NomotoParams(K_TRUE, T_TRUE, n3=2.0))
    assert xd[1] == pytest.approx((-r - 2.0 * r**3 + K_TRUE * 0.1) / T_TRUE)


def _servo_reference(u, h, tau, rate, sub=4000):
    d, out = u[0], []
    for uk in u:
        acc = 0.0
        for _ in range(sub):
            v = min(max((uk - d) / tau, -rate), rate)
            dn = d + h / sub * v
            acc += 0.5 * (d + dn)
            d = dn
        out.append(acc / sub)
    return np.array(out)


@pytest.mark.parametrize("rate", [math.inf, math.radians(5.0)])
def test_servo_response_lag_and_rate_limit(rate):
    u = np.r_[np.zeros(5), np.full(30, math.radians(20)), np.full(25, -math.radians(10))]
    got = servo_response(u, H, 1.0, rate)
    ref = _servo_reference(u, H, 1.0, rate)
    np.testing.assert_allclose(got, ref, atol=2e-4 if math.isfinite(rate) else 1e-5)
    if math.isfinite(rate):
        assert np.max(np.abs(np.diff(got))) <= rate * H * 1.01


# --------------------------------------------------------------------------- ship records
def _ship_log(delta_c, tau=1.0, rate=math.inf, measured=False, seed=0, order1=True, rudder_noise_deg=0.1):
    """Heading and yaw rate of a Nomoto ship behind a servo, simulated on a 20x finer grid."""
    sub = 20
    h = H / sub
    fine_c = np.repeat(delta_c, sub)
    d = servo_response(fine_c, h, tau, rate) if tau > 0 else fine_c
    if order1:
        a, b = nomoto_matrices(1, (K_TRUE, T_TRUE))
    else:
        a, b = nomoto_matrices(ORDER2_SUM_PRODUCT, (0.09, 13.5, 64.0, 10.8))
    ad, bd = discretise.zoh(a, b, h)
    x = np.zeros(a.shape[0])
    xs = np.empty((fine_c.size, a.shape[0]))
    for k, dk in enumerate(d):
        xs[k] = x
        x = ad @ x + bd[:, 0] * dk
    rng = np.random.default_rng(seed)
    n = delta_c.size
    psi = xs[::sub, 0] + math.radians(0.1) * rng.standard_normal(n)
    r = xs[::sub, 1] + math.radians(0.03) * rng.standard_normal(n)
    rudder = d[::sub] + math.radians(rudder_noise_deg) * rng.standard_normal(n) if measured else delta_c
    t = np.arange(n) * H
    return Trial("ship", pd.DataFrame({"t": t, "psi": (psi + np.pi) % (2 * np.pi) - np.pi, "r": r, "delta": rudder}),
                 1 / H)


def _steps(levels_deg, hold_s):
    return np.concatenate([np.full(int(hold_s / H), math.radians(v)) for v in levels_deg])


def test_measured_rudder_steps_sized_between_steady_holds():
    trial = _ship_log(_steps([0, 20, 0, -20, 0], 60.0), tau=1.0, rate=math.radians(5.0), measured=True)
    u = trial.data["delta"].to_numpy()
    assert not is_command_like(u)
    segs = detect_segments(trial).of("rudder_step")
    assert len(segs) == 4
    for seg, (a, b) in zip(segs, [(0, 20), (20, 0), (0, -20), (-20, 0)]):
        # The size comes from the holds before and after the whole 4 s ramp, not from its tail.
        assert seg.input_before == pytest.approx(math.radians(a), abs=math.radians(0.1))
        assert seg.input_after == pytest.approx(math.radians(b), abs=math.radians(0.1))
        # The window runs to the next rudder change, not to a settle-time guess.
        assert seg.duration > 55.0


def test_noise_free_measured_rudder_is_a_servo_angle_not_a_command():
    # A simulator's servo state logged without sensor noise: exact holds, ramps and exponential tails
    # between them. It was read as a held command (most samples repeat exactly), its ramps as
    # one-period "sinusoids" that were then rejected, and its fit added a second servo on top.
    trial = _ship_log(_steps([0, 20, 0, -20, 0], 60.0), tau=1.0, rate=math.radians(5.0), measured=True,
                      rudder_noise_deg=0.0)
    u = trial.data["delta"].to_numpy()
    assert not is_command_like(u) and not is_servo_command(u, 1 / H)
    segs = detect_segments(trial)
    assert not segs.of("sinusoid") and len(segs.of("rudder_step")) == 4
    sf = fit_nomoto_window(trial, segs.of("rudder_step")[0], 0.0, segs.of("rudder_step")[0].t_end)
    assert "t_servo" not in sf.params and "measured angle" in sf.message
    assert sf.success or sf.message.startswith("unsure:")
    assert sf.params["K"] == pytest.approx(K_TRUE, rel=0.01) and sf.params["T"] == pytest.approx(T_TRUE, rel=0.02)
    # The same steps logged as the command are a servo command; a computed sine too.
    assert is_servo_command(_steps([0, 20, 0, -20, 0], 60.0), 1 / H)
    t = np.arange(0, 600, H)
    assert is_servo_command(math.radians(10) * np.sin(2 * math.pi * t / 300.0), 1 / H)


def test_measured_zigzag_and_sinusoid_are_recognised():
    fs = 1 / H
    rng = np.random.default_rng(3)
    cmd = _steps([0, 10, -10, 10, -10, 0], 30.0)
    u = servo_response(cmd, H, 1.0) + math.radians(0.1) * rng.standard_normal(cmd.size)
    holds = find_holds(u, fs, math.radians(0.1))
    steps, varying = classify_changes(holds, fs, math.radians(2.0))
    (run,) = zigzag_runs(steps)
    assert len(run) == 4 and not varying
    t = np.arange(1500) * H
    sine = math.radians(10) * np.sin(0.05 * t) + math.radians(0.1) * rng.standard_normal(t.size)
    steps, varying = classify_changes(find_holds(sine, fs, math.radians(0.1)), fs, math.radians(2.0))
    assert not steps and varying and (varying[0][1] - varying[0][0]) * H > 0.6 * 300


@pytest.mark.slow
def test_commanded_step_fit_estimates_the_servo_lag():
    trial = _ship_log(_steps([0, 15, 0, -15], 80.0), tau=1.5)
    seg = Segment("zigzag", "yaw", 0.0, float(trial.t[-1]), "delta", 0.0, math.radians(15))
    sf = fit_nomoto_window(trial, seg, seg.t_start, seg.t_end)
    assert sf.success, sf.message
    assert "servo lag estimated" in sf.message
    assert abs(sf.params["K"] - K_TRUE) < max(3 * sf.stderr["K"], 0.003 * K_TRUE)
    assert abs(sf.params["T"] - T_TRUE) < max(3 * sf.stderr["T"], 0.01 * T_TRUE)
    assert sf.params["t_servo"] == pytest.approx(1.5, rel=0.1)
    # Without the servo the same record biases T by about the lag.
    rows = trial.data
    plain = fit_nomoto(NomotoRecord(t=rows["t"].to_numpy(), delta=rows["delta"].to_numpy(),
                                    psi=rows["psi"].to_numpy(), r=rows["r"].to_numpy()), noise="white")
    assert plain.T - T_TRUE > 1.0


@pytest.mark.slow
def test_second_order_ship_selects_second_order_by_held_out_error():
    trial = _ship_log(_steps([0, 10, -10, 10, -10, 10], 40.0), tau=0.0, order1=False)
    seg = Segment("zigzag", "yaw", 0.0, float(trial.t[-1]), "delta", 0.0, math.radians(10))
    sf = fit_nomoto_window(trial, seg, seg.t_start, seg.t_end)
    assert "second-order Nomoto (T1, T2, T3) selected" in sf.message and "first order" in sf.message
    assert sf.params["K"] == pytest.approx(0.09, rel=0.02)
    assert sf.params["T"] == pytest.approx(13.5 - 10.8, rel=0.1)
    assert "complex pole pair" in sf.message
    assert structure_note([sf, sf]) == ""


# --------------------------------------------------------------------------- structure chosen across segments
def test_second_order_chosen_once_across_rudder_steps():
    # Steps of a second-order ship (complex poles and a zero): each step's own held-out end is its
    # steady turn, where the structures differ least, so the per-segment choice kept the first order
    # (T biased). Leaving whole segments out holds out their transients.
    from pipeline.fit import fit_trial
    from pipeline.vessel import parse_vessel

    trial = _ship_log(_steps([0, 10, 0, -10, 0, 5, 0], 45.0), tau=0.0, order1=False, measured=True)
    segs = detect_segments(trial)
    assert len(segs.of("rudder_step")) >= 4
    fits = fit_trial(trial, segs, parse_vessel({"name": "ship2"}), extend=False)
    k, t = fits.estimates["K_nomoto"], fits.estimates["T_nomoto"]
    assert "second-order Nomoto (T1, T2, T3) selected, the first order loses" in k.message, k.message
    assert "leave-one-segment-out" in t.message and "first order" in t.message
    assert k.success, k.message
    # T comes out +5.9 % (this rudder jumps exactly at the samples, read half a sample late:
    # tests/test_nomoto_segment_held_rudder.py), and its steps into a turn and out of one give T 14 %
    # apart: a value that far off must not be success; it is unsure, not reproduced (nomoto_quality).
    assert not t.success and "unsure: not reproduced" in t.message, t.message
    assert k.value == pytest.approx(0.09, rel=0.02)
    # T = T1 + T2 - T3 is the difference of two 11-13 s constants: each step's own T is biased (their
    # combination gave 3.22 +- 0.15 s, +19 %); the pooled (K, T1 + T2, T1 T2, T3) vector's is not.
    assert "generalised least-squares mean" in t.message
    assert t.value == pytest.approx(13.5 - 10.8, rel=0.08)
    assert abs(t.value - 2.7) < 2.5 * t.stderr
    assert "T3_nomoto" in fits.estimates and fits.estimates["T3_nomoto"].value == pytest.approx(10.8, rel=0.2)
    assert all("T3" in sf.params for sf in fits.segment_fits if sf.success and sf.segment.kind == "rudder_step")


def test_first_order_steps_stop_the_second_order_early():
    from pipeline.fit import fit_trial
    from pipeline.vessel import parse_vessel

    trial = _ship_log(_steps([0, 10, 0, -10, 0], 60.0), tau=0.0, measured=True)
    segs = detect_segments(trial)
    fits = fit_trial(trial, segs, parse_vessel({"name": "ship1"}), extend=False)
    k, t = fits.estimates["K_nomoto"], fits.estimates["T_nomoto"]
    assert "first-order Nomoto" in k.message and "stopped after" in k.message, k.message
    assert k.value == pytest.approx(K_TRUE, rel=0.01) and t.value == pytest.approx(T_TRUE, rel=0.03)
    assert "T3_nomoto" not in fits.estimates
    # The records fitted together with one rudder bias agree with the steps' own fits on a first-order
    # ship with a constant offset: nothing is marked unsure for it.
    from pipeline.fit.nomoto_quality import SHARED_BIAS

    notes = [p for sf in fits.segment_fits for p in sf.message.split("; ") if p.startswith(SHARED_BIAS)]
    assert notes, [sf.message for sf in fits.segment_fits]
    joint_t = float(notes[0].split("T = ")[1].split(" ")[0])
    assert joint_t == pytest.approx(T_TRUE, rel=0.03)
    assert k.success and t.success and "rudder bias is modelled" not in k.message + t.message


def test_gain_floor_stops_a_second_order_fit_on_first_order_data():
    from pipeline.fit.nomoto_oe import GainFloor, SecondOrderNoGain

    trial = _ship_log(_steps([0, 10, -10, 10, -10], 40.0), tau=0.0)
    rows = trial.data
    rec = NomotoRecord(t=rows["t"].to_numpy(), delta=rows["delta"].to_numpy(), psi=rows["psi"].to_numpy(),
                       r=rows["r"].to_numpy())
    first = fit_nomoto(rec, noise="white")
    floor = GainFloor.from_first_order(first, rec)
    with pytest.raises(SecondOrderNoGain, match="stopped after"):
        fit_nomoto(rec, order=ORDER2_SUM_PRODUCT, noise="white", start={"K": first.K, "T": first.T},
                   gain_floor=floor)
    # On second-order data the same floor lets the fit run.
    trial2 = _ship_log(_steps([0, 10, -10, 10, -10], 40.0), tau=0.0, order1=False)
    rows = trial2.data
    rec2 = NomotoRecord(t=rows["t"].to_numpy(), delta=rows["delta"].to_numpy(), psi=rows["psi"].to_numpy(),
                        r=rows["r"].to_numpy())
    first2 = fit_nomoto(rec2, noise="white")
    second = fit_nomoto(rec2, order=ORDER2_SUM_PRODUCT, noise="white", start={"K": first2.K, "T": first2.T},
                        gain_floor=GainFloor.from_first_order(first2, rec2))
    assert second.T == pytest.approx(13.5 - 10.8, rel=0.1)


def _fake_fit(kind, k, se_k, amp):
    from dataclasses import replace as _replace

    from pipeline.fit.segment_fit import failed_segment_fit

    seg = Segment(kind, "yaw", 0.0, 100.0, "delta", 0.0, amp)
    return _replace(failed_segment_fit(seg, "nomoto_oe", "", ""), success=True, params={"K": k, "T": 20.0},
                    stderr={"K": se_k, "T": 0.01})


def test_disagreement_note_names_amplitude_trend_or_structure():
    from pipeline.fit.nomoto_structure import disagreement_note

    amps = np.radians([5.0, 10.0, 15.0, 20.0, 10.0])
    trend = [_fake_fit("rudder_step", 0.15 * (1 - 0.5 * a), 1e-4, a) for a in amps]
    note = disagreement_note(trend, amps)
    assert "K changes with the rudder amplitude" in note and "Norrbin" in note and "T from" not in note
    kinds = [_fake_fit(kd, k, 1e-4, math.radians(10.0)) for kd, k in
             [("rudder_step", 0.150), ("rudder_step", 0.1501), ("zigzag", 0.140), ("zigzag", 0.1399)]]
    note = disagreement_note(kinds, [math.radians(10.0)] * 4)
    assert "differs between manoeuvre kinds" in note and "structure" in note
    agree = [_fake_fit("rudder_step", 0.15 + 1e-5 * i, 1e-4, a) for i, a in enumerate(amps)]
    assert disagreement_note(agree, amps) == ""


def test_structure_near_tie_marks_only_the_undecided_coefficient_unsure():
    from dataclasses import replace as _replace

    from pipeline.fit.nomoto_quality import STRUCTURE_UNDECIDED, judge_nomoto
    from pipeline.records import Estimate

    fit = _fake_fit("rudder_step", 0.15, 1e-4, 0.1)
    fit = _replace(fit, message=f"OE; {STRUCTURE_UNDECIDED} T: near-tie, T 4.17 (first order) vs 3.48 (second order)")
    est = {n: Estimate(name=n, value=v, stderr=0.01 * v, ci95=(0.98 * v, 1.02 * v), unit="", n_segments=6,
                       method="m", success=True, message="") for n, v in (("K_nomoto", 0.15), ("T_nomoto", 4.0))}
    out = judge_nomoto(est, [fit, fit])
    assert out["K_nomoto"].success
    assert not out["T_nomoto"].success and out["T_nomoto"].message.startswith(STRUCTURE_UNDECIDED)


def test_structure_term_widens_or_marks_unsure_when_the_structures_disagree():
    # Measured on the PythonVehicleSimulator tanker at 20 m (rudder steps, measured rudder, waves):
    # the second order was significantly better on held-out segments (p = 5e-6) but by 0.1 % only,
    # so the first order was kept: T 10.5 +- 0.19 s marked success, truth 9.32 s. Where fitted, the
    # second order gave T about 1 s lower, with errors of 0.7-1.1 s.
    from dataclasses import replace as _replace

    from pipeline.fit.nomoto_quality import STRUCTURE_UNDECIDED, judge_nomoto
    from pipeline.fit.nomoto_structure import (STRUCTURE_TERM_PREFIX, StructureChoice, choice_is_clear,
                                               structure_gaps, structure_term_notes)
    from pipeline.records import Estimate

    near = StructureChoice(1, "note", near_tie=True, shrink=0.1, p_value=5.4e-6)
    clear, why = choice_is_clear(near)
    assert not clear and "significantly better" in why and "+0.1 %" in why
    assert choice_is_clear(StructureChoice(2, "note", shrink=14.5, p_value=1e-100))[0]
    assert choice_is_clear(StructureChoice(1, "note", near_tie=False, shrink=-30.0, p_value=1.0))[0]

    pairs = [{"K": (-0.00584, 2e-5, -0.00585, 3e-5), "T": (10.70, 0.43, 9.79, 0.73)},
             {"K": (-0.00573, 4e-5, -0.00570, 5e-5), "T": (11.85, 0.89, 10.85, 1.14)}]
    gaps = {g.name: g for g in structure_gaps(pairs)}
    assert gaps["T"].diff == pytest.approx(-0.95, abs=0.05) and not gaps["T"].beyond_errors
    assert structure_term_notes(gaps.values(), "clear", "") == []       # decided across segments: nothing
    notes = structure_term_notes(gaps.values(), "undecided", why)
    assert any(n.startswith(f"{STRUCTURE_TERM_PREFIX} T: +-0.9") for n in notes), notes
    assert not any(n.startswith(STRUCTURE_UNDECIDED) for n in notes)
    est = {n: Estimate(name=n, value=v, stderr=s, ci95=(v - 2 * s, v + 2 * s), unit=u, n_segments=6, method="m",
                       success=True, message="") for n, v, s, u in (("K_nomoto", -0.00584, 2.5e-5, "1/s"),
                                                                   ("T_nomoto", 10.50, 0.19, "s"))}
    fit = _replace(_fake_fit("rudder_step", -0.00584, 2e-5, 0.17), message="; ".join(["OE"] + notes))
    out = judge_nomoto(est, [fit, fit])
    t = out["T_nomoto"]
    assert t.stderr == pytest.approx(math.hypot(0.19, gaps["T"].term), rel=1e-3)
    assert t.ci95[0] < 9.32 < t.ci95[1]                                  # the truth is now inside
    assert "model-structure term" in t.message
    # Values that differ beyond their errors on an undecided structure: unsure, with both values.
    far = [{"T": (10.70, 0.10, 9.00, 0.20)}, {"T": (11.00, 0.10, 9.20, 0.20)}]
    notes = structure_term_notes(structure_gaps(far), "undecided", why)
    assert notes[0].startswith(f"{STRUCTURE_UNDECIDED} T:") and "first order 10.8" in notes[0]
    fit = _replace(fit, message="; ".join(["OE"] + notes))
    out = judge_nomoto(est, [fit])
    assert not out["T_nomoto"].success and out["T_nomoto"].message.startswith(STRUCTURE_UNDECIDED)
    assert out["K_nomoto"].success
    # The second order chosen on one record's end only (a lone zig-zag): its value, the error widened.
    notes = structure_term_notes(structure_gaps(far), "weak", "one record")
    assert len(notes) == 1 and notes[0].startswith(STRUCTURE_TERM_PREFIX)
    assert structure_term_notes(structure_gaps(far), "clear", "") == []


def test_rate_limit_not_tried_when_the_lag_is_below_a_sample():
    # The rudder logged as the command of a ship whose servo is far faster than a sample (0.03 s lag at
    # 5 Hz): the lag is kept, but the costly rate-limit fit is not tried (a ramp shorter than about two
    # samples cannot be told from the lag); it was tried, and rejected by the BIC, before.
    from pipeline.fit.nomoto_segment import prepare_window

    trial = _ship_log(_steps([0, 15, 0], 60.0), tau=0.03)
    seg = Segment("rudder_step", "yaw", 60.0, float(trial.t[-1]), "delta", 0.0, math.radians(15))
    win = prepare_window(trial, seg, 0.0, seg.t_end)
    assert win.servo == ("t_servo",)
    assert any("a rate limit not tried" in n for n in win.notes)


# --------------------------------------------------------------------------- sinusoids fitted jointly
def _sine_pair(T_scale):
    """3 periods at 2/T, a 10 T hold, 3 periods at 0.5/T, a 4 T hold (the independent benchmark's pair) [rad]."""
    parts = []
    for w in (2.0 / T_scale, 0.5 / T_scale):
        t = np.arange(0.0, 3 * 2 * math.pi / w, H)
        parts += [math.radians(10) * np.sin(w * t), np.zeros(int(10 * T_scale / H))]
    return np.concatenate(parts[:3] + [np.zeros(int(4 * T_scale / H))])


def _fit_sine_pair(order1, measured):
    from pipeline.fit import fit_trial
    from pipeline.vessel import parse_vessel

    trial = _ship_log(_sine_pair(T_TRUE if order1 else 13.5), tau=1.0, measured=measured, order1=order1)
    segs = detect_segments(trial)
    assert len(segs.of("sinusoid")) == 2
    return fit_trial(trial, segs, parse_vessel({"name": "ship"}), extend=False)


@pytest.mark.slow
def test_sinusoids_of_a_second_order_ship_fitted_jointly():
    # One sinusoid cannot identify the second order (a gain and a phase for four constants), so each
    # frequency's own fit was first order, K and T spread between them and both were refused.
    from pipeline.fit.nomoto_pool import is_joint_follower

    fits = _fit_sine_pair(order1=False, measured=True)
    k, t = fits.estimates["K_nomoto"], fits.estimates["T_nomoto"]
    assert "sinusoids fitted jointly" in k.message or any(
        "sinusoids fitted jointly" in sf.message for sf in fits.segment_fits), k.message
    sines = [sf for sf in fits.segment_fits if sf.segment.kind == "sinusoid"]
    assert [is_joint_follower(sf) for sf in sines] == [False, True]
    assert all("T3" in sf.params for sf in sines)
    assert k.n_segments == 1 and t.n_segments == 1
    assert k.success, k.message
    assert k.value == pytest.approx(0.09, rel=0.02)
    assert t.value == pytest.approx(13.5 - 10.8, rel=0.05)
    assert abs(t.value - 2.7) < 3 * t.stderr + 0.01 * 2.7
    # Two frequencies give four numbers for the four constants: nothing is left to test the structure
    # (PythonVehicleSimulator's Clarke83 ship: T -4 % with a 0.8 % error), so T is not marked success.
    assert not t.success and "leave none to test the structure" in t.message, t.message


@pytest.mark.slow
def test_sinusoids_of_a_first_order_ship_keep_the_first_order():
    fits = _fit_sine_pair(order1=True, measured=True)
    k, t = fits.estimates["K_nomoto"], fits.estimates["T_nomoto"]
    sines = [sf for sf in fits.segment_fits if sf.segment.kind == "sinusoid"]
    assert all("T3" not in sf.params for sf in sines)
    assert any("sinusoids fitted jointly" in sf.message and "first-order Nomoto" in sf.message for sf in sines)
    assert k.success and t.success, (k.message, t.message)
    assert k.value == pytest.approx(K_TRUE, rel=0.01) and t.value == pytest.approx(T_TRUE, rel=0.02)


@pytest.mark.slow
def test_two_commanded_sinusoids_leave_the_second_order_t_unsure():
    # Two frequencies give four numbers; the second order and the servo lag are five unknowns.
    fits = _fit_sine_pair(order1=False, measured=False)
    t = fits.estimates["T_nomoto"]
    sines = [sf for sf in fits.segment_fits if sf.segment.kind == "sinusoid"]
    assert all("T3" in sf.params and "t_servo" in sf.params for sf in sines), [sf.message for sf in sines]
    assert not t.success and "servo lag trades off against the pole-zero pair" in t.message, t.message


# --------------------------------------------------------------------------- second-order vectors pooled
def _second_order_fit(vec, cov, t0, t1):
    from dataclasses import replace as _replace

    from pipeline.fit.segment_fit import failed_segment_fit

    seg = Segment("rudder_step", "yaw", t0, t1, "delta", 0.0, 0.1)
    names = ["K", "T12", "T1T2", "T3", "b"]
    c = np.zeros((5, 5))
    c[:4, :4] = cov
    c[4, 4] = 1e-8
    params = dict(zip(names, list(vec) + [0.0]))
    params["T"] = vec[1] - vec[3]
    return _replace(failed_segment_fit(seg, "nomoto_oe", "psi", ""), success=True, params=params, param_names=names,
                    stderr={n: math.sqrt(c[i, i]) for i, n in enumerate(names)}, covariance=c,
                    t=np.array([0.0, t1 - t0]))


def test_pooled_second_order_vector_by_hand():
    from pipeline.fit.nomoto_pool import pool_second_order

    rng = np.random.default_rng(4)
    truth = np.array([0.09, 13.5, 64.0, 10.8])
    covs, vecs = [], []
    for _ in range(3):
        a = rng.standard_normal((4, 4)) * np.array([1e-4, 0.5, 2.0, 0.5])
        covs.append(a @ a.T + np.diag([1e-9, 0.01, 0.1, 0.01]))
        vecs.append(truth + rng.multivariate_normal(np.zeros(4), covs[-1]))
    # Windows that do not overlap: the plain generalised least-squares mean.
    fits = [_second_order_fit(v, c, 200.0 * i, 200.0 * i + 100.0) for i, (v, c) in enumerate(zip(vecs, covs))]
    pooled = pool_second_order(fits)
    info = sum(np.linalg.inv(c) for c in covs)
    cov = np.linalg.inv(info)
    theta = cov @ sum(np.linalg.inv(c) @ v for c, v in zip(covs, vecs))
    chi2 = sum((v - theta) @ np.linalg.inv(c) @ (v - theta) for c, v in zip(covs, vecs))
    g = np.array([0.0, 1.0, 0.0, -1.0])
    assert pooled.chi2 == pytest.approx(chi2, rel=1e-6) and pooled.dof == 8
    # The segments agree within their errors (p >= 0.01): the inverse-variance mean and its own error.
    assert pooled.values["T"].p_value >= 0.01 and not np.any(pooled.psi)
    assert pooled.values["T"].value == pytest.approx(theta[1] - theta[3], rel=1e-9)
    assert pooled.values["T"].stderr == pytest.approx(math.sqrt(g @ cov @ g), rel=1e-6)
    assert pooled.values["K"].value == pytest.approx(theta[0], rel=1e-9)
    # The same windows overlapping by half: the design effect (1 + 2 * 0.5 * 2 / 3) widens the errors only.
    over = [_second_order_fit(v, c, 50.0 * i, 50.0 * i + 100.0) for i, (v, c) in enumerate(zip(vecs, covs))]
    pooled_o = pool_second_order(over)
    assert pooled_o.values["T"].value == pytest.approx(pooled.values["T"].value, rel=1e-9)
    assert pooled_o.values["T"].stderr == pytest.approx(pooled.values["T"].stderr * math.sqrt((3 + 2 * 0.5 * 2) / 3),
                                                        rel=1e-6)
    # A first-order segment among them, or a single segment: nothing pooled.
    first = _replace_first_order(fits[0])
    assert pool_second_order([first] + fits[1:]) is None and pool_second_order(fits[:1]) is None


def test_dersimonian_laird_psi_is_tau2_for_one_parameter():
    from pipeline.fit.combine import dersimonian_laird_psi, dersimonian_laird_tau2

    x = np.array([1.0, 1.4, 0.7, 1.9, 1.2])
    se = np.array([0.1, 0.2, 0.15, 0.3, 0.12])
    w = 1.0 / se**2
    chi2 = float(w @ (x - w @ x / w.sum()) ** 2)
    psi = dersimonian_laird_psi(x[:, None], [np.array([[wi]]) for wi in w])
    assert psi.shape == (1, 1) and psi[0, 0] == pytest.approx(dersimonian_laird_tau2(chi2, w), rel=1e-12)
    assert dersimonian_laird_psi(np.full((3, 1), 2.0), [np.eye(1)] * 3)[0, 0] == 0.0  # no spread: 0, not negative


def test_pooled_second_order_covers_a_spread_in_one_direction():
    # Six second-order steps whose T1 + T2 differs between manoeuvres by 0.6 s (a model error that
    # differs per segment) while K, T1 T2 and T3 agree: the T = T1 + T2 - T3 sought is the spread's
    # centre. A Birge ratio spreads the one direction's chi-square over the vector's four (4 (k - 1)
    # degrees of freedom) and widened T too little: 67 % coverage of 300 draws. The multivariate
    # DerSimonian-Laird spread covers: the fixed-effect mean's error under it 93 %, with the spread
    # added (the prediction error, as pipeline.fit.combine reports the first-order K and T) 99.7 %.
    from pipeline.fit.nomoto_pool import pool_second_order

    rng = np.random.default_rng(7)
    truth = np.array([0.09, 13.5, 64.0, 10.8])
    a = np.diag([2e-4, 0.15, 1.0, 0.15])
    cov = a @ np.array([[1, 0, 0, 0], [0, 1, 0.5, 0.9], [0, 0.5, 1, 0.5], [0, 0.9, 0.5, 1]]) @ a
    hits, n = 0, 300
    for _ in range(n):
        fits = []
        for i in range(6):
            v = truth + rng.multivariate_normal(np.zeros(4), cov) + np.array([0.0, 0.6 * rng.standard_normal(), 0, 0])
            fits.append(_second_order_fit(v, cov, 200.0 * i, 200.0 * i + 100.0))
        pooled = pool_second_order(fits)
        pv = pooled.values["T"]
        hits += abs(pv.value - (truth[1] - truth[3])) <= 1.96 * pv.stderr
    assert hits / n >= 0.9, hits / n
    # The last draw by hand: Psi, the fixed-effect mean, its covariance under the random-effects model
    # (Henmi & Copas) and the prediction error of T.
    from pipeline.fit.combine import dersimonian_laird_psi

    xs = np.array([[sf.params[k] for k in ("K", "T12", "T1T2", "T3")] for sf in fits])
    scale = np.abs(np.median(xs, axis=0))
    w = np.linalg.inv(cov / np.outer(scale, scale))
    psi = dersimonian_laird_psi(xs / scale, [w] * 6)
    assert pooled.values["T"].p_value < 0.01 and np.allclose(pooled.psi, psi * np.outer(scale, scale))
    v = np.linalg.inv(6 * w)
    v_hc = v + v @ (6 * w @ psi @ w) @ v
    g = np.array([0.0, 1.0, 0.0, -1.0]) * scale
    assert pv.value == pytest.approx(g @ (xs.mean(axis=0) / scale), rel=1e-9)
    assert pv.stderr == pytest.approx(math.sqrt(g @ (v_hc + psi) @ g), rel=1e-9)


def _replace_first_order(sf):
    from dataclasses import replace as _replace

    return _replace(sf, params={"K": 0.09, "T": 2.7}, param_names=["K", "T"], covariance=np.eye(2) * 1e-6)


def test_second_order_chosen_below_the_shrink_only_when_robust_and_fitted_on_most_segments():
    from pipeline.fit.nomoto_structure import significant_small_gain

    # Clarke83 steps with waves: p = 1e-37, 1e-26 with the most favourable segment left out, 6 of 6 fitted.
    assert significant_small_gain(1e-37, 1e-26, 0.01, 6, 6)
    # The tanker at 20 m: p = 5e-6 but 0.008 without its most favourable segment: a near-tie still.
    assert not significant_small_gain(5e-6, 0.008, 0.01, 6, 6)
    # Fitted with both structures on too few segments (a first-order ship's second order stops early).
    assert not significant_small_gain(1e-37, 1e-26, 0.01, 2, 6)
    assert not significant_small_gain(1e-3, 1e-26, 0.01, 6, 6)


def test_pooled_dynamics_stays_within_the_fits_values():
    """Correlated K and T: the generalised mean would leave the fits' range in T; the pool falls back to
    per-parameter inverse-variance means, which lie between the fits' values."""
    from types import SimpleNamespace

    from pipeline.fit.nomoto_structure import pooled_dynamics

    def fit(values, sd, rho):
        cov = np.array([[sd[0] ** 2, rho * sd[0] * sd[1]], [rho * sd[0] * sd[1], sd[1] ** 2]])
        return SimpleNamespace(order=1, values=np.array(values), covariance=cov, stderr=np.array(sd))

    a = fit([0.090, 1.6], [0.002, 0.4], 0.995)
    b = fit([0.086, 1.4], [0.001, 0.5], 0.0)
    k = np.linalg.inv(np.linalg.inv(a.covariance) + np.linalg.inv(b.covariance))
    gls = k @ (np.linalg.inv(a.covariance) @ a.values + np.linalg.inv(b.covariance) @ b.values)
    assert gls[1] < 1.4                      # the case: the generalised mean extrapolates T
    pooled = pooled_dynamics([a, b])
    assert 1.4 <= pooled[1] <= 1.6 and 0.086 <= pooled[0] <= 0.090
    w = 1 / np.array([a.stderr, b.stderr]) ** 2
    np.testing.assert_allclose(pooled, (w * np.array([a.values, b.values])).sum(0) / w.sum(0))
    # Fits that agree keep the generalised mean.
    c = fit([0.0895, 1.55], [0.002, 0.4], 0.5)
    pooled = pooled_dynamics([a, c])
    assert 1.55 <= pooled[1] <= 1.6
