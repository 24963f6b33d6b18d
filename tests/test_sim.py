"""The simulator: determinism, what each effect changes (and what it leaves alone), sensor noise,
the sea-trial programme, bad input, and a Nomoto-only ship.

Most tests run short schedules on AAUSHIP (a fraction of a second each); the full sea trial is
simulated once per module.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from pipeline.errors import SimError
from pipeline.geo import latlon_to_ned, wrap_pi
from pipeline.model.waves import WaveParams
from pipeline.records import Segment
from pipeline.sim import (EFFECT_NAMES, Effects, Schedule, SensorSpec, chain, default_sensors, free_decay, rest,
                          rudder_step, sea_trial, simulate, sinusoid, step_and_coast, zigzag)
from pipeline.sim.sensors import NOISE_LEVELS, scaled
from pipeline.vessel import load_vessel, parse_vessel

from conftest import AAUSHIP  # noqa: E402 - the vessel, loaded once per session
SHIP = parse_vessel({"name": "ship", "nomoto": {"K": 0.156, "T": 72.4}})
D = np.diag(AAUSHIP.damping)
M = np.diag(AAUSHIP.mass_matrix())
DT = 0.01
# Step at 3 s, coast-down at 33 s, end at 66 s; 30 s is 6.6 surge time constants (13 / 2.86 s).
SURGE = chain(step_and_coast("surge", 4.0, 30.0, 30.0), rest_s=3.0)
NOISELESS = scaled(default_sensors(), 0.0)


def _sim(schedule=SURGE, effects=Effects(), **kw):
    return simulate(AAUSHIP, schedule, effects, **kw)


def _col(res, name):
    return res.truth[name].to_numpy()


def _at(res, name, t):
    return float(np.interp(t, _col(res, "t"), _col(res, name)))


def _first_at(res, name, t):
    """Value at the first integration step at or after ``t`` (a manoeuvre starts there)."""
    i = int(np.searchsorted(_col(res, "t"), t - 1e-9))
    return float(_col(res, name)[i])


@pytest.fixture(scope="module")
def base():
    return _sim(seed=3)


@pytest.fixture(scope="module")
def trial(sea_trial_sim):
    return sea_trial_sim("nominal", 0)


# --------------------------------------------------------------------------- determinism
def test_same_seed_same_log_and_truth(base):
    again = _sim(seed=3)
    assert again.log.channels.keys() == base.log.channels.keys()
    for name, ch in base.log.channels.items():
        np.testing.assert_array_equal(again.log.channels[name].t, ch.t)
        np.testing.assert_array_equal(again.log.channels[name].values, ch.values)
    assert again.truth.equals(base.truth)


def test_other_seed_other_noise_same_truth(base):
    other = _sim(seed=4)
    assert other.truth.equals(base.truth)  # noise is on the sensors, not the dynamics
    a, b = base.log.channels["r"].values, other.log.channels["r"].values
    diff = a - b
    # Two independent N(0, 0.002^2) draws differ with std 0.002 sqrt 2.
    assert np.std(diff) == pytest.approx(0.002 * np.sqrt(2), rel=0.1)
    np.testing.assert_array_equal(base.log.channels["tau_x"].values, other.log.channels["tau_x"].values)


# --------------------------------------------------------------------------- input effects
def test_actuator_delay_shifts_the_response(base):
    delay = 0.3
    res = _sim(effects=Effects(actuator_delay=delay), seed=3)
    k = int(round(delay / DT))
    u0, ud = _col(base, "u"), _col(res, "u")
    np.testing.assert_allclose(ud[k:], u0[:-k], rtol=0, atol=1e-12)
    assert np.all(ud[:k] == 0.0) and np.max(np.abs(ud - u0)) > 0.05
    np.testing.assert_allclose(_col(res, "applied_tau_x")[k:], _col(base, "applied_tau_x")[:-k], atol=0)
    # What the autopilot sent is logged unchanged: the delay is invisible in the command log.
    np.testing.assert_array_equal(res.log.channels["tau_x"].values, base.log.channels["tau_x"].values)
    np.testing.assert_array_equal(_col(res, "cmd_tau_x"), _col(base, "cmd_tau_x"))
    assert "effect on: actuator_delay" in res.log.summary.warnings


def test_rate_limit_bounds_rudder_rate():
    rate = 0.05
    sched = chain(rudder_step(np.radians(10), 10.0, 10.0), rest_s=2.0)
    free = _sim(sched)
    lim = _sim(sched, Effects(actuator_rate_limit={"delta": rate}))
    ym = AAUSHIP.rudder["yaw_moment"]
    applied = _col(lim, "applied_tau_n") / ym
    assert np.max(np.abs(np.diff(applied))) / DT <= rate * (1 + 1e-9)
    # Without the limit the rudder jumps in one step; with it, it ramps for delta / rate seconds.
    assert np.max(np.abs(np.diff(_col(free, "applied_tau_n") / ym))) / DT > 10 * rate
    delta = np.max(_col(lim, "cmd_delta"))  # 10 deg, to the PWM microsecond
    assert delta == pytest.approx(np.radians(10), abs=0.6109 / 400)
    ramp = delta / rate
    assert _at(lim, "applied_tau_n", 2.0 + ramp / 2) / ym == pytest.approx(delta / 2, abs=rate * DT * 2)
    assert _at(lim, "applied_tau_n", 2.0 + ramp + 0.05) / ym == pytest.approx(delta, abs=1e-12)
    assert np.max(np.abs(_col(lim, "r"))) < np.max(np.abs(_col(free, "r")))
    np.testing.assert_array_equal(_col(lim, "cmd_delta"), _col(free, "cmd_delta"))


@pytest.mark.parametrize("effects", [Effects(), Effects(actuator_delay=0.37, actuator_rate_limit={"delta": 0.05},
                                                       thrust_reverse_gain=0.6)])
def test_open_loop_stretches_simulate_like_the_tick_by_tick_loop(effects):
    """An open-loop programme is integrated a stretch at a time; read tick by tick (as a manoeuvre
    that watches the state is) it gives the same truth to rounding, effects included."""
    from dataclasses import replace

    sched = chain(rudder_step(np.radians(10), 8.0, 6.0, thrust={"tau_x": -3.0}),
                  step_and_coast("surge", 4.0, 3.0, 3.0), rest_s=1.5)
    ticked = Schedule(tuple(replace(m, uses_state=True) for m in sched.manoeuvres))
    assert not any(m.uses_state for m in sched.manoeuvres)
    a, b = _sim(sched, effects, seed=4), _sim(ticked, effects, seed=4)
    np.testing.assert_allclose(a.truth.to_numpy(), b.truth.to_numpy(), rtol=1e-12, atol=1e-12)
    assert np.ptp(_col(a, "r")) > 0.05


def test_rate_limit_bounds_thrust_rate(base):
    res = _sim(effects=Effects(actuator_rate_limit={"tau_x": 1.0}), seed=3)
    tx = _col(res, "applied_tau_x")
    assert np.max(np.abs(np.diff(tx))) / DT == pytest.approx(1.0, rel=1e-9)
    assert _at(res, "applied_tau_x", 3.0 + 2.0) == pytest.approx(2.0, abs=0.011)
    assert _at(res, "applied_tau_x", 3.0 + 4.5) == pytest.approx(4.0, abs=1e-12)
    assert _at(res, "applied_tau_x", 33.0 + 2.0) == pytest.approx(2.0, abs=0.011)  # ramps down too
    assert _at(res, "u", 10.0) < _at(base, "u", 10.0)


def test_thrust_reverse_gain_scales_negative_thrust_only():
    sched = chain(step_and_coast("surge", -4.0, 20.0, 5.0), step_and_coast("surge", 4.0, 20.0, 5.0), rest_s=2.0)
    res = _sim(sched, Effects(thrust_reverse_gain=0.5))
    cmd, applied = _col(res, "cmd_tau_x"), _col(res, "applied_tau_x")
    neg, pos = cmd < 0, cmd > 0
    np.testing.assert_allclose(applied[neg], 0.5 * cmd[neg], rtol=0, atol=0)
    np.testing.assert_array_equal(applied[pos], cmd[pos])
    # Astern the speed rises toward the reduced thrust over the damping: -2/d (1 - exp(-d t / m)).
    t = 19.99
    assert _at(res, "u", 2.0 + t) == pytest.approx(-2.0 / D[0] * (1 - np.exp(-D[0] / M[0] * t)), rel=1e-3)


def test_thrust_reverse_gain_with_rate_limit_reaches_scaled_thrust():
    # The rate limiter acts on the command; the reverse gain on what the propeller makes of it.
    sched = chain(step_and_coast("surge", -4.0, 20.0, 5.0), rest_s=2.0)
    res = _sim(sched, Effects(thrust_reverse_gain=0.5, actuator_rate_limit={"tau_x": 2.0}))
    applied = _col(res, "applied_tau_x")
    assert _at(res, "applied_tau_x", 2.0 + 1.0) == pytest.approx(-1.0, abs=0.02)   # -2 N command, halved
    assert _at(res, "applied_tau_x", 2.0 + 10.0) == pytest.approx(-2.0, abs=1e-12)  # -4 N command, halved
    assert np.min(applied) == pytest.approx(-2.0, abs=1e-12)


# --------------------------------------------------------------------------- dynamics effects
def test_current_moves_over_ground_not_through_water(base):
    cn, ce = 0.3, -0.2
    res = _sim(effects=Effects(current=(cn, ce)), seed=3)
    np.testing.assert_array_equal(_col(res, "u"), _col(base, "u"))  # water-relative truth unchanged
    np.testing.assert_array_equal(_col(res, "v"), _col(base, "v"))
    np.testing.assert_allclose(_col(res, "vn") - _col(base, "vn"), cn, atol=1e-12)
    np.testing.assert_allclose(_col(res, "ve") - _col(base, "ve"), ce, atol=1e-12)
    t = _col(res, "t")
    np.testing.assert_allclose(_col(res, "x_n") - _col(base, "x_n"), cn * t, atol=1e-9)
    # Measured: at rest in the water (first 3 s) the boat drifts with the current over ground.
    sog, cog = res.log.channels["sog"], res.log.channels["cog"]
    still = sog.t < 2.9
    assert np.mean(sog.values[still]) == pytest.approx(np.hypot(cn, ce), abs=0.003)
    assert np.mean(cog.values[still]) == pytest.approx(np.arctan2(ce, cn), abs=0.01)
    assert np.mean(base.log.channels["sog"].values[still]) < 0.02
    # Under way at steady speed (heading north) the ground speed is the vector sum.
    late = (sog.t > 31.0) & (sog.t < 33.0)
    assert np.mean(sog.values[late]) == pytest.approx(np.hypot(4.0 / D[0] + cn, ce), abs=0.005)
    assert np.mean(base.log.channels["sog"].values[late]) == pytest.approx(4.0 / D[0], abs=0.005)


def test_quadratic_damping_coast_down_follows_riccati_solution(base):
    d2 = 3.0
    res = _sim(effects=Effects(quadratic_damping=np.array([d2, 0, 0, 0, 0])), seed=3)
    m, d, f = M[0], D[0], 4.0
    # Steady state of d u + d2 u^2 = F: lower than the linear F / d.
    u_ss = (-d + np.sqrt(d**2 + 4 * d2 * f)) / (2 * d2)
    assert _at(res, "u", 32.99) == pytest.approx(u_ss, rel=2e-3)
    assert _at(base, "u", 32.99) == pytest.approx(f / d, rel=2e-3)
    # Coast-down of m u' = -d u - d2 u^2 from u0: u = d u0 e^{-at} / (d + d2 u0 (1 - e^{-at})), a = d/m.
    t = _col(res, "t")
    coast = (t >= 33.0 - 1e-9) & (t <= 63.0)
    u0 = _first_at(res, "u", 33.0)
    e = np.exp(-d / m * (t[coast] - t[coast][0]))
    np.testing.assert_allclose(_col(res, "u")[coast], d * u0 * e / (d + d2 * u0 * (1 - e)), rtol=1e-6, atol=1e-9)
    # It decays faster than the linear coast-down from the same speed.
    lin = u0 * e
    assert np.all(_col(res, "u")[coast][1:] < lin[1:])


def test_coupling_adds_off_diagonal_damping():
    c = np.zeros((5, 5))
    c[1, 4] = 2.0  # sway force from yaw rate
    sched = chain(step_and_coast("yaw", 0.13, 30.0, 5.0), rest_s=2.0)
    plain = _sim(sched)
    coupled = _sim(sched, Effects(coupling=c))
    assert np.all(_col(plain, "v") == 0.0)  # cg = 0 and diagonal D: yaw does not move sway
    tau = np.array([0, 0, 0, 0, 0.13])
    nu_ss = np.linalg.solve(AAUSHIP.damping + c, tau)
    t_end = 2.0 + 29.99
    assert _at(coupled, "r", t_end) == pytest.approx(nu_ss[4], rel=1e-3)
    assert _at(coupled, "v", t_end) == pytest.approx(nu_ss[1], rel=1e-3)
    assert nu_ss[1] == pytest.approx(-2.0 * 0.13 / D[4] / D[1])
    np.testing.assert_array_equal(_col(coupled, "r"), _col(plain, "r"))  # c only couples v <- r
    assert "effect on: coupling" in coupled.log.summary.warnings


def test_waves_add_to_measured_heading_only():
    sched = chain(rudder_step(np.radians(10), 10.0, 10.0), rest_s=2.0)
    waves = WaveParams(omega0=0.8, lam=0.1, kw=0.02)
    calm = _sim(sched, sensors=NOISELESS, seed=9)
    wavy = _sim(sched, Effects(waves=waves), sensors=NOISELESS, seed=9)
    for col in ("u", "v", "r", "psi", "x_n", "y_e"):
        np.testing.assert_array_equal(_col(wavy, col), _col(calm, col))
    assert np.all(_col(calm, "psi_w") == 0.0) and np.std(_col(wavy, "psi_w")) > 0.005
    for name, ch in calm.log.channels.items():
        if name != "psi":
            np.testing.assert_array_equal(wavy.log.channels[name].values, ch.values)
    psi = wavy.log.channels["psi"]
    expected = np.interp(psi.t, _col(wavy, "t"), _col(wavy, "psi_w"))
    np.testing.assert_allclose(wrap_pi(psi.values - calm.log.channels["psi"].values), expected, atol=1e-12)


def test_effects_active_names():
    e = Effects(quadratic_damping=np.ones(5), current=(0.1, 0.0), actuator_delay=0.1,
                actuator_rate_limit={"delta": 0.1}, thrust_reverse_gain=0.7,
                waves=WaveParams(0.8, 0.1, 0.02), coupling=np.ones((5, 5)))
    assert e.active() == EFFECT_NAMES
    assert Effects().active() == ()


# --------------------------------------------------------------------------- sensors
@pytest.mark.parametrize("level", ["low", "nominal", "high"])
def test_sensor_noise_matches_spec(level):
    k = NOISE_LEVELS[level]
    res = simulate(AAUSHIP, Schedule((rest(60.0),)), sensors=default_sensors(level), seed=21)
    assert np.all(res.truth[["u", "v", "p", "q", "r", "phi", "theta", "psi"]].to_numpy() == 0.0)
    ch = res.log.channels
    # 6001 samples: the sample std has 0.9% relative scatter; 5% is over five of them.
    for name, sigma, mean in [("p", 0.002, 0), ("q", 0.002, 0), ("r", 0.002, 0), ("ax", 0.05, 0),
                              ("ay", 0.05, 0), ("az", 0.05, -9.81), ("phi", 0.002, 0), ("theta", 0.002, 0),
                              ("psi", 0.002, 0)]:
        v = ch[name].values
        assert len(v) == 6001
        assert np.std(v) == pytest.approx(sigma * k, rel=0.05), name
        assert abs(np.mean(v) - mean) < 5 * sigma * k / np.sqrt(len(v)), name
    # Raw GPS position noise is given in metres north/east (601 samples: 3% scatter).
    x_n, y_e = latlon_to_ned(ch["lat@gps"].values, ch["lon@gps"].values, 57.05, 9.92)
    assert np.std(x_n) == pytest.approx(0.3 * k, rel=0.15)
    assert np.std(y_e) == pytest.approx(0.3 * k, rel=0.15)
    # Speed over ground at rest is the magnitude of 2-D noise: Rayleigh with mean sigma sqrt(pi/2).
    assert np.mean(ch["sog"].values) == pytest.approx(0.005 * k * np.sqrt(np.pi / 2), rel=0.05)
    # The nav filter's position has no noise at all.
    np.testing.assert_allclose(latlon_to_ned(ch["lat"].values, ch["lon"].values, 57.05, 9.92)[0], 0.0, atol=1e-6)


def test_sensor_rates_and_sensor_suffix(base):
    ch = base.log.channels
    rates = {n: 1.0 / np.median(np.diff(c.t)) for n, c in ch.items()}
    assert rates["r"] == pytest.approx(100.0) and rates["psi"] == pytest.approx(100.0)
    assert rates["sog"] == pytest.approx(50.0) and rates["sog@gps"] == pytest.approx(10.0)
    assert rates["tau_x"] == pytest.approx(50.0)
    assert {"lat@gps", "lon@gps", "sog@gps", "cog@gps"} <= set(ch)
    slow = default_sensors(fast_attitude=False)
    assert [s.rate for s in slow if s.name == "attitude"] == [50.0]


def test_sensor_bias_adds_a_constant():
    sensors = (SensorSpec("gyro", ("r",), 50.0, bias={"r": 0.01}),)
    res = simulate(AAUSHIP, Schedule((rest(5.0),)), sensors=sensors, seed=1)
    np.testing.assert_allclose(res.log.channels["r"].values, 0.01, atol=1e-15)


# --------------------------------------------------------------------------- the sea trial
def test_sea_trial_truth_segments_are_the_expected_kinds(trial):
    kinds = Counter((s.kind, s.dof) for s in trial.segments.items)
    assert kinds == Counter({("step", "surge"): 1, ("coast_down", "surge"): 1, ("step", "sway"): 1,
                             ("coast_down", "sway"): 1, ("step", "yaw"): 1, ("coast_down", "yaw"): 1,
                             ("free_decay", "roll"): 2, ("free_decay", "pitch"): 2,
                             ("rudder_step", "yaw"): 4, ("zigzag", "yaw"): 1})
    starts = [s.t_start for s in trial.segments.items]
    assert starts == sorted(starts)
    t_end = float(_col(trial, "t")[-1])
    for s in trial.segments.items:
        assert isinstance(s, Segment) and s.origin == "truth"
        assert 0 < s.t_start < s.t_end <= t_end + 1e-9
        assert (s.input_channel is None) == (s.kind == "free_decay")


def test_sea_trial_manoeuvres_do_what_they_say(trial):
    segs = trial.segments
    # Steps hold long enough (>= 6 time constants) to reach the design speeds.
    for dof, col, speed in (("surge", "u", 1.5), ("sway", "v", 0.3), ("yaw", "r", 0.5)):
        (step,) = segs.of("step", dof)
        assert _at(trial, f"cmd_{step.input_channel}", step.t_start + 0.5) == pytest.approx(step.input_after)
        assert _at(trial, col, step.t_end - 0.01) == pytest.approx(speed, rel=0.005)
        (coast,) = segs.of("coast_down", dof)
        assert coast.t_start == pytest.approx(step.t_end)
        assert abs(_at(trial, col, coast.t_end - 0.01)) < 0.005 * speed
    # Free decays start from the pushed-down hull and die out.
    for dof, angle, a0 in (("roll", "phi", 20.0), ("pitch", "theta", 6.0)):
        first, second = segs.of("free_decay", dof)
        assert np.degrees(_first_at(trial, angle, first.t_start)) == pytest.approx(a0, abs=1e-9)
        assert np.degrees(_first_at(trial, angle, second.t_start)) == pytest.approx(-a0, abs=1e-9)
        assert abs(_at(trial, angle, first.t_end - 0.01)) < np.radians(a0) * 0.05
    # Rudder steps of +-10 deg give K delta with K = yaw_moment / D_r.
    k = AAUSHIP.rudder["yaw_moment"] / D[4]
    on = [s for s in segs.of("rudder_step") if s.input_after != 0]
    assert [round(np.degrees(s.input_after)) for s in on] == [10, -10]
    for s in on:
        assert _at(trial, "r", s.t_end - 0.01) == pytest.approx(k * s.input_after, rel=0.01)
    # The zig-zag reverses the rudder each time the heading passes +-10 deg from the start.
    (zz,) = segs.of("zigzag")
    t = _col(trial, "t")
    inside = (t >= zz.t_start) & (t < zz.t_end)
    cmd, psi = _col(trial, "cmd_delta")[inside], np.unwrap(_col(trial, "psi")[inside])
    flips = np.flatnonzero(np.diff(np.sign(cmd)) != 0) + 1
    assert len(flips) >= 4
    for i in flips:
        dpsi = psi[i] - psi[0]
        assert np.sign(dpsi) == -np.sign(cmd[i]) and abs(dpsi) >= np.radians(10) - 1e-9
        assert abs(dpsi) < np.radians(10) + 0.5 * DT  # reversed at the first sample past the trigger


def test_sea_trial_log_has_every_sensor_and_input(trial):
    ch = trial.log.channels
    assert {"p", "q", "r", "ax", "ay", "az", "phi", "theta", "psi", "lat", "lon", "sog", "cog",
            "tau_x", "tau_y", "tau_n", "delta"} <= set(ch)
    assert trial.log.format == "sim" and trial.log.time_reference == "trial"
    assert trial.log.summary.read["imu"] == len(ch["r"].t)


# --------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("effects, match", [
    (Effects(actuator_delay=-0.1), r"actuator_delay: expected >= 0 s, found -0.1"),
    (Effects(thrust_reverse_gain=0.0), r"thrust_reverse_gain: expected > 0, found 0.0"),
    (Effects(actuator_rate_limit={"delta": 0.0}), r"actuator_rate_limit\['delta'\]: expected a positive rate, found 0.0"),
    (Effects(actuator_rate_limit={"rudder": 0.1}), r"actuator_rate_limit: expected input channels .*'delta'.*found 'rudder'"),
    (Effects(quadratic_damping=np.ones(3)), r"quadratic_damping: expected 5 values .*found shape \(3,\)"),
    (Effects(coupling=np.ones((4, 4))), r"coupling: expected a 5x5 matrix, found shape \(4, 4\)"),
])
def test_bad_effects(effects, match):
    with pytest.raises(SimError, match=match):
        _sim(effects=effects)


def test_unknown_noise_level():
    with pytest.raises(SimError, match=r"noise level: expected one of \['high', 'low', 'nominal'\], found 'extreme'"):
        default_sensors("extreme")


@pytest.mark.parametrize("doc", [{"name": "hull"}, {"name": "hull", "rigid_body": {"mass": 13.0, "inertia": [1, 1, 1]}}])
def test_vessel_without_damping_or_nomoto(doc):
    hull = parse_vessel(doc)
    with pytest.raises(SimError, match=r"hull: expected rigid_body \+ \[damping\] .* or \[nomoto\] .*found neither"):
        simulate(hull, Schedule((rest(1.0),)))
    with pytest.raises(SimError, match=r"hull: expected \[damping\] with rigid_body, or \[nomoto\].*found neither"):
        sea_trial(hull)


def test_other_bad_requests():
    with pytest.raises(SimError, match=r"dt: expected a positive step \[s\], found 0"):
        _sim(dt=0)
    with pytest.raises(SimError, match=r"Nomoto ship: expected only rudder \(delta\) commands, found \('tau_x',\)"):
        simulate(SHIP, SURGE)
    with pytest.raises(SimError, match=r"sensor imu: channel 'p' is not simulated for ship"):
        simulate(SHIP, Schedule((rest(1.0),)), sensors=(SensorSpec("imu", ("p", "r"), 10.0),))
    with pytest.raises(SimError, match=r"sensor gyro: expected a positive rate \[Hz\], found 0"):
        SensorSpec("gyro", ("r",), 0)
    with pytest.raises(SimError, match=r"sensor gyro: noise/bias for 'p', which it does not measure"):
        SensorSpec("gyro", ("r",), 10.0, noise={"p": 0.1})
    with pytest.raises(SimError, match=r"step_and_coast: expected positive durations, found t_on=0"):
        step_and_coast("surge", 1.0, 0, 5)
    with pytest.raises(SimError, match=r"manoeuvre DOF: expected one of .*'surge'.*found 'heave'"):
        step_and_coast("heave", 1.0, 5, 5)
    with pytest.raises(SimError, match=r"free_decay: expected dof roll or pitch, found 'yaw'"):
        free_decay("yaw", 0.1, 5)
    with pytest.raises(SimError, match=r"sinusoid: expected positive omega and periods, found 0"):
        sinusoid(0.1, 0.0, 3)


# --------------------------------------------------------------------------- Nomoto-only ship
@pytest.fixture(scope="module")
def ship_trial():
    # T = 72 s: a 0.1 s step (commands at 10 Hz) resolves the dynamics many times over and keeps
    # the hour-long trial fast.
    return simulate(SHIP, sea_trial(SHIP), seed=5, dt=0.1, actuator_rate=10.0)


def test_nomoto_ship_rudder_steps_follow_nomoto(ship_trial):
    res = ship_trial
    kinds = [(s.kind, round(np.degrees(s.input_after))) for s in res.segments.items]
    assert kinds == [("rudder_step", 10), ("rudder_step", 0), ("rudder_step", -10), ("rudder_step", 0),
                     ("zigzag", 10)]
    K, T = 0.156, 72.4
    t = _col(res, "t")
    for s in [s for s in res.segments.items if s.kind == "rudder_step" and s.input_after != 0]:
        inside = (t >= s.t_start) & (t < s.t_end)
        tl = t[inside] - t[inside][0]
        r0 = _col(res, "r")[inside][0]
        assert abs(r0) < 1e-3 * K * np.radians(10)  # the rest before let the last turn die out
        expected = K * s.input_after * (1 - np.exp(-tl / T)) + r0 * np.exp(-tl / T)
        np.testing.assert_allclose(_col(res, "r")[inside], expected, rtol=0, atol=1e-6)


def test_nomoto_ship_zigzag_and_log(ship_trial):
    res = ship_trial
    (zz,) = res.segments.of("zigzag")
    t = _col(res, "t")
    inside = (t >= zz.t_start) & (t < zz.t_end)
    cmd, psi = _col(res, "cmd_delta")[inside], np.unwrap(_col(res, "psi")[inside])
    flips = np.flatnonzero(np.diff(np.sign(cmd)) != 0) + 1
    assert len(flips) >= 3
    for i in flips:
        assert abs(psi[i] - psi[0]) >= np.radians(10) - 1e-9
    # The log has what a rudder ship's sensors give, and nothing it cannot simulate.
    ch = res.log.channels
    assert {"psi", "r", "lat", "lon", "sog", "cog", "delta"} <= set(ch)
    assert not {"p", "q", "phi", "theta", "ax", "u", "v"} & set(ch)
    # Constant speed through the water (5 m/s) and no current: ground speed 5 m/s.
    assert np.mean(ch["sog"].values) == pytest.approx(5.0, abs=0.002)
    assert np.all(np.abs(ch["psi"].values) <= np.pi)
