"""The noise floor of a channel whose noise is smooth over several trial samples.

Body velocities derived from a 5 Hz GNSS in a 50 Hz trial (or any sensor interpolated or held to
the trial rate) have noise that is a straight line between the sensor's own samples: the quarter
contrast at the analysis block's scale cancels it, and a floor measured there is many times too
low, which made clean GNSS-only trials report an "unexplained" gap of 9-25 noise units. The floor
is now measured at the noise's own correlation scale (:func:`pipeline.diagnose.problem.noise_scale`).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from pipeline.diagnose import diagnose
from pipeline.diagnose.problem import Window, block_average, block_noise, noise_scale
from pipeline.flow import load_trial


def _interpolated_noise(n: int, every: int, sigma: float, rng: np.random.Generator) -> np.ndarray:
    nodes = rng.normal(0.0, sigma, n // every + 2)
    return np.interp(np.arange(n), np.arange(len(nodes)) * every + int(rng.integers(every)), nodes)


def test_white_noise_keeps_the_white_floor():
    rng = np.random.default_rng(3)
    n = 40000
    x = rng.normal(0.0, 0.01, n) + 0.3 * np.sin(np.arange(n) / 500.0)
    w = (Window(0, n, 0.0, n - 1.0, ("step",)),)
    assert not np.isfinite(noise_scale(x, w)[0])
    for m in (1, 3, 11):
        measured = float(np.nanstd(block_average(x - 0.3 * np.sin(np.arange(n) / 500.0), w, m, n // m,
                                                 trapezoid=True)[0]))
        assert block_noise(x, w, m, trapezoid=True) == pytest.approx(measured, rel=0.1)


@pytest.mark.parametrize("every", [3, 10, 25])
@pytest.mark.parametrize("m", [1, 2, 11])
def test_interpolated_noise_floor_is_that_of_the_block_means(every, m):
    rng = np.random.default_rng(every * 100 + m)
    n = 60000
    slow = 0.5 * np.sin(2 * np.pi * np.arange(n) / 3000.0)
    e = _interpolated_noise(n, every, 0.02, rng)
    w = (Window(0, n, 0.0, n - 1.0, ("step",)),)
    measured = float(np.nanstd(block_average(e, w, m, n // m, trapezoid=True)[0]))
    got = block_noise(e + slow, w, m, trapezoid=True)
    # Before: the contrast at the block's own scale saw straight pieces, 0.01-0.2 of the truth.
    assert 0.75 < got / measured < 1.3


def test_clean_surge_from_interpolated_gnss_speed_is_explained(tmp_path):
    # A first-order boat (T = 4 s) driven by thrust steps, logged at 50 Hz; its only speed sensor
    # is a 5 Hz GNSS whose speed the logger interpolates to 50 Hz. Clean: no verdict and nothing
    # unexplained (before: "unexplained" surge gap of about 20 noise units).
    rng = np.random.default_rng(8)
    fs, n = 50.0, int(50.0 * 600)
    t = np.arange(n) / fs
    hold = int(25 * fs)
    tau = np.repeat(rng.uniform(5, 40, n // hold + 1), hold)[:n]
    u = np.zeros(n)
    for k in range(n - 1):
        u[k + 1] = u[k] + (-u[k] + 0.05 * tau[k]) / 4.0 / fs
    fix = np.arange(0, n, 10)
    sog = np.interp(np.arange(n), fix, u[fix] + rng.normal(0.0, 0.02, len(fix)))
    path = tmp_path / "gnss_speed.csv"
    pd.DataFrame({"t": t, "sog": sog, "tau_x": tau}).to_csv(path, index=False, float_format="%.9g")
    rep = diagnose(load_trial([path]))
    assert rep.effect is None
    assert not rep.unexplained
    surge = next(d for d in rep.dofs if d.dof == "surge")
    assert 0.6 < surge.gap < 1.6


def _heading_with_waves(n: int, sigma: float, rng: np.random.Generator) -> np.ndarray:
    # A heading wave of 0.05 rad at 4 log samples per period (a 1.5 rad/s sea logged at 1 Hz):
    # from the data alone it is as fast as the compass noise.
    phase = np.cumsum(rng.normal(2 * np.pi / 4, 0.05, n))
    return 0.05 * np.sin(phase) + rng.normal(0.0, sigma, n) + 0.3 * np.sin(np.arange(n) / 500.0)


@pytest.mark.parametrize("m", [1, 2])
def test_stated_compass_noise_keeps_waves_out_of_the_floor(m):
    rng = np.random.default_rng(12 + m)
    n = 20000
    x = _heading_with_waves(n, 0.002, rng)
    w = (Window(0, n, 0.0, n - 1.0, ("step",)),)
    white = 0.002 * np.sqrt((m - 0.5) / m) / np.sqrt(m)
    # From the data alone the wave is taken for noise: a floor ten times the compass'.
    assert block_noise(x, w, m, trapezoid=True) > 8 * white
    # Stated in the vessel config, the floor is the compass' own: its white block mean, or at most
    # one sample's noise when the wave makes the noise look held over a few samples.
    assert 0.99 * white <= block_noise(x, w, m, trapezoid=True, stated=0.002) <= 0.002 * 1.01


def test_a_sensor_better_than_stated_keeps_its_measured_floor():
    rng = np.random.default_rng(5)
    n = 20000
    x = rng.normal(0.0, 0.001, n) + 0.3 * np.sin(np.arange(n) / 500.0)
    w = (Window(0, n, 0.0, n - 1.0, ("step",)),)
    assert block_noise(x, w, 2, trapezoid=True, stated=0.01) == pytest.approx(
        block_noise(x, w, 2, trapezoid=True), rel=1e-12)


def test_interpolated_sensor_keeps_a_long_run_floor_when_noise_is_stated():
    rng = np.random.default_rng(6)
    n = 60000
    e = _interpolated_noise(n, 10, 0.02, rng)
    w = (Window(0, n, 0.0, n - 1.0, ("step",)),)
    measured = float(np.nanstd(block_average(e, w, 2, n // 2, trapezoid=True)[0]))
    # Stated per logged sample of the 5 Hz sensor: its interpolated block means are not 10 times
    # quieter than that.
    assert 0.7 < block_noise(e, w, 2, trapezoid=True, stated=0.02) / measured < 1.3


def test_stated_compass_noise_reaches_the_heading_floor_of_a_slow_log(tmp_path):
    # A Nomoto ship (T = 10 s) in 2 deg heading waves at 2 rad/s, logged at 2 Hz (6 samples per wave
    # period): from the data alone the heading's floor is the wave's; with the compass noise stated
    # in the vessel config it is the compass'.
    from dataclasses import replace

    from diagnose_synthetic import simulated_trial, waves_with_sigma
    from pipeline.diagnose.gridfit import grid_data
    from pipeline.diagnose.problem import build_problems
    from pipeline.diagnose.segments import diagnose_segments
    from pipeline.sim import Effects, sea_trial
    from pipeline.vessel import parse_vessel

    v = parse_vessel({"name": "ship", "nomoto": {"K": 0.2, "T": 10.0}})
    trial, _ = simulated_trial(v, sea_trial(v), Effects(waves=waves_with_sigma(2.0, 0.1, np.radians(2.0))),
                               tmp_path, "ship", noise="low", seed=4, dt=0.1, rate=2.0)
    segs = diagnose_segments(trial)
    compass = 0.002 * 0.3
    floors = {}
    for told in (False, True):
        vessel = replace(v, sensor_noise={"psi": compass}) if told else v
        p = next(q for q in build_problems(trial, segs, vessel) if q.dof == "yaw")
        floors[told] = grid_data(p).sigma_angle
        white = compass * np.sqrt((p.m - 0.5) / p.m) / np.sqrt(p.m)
    assert floors[False] > 10 * white
    assert 0.99 * white <= floors[True] <= 1.01 * compass
