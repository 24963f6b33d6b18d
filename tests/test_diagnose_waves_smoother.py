"""The waves candidate's smoother and its likelihood test (issue 12, randomised seeds 28, 34 and 27).

- The smoother returns the whole wave, also near the window ends: the FFT smoother before it took
  a line through each window's end samples off and never returned it, so the wave's value at both
  ends stayed in the residual (a quarter of its RMS on seed 34 r006, which then read "unexplained").
- A residual without waves gets no wave: a peak of the autoregressive spectrum that passes the
  peak test is kept only when the smoother's model with the wave is likelier than without it by
  the chi-square test; before, the residual's own colour at one trial sample per analysis step
  fitted as a broad wave and the smoother removed part of the sensor noise with it (seed 28 r006,
  a clean twin named ``waves``).

Every trial here is simulated, written as canonical CSV, read back and diagnosed.
"""

from __future__ import annotations

import numpy as np

from diagnose_synthetic import simulated_trial, waves_with_sigma
from pipeline.diagnose import diagnose
from pipeline.diagnose.waves import fit_residual_spectrum, refine_background, smooth_waves
from pipeline.model.waves import simulate_waves
from pipeline.sim import Effects, sea_trial
from pipeline.vessel import parse_vessel


def _demeaned(x: np.ndarray) -> np.ndarray:
    # A heading's per-window offset is projected out of every window: it is no part of the gap.
    return x - x.mean(axis=1, keepdims=True)


def test_the_smoother_returns_the_wave_up_to_the_window_ends():
    rng = np.random.default_rng(5)
    dt, n, rows, sigma = 0.25, 60, 24, 0.05
    # Windows of 15 s (five wave periods), each with its own drift line and 0.002 rad white noise.
    wave = simulate_waves(np.arange(n * rows) * dt, waves_with_sigma(1.5, 0.1, sigma), rng).reshape(rows, n)
    t = np.arange(n) * dt
    drift = rng.normal(0, 0.01, (rows, 1)) + rng.normal(0, 0.002, (rows, 1)) * t[None, :]
    resid = wave + drift + 0.002 * rng.standard_normal((rows, n))
    spec = refine_background(resid, dt, fit_residual_spectrum(resid, dt, (0.3, 0.8 * np.pi / dt)), 0.002, 1)
    assert abs(spec.omega0 - 1.5) < 0.15
    err = np.sqrt(np.mean(_demeaned(smooth_waves(resid, dt, spec) - wave) ** 2))
    # The FFT smoother left 0.017 rad (38 % of the wave's RMS); this one 0.004.
    assert err < 0.15 * np.sqrt(np.mean(_demeaned(wave) ** 2))


def test_strong_waves_leave_no_unexplained_heading(tmp_path):
    ship = parse_vessel({"name": "small", "nomoto": {"K": 0.3, "T": 6.0}})
    eff = Effects(waves=waves_with_sigma(1.5, 0.1, np.radians(3.3)))
    trial, _ = simulated_trial(ship, sea_trial(ship), eff, tmp_path, "waves", seed=1, dt=0.05, rate=10.0)
    rep = diagnose(trial, ship)
    assert (rep.effect, rep.dof) == ("waves", "yaw")
    # Before: 58 % with the heading "unexplained" at 1.9 noise units (the wave left at the window ends).
    assert rep.verdict.shrink > 75
    assert not [u for u in rep.unexplained if u.channel == "psi"], rep.unexplained


def test_a_clean_fast_ship_gets_no_wave(tmp_path):
    # T = 1 s logged at 10 Hz: one trial sample per analysis step, the trapezoidal block means are
    # two-sample averages (lag-1 correlation 1/2).
    ship = parse_vessel({"name": "fast", "nomoto": {"K": 0.5, "T": 1.0}})
    trial, _ = simulated_trial(ship, sea_trial(ship), Effects(), tmp_path, "clean", seed=2, dt=0.01, rate=10.0,
                               noise="low")
    rep = diagnose(trial, ship)
    waves = [c for c in rep.candidates if c.effect == "waves"]
    assert waves
    # Before: the waves candidate took 17.2 % of the yaw gap (p = 3e-15) from a clean trial.
    assert all(c.shrink < 2.0 and not c.significant for c in waves), [(c.dof, c.shrink, c.p_value) for c in waves]
    assert rep.effect is None


def test_the_smoother_models_the_noise_of_the_grid_s_own_blocks(tmp_path):
    # The waves of the test above at 20 Hz: the yaw DOF's analysis step (T / 20 = 0.3 s) averages
    # six samples, whose trapezoidal means have lag-1 correlation 1/22, not the 1/2 of one sample.
    from pipeline.diagnose import verdict
    from pipeline.diagnose.candidates import Waves
    from pipeline.diagnose.gridfit import grid_data
    from pipeline.diagnose.problem import build_problems
    from pipeline.diagnose.segments import diagnose_segments

    ship = parse_vessel({"name": "small", "nomoto": {"K": 0.3, "T": 6.0}})
    eff = Effects(waves=waves_with_sigma(1.5, 0.1, np.radians(3.3)))
    trial, _ = simulated_trial(ship, sea_trial(ship), eff, tmp_path, "waves20", seed=1, dt=0.05, rate=20.0)
    segs = diagnose_segments(trial, None)
    tc = verdict._refine_time_constants(trial, segs, ship)
    p = next(q for q in build_problems(trial, segs, ship, time_constants=tc) if q.dof == "yaw")
    d = grid_data(p)
    assert d.m > 1
    _, specs = Waves(p, d).fit(np.arange(len(p.windows))).state
    assert specs["angle"].sigma > 0 and specs["angle"].m == d.m
