"""Actuator space: with the vessel config's allocation (``[[actuators]]`` maps of one channel to
several inputs), delay, rate-limit and asymmetry candidates act on one actuator and name it.

The twin-thruster boat is integrated here (first-order surge and yaw, Euler at the log rate), written
as canonical CSV (``tau_x``, ``tau_n``, ``sog``, ``r``, ``psi``) and read back by ``load_trial``: not
made by the project's simulator. ``tau_x = t_port + t_stbd``, ``tau_n = 0.3 (t_port - t_stbd)``.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from pipeline.diagnose import diagnose
from pipeline.diagnose.actuators import actuator_key, actuator_space
from pipeline.diagnose.candidates import (ActuatorDelay, ActuatorRateLimit, ThrustAsymmetry, candidate_label,
                                          candidates_for, delay_input, rate_limit)
from pipeline.diagnose.gridfit import grid_data
from pipeline.diagnose.problem import build_problems
from pipeline.diagnose.segments import diagnose_segments
from pipeline.errors import ConfigError
from pipeline.flow import load_trial
from pipeline.vessel import actuator_allocation, parse_vessel

FULL, ARM = 12.0, 0.3


def twin_vessel(reverse: float = FULL):
    """Each thruster's servo channel drives surge force and yaw moment (full scale 12 N, arm 0.3 m)."""
    acts = []
    for ch, name, arm in ((1, "thruster_port", ARM), (3, "thruster_stbd", -ARM)):
        acts += [{"source": "servo", "channel": ch, "target": "tau_x", "full_scale": FULL, "name": name,
                  "reverse_scale": reverse},
                 {"source": "servo", "channel": ch, "target": "tau_n", "full_scale": arm * FULL,
                  "reverse_scale": arm * reverse}]
    return parse_vessel({"name": "twin", "actuators": acts})


def twin_log(path, seed=1, fs=5.0, minutes=5.0, port_lag=0.0, port_rate=0.0, lo=2.0, port_gain=1.0, alike=False):
    """Thrust commands held 15-35 s (``lo`` to 12 N each); the port thruster applies its command
    ``port_lag`` [s] late, (``port_rate`` > 0) at most ``port_rate`` [N/s] fast and pushes
    ``port_gain`` times its command; ``alike``: both thrusters always commanded alike."""
    rng = np.random.default_rng(seed)
    n = int(minutes * 60 * fs)
    t = np.arange(n) / fs
    hold = int(rng.uniform(15, 35) * fs)
    t1 = np.repeat(rng.uniform(lo, 12, n // hold + 1), hold)[:n]
    t2 = t1.copy() if alike else np.repeat(rng.uniform(lo, 12, n // hold + 1), hold)[:n]
    p1 = port_gain * delay_input(t1, port_lag, fs)
    if port_rate:
        p1 = rate_limit(p1, port_rate, fs)
    tx, tn = p1 + t2, ARM * (p1 - t2)
    u, r, psi = np.zeros(n), np.zeros(n), np.zeros(n)
    h, sub = 1.0 / fs, 10
    for k in range(n - 1):
        uu, rr, pp = u[k], r[k], psi[k]
        for _ in range(sub):
            uu, rr, pp = (uu + h / sub * (-uu + 0.08 * tx[k]) / 6.0, rr + h / sub * (-rr + 0.05 * tn[k]) / 2.5,
                          pp + h / sub * rr)
        u[k + 1], r[k + 1], psi[k + 1] = uu, rr, pp
    pd.DataFrame({"t": t, "sog": u + 0.01 * rng.standard_normal(n), "r": r + 0.002 * rng.standard_normal(n),
                  "psi": np.angle(np.exp(1j * (psi + 0.003 * rng.standard_normal(n)))),
                  "tau_x": t1 + t2, "tau_n": ARM * (t1 - t2)}).to_csv(path, index=False)
    return path, t1, t2


def test_allocation_groups_the_maps_of_one_channel_into_one_named_actuator():
    acts = actuator_allocation(twin_vessel().actuators)
    assert [a.name for a in acts] == ["thruster_port", "thruster_stbd"]
    assert acts[1].gains == {"tau_x": (12.0, 12.0), "tau_n": (-ARM * FULL, -ARM * FULL)}
    # An unnamed actuator is named after its source and channel; a pilot's RC stick is no actuator.
    v = parse_vessel({"name": "b", "actuators": [{"source": "servo", "channel": 3, "target": "tau_x"},
                                                 {"source": "rc", "channel": 3, "target": "tau_x"}]})
    assert [a.name for a in actuator_allocation(v.actuators)] == ["servo3"]


@pytest.mark.parametrize("maps, found", [
    ([{"source": "servo", "channel": 1, "target": "tau_x", "name": "a"},
      {"source": "servo", "channel": 1, "target": "tau_n", "name": "b"}], "names ['a', 'b']"),
    ([{"source": "servo", "channel": 1, "target": "tau_x", "name": "a"},
      {"source": "servo", "channel": 2, "target": "tau_n", "name": "a"}], "found 'a' on servo channel 1"),
    ([{"source": "servo", "channel": 1, "target": "tau_x"},
      {"source": "servo", "channel": 1, "target": "tau_n", "pwm_trim": 1520.0}], "(trim, span)"),
])
def test_inconsistent_actuator_maps_are_refused_with_what_was_found(maps, found):
    with pytest.raises(ConfigError, match="expected one") as err:
        parse_vessel({"name": "b", "actuators": maps})
    assert found in str(err.value)


def test_actuator_signals_are_recovered_from_the_logged_forces(tmp_path):
    path, t1, t2 = twin_log(tmp_path / "twin.csv", minutes=2.0, lo=-8.0)
    trial = load_trial([path], twin_vessel(reverse=6.0))
    space = actuator_space(trial, twin_vessel(reverse=6.0))
    assert space.used and "thruster_port" in space.note
    # Astern (negative) commands with the astern gain: the logged forces were made with 12 N both
    # ways, so the signals recovered with a 6 N astern scale are twice as large below zero.
    a = space.signals["thruster_port"]
    want = np.where(t1 >= 0, t1 / 12.0, t1 / 6.0)
    assert np.allclose(a, want, atol=1e-6)
    assert np.allclose(actuator_space(trial, twin_vessel()).signals["thruster_stbd"], t2 / 12.0, atol=1e-6)
    # Without the yaw moment logged the two thrusters cannot be told apart: the note says so.
    only_x = load_trial([path], None)
    only_x = type(only_x)(**{**only_x.__dict__, "data": only_x.data.drop(columns=["tau_n"])})
    none = actuator_space(only_x, twin_vessel())
    assert not none.used and "does not log tau_n" in none.note


def test_one_thrusters_delay_and_rate_limit_are_fitted_on_that_thruster(tmp_path):
    path, _, _ = twin_log(tmp_path / "twin.csv", port_lag=0.6)
    vessel = twin_vessel()
    trial = load_trial([path], vessel)
    probs = {p.dof: p for p in build_problems(trial, diagnose_segments(trial), vessel)}
    yaw = probs["yaw"]
    assert [a.name for a in yaw.actuators] == ["thruster_port", "thruster_stbd"]
    labels = [candidate_label(c) for c in candidates_for(yaw, grid_data(yaw))]
    # The rate limit and asymmetry act on the thrusters, not on tau_n (no candidate names tau_n).
    assert "actuator_delay[thruster_port]" in labels and "actuator_rate_limit[thruster_stbd]" in labels
    assert not any("tau_n" in lab for lab in labels), labels
    every = np.arange(len(yaw.windows))
    d = grid_data(yaw)
    port = ActuatorDelay(yaw, d, yaw.actuators[0]).fit(every)
    both = ActuatorDelay(yaw, d).fit(every)
    assert abs(port.params["tau_d"] - 0.6) < 0.1, port.params
    # Delaying both thrusters fits the one late thruster worse.
    assert port.sse < 0.5 * both.sse
    # A rate limit of the port thruster is the port thruster's signal slewing [1/s of full scale].
    slow = load_trial([twin_log(tmp_path / "slow.csv", port_rate=1.2)[0]], vessel)
    ps = {p.dof: p for p in build_problems(slow, diagnose_segments(slow), vessel)}["surge"]
    fit = ActuatorRateLimit(ps, grid_data(ps), "", ps.actuators[0]).fit(np.arange(len(ps.windows)))
    assert abs(fit.params["R"] - 1.2 / FULL) < 0.2 * 1.2 / FULL, fit.params
    # Thrust asymmetry of one thruster needs that thruster working both ahead and astern.
    assert not ThrustAsymmetry(ps, grid_data(ps), "", ps.actuators[0]).applicable()


def _verdict(tmp_path, vessel, **kw):
    path, _, _ = twin_log(tmp_path / "twin.csv", **kw)
    return diagnose(load_trial([path], vessel), vessel)


def test_a_late_port_thruster_is_named(tmp_path):
    rep = _verdict(tmp_path, twin_vessel(), port_lag=0.6)
    assert rep.effects, rep.notes
    first = rep.effects[0]
    assert first.label == "actuator_delay[thruster_port]" and first.input_channel == "thruster_port", first
    tau = next(q for q in first.params if q.name == "tau_d")
    assert abs(tau.value - 0.6) < max(3 * tau.stderr, 0.1), tau
    assert any(n.startswith("actuator space:") for n in rep.notes)


@pytest.mark.slow  # two whole diagnoses, 10-20 s of CPU
def test_a_rate_limited_port_thruster_is_named_and_a_clean_twin_stays_null(tmp_path):
    rep = _verdict(tmp_path, twin_vessel(), port_rate=1.0)
    assert rep.effects and rep.effects[0].label == "actuator_rate_limit[thruster_port]", \
        [(e.label, e.dof, e.shrink) for e in rep.effects]
    clean = _verdict(tmp_path, twin_vessel(), seed=3)
    assert not clean.effects, [(e.label, e.dof, e.shrink) for e in clean.effects]


def test_a_weaker_port_thruster_is_a_thrust_imbalance(tmp_path):
    rep = _verdict(tmp_path, twin_vessel(), port_gain=0.7)
    assert rep.effects, rep.notes
    first = rep.effects[0]
    assert first.label == "thrust_imbalance[thruster_port/thruster_stbd]", [(e.label, e.dof) for e in rep.effects]
    ratio = next(q for q in first.params if q.name == "ratio")
    assert abs(ratio.value - 0.7) < max(3 * ratio.stderr, 0.03), ratio


def test_thrust_imbalance_needs_thrusters_driven_differently(tmp_path):
    vessel = twin_vessel()
    for alike, expected in ((False, True), (True, False)):
        trial = load_trial([twin_log(tmp_path / f"twin_{alike}.csv", alike=alike)[0]], vessel)
        surge = {p.dof: p for p in build_problems(trial, diagnose_segments(trial), vessel)}["surge"]
        labels = [candidate_label(c) for c in candidates_for(surge, grid_data(surge))]
        assert ("thrust_imbalance[thruster_port/thruster_stbd]" in labels) == expected, labels
