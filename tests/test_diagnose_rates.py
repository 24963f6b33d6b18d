"""Clean data logged slowly gives no verdict: the analysis grid compares like with like.

At one analysis step per logged sample (1 Hz logs, or a fast DOF at 10 Hz) the model's exact
block means over ``[t_k, t_k + dt)`` must be compared with the measurement's mean over the same
interval (a trapezoid of the point samples at both ends), not with the point sample at ``t_k``:
that is half a sample of lag, which the delay and rate-limit candidates would "explain". And the
noise of such means is coloured (neighbouring blocks share an end sample), which the wave
candidate must not take for a wave.
"""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.diagnose import diagnose
from pipeline.diagnose.problem import Window, block_average, block_noise
from diagnose_synthetic import simulated_trial
from pipeline.diagnose.waves import fit_residual_spectrum
from pipeline.sim import Effects, sea_trial
from pipeline.vessel import parse_vessel


def test_one_sample_block_mean_is_the_interval_mean():
    # A point-sampled ramp x(t) = t at 1 Hz: the mean over [k, k + 1) is k + 1/2.
    x = np.arange(20.0)
    w = (Window(0, 20, 0.0, 19.0, ("step",)),)
    got = block_average(x, w, 1, 20, trapezoid=True)[0]
    assert np.allclose(got[:19], np.arange(19) + 0.5)


def test_start_value_at_a_slow_rate_is_not_a_line_across_a_switch():
    # A first-order response (T = 4 s) logged at 1 Hz whose input switches one sample before a
    # window starts: five samples through the switch miss the start value; the span stays under
    # a tenth of T, here the start sample itself.
    from pipeline.diagnose.gridfit import START_SPAN_T
    from pipeline.diagnose.problem import initial_values

    t = np.arange(40.0)
    x = np.where(t < 20, 1 - np.exp(-t / 4.0), 0.0)
    x[20:] = x[19] * np.exp(-(t[20:] - 19) / 4.0) - 1 + np.exp(-(t[20:] - 19) / 4.0)
    w = (Window(21, 40, 21.0, 39.0, ("zigzag",)),)
    assert int(START_SPAN_T * 4.0 * 1.0) == 0
    assert initial_values(x, w, 0)[0] == pytest.approx(x[21])
    assert abs(initial_values(x, w, 2)[0] - x[21]) > 0.05


def test_trapezoid_block_noise_is_that_of_the_trapezoid():
    rng = np.random.default_rng(0)
    x = rng.normal(0.0, 1.0, 40000)
    w = (Window(0, len(x), 0.0, len(x) - 1.0, ("step",)),)
    for m in (1, 4):
        means = block_average(x, w, m, len(x) // m, trapezoid=True)[0]
        measured = float(np.nanstd(means))
        assert abs(block_noise(x, w, m, trapezoid=True) / measured - 1) < 0.05
        assert abs(measured - np.sqrt((m - 0.5) / m**2)) < 0.02


def test_coloured_noise_is_no_wave():
    # Trapezoid means of white noise at one sample per step: lag-1 correlation 1/2, a spectrum
    # falling to zero at Nyquist. No wave in it.
    rng = np.random.default_rng(1)
    rows = []
    for _ in range(12):
        e = rng.normal(0.0, 1.0, 201)
        rows.append(0.5 * (e[:-1] + e[1:]))
    spec = fit_residual_spectrum(np.array(rows), 0.5, (0.5, 0.8 * np.pi / 0.5))
    assert spec.sigma == 0.0 or not np.isfinite(spec.omega0)


@pytest.mark.parametrize("rate, t_const", [(1.0, 5.0), (10.0, 0.5)])
def test_clean_slow_log_gives_no_verdict(tmp_path, rate, t_const):
    # One analysis step per logged sample (T / 20 is below the log's step), commands held.
    ship = parse_vessel({"name": "small", "nomoto": {"K": 0.5, "T": t_const}})
    trial, _ = simulated_trial(ship, sea_trial(ship), Effects(), tmp_path, f"clean_{rate:g}", seed=4, noise="low",
                               dt=min(0.05, t_const / 100), rate=rate)
    rep = diagnose(trial, ship)
    top = [(c.label, c.dof, round(c.shrink, 1), c.p_value) for c in rep.candidates[:3]]
    assert rep.effect is None, top
    assert not any(c.significant for c in rep.candidates), top


def test_true_delay_at_one_hertz_is_still_named(tmp_path):
    ship = parse_vessel({"name": "small", "nomoto": {"K": 0.5, "T": 5.0}})
    trial, _ = simulated_trial(ship, sea_trial(ship), Effects(actuator_delay=1.5), tmp_path, "delay_1hz", seed=4,
                               dt=0.05, rate=1.0)
    rep = diagnose(trial, ship)
    assert (rep.effect, rep.dof) == ("actuator_delay", "yaw")
    tau = {p.name: p for p in rep.verdict.params}["tau_d"]
    assert abs(tau.value - 1.5) < 0.3


@pytest.mark.slow
def test_parallel_dofs_give_the_same_report(tmp_path):
    # Surge and yaw of a boat whose two DOFs are cross-validated in two processes.
    from pipeline.sim.manoeuvres import chain, rudder_step, step_and_coast
    from conftest import AAUSHIP

    d = np.diag(AAUSHIP.damping)
    sched = chain(step_and_coast("surge", float(d[0]), 20.0, 20.0),
                  rudder_step(np.radians(10), 20.0, 20.0, {"tau_x": float(d[0])}), rest_s=10.0)
    trial, _ = simulated_trial(AAUSHIP, sched, Effects(actuator_delay=0.3), tmp_path, "par", seed=2, rate=20.0)
    one = diagnose(trial, AAUSHIP, jobs=1)
    two = diagnose(trial, AAUSHIP, jobs=2)
    assert len({c.dof for c in one.candidates}) >= 2
    assert [(c.label, c.dof, c.shrink) for c in one.candidates] == [(c.label, c.dof, c.shrink) for c in two.candidates]
    assert (one.effect, one.dof) == (two.effect, two.dof)


def _gyro_biased(trial, bias):
    from dataclasses import replace

    data = trial.data.copy()
    data["r"] = data["r"] + bias
    return replace(trial, data=data)


@pytest.mark.slow  # 11-16 s on an idle core: run by make test-ci (make test stays under 5 min)
def test_gyro_bias_is_a_sensor_bias_not_a_moment(tmp_path):
    # The gyro reads r + 0.01 rad/s; the compass sees the true heading. A yaw moment would turn
    # the boat, so the compass tells the two apart.
    ship = parse_vessel({"name": "small", "nomoto": {"K": 0.5, "T": 5.0}})
    trial, _ = simulated_trial(ship, sea_trial(ship), Effects(), tmp_path, "gyro_bias", seed=4, dt=0.05, rate=10.0)
    rep = diagnose(_gyro_biased(trial, 0.01), ship)
    top = [(c.label, c.dof, round(c.shrink, 1), c.p_value) for c in rep.candidates[:3]]
    assert (rep.effect, rep.dof) == ("sensor_bias", "yaw"), top
    b = {p.name: p for p in rep.verdict.params}["b_sensor"]
    assert abs(b.value - 0.01) < 3 * max(b.stderr, 5e-4), b
    clean = diagnose(trial, ship)
    assert clean.effect is None, [(c.label, c.dof, round(c.shrink, 1)) for c in clean.candidates[:3]]
