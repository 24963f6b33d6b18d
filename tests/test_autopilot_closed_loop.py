"""Closed-loop check: the seed's two problems (steady error from current, rudder chasing waves),
measured, and their removal by bias feed-forward and Kalman wave filtering, measured."""

import math
import time

import numpy as np
import pytest

from pipeline.autopilot.closed_loop import CASES, closed_loop_check, default_scenarios, simulate_heading_loop
from pipeline.autopilot.config import build_autopilot_config
from pipeline.errors import AutopilotError
from pipeline.records import Scenario

K_SEED, T_SEED = 0.1561, 72.4385
D = math.degrees


@pytest.fixture(scope="module")
def config():
    return build_autopilot_config(K_SEED, T_SEED)


@pytest.fixture(scope="module")
def check(config):
    return closed_loop_check(config)


def test_each_simulation_is_fast(config):
    # CPU time, not wall time: the test machine may be shared.
    sea = default_scenarios(config)[1]
    t0 = time.process_time()
    simulate_heading_loop(config, sea, "pd_kalman_ff")
    assert time.process_time() - t0 < 3.0


def test_the_gains_are_those_of_the_filter_run_step_by_step(config):
    from pipeline.autopilot.closed_loop import kalman_gains
    from pipeline.autopilot.kalman import kalman_predict, kalman_update

    km = config.kalman
    gains = kalman_gains(km, 300)
    assert kalman_gains(km, 300) is gains  # computed once per filter
    rng = np.random.default_rng(0)
    x, p = km.x0.copy(), km.p0.copy()
    for k in range(300):
        x_post, p_post, gain = kalman_update(km, x, p, float(rng.normal(0.0, 0.3)))
        assert np.array_equal(gain, gains[k]), k
        x, p = kalman_predict(km, x_post, p_post, float(rng.normal(0.0, 0.1)))


def test_current_gives_steady_error_without_bias_feed_forward(check, config):
    pd = check.run("sea", "pd").metrics
    filt = check.run("sea", "pd_kalman").metrics
    ff = check.run("sea", "pd_kalman_ff").metrics
    sea = check.scenarios[1]
    assert D(pd.steady_error) > 2.0  # the seed saw about 4 deg
    assert D(filt.steady_error) > 2.0  # wave filtering alone does not remove it
    # a PD on an integrating plant settles where K_pd e = b
    assert pd.steady_error == pytest.approx(sea.current_bias / config.pd.kpd, rel=0.2)
    assert abs(D(ff.steady_error)) < 0.5
    assert math.isnan(pd.settling_time) and math.isfinite(ff.settling_time)
    assert ff.bias_estimate == pytest.approx(sea.current_bias, abs=math.radians(0.3))


def test_waves_make_the_rudder_swing_without_wave_filtering(check):
    pd = check.run("sea", "pd").metrics
    filt = check.run("sea", "pd_kalman").metrics
    ff = check.run("sea", "pd_kalman_ff").metrics
    # The seed's simulator had no rate limit and saw 40 deg within 5 s; our command does the same
    # kind of thing, and the rate-limited rudder spends most of its time at the limit.
    assert D(pd.max_swing_cmd) > 20.0
    assert pd.rate_limited > 0.5
    assert pd.max_swing > 10 * filt.max_swing
    assert pd.max_swing > 10 * ff.max_swing
    assert pd.rms_rudder_rate > 5 * filt.rms_rudder_rate
    assert filt.rate_limited < 0.05
    # because the filter's heading is far closer to the true heading than the compass is
    assert filt.heading_estimate_rms < 0.2 * filt.compass_error_rms


def test_identified_model_in_calm_water_settles(check):
    for case in CASES:
        m = check.run("model", case).metrics
        assert abs(D(m.steady_error)) < 0.1
        assert 50.0 < m.settling_time < 300.0  # crossover 0.1 rad/s
        assert D(m.max_swing) < 0.1


def test_no_limit_cycle_in_the_standard_scenarios(check):
    assert not any(r.metrics.limit_cycle for r in check.runs)


def test_rudder_limits_hold(check, config):
    for run in check.runs:
        assert np.max(np.abs(run.delta)) <= config.rudder_max_angle + 1e-12
        assert np.max(np.abs(np.diff(run.delta))) <= config.rudder_max_rate * config.ts * (1 + 1e-9)


def test_same_seed_same_sea(config):
    sea = default_scenarios(config)[1]
    a = simulate_heading_loop(config, sea, "pd")
    b = simulate_heading_loop(config, sea, "pd_kalman")
    np.testing.assert_array_equal(a.psi_w, b.psi_w)  # the cases see the same waves
    c = simulate_heading_loop(config, sea, "pd")
    np.testing.assert_array_equal(a.delta, c.delta)


def test_truth_differing_from_the_identified_model(config):
    # The simulator's ship is 10 % faster than identified; the bias state absorbs the mismatch.
    scen = default_scenarios(config, plant_K=K_SEED * 1.1, plant_T=T_SEED / 1.1)
    run = simulate_heading_loop(config, scen[1], "pd_kalman_ff")
    assert abs(D(run.metrics.steady_error)) < 0.5
    assert not run.metrics.limit_cycle


def test_limit_cycle_is_detected_and_a_faster_rudder_removes_it(config):
    # Measured limitation: a ship 15 % faster than identified, a 30 deg step and the SOLAS-minimum
    # rudder rate (2.32 deg/s) drive the Kalman loop into a limit cycle that PD alone escapes; the
    # check must say so rather than report a steady error.
    scen = default_scenarios(config, plant_K=K_SEED * 1.15, plant_T=T_SEED / 1.15)[1]
    calm = Scenario(name="fast", K=scen.K, T=scen.T, duration=600.0)
    assert simulate_heading_loop(config, calm, "pd_kalman_ff").metrics.limit_cycle
    assert not simulate_heading_loop(config, calm, "pd").metrics.limit_cycle
    quick = build_autopilot_config(K_SEED, T_SEED, rudder={"max_rate": math.radians(5.0)})
    assert not simulate_heading_loop(quick, calm, "pd_kalman_ff").metrics.limit_cycle


def test_metrics_dict_is_in_degrees(check):
    d = check.to_dict()
    assert set(d) == {"model", "sea"}
    m = d["sea"]["cases"]["pd"]
    assert m["steady_error_deg"] == pytest.approx(D(check.run("sea", "pd").metrics.steady_error))
    assert m["settling_time_s"] is None  # never settled: said, not hidden


def test_bad_cases(config):
    sea = default_scenarios(config)[1]
    with pytest.raises(AutopilotError, match="expected one of"):
        simulate_heading_loop(config, sea, "pid")
    with pytest.raises(AutopilotError, match="duration"):
        simulate_heading_loop(config, Scenario(name="x", K=0.1, T=50.0, duration=0.5), "pd")
    with pytest.raises(AutopilotError, match="K > 0"):
        simulate_heading_loop(config, Scenario(name="x", K=-0.1, T=50.0), "pd")
    with pytest.raises(KeyError, match="no run"):
        closed_loop_check(config, (Scenario(name="x", K=0.1, T=50.0, duration=30.0),)).run("sea", "pd")
