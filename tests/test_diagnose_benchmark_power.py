"""The benchmark's power of a pair's missed effect (benchmarks/diagnose.py, ``power_off``,
``perfect_shrink``): the same trial diagnosed with that effect switched off (every draw, the sensor
noise among them, as in the trial) leaves what a perfect candidate of it could leave at best; where
that is within the significance rule's least shrink, the miss is below detection whatever the test."""

from __future__ import annotations

import pytest

from test_diagnose_benchmark_signature import _bench


def _miss(**extra):
    # Randomised seed 46 r005 (the twin at 3.6 Hz): a quadratic yaw damping (found) and a GNSS lag in
    # surge (missed). Measured on main: surge 1.374 noise units with the lag (unit 0.010956 m/s), 1.163
    # without it (unit 0.012338 m/s).
    r = {"kind": "pair", "effects": [{"effect": "nonlinear_damping", "dof": "yaw"},
                                     {"effect": "sensor_delay", "dof": "surge"}],
         "selected": [{"effect": "nonlinear_damping", "dof": "yaw", "shrink": 6.5}],
         "alone": [None, {"dof": "surge", "shrink": 1.67, "p": 3e-4, "significant": False}],
         "signature": [{"rms": 2.22}, {"rms": 0.35}],
         "channel_gaps": {"yaw": {"r": 1.31, "psi": 1.46}, "surge": {"sog": 1.374}},
         "floors": {"yaw": {"r": 1.21, "psi": 1.27}, "surge": {"sog": 1.159}},
         "dof_gaps": {"yaw": 1.39, "surge": 1.374}, "dof_gaps_after": {"yaw": 1.30},
         "dof_noise": {"yaw": 0.0021, "surge": 0.010956},
         "power": {"effect": 1, "dof_gaps": {"yaw": 1.39, "surge": 1.163}, "dof_gaps_after": {"yaw": 1.30},
                   "channel_gaps": {"yaw": {"r": 1.31, "psi": 1.46}, "surge": {"sog": 1.163}},
                   "dof_noise": {"yaw": 0.0021, "surge": 0.012338}, "selected": ["nonlinear_damping"]}}
    r.update(extra)
    return r


def test_perfect_shrink_compares_the_trial_without_the_effect_in_the_same_noise_unit():
    b = _bench()
    s, where = b.perfect_shrink(_miss())
    assert where == "surge/sog"
    # 1.163 x 0.012338 / 0.010956 = 1.310 noise units of the trial with the lag: 4.7 % of the gap, and
    # 1 - sqrt(1.310^2 - 1) / sqrt(1.374^2 - 1) = 10.2 % of the error above the noise.
    assert s == pytest.approx(10.2, abs=0.2)
    # Without the noise units the two trials' gaps would read as a 22 % shrink.
    r = _miss()
    del r["dof_noise"]
    assert b.perfect_shrink(r)[0] > 20.0
    assert b.perfect_shrink(_miss(power=None)) is None


def test_a_miss_whose_trial_without_it_leaves_the_same_gap_is_below_detection():
    b = _bench()
    r = _miss()
    r["power"] = {**r["power"], "channel_gaps": {"yaw": {"r": 1.31, "psi": 1.46}, "surge": {"sog": 1.36}},
                  "dof_noise": {"yaw": 0.0021, "surge": 0.010956}}
    assert b.miss_cause(r) == "pair, second: the trial without it leaves gaps less than 10 % smaller (below detection)"
    assert b.miss_cause(_miss()) == "pair, second: the trial without it leaves a gap 10 % smaller or more (an upper bound of power)"
    # A delay of every input (no DOF of its own) is judged where a perfect candidate would shrink most.
    r = _miss(effects=[{"effect": "nonlinear_damping", "dof": "yaw"}, {"effect": "actuator_delay", "dof": None}])
    assert b.perfect_shrink(r)[1] == "surge/sog"
    # The rule asks its shrink of one channel: randomised seed 42 r013 (AAUSHIP at 2.1 Hz, an N_v coupling
    # in yaw, missed; a surge rate limit, found). Without the coupling r reads 7.58 noise units against
    # 9.61 with it, psi 20.36 against 20.47: 3.9 % of the DOF's gap, 21 % of r's.
    r = _miss(effects=[{"effect": "coupling", "dof": "yaw"}, {"effect": "actuator_rate_limit", "dof": "surge"}],
              selected=[{"effect": "actuator_rate_limit", "dof": "surge", "shrink": 23.6}],
              channel_gaps={"yaw": {"r": 9.611, "psi": 20.473}, "surge": {"u": 6.296}},
              floors={"yaw": {"r": 7.99, "psi": 20.93}, "surge": {"u": 2.17}},
              dof_gaps={"yaw": 15.99, "surge": 6.296}, dof_gaps_after={"surge": 4.81}, dof_noise={"yaw": 0.01, "surge": 0.01})
    r["power"] = {"effect": 0, "dof_gaps": {"yaw": 15.36, "surge": 6.33}, "dof_gaps_after": {"surge": 4.84},
                  "channel_gaps": {"yaw": {"r": 7.578, "psi": 20.358}, "surge": {"u": 6.329}},
                  "dof_noise": {"yaw": 0.01, "surge": 0.01}, "selected": ["actuator_rate_limit[tau_x]"]}
    s, where = b.perfect_shrink(r)
    assert where == "yaw/r" and s == pytest.approx(21.2, abs=0.3)
    # Without a power record the causes are as before.
    assert b.miss_cause(_miss(power=None)) == "pair, second: at the floor (below detection)"


def test_a_framed_power_is_a_perfect_candidates_reach_not_an_upper_bound():
    # Measured on the frame of the trial with the effect (power_off's default, diag25) the comparison is of
    # the effect alone: at or above the rule's shrink the miss is within a perfect candidate's reach.
    b = _bench()
    r = _miss()
    r["power"] = {**r["power"], "framed": True, "dof_noise": {"yaw": 0.0021, "surge": 0.010956}}
    assert b.miss_cause(r) == ("pair, second: the trial without it on the same frame leaves a gap 10 % smaller "
                               "or more (within a perfect candidate's reach)")
    # Seed 46 r005 on the same frame: sog 1.351 against 1.374, below detection.
    r["power"]["channel_gaps"] = {"yaw": {"r": 1.31, "psi": 1.46}, "surge": {"sog": 1.351}}
    assert b.miss_cause(r) == ("pair, second: the trial without it on the same frame leaves gaps less than 10 % "
                               "smaller (below detection)")


@pytest.mark.slow
def test_power_off_diagnoses_the_same_trial_without_the_effect():
    # Slow (one twin trial made and diagnosed, about 30 s CPU). Randomised seed 46 r005: with the GNSS lag
    # (0.20 s at 3.6 Hz) surge's gap is 1.374 noise units; the same draws and noise without it, 1.163
    # (main efba945); the quadratic yaw damping is selected in both.
    b = _bench()
    case = b.random_cases(16, 46, ("pair",))[5]
    pw = b.power_off(case, 1, framed=False)
    assert pw["effect"] == 1 and not pw["framed"]
    assert pw["dof_gaps"]["surge"] == pytest.approx(1.163, abs=0.01)
    assert pw["dof_noise"]["surge"] == pytest.approx(0.01234, rel=0.01)
    assert pw["selected"] == ["nonlinear_damping"]
    # On the frame of the trial with the lag (diag25): its windows and its sog noise unit (0.010956 m/s);
    # without the lag sog reads 1.351 noise units against 1.374 with it, 3.6 % of the error above the noise.
    pw = b.power_off(case, 1)
    assert pw["framed"]
    assert pw["dof_noise"]["surge"] == pytest.approx(0.010956, rel=1e-3)
    assert pw["dof_gaps"]["surge"] == pytest.approx(1.351, abs=0.01)
    assert pw["selected"] == ["nonlinear_damping"]
