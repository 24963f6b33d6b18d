"""A delay and a rate limit of one input, told apart by how they are fitted (issue 12).

Both make a response late; a rate limit's lag grows with the step (a ramp lasting ``|du| / R``),
a delay's does not. The candidates must be fitted well enough for that to show: the rate limit
as the mean of its continuous ramp over each logged sample (a held staircase of the limiter at the
log rate is half a sample ahead and hides the lag of small steps), its value refined together with
the time constant (the two trade along a valley), and the log's own timing not chosen arbitrarily
where an effect dominates the misfit. The logs are integrated here (first-order surge, 50 Hz), not
made by the project's simulator.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from pipeline.diagnose.candidates import ActuatorDelay, ActuatorRateLimit, Candidate, rate_limit, rate_limit_means
from pipeline.diagnose.gridfit import grid_data
from pipeline.diagnose.problem import build_problems
from pipeline.diagnose.segments import diagnose_segments
from pipeline.diagnose.timing import ADVANCES, pinned_advance
from pipeline.flow import load_trial


def test_rate_limit_means_are_the_sample_means_of_the_continuous_ramp():
    u = np.array([0.0, 0.0, 4.0, 4.0, 4.0, 4.0, 0.5, 0.5, 0.5, 1.0, 1.0, 1.0])
    fs, rate, fine = 1.0, 3.0, 2000
    # The limiter integrated 2000 times finer, averaged over each logged sample.
    ref = rate_limit(np.repeat(u, fine), rate, fs * fine).reshape(-1, fine).mean(axis=1)
    np.testing.assert_allclose(rate_limit_means(u, rate, fs), ref, atol=2e-3)
    # The held staircase is half a sample ahead: 3.0 in the first sample where the ramp averages 1.5.
    assert rate_limit(u, rate, fs)[2] == 3.0 and abs(rate_limit_means(u, rate, fs)[2] - 1.5) < 1e-12
    # A step smaller than rate / fs still lags: its mean over the first sample is not the new level.
    assert rate_limit(u, rate, fs)[9] == 1.0 and abs(rate_limit_means(u, rate, fs)[9] - (1.0 - 0.5 * 0.5 / 6)) < 1e-12


def test_the_log_timing_is_applied_only_where_the_fit_pins_it():
    sharp = 1.0 + 0.5 * (ADVANCES - 0.3) ** 2
    assert abs(pinned_advance(sharp, n_eff=2000.0) - 0.3) < 1e-9
    # An effect dominates the misfit (randomised seed 22, r036: a rate limit, the sum of squares
    # 0.03 % lower at one sample than at none): the minimum is arbitrary, the inputs stay as logged.
    flat = 7.408 - 0.002 * ADVANCES
    assert pinned_advance(flat, n_eff=200.0) == 0.0
    assert pinned_advance(flat, n_eff=2e6) == 1.0


def _slewing_surge_log(path, seed=4, rate=0.6, t_surge=4.5, log_hz=7.0, minutes=12.0):
    """Thrust commands of 1-5 N held 15-25 s, the thruster slewing at ``rate`` [N/s]; surge
    ``t_surge u_dot = -u + 0.35 tau``, integrated at 50 Hz; logged at ``log_hz`` with each command
    switch on a log sample (an event log), speed with noise."""
    rng = np.random.default_rng(seed)
    fs = 50.0
    step = int(round(fs / log_hz))
    n = int(minutes * 60 * fs) // step * step
    hold = (rng.uniform(15, 25, 200) * fs).astype(int) // step * step
    edges = np.cumsum(hold)
    edges = edges[edges < n]
    levels = rng.uniform(1.0, 5.0, len(edges) + 1) * rng.choice([0.0, 1.0], len(edges) + 1, p=[0.3, 0.7])
    tau = np.repeat(levels, np.diff(np.concatenate([[0], edges, [n]])))
    act = rate_limit(tau, rate, fs)
    u = np.zeros(n)
    for k in range(n - 1):
        u[k + 1] = u[k] + (-u[k] + 0.35 * act[k]) / t_surge / fs
    sl = slice(0, n, step)
    t = np.arange(n) / fs
    pd.DataFrame({"t": t[sl], "u": u[sl] + rng.normal(0, 0.004, len(t[sl])), "tau_x": tau[sl]}).to_csv(path, index=False)
    return path


def test_a_rate_limit_is_found_at_its_rate_where_the_time_constant_trades_with_it(tmp_path):
    trial = load_trial([_slewing_surge_log(tmp_path / "surge.csv")], None)
    p = build_problems(trial, diagnose_segments(trial), None)[0]
    d = grid_data(p)
    every = np.arange(len(p.windows))
    base = Candidate(p, d).fit(every)
    limit = ActuatorRateLimit(p, d, "tau_x").fit(every, base)
    delay = ActuatorDelay(p, d).fit(every, base)
    assert abs(limit.params["R"] / 0.6 - 1.0) < 0.05, limit.params
    assert abs(limit.params["T"] / 4.5 - 1.0) < 0.05, limit.params
    # The rate limit fits far better than a delay: its lag grows with the step, a delay's does not.
    assert limit.sse < 0.5 * delay.sse, (limit.sse, delay.sse)


def _small_ship_log(path, seed=7, log_hz=2.0, gyro=0.012, compass=0.003, minutes=6.0):
    """A small Nomoto ship (T = 4 s, K = 0.3 1/s), rudder steps of +-10 deg held 20 s, integrated at
    50 Hz: the yaw rate stays within about 4 gyro noise units, the heading turns by a radian."""
    rng = np.random.default_rng(seed)
    fs, t_yaw, k_yaw = 50.0, 4.0, 0.3
    n = int(minutes * 60 * fs)
    seq = np.radians([0, 10, 0, -10, 0, 10, -10, 0, -10, 10, 0])
    hold = int(20 * fs)
    delta = np.repeat(np.resize(seq, n // hold + 1), hold)[:n]
    r, psi = np.zeros(n), np.zeros(n)
    for k in range(n - 1):
        r[k + 1] = r[k] + (-r[k] + k_yaw * delta[k]) / t_yaw / fs
        psi[k + 1] = psi[k] + r[k] / fs
    sl = slice(0, n, int(fs / log_hz))
    t = np.arange(n) / fs
    m = len(t[sl])
    pd.DataFrame({"t": t[sl], "r": r[sl] + rng.normal(0, gyro, m),
                  "psi": np.angle(np.exp(1j * (psi[sl] + rng.normal(0, compass, m)))),
                  "delta": delta[sl]}).to_csv(path, index=False)
    return path


def test_a_small_ship_whose_turns_the_compass_sees_is_analysed_and_clean_is_null(tmp_path):
    from pipeline.diagnose import diagnose

    from pipeline.diagnose.problem import _excursion, _merge_windows, _unwrap_nan
    from pipeline.segment import noise_std

    trial = load_trial([_small_ship_log(tmp_path / "ship.csv")], None)
    segs = diagnose_segments(trial)
    windows = _merge_windows(trial, segs.items)
    r, psi = trial.data["r"].to_numpy(float), _unwrap_nan(trial.data["psi"].to_numpy(float))
    # The gyro alone does not pass the excitation test (the yaw rate peaks at 0.052 rad/s); the compass does.
    assert _excursion(r, windows, noise_std(r), trial.fs) < 10
    assert _excursion(psi, windows, noise_std(psi), trial.fs) > 30
    assert [p.dof for p in build_problems(trial, segs, None)] == ["yaw"]
    rep = diagnose(trial)
    assert rep.effect is None and not rep.unexplained, [e.label for e in rep.effects]
